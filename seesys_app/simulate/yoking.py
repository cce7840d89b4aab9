"""The ``yoked`` condition's partner and recording: whose ``seesys`` pulses a yoked session plays.

Participant k of a study is yoked to the next participant in the protocol's order (the last to the first), so the
pulses come from another simulated operator's session: the same amount and rhythm of sound as SEESys gave someone,
unrelated to this session's error. The recording is the partner's ``seesys`` buffers of ``advisory.csv``, their
times taken from the start of the partner's advisory (``advice_start`` of its ``run.json``).
"""

from __future__ import annotations

from pathlib import Path

from advisory.advice import RecordedBuffer
from seesys.core.errors import SeesysError
from seesys.core.session_layout import ADVISORY_CSV
from seesys.io.logfiles import read_csv_log
from study.protocol import Protocol
from study.sessions import advice_start, done_attempts

#: The condition a yoked session replays.
YOKED_TO = "seesys"


def partner_of(protocol: Protocol, participant_id: str) -> str:
    """The participant whose ``seesys`` session ``participant_id``'s yoked session plays; :class:`SeesysError` for a
    study of one participant (no one to be yoked to)."""
    ids = [p.id for p in protocol.participants]
    if len(ids) < 2:
        raise SeesysError("a yoked condition needs at least two participants: each plays another one's pulses")
    return ids[(ids.index(participant_id) + 1) % len(ids)]


def partner_folder(study: Path, protocol: Protocol, phase: str, participant_id: str) -> Path:
    """The phase folder of the session a yoked session of ``participant_id`` replays."""
    return protocol.phase_folder(study, partner_of(protocol, participant_id), phase, YOKED_TO)


def recorded_advice(phase_folder: Path) -> list[RecordedBuffer]:
    """The buffers the used attempt of ``phase_folder`` played, their times from its advisory's start;
    :class:`SeesysError` when it has none to replay (not done, or made without the start recorded)."""
    attempts = done_attempts(phase_folder)
    if not attempts:
        raise SeesysError(f"{phase_folder} has no session to replay for a yoked condition")
    attempt = attempts[-1]
    start = advice_start(attempt)
    if start is None:
        raise SeesysError(f"{attempt}: its run.json records no advice_start to replay the pulses from")
    try:
        log = read_csv_log(attempt / ADVISORY_CSV)
    except (OSError, ValueError) as e:
        raise SeesysError(f"{attempt}: cannot read the pulses to replay ({e})") from None
    return [
        RecordedBuffer(float(row.time_mono) - start, int(row.n_pulses), int(row.played_pulses), str(row.trigger))
        for row in log.itertuples()
    ]
