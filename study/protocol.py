"""A study's protocol (``protocol.json``) and folder layout.

``seesys study new DIR`` writes the protocol once: the conditions, the design, the phases, the participant ids
and each participant's condition (between-subjects) or order of conditions (within-subjects), drawn with a
seeded random generator so that the same seed gives the same assignment.

- **Between-subjects**: every condition gets the same number of participants; the list of condition slots is
  shuffled and dealt to P01, P02, ...
- **Within-subjects**: every participant does every condition, so N participants per condition are N participants;
  the orders are the rows of a balanced Latin square (Williams design: each condition equally often in each position
  and, for an even number of conditions, equally often right after each other one; for an odd number the square and
  its mirror image are used), dealt in turn and shuffled, so that every order is used equally often when N is a
  multiple of the number of orders (k for k conditions, 2k for an odd k).

Layout: ``DIR/protocol.json`` and ``DIR/participants/<id>/<phase>[-<condition>]/attempt-<n>/``, one attempt
folder per ``seesys study run`` (a device session folder plus the study's logs); the condition is part of the
phase folder's name in a within-subjects design only.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from advisory.conditions import LIVE_CONDITIONS
from seesys.core.errors import SeesysError
from seesys.io.logfiles import write_json_atomically
from study.config import ProtocolConfig

PROTOCOL_JSON = "protocol.json"
PARTICIPANTS = "participants"
DESIGNS = ("between", "within")


class ProtocolError(SeesysError):
    """The study folder or its protocol is missing, malformed, or asked for something it does not have."""


@dataclass(frozen=True)
class Participant:
    id: str
    conditions: list[str]  # one for between-subjects; the order for within-subjects


@dataclass(frozen=True)
class Protocol:
    design: str
    conditions: list[str]
    phases: list[str]
    objects: int
    assignment_seed: int
    participants: list[Participant]

    @property
    def analysed_phase(self) -> str:
        """The phase the metrics and the analysis use: the last one (the task)."""
        return self.phases[-1]

    def participant(self, participant_id: str) -> Participant:
        for p in self.participants:
            if p.id == participant_id:
                return p
        raise ProtocolError(
            f"no participant {participant_id!r} in the protocol ({', '.join(p.id for p in self.participants)})"
        )

    def phase_folder(self, study: Path, participant_id: str, phase: str, condition: str) -> Path:
        name = phase if self.design == "between" else f"{phase}-{condition}"
        return Path(study) / PARTICIPANTS / participant_id / name


def williams_orders(k: int) -> list[list[int]]:
    """The rows of a balanced Latin square for ``k`` conditions (and its mirror for odd ``k``)."""
    first = [0]
    low, high = 1, k - 1
    for position in range(1, k):
        if position % 2:
            first.append(low)
            low += 1
        else:
            first.append(high)
            high -= 1
    rows = [[(c + shift) % k for c in first] for shift in range(k)]
    return rows + [row[::-1] for row in rows] if k % 2 else rows


def make_protocol(
    cfg: ProtocolConfig,
    participants_per_condition: int | None = None,
    design: str | None = None,
    seed: int | None = None,
    conditions: list[str] | None = None,
    known: Sequence[str] = LIVE_CONDITIONS,
) -> Protocol:
    """Draw the assignment (see the module docstring); arguments override ``configs/study.toml``. ``known``: the
    conditions a study may have (a study with people: those a live advisory runs)."""
    design = design or cfg.design
    conditions = list(conditions or cfg.conditions)
    per = cfg.participants_per_condition if participants_per_condition is None else participants_per_condition
    if per < 1:
        # 0 would silently mean the configured number, and a negative one a study of nobody.
        raise ProtocolError(f"participants per condition must be at least 1, got {per}")
    seed = cfg.assignment_seed if seed is None else seed
    if design not in DESIGNS:
        raise ProtocolError(f"unknown design {design!r} (one of {', '.join(DESIGNS)})")
    unknown = [c for c in conditions if c not in known]
    if unknown or len(set(conditions)) != len(conditions) or len(conditions) < 2:
        raise ProtocolError(f"conditions must be two or more distinct of {', '.join(known)}, got {conditions}")
    rng = np.random.default_rng(seed)
    if design == "between":
        slots = [c for c in conditions for _ in range(per)]
        assigned = [[slots[i]] for i in rng.permutation(len(slots))]
    else:
        # Every participant does every condition: N per condition is N participants.
        orders = williams_orders(len(conditions))
        count = per
        dealt = [orders[i % len(orders)] for i in range(count)]
        assigned = [[conditions[c] for c in dealt[i]] for i in rng.permutation(count)]
    width = len(str(len(assigned)))
    people = [Participant(f"{cfg.participant_prefix}{i + 1:0{max(width, 2)}d}", a) for i, a in enumerate(assigned)]
    return Protocol(design, conditions, list(cfg.phases), cfg.objects, seed, people)


def write_protocol(study: Path, protocol: Protocol) -> Path:
    """Create the study folder with its protocol; an existing protocol is never replaced."""
    study = Path(study)
    path = study / PROTOCOL_JSON
    if path.exists():
        raise ProtocolError(f"{path} exists: a study's assignment is drawn once (start a new folder)")
    (study / PARTICIPANTS).mkdir(parents=True, exist_ok=True)
    write_json_atomically(path, asdict(protocol))
    return path


def read_protocol(study: Path) -> Protocol:
    path = Path(study) / PROTOCOL_JSON
    try:
        data = json.loads(path.read_text())
        data["participants"] = [Participant(**p) for p in data["participants"]]
        return Protocol(**data)
    except FileNotFoundError:
        raise ProtocolError(
            f"{study} is not a study folder (no {PROTOCOL_JSON}; create one with `seesys study new`)"
        ) from None
    except (ValueError, TypeError, KeyError) as e:
        raise ProtocolError(f"{path}: malformed protocol ({e})") from None
