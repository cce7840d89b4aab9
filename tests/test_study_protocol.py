"""Study protocol: seeded balanced assignment, counterbalanced within-subjects orders, a protocol is never
redrawn; operator events from a pipe; `seesys study new` and `status` on an empty study."""

from __future__ import annotations

import io
import itertools
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest

from study.config import load_study_config
from study.operator import OperatorInput, parse_command
from study.protocol import ProtocolError, make_protocol, read_protocol, williams_orders, write_protocol

REPO = Path(__file__).resolve().parent.parent


def test_between_subjects_assignment_is_balanced_and_seeded():
    cfg = load_study_config().protocol
    a = make_protocol(cfg, participants_per_condition=10)
    assert Counter(p.conditions[0] for p in a.participants) == dict.fromkeys(cfg.conditions, 10)
    assert [p.id for p in a.participants][:2] == ["P01", "P02"]
    assert make_protocol(cfg, participants_per_condition=10) == a
    assert make_protocol(cfg, participants_per_condition=10, seed=1) != a


@pytest.mark.parametrize("k", [2, 3, 4, 5])
def test_williams_orders_balance_positions_and_carry_over(k):
    orders = williams_orders(k)
    for position in range(k):
        assert Counter(o[position] for o in orders) == {c: len(orders) // k for c in range(k)}
    follows = Counter((o[i], o[i + 1]) for o in orders for i in range(k - 1))
    assert len(set(follows.values())) == 1 and len(follows) == k * (k - 1)  # every ordered pair equally often


def test_within_subjects_orders_are_counterbalanced():
    cfg = load_study_config().protocol
    p = make_protocol(cfg, participants_per_condition=6, design="within")
    orders = Counter(tuple(x.conditions) for x in p.participants)
    assert len(p.participants) == 6 and len(orders) == 6 and set(orders.values()) == {1}
    assert all(sorted(x.conditions) == sorted(cfg.conditions) for x in p.participants)


def test_protocol_is_written_once(tmp_path):
    cfg = load_study_config().protocol
    write_protocol(tmp_path / "s", make_protocol(cfg, 1))
    assert read_protocol(tmp_path / "s").participants[0].id == "P01"
    with pytest.raises(ProtocolError, match="drawn once"):
        write_protocol(tmp_path / "s", make_protocol(cfg, 2))
    with pytest.raises(ProtocolError, match="not a study folder"):
        read_protocol(tmp_path)
    with pytest.raises(ProtocolError, match="conditions"):
        make_protocol(cfg, 1, conditions=["none", "loud"])


def test_operator_events_from_a_pipe():
    assert parse_command("o", 3).detail == "4" and parse_command("o 7", 3).detail == "7"
    assert parse_command("x", 0) is None
    recorded = []
    reader = OperatorInput(io.StringIO("i\no\nbogus\nn scanned the back\no\nq\ni\n"))
    reader.record = recorded.append
    reader.run()
    assert [(e.kind, e.detail) for e in recorded] == [
        ("initialised", ""),
        ("object", "1"),
        ("note", "scanned the back"),
        ("object", "2"),
        ("end", ""),
    ]
    assert all(a.time <= b.time for a, b in itertools.pairwise(recorded))
    assert reader.events.qsize() == 5


@pytest.mark.system
def test_new_and_status_commands(tmp_path):
    run = lambda *a: subprocess.run(  # noqa: E731
        [sys.executable, "-m", "seesys", "study", *a],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    made = run("new", str(tmp_path / "s"), "--per-condition", "6", "--design", "within")
    assert made.returncode == 0, made.stderr
    assert "within-subjects, 6 participants" in made.stdout
    status = run("status", str(tmp_path / "s"))
    assert status.returncode == 0 and "task: 18 pending" in status.stdout
    again = run("new", str(tmp_path / "s"))
    assert again.returncode == 2 and "drawn once" in again.stderr
    for per in ("0", "-3"):  # 0 had meant the configured 30 participants, -3 a study of nobody
        refused = run("new", str(tmp_path / f"s{per}"), "--per-condition", per)
        assert refused.returncode == 2 and refused.stderr.strip().count("\n") == 0, refused.stderr
        assert f"participants per condition must be at least 1, got {per}" in refused.stderr
        assert not (tmp_path / f"s{per}").exists()


def test_operator_keys_on_a_terminal():
    """Single keys on a (pseudo) terminal, a note typed up to Enter; the terminal's mode is restored."""
    import os
    import termios

    master, slave = os.openpty()
    before = termios.tcgetattr(slave)
    with os.fdopen(slave, "r") as terminal:
        recorded = []
        reader = OperatorInput(terminal)
        reader.record = recorded.append
        reader.start()
        deadline = time.monotonic() + 30
        while termios.tcgetattr(slave)[3] & termios.ICANON:  # until the reader has put it in cbreak mode
            assert time.monotonic() < deadline
            time.sleep(0.01)
        os.write(master, b"io" + b"nback side\n" + b"xq")
        reader.join(timeout=30)
        assert not reader.is_alive()
        assert [(e.kind, e.detail) for e in recorded] == [
            ("initialised", ""),
            ("object", "1"),
            ("note", "back side"),
            ("end", ""),
        ]
        assert termios.tcgetattr(slave) == before
    os.close(master)
