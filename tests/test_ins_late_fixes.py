"""Late GPS fixes in the navigation filter (autopilot.estimation.ins): fused when they
arrive, at their validity time, through the cross-covariance carried from that time
(docs/estimator.md, "Late fixes"), they leave the filter where fixes on time would have."""

from __future__ import annotations

import math

import numpy as np

from autopilot.estimation import ins
from autopilot.estimation.config import EstimatorConfig
from heli_common.kinematics import rot_body_to_earth
from heli_common.world.magnetic import earth_field_nwu_gauss

FIELD = np.array(earth_field_nwu_gauss(47.397742, 8.545594))
G = 9.81


def _fly(lag_ticks: int, seconds: float = 20.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A level circle of 20 m at 5 m/s with a noisy IMU, compass (75 Hz) and baro (50 Hz),
    and GPS fixes at 5 Hz delivered ``lag_ticks`` late. Per tick: the nominal state and
    the covariance's diagonal after the tick's fusions (with no lag: before the tick's fix,
    the state a late filter reaches when that fix's predecessor comes in); and the
    filter's final state array."""
    rng = np.random.default_rng(4)
    k = ins.make_params(EstimatorConfig(attitude="ins"), 100.0, tuple(FIELD))
    st = np.zeros(ins.state_size(int(k[ins.K_N_BUF])))
    x0 = np.zeros(12)
    x0[3] = 5.0
    ins.est_init(k, st, x0)
    radius, omega, dt = 20.0, 0.25, 0.01
    pending: list[tuple[float, int, np.ndarray, np.ndarray]] = []
    noms, sds = [], []
    for i in range(int(seconds / dt) + 1):
        t = i * dt
        psi = omega * t
        r = rot_body_to_earth(0.0, 0.0, psi)
        speed = omega * radius
        a_e = np.array([-speed * omega * math.sin(psi), speed * omega * math.cos(psi), 0.0])
        ins.est_predict(k, st, t, np.array([0.0, 0.0, omega]) + rng.normal(0, 0.0008, 3),
                        r.T @ (a_e + [0.0, 0.0, G]) + rng.normal(0, 0.05, 3))  # fmt: skip
        if i % 4 != 3:
            ins.est_mag(k, st, t, r.T @ FIELD + rng.normal(0, 0.003, 3))
        if i % 2 == 0:
            ins.est_baro(k, st, t, rng.normal(0, 0.3))
        if i % 20 == 0 and i > 0:  # (the first tick only sets the time: no fix there)
            pos = np.array([radius * math.sin(psi), radius * (1.0 - math.cos(psi)), 0.0])
            vel = np.array([speed * math.cos(psi), speed * math.sin(psi), 0.0])
            pos += rng.normal(0, 0.3, 3)
            vel += rng.normal(0, 0.1, 3)
            pending.append((t, i + lag_ticks, pos, vel))
        before = (st[ins.E_NOM : ins.E_NOM + ins.N_NOM].copy(), np.diag(ins._cov(st)).copy())
        while pending and pending[0][1] == i:
            t_fix, _, pos, vel = pending.pop(0)
            ins.est_gps(k, st, t_fix, pos, vel)
        after = (st[ins.E_NOM : ins.E_NOM + ins.N_NOM].copy(), np.diag(ins._cov(st)).copy())
        nom, sd = before if lag_ticks == 0 else after
        noms.append(nom)
        sds.append(np.sqrt(sd))
    return np.array(noms), np.array(sds), st


def test_a_fix_200_ms_late_leaves_the_filter_where_the_fix_on_time_did() -> None:
    """Fixes 200 ms late, each fused as it arrives (20 ticks, 15 compass samples and 10
    baro heights after its time), against the same fixes on time: at the tick a late fix
    comes in, the two filters have fused the same measurements. They agree to second order
    in the corrections, the filter's own linearisation: 0.075 mm of position, 0.84 mm/s of
    velocity and 2.1e-4 of a quaternion component (0.024 deg) at worst, their 1-sigma to
    0.31 %; they make the same gate decisions, and no late fix needs the ticks since its
    time run again."""
    on_time, sd_on_time, st_on_time = _fly(0)
    late, sd_late, st = _fly(20)
    ticks = np.arange(40, on_time.shape[0], 20)  # a late fix comes in
    d = np.abs(on_time[ticks] - late[ticks])
    d_pos = d[:, ins.N_POS : ins.N_POS + 3].max()
    d_vel = d[:, ins.N_VEL : ins.N_VEL + 3].max()
    d_q = d[:, ins.N_Q : ins.N_Q + 4].max()
    print(f"largest difference: position {d_pos:.2e} m, velocity {d_vel:.2e} m/s, quaternion {d_q:.2e}")
    assert d_pos < 1e-3 and d_vel < 5e-3
    assert d_q < 1e-3  # ~0.1 deg
    rel = np.abs(sd_on_time[ticks] - sd_late[ticks]) / sd_on_time[ticks]
    print(f"largest relative difference of the 1-sigma: {rel.max():.2e}")
    assert rel.max() < 0.01
    # the same gate decisions (the last fix is still on its way to the late filter)
    assert st[ins.E_N_FIX] == st_on_time[ins.E_N_FIX] - 1 and st[ins.E_N_REJECT] == st_on_time[ins.E_N_REJECT]
    # the ticks since the last fix's time still start without it: it was not replayed
    newest = ins.E_HIST + int(st[ins.E_HEAD]) * ins.N_REC
    assert st[newest + ins.R_STALE] == 1.0
