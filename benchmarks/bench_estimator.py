"""The navigation filter's cost per tick (autopilot.estimation.kf): propagation and output
inside a compiled loop and called from Python, a late GPS fix (roll back and replay), and
the ``Estimator.update`` wrapper, each beside its floor measured in the same run: the
in-process closed-loop tick (plant + TLC in one compiled loop) and a compiled call from
Python that does nothing (the price of crossing into numba).

Per-call figures are medians (``perf_counter_ns``, gc off); the compiled loop's is its
total over the ticks.
"""

from __future__ import annotations

import time

import numba
import numpy as np

from autopilot.estimation import Estimator, EstimatorConfig
from autopilot.estimation.kf import est_gps, est_output, est_predict
from benchmarks import Row, bench
from benchmarks.bench_sim import flight, median_ns
from heli_common.state import N_STATE, FloatArray
from heli_common.wire.measurements import AttitudeSample, ImuSample

RATE_HZ = 100.0
DT = 1.0 / RATE_HZ
G = 9.81
LATE_S = 0.1  # a GPS fix 100 ms late: the filter rolls back 10 ticks and re-propagates


@numba.njit  # not cached: it compiles the filter's kernels into itself (heli_common.jit)
def _in_loop(
    params: FloatArray, st: FloatArray, t0: float, n: int, gyro: FloatArray, accel: FloatArray,
    att: FloatArray, out: FloatArray,
) -> float:  # fmt: skip
    acc = 0.0
    for k in range(n):
        est_predict(params, st, t0 + (k + 1) * DT, gyro, accel, att)
        est_output(st, out)
        acc += out[2]
    return acc


@numba.njit
def _nothing(params: FloatArray, st: FloatArray) -> None:
    pass


@bench("navigation filter, per tick")
def bench_estimator() -> list[Row]:
    est = Estimator(EstimatorConfig(), np.zeros(N_STATE), RATE_HZ)
    est.warm_up()
    gyro, att = np.zeros(3), np.zeros(3)
    accel = np.array([0.0, 0.0, G])
    out = np.zeros(N_STATE)
    p, st = est.params, est.state
    est_predict(p, st, 0.0, gyro, accel, att)
    _in_loop(p, st.copy(), 0.0, 10, gyro, accel, att, out)  # compile
    _nothing(p, st)
    t = 0.0  # the filter's time: every call one tick on

    n = 20000
    t0 = time.perf_counter()
    _in_loop(p, st, t, n, gyro, accel, att, out)
    in_loop = (time.perf_counter() - t0) / n * 1e6
    t += n * DT

    def from_python(i: int) -> None:
        est_predict(p, st, t + (i + 1) * DT, gyro, accel, att)
        est_output(st, out)

    predict = median_ns(from_python, n) / 1e3
    t += n * DT
    pos, vel = np.zeros(3), np.zeros(3)

    def late_fix(i: int) -> None:
        now = t + (i + 1) * DT
        est_predict(p, st, now, gyro, accel, att)
        est_gps(p, st, now - LATE_S, pos, vel)

    m = 2000
    gps = median_ns(late_fix, m) / 1e3
    t += m * DT
    imu = ImuSample(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, G))
    a = AttitudeSample(0.0, (0.0, 0.0, 0.0))
    wrapper = median_ns(lambda i: est.update(t + (i + 1) * DT, imu, a), n) / 1e3
    call = median_ns(lambda i: _nothing(p, st), n) / 1e3
    rec = flight()
    tick = rec.wall_s / (rec.t_s.size - 1) * 1e6
    return [
        Row("floor: in-process closed-loop tick (plant + TLC, one compiled loop)", tick, "us"),
        Row("est_predict + est_output inside a compiled loop, per tick", in_loop, "us"),
        Row("  / the closed-loop tick (floor)", in_loop / tick, "x"),
        Row("floor: a compiled call from Python that does nothing (median)", call, "us"),
        Row("est_predict + est_output called from Python (median)", predict, "us"),
        Row("predict + a 100 ms-late GPS fix (replay of 10 ticks), from Python (median)", gps, "us"),
        Row("Estimator.update, no fix (median)", wrapper, "us"),
        Row("  / the compiled no-op call (floor)", wrapper / call, "x"),
    ]
