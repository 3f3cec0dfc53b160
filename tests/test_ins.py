"""The navigation filter (autopilot.estimation.ins) against its derivation and against the
truth: Jacobians by finite differences, alignment at rest, bias observability, NEES."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.estimation import ins
from autopilot.estimation.config import EstimatorConfig, InsConfig
from heli_common.kinematics import quat_from_euler, rot_body_to_earth, rot_from_quat
from heli_common.world.magnetic import earth_field_nwu_gauss

HOME_FIELD = np.array(earth_field_nwu_gauss(47.397742, 8.545594))
G = 9.81


def _filter(
    cfg: EstimatorConfig | None = None, field: np.ndarray = HOME_FIELD
) -> tuple[np.ndarray, np.ndarray]:
    k = ins.make_params(cfg or EstimatorConfig(attitude="ins"), 100.0, tuple(field))
    return k, np.zeros(ins.state_size(int(k[ins.K_N_BUF])))


def _error(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The error state that takes nominal ``b`` to nominal ``a`` (local attitude error)."""
    ra, rb = rot_from_quat(a[ins.N_Q : ins.N_Q + 4]), rot_from_quat(b[ins.N_Q : ins.N_Q + 4])
    d = rb.T @ ra
    angle = math.acos(max(-1.0, min(1.0, 0.5 * (np.trace(d) - 1.0))))
    k = 0.5 if angle < 1e-12 else 0.5 * angle / math.sin(angle)
    e = np.zeros(ins.N_ERR)
    e[ins.D_ATT : ins.D_ATT + 3] = k * np.array([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]])
    for d_off, n_off in ((ins.D_VEL, ins.N_VEL), (ins.D_POS, ins.N_POS), (ins.D_BG, ins.N_BG),
                         (ins.D_BA, ins.N_BA), (ins.D_GW, ins.N_GW), (ins.D_BM, ins.N_BM)):  # fmt: skip
        e[d_off : d_off + 3] = a[n_off : n_off + 3] - b[n_off : n_off + 3]
    return e


def test_error_transition_matches_finite_differences() -> None:
    """F of docs/estimator.md against the nominal mechanisation, perturbed one error
    component at a time (central differences) over one 10 ms tick at high rates."""
    k, st = _filter()
    rng = np.random.default_rng(3)
    nom = st[ins.E_NOM : ins.E_NOM + ins.N_NOM]
    nom[ins.N_Q : ins.N_Q + 4] = quat_from_euler(0.3, -0.2, 2.0)
    nom[ins.N_VEL : ins.N_VEL + 3] = [5.0, -2.0, 1.0]
    nom[ins.N_BG : ins.N_BG + 3] = rng.normal(0, 0.01, 3)
    nom[ins.N_BA : ins.N_BA + 3] = rng.normal(0, 0.2, 3)
    gyro, accel, dt = np.array([0.8, -0.5, 0.3]), np.array([1.5, -0.7, 10.5]), 0.01
    q = nom[ins.N_Q : ins.N_Q + 4].copy()
    f = ins.error_transition(q, gyro, accel, nom.copy(), dt, k[ins.K_WANDER_TAU])
    eps = 1e-6
    num = np.zeros((ins.N_ERR, ins.N_ERR))
    for j in range(ins.N_ERR):
        out = []
        for sgn in (1.0, -1.0):
            s = st.copy()
            dx = np.zeros(ins.N_ERR)
            dx[j] = sgn * eps
            ins._inject(s, dx)
            ins._propagate(k, s, gyro, accel, dt)
            out.append(s[ins.E_NOM : ins.E_NOM + ins.N_NOM].copy())
        num[:, j] = _error(out[0], out[1]) / (2 * eps)
    # the mechanisation rotates the specific force with the mid-interval attitude; F takes
    # the start's: they differ by O(w dt) in the velocity-attitude block
    err = np.abs(num - f)
    print(f"max |F - F_fd| = {err.max():.2e} at {np.unravel_index(err.argmax(), err.shape)}")
    assert err.max() < 6e-5  # the rest (3.9e-5): the half-tick rotation's Jacobian taken as I
    assert np.abs(num[ins.D_VEL : ins.D_VEL + 3, ins.D_ATT : ins.D_ATT + 3]).max() > 0.05  # a real block


def test_magnetometer_jacobian_matches_finite_differences() -> None:
    r = rot_body_to_earth(0.4, -0.3, 1.2)
    j = ins.mag_jacobian(r, HOME_FIELD)
    eps = 1e-7
    for a in range(3):
        d = np.zeros(3)
        d[a] = eps
        plus = (r @ rot_from_quat(ins.quat_from_rotvec(*d))).T @ HOME_FIELD
        minus = (r @ rot_from_quat(ins.quat_from_rotvec(*(-d)))).T @ HOME_FIELD
        np.testing.assert_allclose((plus - minus) / (2 * eps), j[:, a], atol=1e-8)


def test_a_vehicle_at_rest_knows_its_attitude_from_accelerometer_and_magnetometer() -> None:
    rng = np.random.default_rng(7)
    for _ in range(50):
        e = np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-math.pi, math.pi)])
        r = rot_body_to_earth(*e)
        got = ins.align(r.T @ np.array([0.0, 0.0, G]), r.T @ HOME_FIELD, HOME_FIELD)
        np.testing.assert_allclose(got, e, atol=1e-9)
    # and the filter started 10 deg off in yaw and 3 deg in roll finds it at rest: the
    # magnetometer fixes two axes, the accelerometer (through the velocity) the tilt. At
    # rest a tilt and a horizontal accelerometer bias look the same, and so do an attitude
    # and a compass offset, so this needs calibrated sensors (priors of 10 mm/s^2 and 1 mG):
    # with the defaults the filter books part of the error as biases, which is why a
    # vehicle aligns (align()) before it starts, and why the biases need motion to separate
    ins_cfg = InsConfig(init_att_sigma_rad=0.3, init_accel_bias_sigma=0.01, init_mag_bias_sigma_gauss=0.001)
    k, st = _filter(EstimatorConfig(attitude="ins", ins=ins_cfg))
    x0 = np.zeros(12)
    x0[6], x0[8] = math.radians(3.0), math.radians(10.0)
    ins.est_init(k, st, x0)
    r = rot_body_to_earth(0.0, 0.0, 0.0)
    out = np.zeros(12)
    for i in range(1000):
        t = i * 0.01
        ins.est_predict(k, st, t, np.zeros(3), r.T @ np.array([0.0, 0.0, G]))
        ins.est_mag(k, st, t, r.T @ HOME_FIELD)
        if i % 20 == 0:
            ins.est_gps(k, st, t, np.zeros(3), np.zeros(3))
    ins.est_output(st, out)
    assert np.degrees(np.abs(out[6:9])).max() < 0.1, np.degrees(out[6:9])


def _circle(k: np.ndarray, st: np.ndarray, bias_z: float, omega: float, seconds: float) -> None:
    """A level flight on a circle of 20 m at ``omega`` (0: hovering), GPS at 5 Hz, no
    magnetometer: only the turn makes the yaw (and its gyro bias) observable."""
    radius, dt = 20.0, 0.01
    for i in range(int(seconds / dt) + 1):
        t = i * dt
        psi = omega * t
        r = rot_body_to_earth(0.0, 0.0, psi)
        speed = omega * radius
        a_e = np.array([-speed * omega * math.sin(psi), speed * omega * math.cos(psi), 0.0])
        ins.est_predict(k, st, t, np.array([0.0, 0.0, omega + bias_z]), r.T @ (a_e + [0.0, 0.0, G]))
        if i % 20 == 0:
            pos = np.array([radius * math.sin(psi), radius * (1.0 - math.cos(psi)), 0.0])
            vel = np.array([speed * math.cos(psi), speed * math.sin(psi), 0.0])
            ins.est_gps(k, st, t, pos, vel)


@pytest.mark.parametrize("omega", [0.0, 0.5])
def test_the_yaw_gyro_bias_is_observable_in_a_turn_and_not_in_a_hover(omega: float) -> None:
    cfg = EstimatorConfig(attitude="ins", ins=InsConfig(use_mag=False, gps_wander_sigma_m=(0.0, 0.0, 0.0)))
    k, st = _filter(cfg)
    x0 = np.zeros(12)
    x0[3] = omega * 20.0
    ins.est_init(k, st, x0)
    bias = math.radians(0.3)
    _circle(k, st, bias, omega, 60.0)
    sd0 = math.sqrt(k[ins.K_P0 + ins.D_BG + 2])
    sd = math.sqrt(ins._cov(st)[ins.D_BG + 2, ins.D_BG + 2])
    est = st[ins.E_NOM + ins.N_BG + 2]
    assert st[ins.E_N_FIX] == 300 and st[ins.E_N_REJECT] == 0
    print(f"omega {omega}: yaw gyro bias {math.degrees(est):.3f} deg/s (true 0.3), "
          f"sigma {math.degrees(sd):.4f} (prior {math.degrees(sd0):.3f})")
    if omega == 0.0:
        assert sd > 0.9 * sd0  # nothing tells a hovering filter its heading without a compass
    else:
        assert sd < 0.008 * sd0 and abs(est - bias) < 3.0 * sd  # 0.0019 of 0.5 deg/s measured


def test_the_filter_is_consistent_over_20_seeded_flights_of_the_consumer_sensors() -> None:
    """NEES of the 15 navigation states, averaged over 20 seeds of the paper scenario with the
    consumer sensors (gps-typical's receiver and baro, imu-consumer's IMU and compass) and a
    filter tuned to them: inside the chi-square 95 % band (13.94 in [12.70, 17.49] measured;
    84.5 % of the ticks inside), and every final gyro bias within 3 sigma (1.95 measured).
    gps-typical alone has an ideal IMU and compass: its six bias states sit exactly at the
    prior's mean, add nothing to NEES, and its mean is 4.6 (docs/estimator.md)."""
    from heli_sitl.studies.nav_study import consistency

    c = consistency("consumer", 20)
    print(c.table())
    assert c.consistent and c.in_band > 0.75
    assert c.gyro_bias_z_max < 3.0
    assert max(c.att_rms_deg) < 0.2


@pytest.mark.parametrize(("world", "att_deg", "rms_m"),
                         [("gps-typical", 0.1, 0.5), ("imu-consumer", 0.2, 0.06)])  # fmt: skip
def test_attitude_and_tracking_when_flying_on_the_filter(world: str, att_deg: float, rms_m: float) -> None:
    """The paper scenario on the navigation filter (default tuning): the true attitude error
    RMS (0.02-0.06 deg with gps-typical, 0.03-0.11 deg with imu-consumer measured) and the
    controller's RMS [45, 120] against the truth (0.42 m: the GPS's 2 m wander; 0.045 m
    with imu-consumer, where the attitude source left 0.19 m)."""
    import heli_sitl as hs
    from autopilot.estimation.log import EST_LOG_COLUMNS

    f = hs.simulate(world=world, estimator=EstimatorConfig(attitude="ins"))
    assert f.record is not None and f.record.est_log is not None and f.metrics is not None
    i = EST_LOG_COLUMNS.index("att_err_x")
    att = np.degrees(np.sqrt(np.nanmean(f.record.est_log[:, i : i + 3] ** 2, axis=0)))
    print(f"{world}: attitude error RMS {att.round(3)} deg; RMS [45, 120] {f.metrics.rms_45_m:.4f} m")
    assert att.max() < att_deg and f.metrics.rms_45_m < rms_m


def test_a_filter_whose_fixes_keep_failing_their_gate_declares_itself_diverged() -> None:
    """A receiver running away (each fix 20 m on from the last, its velocity zero): each run
    of rejections ends in a reset that the next fix fails again; after divergence_s (5 s)
    without a fix inside its gate, the filter says it diverged (and stays so). Fixes that
    agree never trip it."""
    for jumping in (False, True):
        k, st = _filter()
        ins.est_init(k, st, np.zeros(12))
        r = rot_body_to_earth(0.0, 0.0, 0.0)
        for i in range(1001):
            t = i * 0.01
            ins.est_predict(k, st, t, np.zeros(3), r.T @ np.array([0.0, 0.0, G]))
            ins.est_mag(k, st, t, r.T @ HOME_FIELD)
            if i % 20 == 0:
                off = 20.0 * (i // 20 - 9) if jumping and t >= 2.0 else 0.0
                ins.est_gps(k, st, t, np.array([off, 0.0, 0.0]), np.zeros(3))
            ins._check_divergence(k, st)
            if jumping and t < 6.8:  # the last fix inside the gate was at 1.8 s
                assert st[ins.E_DIVERGED] == 0.0, t
        assert st[ins.E_DIVERGED] == (1.0 if jumping else 0.0)
        assert (st[ins.E_N_RESET] > 0) == jumping


def test_a_gps_outage_in_hover_grows_the_position_sigma_over_the_drift(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """gps-typical, a 5 m hover, no fix valid in [12, 22) s: the filter dead-reckons on an
    ideal IMU. Its horizontal 1-sigma grows from 0.5 m to 0.8/1.5 m (north/west), the truth
    stays inside 2 sigma on every tick, and the vehicle drifts 1.0 m (west): the error of
    the gyro-bias estimate integrates into a roll error the controller flies as a lean."""
    import dataclasses
    from pathlib import Path

    from test_world_processes import HOVER_SCENARIO

    import heli_sitl as hs
    from autopilot.estimation.log import EST_LOG_COLUMNS
    from heli_common.world.config import World

    configs = Path(__file__).resolve().parent.parent / "configs"
    scenario = tmp_path / "hover.toml"
    text = HOVER_SCENARIO.replace("14.0", "24.0").replace("10.0]", "5.0]")  # 24 s at 5 m
    scenario.write_text(text.replace('"xcell60.toml"', f'"{configs / "xcell60.toml"}"')
                        .replace('"gains_paper.toml"', f'"{configs / "gains_paper.toml"}"'))  # fmt: skip
    base = World.load("gps-typical")
    gps = dataclasses.replace(base.sensors.gps, outage_start_s=12.0, outage_s=10.0)
    world = dataclasses.replace(base, sensors=dataclasses.replace(base.sensors, gps=gps))
    f = hs.simulate(scenario=scenario, world=world)
    r = f.record
    assert r is not None and r.est_log is not None and r.x_hat is not None
    t, e = r.t_s, r.est_log
    i0 = EST_LOG_COLUMNS.index("sd_pos_n")
    sd = e[:, i0 : i0 + 2]
    out = (t >= 12.2) & (t < 22.0)  # the last fix (valid 11.8 s) arrives at 11.9 s
    err = np.abs(r.x_hat[:, 0:2] - r.x[:, 0:2])
    covered = float(np.mean(err[out] <= 2.0 * sd[out]))
    k0, k1 = np.flatnonzero(out)[[0, -1]]
    drift = float(np.linalg.norm(r.x[k1, 0:2] - r.x[k0, 0:2]))
    since = e[:, EST_LOG_COLUMNS.index("since_fix_s")]
    print(f"sigma {sd[k0].round(3)} -> {sd[k1].round(3)} m; truth inside 2 sigma "
          f"{100 * covered:.1f} %; drift {drift:.3f} m; since fix {since[k1]:.2f} s")
    assert since[k1] > 9.5  # no fix reached the filter in the window
    assert np.all(sd[k1] > 1.5 * sd[k0]) and sd[k1].max() < 2.0
    assert covered == 1.0
    assert 0.5 < drift < 1.5


def test_nees_is_the_error_weighted_by_the_navigation_block_inverse() -> None:
    """NEES = e^T P_nav^-1 e over the 15 navigation states (the marginal block of the 21 x 21
    covariance), as numpy's solve has it, to rounding; inf where the block is not positive
    definite (the elimination meets a pivot <= 0)."""
    rng = np.random.default_rng(7)
    st = np.zeros(ins.state_size(4))
    a = rng.normal(size=(ins.N_ERR, ins.N_ERR))
    p = a @ a.T + 0.1 * np.eye(ins.N_ERR)
    st[ins.E_COV : ins.E_COV + ins.N_COV] = p.ravel()
    st[ins.E_CHOL : ins.E_CHOL + (ins.N_NAV + 1) ** 2] = np.nan  # the scratch's old contents are not read
    e = rng.normal(size=ins.N_ERR)
    n = ins.N_NAV
    want = e[:n] @ np.linalg.solve(p[:n, :n], e[:n])
    assert ins.nees(st, e) == pytest.approx(want, rel=1e-10)
    p[3, 3] = -1.0  # no longer positive definite
    st[ins.E_COV : ins.E_COV + ins.N_COV] = p.ravel()
    assert ins.nees(st, e) == math.inf
