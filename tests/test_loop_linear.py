"""The whole closed loop linearised (heli_sitl.engine.loop_linear) against simulation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from autopilot.controllers import build_controller
from autopilot.scenario import Scenario
from heli_common.state import EPS
from heli_common.vehicle.plant_model import PlantModel
from heli_common.world.config import Servos, World
from heli_sitl.engine.closed_loop import SimOptions, simulate
from heli_sitl.engine.loop_linear import linearize_loop, servo_model

SC = Scenario.load("paper")


def _tlc():  # type: ignore[no-untyped-def]
    return build_controller("tlc", SC.airframe, SC.gains, 100.0)


def test_table2_on_the_paper_plant_is_stable_with_margins() -> None:
    lin = linearize_loop(_tlc(), PlantModel.load("paper"), SC.airframe, Servos(), "ideal")
    assert lin.stable and 0.99 < lin.spectral_radius < 1.0  # the slow integral modes, 0.13 rad/s
    eps = next(b for b in lin.break_points if b.name == "input eps")
    # the balanced disk at the cyclic input: 0.71 (+/- 16.2 dB, +/- 39 deg) with ideal servos
    assert 0.65 < eps.disk_margin < 0.78
    assert 35.0 < eps.phase_margin_deg < 43.0
    # the default servos (10 ms + 20 ms) shrink it to 0.32 (18 deg)
    sv = World.load("servos-default").servos
    slow = linearize_loop(_tlc(), PlantModel.load("paper"), SC.airframe, sv, "default")
    eps2 = next(b for b in slow.break_points if b.name == "input eps")
    assert 0.28 < eps2.disk_margin < 0.36


def test_table2_on_the_rotor_plant_is_unstable_at_the_simulated_limit_cycle() -> None:
    """The linear check predicts a growing rotor-body oscillation; the nonlinear flight shows
    it as a limit cycle of the cyclic between its stops at the same frequency."""
    name, sv = servo_model("ideal")
    lin = linearize_loop(_tlc(), PlantModel.load("gavrilets"), SC.airframe, sv, name)
    assert not lin.stable
    w_lin = abs(lin.dominant_rad_s.imag)
    assert 22.0 < w_lin < 30.0  # 26 rad/s
    rec = simulate(SC, SimOptions(duration_s=20.0, plant=PlantModel.load("gavrilets")))
    e = rec.pitches[rec.t_s >= 10.0, EPS]
    crossings = np.count_nonzero(np.diff(np.sign(e - e.mean())) != 0)
    w_sim = np.pi * crossings / 10.0  # two crossings a period
    print(f"linear {w_lin:.1f} rad/s, simulated limit cycle {w_sim:.1f} rad/s")
    assert w_sim == pytest.approx(w_lin, rel=0.15)
    # and it is a limit cycle, not a divergence: the cyclic sits on its stops, the flight goes on
    assert np.mean(np.abs(e) >= 0.14 - 1e-9) > 0.3
    assert np.all(np.isfinite(rec.x))


def test_margins_match_python_controls_disk_margins() -> None:
    """The batched frequency responses and disk formula give python-control's figures: each
    break point's loop built as a python-control system (ct.feedback) and its disk margin."""
    import control as ct

    from heli_sitl.engine.loop_linear import OMEGA_RAD_S, loop_blocks

    sv = World.load("servos-default").servos
    blocks = loop_blocks(_tlc(), PlantModel.load("paper"), SC.airframe, sv)
    lin = linearize_loop(_tlc(), PlantModel.load("paper"), SC.airframe, sv, "default")
    ctl, pl = blocks.controller.to_control(), blocks.plant.to_control()
    for loop, names in ((-(ctl * pl), lin.break_points[:4]), (-(pl * ctl), lin.break_points[4:])):
        for i, bp in enumerate(names):
            others = np.eye(loop.ninputs)
            others[i, i] = 0.0
            siso = ct.feedback(loop, ct.ss([], [], [], others, loop.dt), sign=-1)[i, i]
            dm, dgm_db, dpm_deg = ct.disk_margins(siso, OMEGA_RAD_S)
            assert bp.disk_margin == pytest.approx(float(dm), rel=1e-6), bp.name
            assert bp.gain_margin_db == pytest.approx(float(dgm_db), rel=1e-6), bp.name
            assert bp.phase_margin_deg == pytest.approx(float(dpm_deg), rel=1e-6), bp.name


def test_linearisation_pipeline_on_loop_4_alone_has_the_known_answer() -> None:
    """A case with a known answer: Table 2's loop 4 (the TLC's rate PI, its constants from the
    kernel's own ``make_constants``) closed around the paper plant's rigid-body rotation at hover
    (``J w' = tau``, exact ZOH at 100 Hz). The tick map goes through the same numerical
    Jacobian, block split, loop breaking and disk formula as the whole loop; the answer is the
    analytic one: per axis ``L(z) = (2 zeta w + w^2 dt/(z-1)) dt/(z-1)``, closed-loop poles near
    ``s = w(-zeta +/- j sqrt(1 - zeta^2))`` = -8.5 +/- 8.5j rad/s, and python-control's disk margin
    of that transfer function."""
    import control as ct

    from autopilot.tlc.controller import Feedforward, make_constants
    from heli_plant.trim import jacobian
    from heli_sitl.engine.loop_linear import Discrete, balanced_disk, loop_at_a_time

    k = make_constants(SC.airframe, SC.gains, 100.0, Feedforward.PSEUDO)
    dt, j, j_inv = k.dt_s, k.j, k.j_inv
    w2, zw2 = k.w2[3], k.zw2[3]

    def control(x: np.ndarray) -> np.ndarray:  # (omega, i4) -> (torque, i4+), rate command 0
        e = -x[:3]
        tau = j @ (w2 * x[3:] + zw2 * e)
        return np.concatenate([tau, x[3:] + dt * e])

    def plant(v: np.ndarray) -> np.ndarray:  # (omega, torque) -> omega+
        return v[:3] + dt * (j_inv @ v[3:])

    def tick(x: np.ndarray) -> np.ndarray:
        c = control(x)
        return np.concatenate([plant(np.concatenate([x[:3], c[:3]])), c[3:]])

    z0 = np.zeros(6)
    lam = np.linalg.eigvals(jacobian(tick, z0, 1e-7))
    # analytic: (z-1)^2 + zw2 dt (z-1) + w2 dt^2 = 0 per axis
    for ax in range(3):
        roots = np.roots([1.0, zw2[ax] * dt - 2.0, 1.0 - zw2[ax] * dt + w2[ax] * dt * dt])
        for r in roots:
            assert np.min(np.abs(lam - r)) < 1e-6
    s = np.log(lam.astype(complex)) / dt
    w, zeta = 12.0, 0.707
    s_exact = w * complex(-zeta, math.sqrt(1 - zeta * zeta))
    # the continuous design within what 100 Hz costs (6.4 % at w dt = 0.12: the explicit integral)
    assert np.all(np.abs(s[s.imag > 0] - s_exact) / abs(s_exact) < 0.08)

    jc = jacobian(control, z0, 1e-7)
    jp = jacobian(plant, np.zeros(6), 1e-7)
    ctl = Discrete(jc[3:, 3:], jc[3:, :3], jc[:3, 3:], jc[:3, :3], dt)
    pl = Discrete(jp[:, :3], jp[:, 3:], np.eye(3), np.zeros((3, 3)), dt)
    omega = np.logspace(-2.0, math.log10(math.pi * 100.0) - 1e-3, 600)
    loop_in = -(ctl.response(omega) @ pl.response(omega))
    zz = ct.tf([1, 0], [1], dt)
    for ax in range(3):
        got = balanced_disk("roll", loop_at_a_time(loop_in, ax))
        analytic = (zw2[ax] + w2[ax] * dt / (zz - 1)) * dt / (zz - 1)
        dm, dgm_db, dpm_deg = ct.disk_margins(analytic, omega)
        assert got.disk_margin == pytest.approx(float(dm), rel=1e-5)
        assert got.phase_margin_deg == pytest.approx(float(dpm_deg), rel=1e-5)
        assert got.gain_margin_db == pytest.approx(float(dgm_db), rel=1e-5)
    # the continuous PI on an integrator (zeta 0.707) has 1.15 (+/- 60 deg); the 100 Hz tick
    # with its explicit integral leaves 1.05 (+/- 56 deg)
    assert 1.00 < got.disk_margin < 1.10
    assert 53.0 < got.phase_margin_deg < 58.0


def _shipped_gain_sets() -> list[tuple[str, str]]:
    """Every configs/gains_*.toml, with its controller (a PID file has a rate loop)."""
    import tomllib

    out = []
    for p in sorted((Path(__file__).parents[1] / "configs").glob("gains_*.toml")):
        out.append(("pid" if "rate" in tomllib.loads(p.read_text()) else "tlc", p.name))
    return out


GAIN_SETS = _shipped_gain_sets()


def test_every_shipped_gain_set_is_found() -> None:
    names = {g for _, g in GAIN_SETS}
    assert {"gains_paper.toml", "gains_tlc_rotor_tuned.toml", "gains_pid.toml"} <= names
    assert ("pid", "gains_pid.toml") in GAIN_SETS and ("tlc", "gains_paper.toml") in GAIN_SETS


@pytest.mark.parametrize(("controller", "gains_file"), GAIN_SETS)
def test_every_shipped_gain_set_passes_at_the_design_point_it_names(controller: str, gains_file: str) -> None:
    """Issue 23's claim: each shipped set names the plant and servos it is for (its [design]
    table), and there the whole closed loop is stable with every break point's disk margin at
    least 0.66 (+/- 6 dB, +/- 36 deg)."""
    import tomllib

    from autopilot.design_point import MIN_DISK_MARGIN
    from autopilot.pid.gains import PidGains
    from autopilot.tlc.gains import Gains

    raw = tomllib.loads((Path(__file__).parents[1] / "configs" / gains_file).read_text())
    assert set(raw.get("design", {})) == {"plant", "servos"}, f"{gains_file}: no [design] table"
    tlc = Gains.load(gains_file) if controller == "tlc" else SC.gains
    pid = PidGains.load(gains_file) if controller == "pid" else None
    design = (pid or tlc).design
    name, sv = servo_model(design.servos)
    c = build_controller(controller, SC.airframe, tlc, 100.0, pid_gains=pid)
    lin = linearize_loop(c, PlantModel.load(design.plant), SC.airframe, sv, name)
    assert lin.stable, lin.summary()
    assert lin.worst().disk_margin >= MIN_DISK_MARGIN, lin.summary()


@pytest.mark.parametrize(("controller", "gains_file"), GAIN_SETS)
def test_every_shipped_gain_set_states_its_margins(controller: str, gains_file: str) -> None:
    """Each gain file's header carries the line `heli-sitl margins` prints for it on both
    plants with the default servos: recomputed here, verbatim."""
    from autopilot.pid.gains import PidGains
    from autopilot.tlc.gains import Gains

    text = (Path(__file__).parents[1] / "configs" / gains_file).read_text()
    tlc = Gains.load(gains_file) if controller == "tlc" else SC.gains
    pid = PidGains.load(gains_file) if controller == "pid" else None
    name, sv = servo_model("servos-default")
    for plant in ("paper", "gavrilets"):
        c = build_controller(controller, SC.airframe, tlc, 100.0, pid_gains=pid)
        line = linearize_loop(c, PlantModel.load(plant), SC.airframe, sv, name).summary()
        assert text.count(line) == 1, line


def test_a_delay_of_several_ticks_linearises_as_the_flights_realise_it() -> None:
    """The tick map keeps the servos' delay ring in canonical order (the next slot to write
    first), so that one map serves every tick: commands through it reach the blades exactly as
    through the flights' own turning ring, here with sloppy-servos' two-tick delay."""
    from heli_common.world.servo_model import SS_FIFO, servo_state, servo_step, servo_table
    from heli_sitl.engine.loop_linear import canonical_fifo

    limits = np.array(SC.airframe.limits.as_tuple())
    params = servo_table(World.load("sloppy-servos").servos, limits, 0.01)
    rest = np.zeros(4)
    ring, canon = servo_state(params, rest), servo_state(params, rest)
    assert (ring.size - SS_FIFO) // 4 == 2  # two slots: the ring turns every tick
    rng = np.random.default_rng(3)
    seen = []
    for _ in range(9):
        cmd = rng.uniform(-0.01, 0.01, 4)
        a, b = np.empty(4), np.empty(4)
        servo_step(params, ring, cmd, a)
        servo_step(params, canon, cmd, b)
        canon = canonical_fifo(canon)
        np.testing.assert_array_equal(a, b)
        seen.append(a.copy())
    assert np.ptp(np.array(seen)) > 1e-3  # the commands did reach the blades
