"""The rotor-aware TLC's flapping observer corrected from the gyro (``[rotor.observer] correction
= "rate"``, autopilot/tlc/rotor_aware.py, docs/tlc-rotor.md "The observer"): its design model,
its Kalman gain, the default left as it was, and its estimate against the plant's true flapping
on a rotor that is not its design model (linkage gains x2, hub spring x1.5)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from scipy.linalg import expm

from autopilot.metrics import ROTOR_RECORD, FlightRecord
from autopilot.scenario import Scenario
from autopilot.tlc.controller import S_FLAP_HAT, S_RATE_HAT, S_STARTED, TLController
from autopilot.tlc.gains import Gains, RotorObserverGains
from autopilot.tlc.rotor_aware import (
    OG_A1,
    OG_B1,
    OG_P,
    OG_Q,
    correct_flapping,
    observer_gain,
    observer_model,
    observer_poles,
)
from heli_common.config import ConfigError, build
from heli_common.state import N_STATE, P_X, Q_Y, FloatArray
from heli_common.vehicle.airframe import Airframe
from heli_common.vehicle.plant_model import PlantModel
from heli_common.world.config import World
from heli_plant.trim import linearize, trim
from heli_sitl.engine.closed_loop import SimOptions, simulate
from heli_sitl.engine.loop_linear import linearize_loop
from heli_sitl.engine.loop_linear import servo_model as servo_preset
from heli_sitl.studies.campaigns.flight import metrics
from heli_sitl.studies.campaigns.spec import CampaignSpec

DESIGN = Airframe.load()
GAV = PlantModel.load("gavrilets")
DT = 0.01
ROTOR_SETS = ("gains_tlc_rotor.toml", "gains_tlc_rotor_tuned.toml")


def _with_observer(gains: Gains, correction: str) -> Gains:
    assert gains.rotor is not None
    obs = dataclasses.replace(gains.rotor.observer, correction=correction)
    return dataclasses.replace(gains, rotor=dataclasses.replace(gains.rotor, observer=obs))


def _mismatched(lon_lat: float, k_beta: float) -> PlantModel:
    """The rotor plant with its linkage gains and hub spring scaled (the controller keeps its
    design model: campaigns' ``plant.flapping.*``)."""
    assert GAV.rotor is not None
    fl = GAV.rotor.flapping
    fl = dataclasses.replace(fl, lon_gain_rad_per_rad=fl.lon_gain_rad_per_rad * lon_lat,
                             lat_gain_rad_per_rad=fl.lat_gain_rad_per_rad * lon_lat,
                             hub_stiffness_n_m_per_rad=fl.hub_stiffness_n_m_per_rad * k_beta)  # fmt: skip
    return dataclasses.replace(GAV, rotor=dataclasses.replace(GAV.rotor, flapping=fl))


def _model() -> tuple[FloatArray, RotorObserverGains]:
    assert GAV.rotor is not None
    rp = GAV.rotor
    return observer_model(DESIGN.constants(), rp.tau_e_s(), rp.flapping.hub_stiffness_n_m_per_rad), \
        RotorObserverGains(correction="rate")  # fmt: skip


def test_the_shipped_sets_keep_the_open_loop_observer_and_never_touch_the_rate_block() -> None:
    for name in ROTOR_SETS:
        g = Gains.load(name)
        assert g.rotor is not None and g.rotor.observer.correction == "open_loop"
        c = TLController(DESIGN, g)
        assert not c.constants.rotor.correct and not c.constants.rotor.obs_gain.any()
        x = np.zeros(N_STATE)
        x[2], x[P_X], x[Q_Y] = 10.0, 0.1, -0.2
        ref = np.zeros(9)
        ref[2] = 10.0
        for k in range(3):
            c.update(k * DT, x, ref)
        assert np.all(c.state[S_RATE_HAT : S_RATE_HAT + 2] == 0.0)


def test_a_bad_correction_is_refused_with_its_key() -> None:
    with pytest.raises(ConfigError, match="correction"):
        build(RotorObserverGains, {"correction": "kalman"}, "gains: rotor.observer")


def test_the_design_model_has_the_plant_rotor_body_modes() -> None:
    """The observer's linear model about hover (the design airframe's inertia, loop 4's torque
    model with the hub spring, the flapping lag) has the rotor plant's rotor-body modes: pitch
    -4.22 +/- 14.09j, roll -4.18 +/- 19.75j (docs/rotor-plant.md, from the plant's Jacobian)."""
    a, _ = _model()
    ev = np.linalg.eigvals(a)
    lin = linearize(trim(GAV, DESIGN), GAV, DESIGN)
    plant_ev = np.linalg.eigvals(lin.a)
    for lam in ev:
        nearest = plant_ev[np.argmin(np.abs(plant_ev - lam))]
        assert abs(nearest - lam) / abs(lam) < 0.02, (lam, nearest)


def test_the_gain_is_the_steady_state_kalman_gain_and_its_error_poles() -> None:
    """K = P C' (C P C' + R)^-1 with P the fixed point of the Riccati recursion (checked by
    running the covariance recursion from P); the estimate's error poles are stable and the
    flapping's are 23 and 42 /s (the open-loop copy's own error decays at 1/tau_e = 8.35 /s)."""
    a, o = _model()
    k = observer_gain(a, o, DT)
    f = expm(a * DT)
    cm = np.zeros((2, 4))
    cm[0, OG_P], cm[1, OG_Q] = 1.0, 1.0
    r = np.eye(2) * o.gyro_noise_rad_s**2
    # a covariance recursion from a large prior converges to the same gain
    qc = np.diag([o.moment_noise_rad_s2_rthz**2] * 2 + [o.flapping_noise_rad_s_rthz**2] * 2)
    p = np.eye(4)
    for _ in range(5000):
        kk = p @ cm.T @ np.linalg.inv(cm @ p @ cm.T + r)
        p = f @ ((np.eye(4) - kk @ cm) @ p) @ f.T + qc * DT  # first-order process noise
    np.testing.assert_allclose(kk, k, rtol=0.03, atol=1e-4)
    poles = observer_poles(a, k, DT)
    assert np.all(poles.real < 0.0)
    slow = np.sort(poles.real)[-2:]
    np.testing.assert_allclose(slow, [-41.9, -23.1], rtol=0.01)
    # the gyro is trusted (the rates' estimate is the measurement), the flapping is corrected
    # mostly from its own axis: a1 from q, b1 from p
    assert k[OG_P, 0] > 0.99 and k[OG_Q, 1] > 0.99
    assert abs(k[OG_A1, 1]) > 10 * abs(k[OG_A1, 0]) and abs(k[OG_B1, 0]) > 10 * abs(k[OG_B1, 1])


def _recording(gains: Gains, log: list[FloatArray]) -> type[Any]:
    """The TLC as a user's class that logs the flapping estimate loop 5 reads each tick: the
    open-loop copy's prediction, or that prediction corrected by this tick's gyro (the very
    :func:`correct_flapping` the kernel runs, on a copy of its state). The bench flies a
    wrapped TLC bit for bit as the compiled one (tested below); its trial tick and warm-up
    copies log too, so a flight's ticks are the log's last entries."""

    class Recording:
        name = "tlc, recording its flapping estimate"

        def __init__(self, airframe: Airframe, rate_hz: float) -> None:
            self.c = TLController(airframe, gains, rate_hz)

        def reset(self) -> None:
            self.c.reset()

        def update(self, t_s: float, x: FloatArray, ref: FloatArray) -> FloatArray:
            st = self.c.state.copy()
            r = self.c.constants.rotor
            if r.correct and st[S_STARTED] != 0.0:
                correct_flapping(r, st, S_FLAP_HAT, S_RATE_HAT, x[P_X], x[Q_Y], False)
            log.append(st[S_FLAP_HAT : S_FLAP_HAT + 2])
            out: FloatArray = self.c.update(t_s, x, ref)
            return out

    return Recording


def _fly(
    gains: Gains, plant: PlantModel, scenario: str, duration_s: float
) -> tuple[FloatArray, FloatArray, FlightRecord]:
    """(estimate, truth) of (a1, b1) each tick, and the record."""
    sc = dataclasses.replace(Scenario.load(scenario), gains=gains)
    log: list[FloatArray] = []
    rec = simulate(sc, SimOptions(world=World.load("servos-default"), plant=plant, duration_s=duration_s,
                                  controller=_recording(gains, log)))  # fmt: skip
    assert rec.rotor is not None
    truth = rec.rotor[:, [ROTOR_RECORD.index("a1_rad"), ROTOR_RECORD.index("b1_rad")]]
    return np.array(log[-truth.shape[0] :]), truth, rec


def _rms_error(est: FloatArray, truth: FloatArray, rec: FlightRecord, t0_s: float = 5.0) -> float:
    m = rec.columns()["t_s"] >= t0_s
    return float(np.sqrt(np.mean(np.sum((est[m] - truth[m]) ** 2, axis=1))))


def test_the_recording_wrapper_flies_the_compiled_flight() -> None:
    g = Gains.load("gains_tlc_rotor.toml")
    _, _, rec = _fly(g, GAV, "hover_gust", 5.0)
    sc = dataclasses.replace(Scenario.load("hover_gust"), gains=g)
    ref = simulate(sc, SimOptions(world=World.load("servos-default"), plant=GAV, duration_s=5.0))
    np.testing.assert_array_equal(rec.columns()["x_m"], ref.columns()["x_m"])
    np.testing.assert_array_equal(rec.columns()["eps_rad"], ref.columns()["eps_rad"])


def test_the_rate_correction_halves_the_flapping_error_on_a_mismatched_rotor() -> None:
    """Linkage gains x2 and hub spring x1.5 on the flying plant (the design model keeps 1 rad/rad
    and 54 N m/rad), the shipped rotor-aware set, hover in a gust (30 s, default servos). The
    open-loop copy flaps half as far as the rotor per rad of cyclic; the corrected estimate
    sees the moment the gyro measures. Measured: RMS error of (a1, b1) from 5 s, corrected
    0.00141 rad against open-loop 0.00329 rad (the true flapping: 0.0071 rad RMS), ratio 0.428;
    pinned at 1.2 times that."""
    plant = _mismatched(2.0, 1.5)
    g = Gains.load("gains_tlc_rotor.toml")
    errors = []
    for gains in (g, _with_observer(g, "rate")):
        est, truth, rec = _fly(gains, plant, "hover_gust", 30.0)
        m = metrics(rec, CampaignSpec(name="t", metrics=("max_err_10_m", "diverged")))
        assert not m["diverged"] and m["max_err_10_m"] < 0.5  # inside the envelope, hovering
        errors.append(_rms_error(est, truth, rec))
    e_open, e_rate = errors
    print(f"flapping estimate RMS error: open loop {e_open:.5f} rad, rate-corrected {e_rate:.5f} rad, "
          f"ratio {e_rate / e_open:.3f}")  # fmt: skip
    assert e_rate <= 1.2 * 0.428 * e_open


@pytest.mark.parametrize(("name", "worst", "at", "all_four"),
                         [("gains_tlc_rotor.toml", 0.64, ("input eps",), 0.61),
                          ("gains_tlc_rotor_tuned.toml", 0.78, ("input eta",), 0.59)])  # fmt: skip
def test_the_rate_correction_margins_at_the_design_point(name: str, worst: float, at: tuple[str, ...],
                                                         all_four: float) -> None:  # fmt: skip
    """The whole loop linearised with the correction on (the rotor plant, default servos): the
    shipped set falls from 0.69 to 0.64, below the 0.66 design target, at the cyclic; the tuned
    set rises from 0.67 to 0.78 (docs/tlc-rotor.md). Measured, pinned at +/- 0.02."""
    c = TLController(DESIGN, _with_observer(Gains.load(name), "rate"), 100.0)
    sv_name, sv = servo_preset("servos-default")
    lin = linearize_loop(c, GAV, DESIGN, sv, sv_name)
    print(lin.summary())
    assert lin.stable
    w = lin.worst()
    assert w.name in at
    assert abs(w.disk_margin - worst) <= 0.02
    assert abs(lin.input_multiloop.disk_margin - all_four) <= 0.02


def _table() -> None:
    """The figures of docs/tlc-rotor.md's observer table: the shipped sets, the paper scenario
    (120 s), open loop against rate-corrected, on the design plant and the mismatched one: each
    cell RMS [45, 120] m / max error after 10 s m / the flapping estimate's RMS error from 5 s mrad."""
    for name in ROTOR_SETS:
        for plant_name, plant in (("gavrilets", GAV), ("x2 linkage, x1.5 K_beta", _mismatched(2.0, 1.5))):
            for world in ("servos-default", "sloppy-servos", "everything", "consumer"):
                cells = []
                for corr in ("open_loop", "rate"):
                    g = _with_observer(Gains.load(name), corr)
                    sc = dataclasses.replace(Scenario.load("paper"), gains=g)
                    log: list[FloatArray] = []
                    rec = simulate(sc, SimOptions(world=World.load(world), plant=plant,
                                                  controller=_recording(g, log)))  # fmt: skip
                    assert rec.rotor is not None
                    truth = rec.rotor[:, [ROTOR_RECORD.index("a1_rad"), ROTOR_RECORD.index("b1_rad")]]
                    est = np.array(log[-truth.shape[0] :])
                    m = metrics(rec, CampaignSpec(name="t", metrics=("rms_45_m", "max_err_10_m", "diverged")))
                    lost = " LOST" if m["diverged"] else ""
                    cells.append(f"{m['rms_45_m']:.4f} / {m['max_err_10_m']:.2f}{lost} / "
                                 f"{1e3 * _rms_error(est, truth, rec):.2f}")  # fmt: skip
                print(f"| {name} | {plant_name} | {world} | {' | '.join(cells)} |", flush=True)


if __name__ == "__main__":  # python tests/test_tlc_rotor_observer.py: the docs' table (~1 min)
    _table()
