"""The suite's two lanes of workers (tests/lanes.py): which file runs where."""

from __future__ import annotations

from pathlib import Path

from lanes import PROCESS_MODULES, REALTIME_MODULES, _realtime, is_realtime_lane, workers

TESTS = Path(__file__).resolve().parent


def test_every_named_realtime_file_exists() -> None:
    """A renamed file would silently leave the real-time lane for the niced one."""
    missing = sorted(m for m in REALTIME_MODULES if not (TESTS / f"{m}.py").is_file())
    assert not missing, missing
    assert PROCESS_MODULES <= REALTIME_MODULES


def test_half_the_workers_are_the_realtime_lane() -> None:
    assert workers(2) == 4 and workers(0) == 2
    assert [is_realtime_lane(f"gw{i}", 4) for i in range(4)] == [True, True, False, False]
    assert [is_realtime_lane(f"gw{i}", 3) for i in range(3)] == [True, True, False]
    assert is_realtime_lane("gw0", 1)
    assert _realtime("tests/test_processes.py") and not _realtime("tests/test_campaign.py")
