"""The autopilot's telemetry schedule (autopilot/links/mavlink_gcs.py, GcsService._due): each
message on a grid of whole microseconds of vehicle time, so the 10 Hz target and the 20 Hz
position of one tick go out together (the view pairs them), and a lockstep tick after idle
ticks stamped ahead of it (the plant silent, the ground's heartbeat kept) goes on from the
grid's next point, not from the idle ticks' (which the flight's 5 s might never reach)."""

from __future__ import annotations

from types import SimpleNamespace

from autopilot.links.mavlink_gcs import GcsService

POS, TARGET = 32, 85  # LOCAL_POSITION_NED (20 Hz), POSITION_TARGET_LOCAL_NED (10 Hz)


def _sent(svc: SimpleNamespace, msg_id: int, interval_s: float, ticks_us: list[int]) -> list[int]:
    return [t for t in ticks_us if GcsService._due(svc, msg_id, interval_s, t)]  # type: ignore[arg-type]


def _grid() -> SimpleNamespace:
    return SimpleNamespace(grid_origin_us={}, next_due_us={})


def test_10_and_20_hz_share_the_ticks_of_a_100_hz_flight() -> None:
    ticks = [round(k * 0.01 * 1e6) for k in range(501)]  # 0 .. 5 s as the runner's t_s = t_us / 1e6
    svc = _grid()
    pos = _sent(svc, POS, 1.0 / 20.0, ticks)
    target = _sent(svc, TARGET, 1.0 / 10.0, ticks)
    assert pos == list(range(0, 5_000_001, 50_000))
    assert target == list(range(0, 5_000_001, 100_000))
    assert set(target) <= set(pos)  # every target has its tick's position


def test_a_clock_that_went_back_goes_on_from_its_grid() -> None:
    svc = _grid()
    before = _sent(svc, TARGET, 0.1, [0, 10_000, 100_000])
    idle = _sent(svc, TARGET, 0.1, [600_000, 1_700_000, 2_300_000])  # ahead of the vehicle's time
    after = _sent(svc, TARGET, 0.1, [110_000, 190_000, 200_000, 210_000, 300_000])  # the flight goes on
    assert before == [0, 100_000]
    assert idle == [600_000, 1_700_000, 2_300_000]
    assert after == [200_000, 300_000]  # the grid of the flight's first tick, from where it is
