"""The world in the plant, flown by the TLC in-process: off means exactly today; steady
loads (drag in a steady wind, an injected force, a heavier airframe) move the hover trim
as the equations say; one seed fixes the air; every preset flies the paper scenario."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from autopilot.metrics import FlightRecord
from autopilot.scenario import Scenario
from autopilot.trajectory.analytic import StraightLine
from heli_common.config import ConfigError
from heli_common.kinematics import rot_body_to_earth
from heli_common.state import EPS, ETA, PHI, PSI, THETA, THETA_M
from heli_common.vehicle import rotor
from heli_common.vehicle.scenario_file import InitialState
from heli_common.world.config import AirLoads as Air
from heli_common.world.config import Disturbance, Mismatch, Wind, World
from heli_plant.dynamics import forces_from_loads, rotor_loads
from heli_plant.model import Plant
from heli_plant.world import air
from heli_sitl.engine.closed_loop import SimOptions, simulate

PRESETS = ("calm", "breezy", "gusty", "servos-default", "sloppy-servos", "heavy-10pct", "everything")
HOVER_M = (0.0, 0.0, 10.0)


@pytest.fixture(scope="module")
def paper() -> Scenario:
    return Scenario.load("paper")


def hover(paper: Scenario, duration_s: float = 40.0) -> Scenario:
    """The paper's vehicle and gains holding a point 10 m up, starting there."""
    return dataclasses.replace(
        paper,
        trajectory=StraightLine(start_nwu_m=HOVER_M, duration_s=duration_s),
        initial=InitialState(pos_nwu_m=HOVER_M),
        run=dataclasses.replace(paper.run, duration_s=duration_s),
    )


def rotor_force_earth(rec: FlightRecord, scenario: Scenario, plant_airframe_constants: object) -> np.ndarray:
    """The rotors' force (gravity taken out), earth NWU, averaged over the last 5 s."""
    c = plant_airframe_constants
    out = []
    for x, u in zip(rec.x[-500:], rec.pitches[-500:], strict=True):
        tm, qm, tt, qt = rotor_loads(u[THETA_M], u[1], c)  # type: ignore[arg-type]
        f, _ = forces_from_loads(x, u, c, tm, qm, tt, qt)  # type: ignore[arg-type]
        r = rot_body_to_earth(x[PHI], x[THETA], x[PSI])
        mg = c.mass_kg * c.gravity_m_s2  # type: ignore[attr-defined]
        out.append(r @ f + np.array([0.0, 0.0, mg]))  # body gravity rotated back is (0, 0, -mg)
    return np.mean(out, axis=0)


def test_a_calm_world_is_the_ideal_world_bit_for_bit(paper: Scenario) -> None:
    opts = SimOptions(duration_s=30.0)
    base = simulate(paper, opts)
    for world in (World(), World.load("calm")):
        rec = simulate(paper, dataclasses.replace(opts, world=world))
        assert np.array_equal(rec.x, base.x) and np.array_equal(rec.pitches, base.pitches)
    assert Plant(paper.airframe, paper.initial.state().to_array(), world=World()).world is None


@pytest.mark.parametrize("case", ["drag", "push"])
def test_a_steady_horizontal_load_tilts_the_rotor_force_by_its_angle(paper: Scenario, case: str) -> None:
    """Holding position, the rotors must cancel the load: their force leans by
    atan(load / weight). Drag: 5 m/s from the north on the frontal flat plate,
    F = (rho/2) V^2 S_x = 1.53 N downwind; push: an injected 3 N toward the east."""
    sc = hover(paper)
    if case == "drag":
        world = World(wind=Wind(speed_m_s=5.0, from_deg=0.0), air=Air(fuselage=True))
        rho, s_x = paper.airframe.air.density_kg_m3, world.air.fuselage_areas_m2[0]
        load = np.array([-0.5 * rho * 25.0 * s_x, 0.0, 0.0])  # air moves south: drag points south
        # the same number from the model's own drag function (air-relative velocity +5 m/s north)
        assert load[0] == pytest.approx(air.fuselage_force_flu(5.0, 0.0, 0.0, 0.0, s_x, 0.22, 0.15, rho)[0])
    else:
        world = World(disturbance=Disturbance(force_n=(0.0, -3.0, 0.0)))  # NWU: east is -y
        load = np.array([0.0, -3.0, 0.0])
    rec = simulate(sc, SimOptions(world=world))
    pos_err = rec.pos_err_m[-500:]
    assert pos_err.max() < 0.02, pos_err.max()  # the integrators took the load
    c = paper.airframe.constants()
    f = rotor_force_earth(rec, sc, c)
    weight = c.mass_kg * c.gravity_m_s2
    lean = math.atan2(math.hypot(f[0], f[1]), f[2])
    predicted = math.atan2(float(np.linalg.norm(load)), weight)
    print(f"{case}: rotor force {f.round(3)} N, lean {lean:.5f} rad, predicted {predicted:.5f} rad")
    assert f[:2] == pytest.approx(-load[:2], abs=0.02 * np.linalg.norm(load))
    assert lean == pytest.approx(predicted, rel=0.02)


def test_a_heavier_plant_needs_the_collective_the_rotor_map_predicts(paper: Scenario) -> None:
    sc = hover(paper)
    world = World(mismatch=Mismatch(mass=1.1))
    rec = simulate(sc, SimOptions(world=world))
    nominal = simulate(sc)
    assert rec.pos_err_m[-500:].max() < 0.02
    plant = world.mismatch.apply(paper.airframe).constants()
    x, u = rec.x[-500:].mean(axis=0), rec.pitches[-500:].mean(axis=0)
    # hover: the main thrust's body-z share carries the weight, eq 12's third row
    seps, seta = math.sin(u[EPS]), math.sin(u[ETA])
    d = math.sqrt(1.0 - seps**2 * seta**2)
    tm = plant.mass_kg * plant.gravity_m_s2 * math.cos(x[THETA]) * math.cos(x[PHI]) * d / (
        math.cos(u[EPS]) * math.cos(u[ETA]))  # fmt: skip
    predicted = rotor.pitch_from_thrust_coeff(tm / plant.thrust_scale_m, plant.a_m, plant.s_m)
    flown = u[THETA_M]
    print(f"collective: nominal {nominal.pitches[-500:, THETA_M].mean():.5f}, +10 % mass {flown:.5f}, "
          f"rotor map {predicted:.5f} rad")  # fmt: skip
    assert flown == pytest.approx(predicted, rel=2e-3)
    assert flown > nominal.pitches[-500:, THETA_M].mean() * 1.04


def test_one_seed_fixes_the_air_and_another_changes_it(paper: Scenario) -> None:
    opts = SimOptions(duration_s=20.0)
    gusty = World.load("gusty")
    a = simulate(paper, dataclasses.replace(opts, world=gusty))
    b = simulate(paper, dataclasses.replace(opts, world=gusty))
    c = simulate(paper, dataclasses.replace(opts, world=dataclasses.replace(gusty, seed=gusty.seed + 1)))
    assert a.air_nwu_m_s is not None and b.air_nwu_m_s is not None and c.air_nwu_m_s is not None
    assert np.array_equal(a.x, b.x) and np.array_equal(a.air_nwu_m_s, b.air_nwu_m_s, equal_nan=True)
    assert np.nanmax(np.abs(a.air_nwu_m_s - c.air_nwu_m_s)) > 0.1
    # the turbulence rides on the 5 m/s mean wind from the north (air moving south): at 3 m
    # up, sigma_u = 1.5 m/s correlated over L_u/V = 4.6 s, so a 20 s mean is within 3 sigma of
    # 3 x 1.5 x sqrt(2 x 4.6 / 20) = 3.1 m/s of it
    assert np.nanmean(a.air_nwu_m_s[:, 0]) == pytest.approx(-5.0, abs=3.1)


@pytest.mark.parametrize("name", PRESETS)
def test_every_preset_flies_the_paper_scenario(paper: Scenario, name: str) -> None:
    """Every preset runs end to end. With the paper's Table 2 gains, sloppy servos (20 ms
    delay, 30 ms lag, rate limits) do not hold the path: the start transient drives the
    cyclic into its rate limit and the attitude loops depart (the linear analysis gives
    12 deg of phase margin before any saturation)."""
    world = World.load(name)
    rec = simulate(paper, SimOptions(world=world))
    s = rec.summary()
    rms = s["rms_pos_err_m"]["45-120"]
    print(f"{name}: RMS [45, 120] s {rms:.4f} m, max after 10 s {rec.pos_err_m[rec.t_s >= 10].max():.3f} m")
    assert np.all(np.isfinite(rec.x))
    if name == "sloppy-servos":
        assert rms > 1.0, rms
    else:
        assert rms < 1.0, rms
    assert rec.extra.get("world", {}).get("name", "calm") == name if world.on else "world" not in rec.extra


def test_a_world_file_with_wind_but_no_air_is_refused(tmp_path: object) -> None:
    from pathlib import Path

    p = Path(str(tmp_path)) / "w.toml"
    p.write_text("[wind]\nspeed_m_s = 3.0\n")
    with pytest.raises(ConfigError, match="the air would not act"):
        World.load(p)
    p.write_text("[wind]\nsped_m_s = 3.0\n")
    with pytest.raises(ConfigError, match="did you mean 'speed_m_s'"):
        World.load(p)


def test_simulate_shows_the_world(tmp_path: object) -> None:
    """`heli-sitl simulate --world` writes Fig 10 and world.csv (the air and the servo
    positions per tick) and names the world in summary.json; a bad world is a usage error."""
    import csv
    import json
    from pathlib import Path

    from heli_sitl import cli

    out = Path(str(tmp_path)) / "out"
    assert cli.main(["simulate", "--world", "servos-default", "--duration-s", "5", "--quiet",
                     "--gains", "gains_servo_aware.toml", "--out", str(out)]) == 0  # fmt: skip
    assert (out / "fig10_world.png").stat().st_size > 10_000
    with (out / "world.csv").open() as fh:
        rows = list(csv.reader(fh))
    assert rows[0][:4] == ["t_s", "air_n_m_s", "air_w_m_s", "air_u_m_s"] and len(rows) == 502
    run = np.loadtxt(out / "run.csv", delimiter=",", skiprows=1)
    reached = np.array(rows[1:], dtype=float)[:, 4:8]
    commanded = run[:, 11:15]
    # the servos lag the command (10 ms delay, 20 ms lag), and follow it
    assert np.isnan(reached[0]).all() and 0.0 < np.abs(reached[1:] - commanded[1:]).max() < 0.3
    summary = json.loads((out / "summary.json").read_text())
    assert summary["world"]["name"] == "servos-default"
    assert summary["world"]["servos"]["delay_s"] == [0.01] * 4
    assert summary["gains"] == "servo-aware"
    assert cli.main(["simulate", "--world", "nosuchworld", "--out", str(out)]) == 2


def test_the_summary_states_the_plant_beside_the_design(paper: Scenario) -> None:
    rec = simulate(paper, SimOptions(duration_s=2.0, world=World.load("everything")))
    diff = rec.extra["world"]["plant_vs_design"]
    c = paper.airframe.constants()
    assert diff["mass_kg"] == pytest.approx([1.1 * c.mass_kg, c.mass_kg])
    assert diff["ixx"] == pytest.approx([1.1 * c.ixx, c.ixx])
    # rotor speed -3 %: thrust per unit coefficient goes as Omega^2
    assert diff["thrust_scale_m"][0] / diff["thrust_scale_m"][1] == pytest.approx(0.97**2)
    assert "a_m" not in diff  # the lift slope was not changed


def test_a_bad_world_is_refused_before_anything_starts() -> None:
    """Every command that takes --world refuses a missing one at once (usage error, exit 2),
    the autopilot included even without its ground-station link."""
    from autopilot import cli as autopilot_cli
    from heli_sitl import cli

    assert cli.main(["run", "--world", "nosuchworld"]) == 2
    assert autopilot_cli.main(["--world", "nosuchworld", "--no-gcs"]) == 2
