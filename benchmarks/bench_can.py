"""CAN servo link benchmark: the cost of one tick's DroneCAN ArrayCommand, and what the
float16 command values do to the closed loop.

Rows (name, value, unit, target):

* encode + send per tick: ``CanServoSender.send`` on a python-can ``virtual`` bus with
  the servo endpoint listening (3 frames; NodeStatus once a second included), mean and
  99th percentile. Target: well inside a 100 Hz tick (10 ms).
* encode alone (dronecan serialisation and framing), and the endpoint's receive +
  reassembly + checks + decode per tick.
* float16 quantisation error of the values, over random pitches within the limits.
* the paper scenario flown over the virtual bus (optional, ~10 s): RMS 3-D position
  error over [45, 120] s, and its change against the in-process loop without the bus.
"""

from __future__ import annotations

import time

import numpy as np

from autopilot.links.can_servo import CanServoSender
from autopilot.scenario import Scenario
from benchmarks import Row as TableRow
from benchmarks import bench
from heli_common.vehicle.airframe import Airframe
from heli_common.wire.can.bus import CanBusConfig
from heli_common.wire.can.dronecan_codec import ArrayCommandEncoder, float16_round
from heli_plant.can_endpoint import CanServoEndpoint
from heli_sitl.engine.can_closed_loop import fly_over_can
from heli_sitl.engine.closed_loop import simulate

Row = tuple[str, float, str, str]
TICK_HZ = 100.0


def _pitch_samples(airframe: Airframe, n: int, seed: int = 7) -> np.ndarray:
    lim = np.array(airframe.limits.as_tuple())
    rng = np.random.default_rng(seed)
    return rng.uniform(lim[:, 0], lim[:, 1], size=(n, 4))


def _rms_45_120_m(t_s: np.ndarray, err_m: np.ndarray) -> float:
    m = (t_s >= 45.0 - 1e-9) & (t_s <= 120.0 + 1e-9)
    return float(np.sqrt(np.mean(err_m[m] ** 2)))


def bench_can(n_ticks: int = 3000, closed_loop: bool = True) -> list[Row]:
    airframe = Airframe.load()
    u = _pitch_samples(airframe, n_ticks)
    bus = CanBusConfig("virtual", "bench-can")
    send_us = np.empty(n_ticks)
    poll_us = np.empty(n_ticks)
    with CanServoEndpoint(bus, limits=airframe.limits) as ep, CanServoSender(bus) as tx:
        for k in range(50):  # warm-up: imports, first-call costs
            tx.send(u[k], -1.0 + k / TICK_HZ)
            ep.poll(-1.0 + k / TICK_HZ)
        for k in range(n_ticks):
            t = k / TICK_HZ
            t0 = time.perf_counter()
            tx.send(u[k], t)
            t1 = time.perf_counter()
            ep.poll(t)
            t2 = time.perf_counter()
            send_us[k], poll_us[k] = (t1 - t0) * 1e6, (t2 - t1) * 1e6
        applied = ep.stats["commands_applied"]
    if applied != n_ticks + 50:
        raise RuntimeError(f"bench: {applied} of {n_ticks + 50} commands applied")

    enc = ArrayCommandEncoder(10)
    t0 = time.perf_counter()
    for k in range(n_ticks):
        enc.encode(u[k].tolist())
    encode_us = (time.perf_counter() - t0) / n_ticks * 1e6

    q = np.array([[float16_round(v) for v in row] for row in u[:1000]])
    f16_err = float(np.abs(q - u[:1000]).max())

    rows: list[Row] = [
        ("can_encode_send_us_per_tick", float(send_us.mean()), "us", "< 1000 (10 % of 10 ms)"),
        ("can_encode_send_p99_us", float(np.percentile(send_us, 99)), "us", "< 2000"),
        ("can_encode_only_us_per_tick", encode_us, "us", "info (struct packing + framing)"),
        ("can_poll_decode_us_per_tick", float(poll_us.mean()), "us", "< 1000"),
        ("can_float16_max_error_rad", f16_err, "rad", "<= 2.5e-4 (half a float16 step at 0.5 rad)"),
    ]  # fmt: skip
    if closed_loop:
        scenario = Scenario.load("paper")
        flight = fly_over_can(scenario)
        rec = flight.record
        base = simulate(scenario)
        rms_can = _rms_45_120_m(rec.t_s, rec.pos_err_m)
        rms_direct = _rms_45_120_m(base.t_s, base.pos_err_m)
        rows += [
            ("can_closed_loop_rms_45_120_m", rms_can, "m", "<= 0.05"),
            ("inprocess_rms_45_120_m", rms_direct, "m", "<= 0.05"),
            ("can_float16_rms_change_pct", 100 * abs(rms_can / rms_direct - 1.0), "%", "< 10"),
            ("can_closed_loop_us_per_tick", rec.wall_s / rec.t_s.size * 1e6, "us", "info"),
        ]  # fmt: skip
    return rows


if __name__ == "__main__":
    for name, value, unit, target in bench_can():
        print(f"{name:34s} {value:12.6g} {unit:4s} target {target}")


@bench("servo link, DroneCAN")
def bench_can_default() -> list[TableRow]:
    return [TableRow(name, value, unit, target) for name, value, unit, target in bench_can()]
