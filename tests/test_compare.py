"""Tuning and comparing controllers (heli-sitl tune, heli-sitl compare): the same procedure
for both, files that load back, a report whose numbers are the flights' own."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from autopilot.pid.gains import PidGains
from autopilot.scenario import Scenario
from heli_common.config import ConfigError
from heli_sitl.engine.closed_loop import SimOptions, simulate
from heli_sitl.studies.comparison import Contender, largest_converged, load_compare, run_compare
from heli_sitl.studies.scorecard import score
from heli_sitl.studies.tune import (
    CONSTRAINT_COST_M,
    Knob,
    MarginConstraint,
    Tuner,
    _get,
    pid_knobs,
    tlc_knobs,
    tune,
    with_knobs,
    write_gains,
)


@given(st.floats(0.0, 1.0), st.booleans())
def test_a_knob_maps_its_unit_interval_onto_its_range_and_back(u: float, log: bool) -> None:
    k = Knob("rate", "kp", (0, 1), 0.5, 50.0, log=log)
    v = k.from_unit(u)
    assert 0.5 <= v <= 50.0 + 1e-9
    assert k.to_unit(v) == pytest.approx(u, abs=1e-9)


def test_knobs_cover_both_controllers_alike_and_set_what_they_name() -> None:
    sc = Scenario.load("paper")
    pid = PidGains.load("starts/pid_table2.toml")
    kp, kt = pid_knobs(pid), tlc_knobs(sc.gains)
    assert len(kp) == len(kt) == 13  # the same number of degrees of freedom
    g = with_knobs(pid, kp[:1], [1.25])
    assert g.position.kp == (1.25, 1.25, pid.position.kp[2])  # x and y share a knob, z its own
    t = with_knobs(sc.gains, [k for k in kt if k.name == "differentiator.omega_rad_s"], [7.5])
    assert (
        t.differentiator.omega_rad_s == 7.5 and t.loop4_attitude_dynamics == sc.gains.loop4_attitude_dynamics
    )
    with pytest.raises(ConfigError):  # outside a gain's range in its file's spec
        with_knobs(pid, kp[:1], [500.0])


def test_the_cost_is_the_worst_flight_and_the_flights_are_the_simulator_s() -> None:
    sc = Scenario.load("paper")
    pid = PidGains.load("starts/pid_table2.toml")
    knobs = pid_knobs(pid)
    tuner = Tuner(sc, "pid", "pseudo", pid, knobs)
    start = [k.from_unit(k.to_unit(getattr(getattr(pid, k.section), k.field)[k.index[0]])) for k in knobs]
    flights = tuner.flights(start)
    assert [f.world for f in flights] == ["ideal", "servos-default", "everything"]
    rec = simulate(sc, SimOptions(controller="pid", pid_gains=pid))
    assert flights[0].rms_10_m == pytest.approx(rec.summary()["rms_pos_err_m"]["10-120"], rel=1e-9)
    cost = tuner(np.array([k.to_unit(v) for k, v in zip(knobs, start, strict=True)]))
    assert cost == max(f.cost_m for f in flights)


def test_the_margin_constraint_keeps_fragile_candidates_from_flying() -> None:
    """Table 2 on the rotor plant has no margin at all (its loop is unstable, max |lambda|
    1.0627): the constraint prices it at 50 m + 10 x (0.66 + 10 x 0.0627) unflown, the way back
    to stability in its slope; the rotor-aware set (worst disk margin 0.69) passes and flies
    its three flights on the rotor plant."""
    con = MarginConstraint(0.66, "gavrilets", "servos-default")
    for gains, rejected in (("gains_paper.toml", True), ("gains_tlc_rotor.toml", False)):
        sc = Scenario.load("paper", gains=gains)
        knobs = tlc_knobs(sc.gains)
        tuner = Tuner(sc, "tlc", "pseudo", sc.gains, knobs, plant="gavrilets", constraint=con)
        u = np.array([k.to_unit(_get(sc.gains, k)) for k in knobs])
        cost = tuner(u)
        assert tuner.rejected == int(rejected)
        if rejected:
            assert cost == pytest.approx(CONSTRAINT_COST_M + 10.0 * (0.66 + 10.0 * 0.0627), abs=0.02)
        else:
            assert 0.2 < cost < 0.33  # the worst of its flights, measured 0.259 m


@pytest.mark.slow
def test_a_short_tuning_never_ends_worse_and_writes_gains_that_load_back(tmp_path: Path) -> None:
    sc = Scenario.load("paper")
    r = tune(sc, "pid", budget=30, start=PidGains.load("starts/pid_table2.toml"))
    before, after = r.cost(r.start_flights), r.cost(r.best_flights)
    print(f"PID tuning, 30 evaluations: {before:.4f} -> {after:.4f} m")
    assert r.evaluations >= 30 and after <= before + 1e-3  # rounding to 4 digits may cost a hair
    out = tmp_path / "pid.toml"
    write_gains(r, out, "test")
    loaded = PidGains.load(out)
    assert loaded == dataclasses.replace(r.gains, name=loaded.name)
    assert "Nelder-Mead" in out.read_text() and "Command: test" in out.read_text()


COMPARE = """
name = "two"
plants = ["paper"]
reference = "TLC paper"
seeds = 3
max_speed_m_s = 5.0
worlds = ["calm", "light-turbulence"]
campaigns = ["{campaign}"]

[[trajectory]]
name = "position_step"

[[contender]]
label = "TLC paper"
controller = "tlc"
gains = "gains_paper.toml"

[[contender]]
label = "PID"
controller = "pid"
pid_gains = "gains_pid_rotor.toml"
[contender.plant.paper]             # on the paper plant it flies these instead
pid_gains = "starts/pid_table2.toml"
"""

GRID = """
name = "grid"
sampler = "grid"
duration_s = 15.0
[[vary]]
key = "servo.delay_s"
dist = "grid"
values = [0.0, 0.2]
[[vary]]
key = "servo.tau_s"
dist = "grid"
values = [0.0, 0.05]
"""


def test_bad_comparison_files_are_refused(tmp_path: Path) -> None:
    f = tmp_path / "c.toml"
    for text, expected in (
        ('name = "x"\n', "at least one [[contender]]"),
        ('[[contender]]\nlabel = "a"\ncontroller = "lqr"\n', "controller"),
        ('[[contender]]\nlabel = "a"\ngains = "nowhere.toml"\n', "nowhere.toml"),
        ('worlds = ["nowhere"]\n[[contender]]\nlabel = "a"\n', "nowhere"),
        ('[[contender]]\nlabel = "a"\n[[contender]]\nlabel = "A"\n', "labels must differ"),
        ('contenders = 1\n[[contender]]\nlabel = "a"\n', "unknown key 'contenders'"),
        ('plant = "gavrilet"\n[[contender]]\nlabel = "a"\n', "expected paper, gavrilets, a plant file"),
        ('reference = "b"\n[[contender]]\nlabel = "a"\n', "reference 'b' is not a contender"),
        ('seeds = 1\n[[contender]]\nlabel = "a"\n', "seeds"),
        ('[[contender]]\nlabel = "a"\n[contender.plant.paper]\ngain = "x.toml"\n', "unknown key 'gain'"),
        ('[[contender]]\nlabel = "a"\n[contender.plant.paper]\ngains = "nowhere.toml"\n', "nowhere.toml"),
        ('reference = {paper = "b"}\n[[contender]]\nlabel = "a"\n', "'b' is not a contender"),
        ('reference = {gavrilets = "a"}\n[[contender]]\nlabel = "a"\n', "not one of the plants"),
        ('[[trajectory]]\nname = "nowhere"\n[[contender]]\nlabel = "a"\n', "nowhere"),
        ('[[trajectory]]\nname = "paper"\nmc_world = "nowhere"\n[[contender]]\nlabel = "a"\n', "nowhere"),
    ):
        f.write_text(text)
        with pytest.raises(ConfigError) as err:
            load_compare(f)
        assert expected in str(err.value), (text, str(err.value))
    shipped = load_compare()  # the shipped file loads
    assert [c.label for c in shipped.contenders][-1] == "PID, ArduPilot-style"
    assert shipped.plants == ("gavrilets", "paper")
    assert Contender("TLC, paper Table 2").slug == "tlc-paper-table-2"
    # each contender flies the gains tuned for the plant it is on; each plant has its reference
    pid = {c.label: c for c in shipped.contenders}["PID, ArduPilot-style"]
    assert pid.on("gavrilets").pid_gains == "gains_pid_rotor.toml"
    assert pid.on("paper").pid_gains == "gains_pid.toml"
    assert shipped.reference_for("gavrilets") == "TLC, rotor-aware"
    assert shipped.reference_for("paper") == "TLC, paper Table 2"


@pytest.mark.slow
def test_compare_reports_the_flights_own_numbers(tmp_path: Path) -> None:
    grid = tmp_path / "grid.toml"
    grid.write_text(GRID)
    f = tmp_path / "two.toml"
    f.write_text(COMPARE.format(campaign=grid))
    out = tmp_path / "report"
    res = run_compare(f, out, tmp_path / "work", workers=1, quiet=True, command="heli-sitl compare test")
    paper = res["plants"]["paper"]
    # the one flight of a trajectory is the simulator's, scored, with the common speed limit
    table2 = PidGains.load("starts/pid_table2.toml")
    table2 = dataclasses.replace(table2, position=dataclasses.replace(table2.position, max_speed_m_s=5.0))
    sc = Scenario.load("position_step")
    direct = score(simulate(sc, SimOptions(controller="pid", pid_gains=table2)), sc)
    assert paper["trajectories"]["position_step"]["PID"] == direct.as_dict()
    # the step's transient as measured: the paper TLC (slow integral loops) settles within 0.1 m
    # 11.6 s after the step starts, 0.45 m past the target on the way
    tlc = paper["trajectories"]["position_step"]["TLC paper"]
    assert 10.0 < tlc["settling_s"] < 13.5 and 0.38 < tlc["overshoot_m"] < 0.52
    # the Monte Carlo sets: calm is deterministic, turbulence is not; paired against the reference
    sets = {m["title"]: m for m in paper["monte_carlo"]}
    assert sets["position_step in calm"]["deterministic"] and not sets["position_step in light-turbulence"][
        "deterministic"
    ]
    turb = sets["position_step in light-turbulence"]["by"]["PID"]["steady_rms_m"]
    assert turb["vs_reference"]["n"] == 3
    assert turb["p50"]["lo"] <= turb["p50"]["estimate"] <= turb["p50"]["hi"]
    camp = paper["campaigns"]["grid"]
    assert camp["PID"]["flights"] == camp["TLC paper"]["flights"] == 4
    text = (out / "report.md").read_text()
    assert "heli-sitl compare test" in text and "| PID |" in text and "(reference)" in text
    assert "Wilcoxon" in text and "deterministic" in text
    saved = json.loads((out / "comparison.json").read_text())
    assert saved["plants"]["paper"]["trajectories"] == paper["trajectories"]
    assert (out / "paper_campaign_grid.png").stat().st_size > 10_000
    # a re-run resumes the campaigns: nothing is flown twice
    res2 = run_compare(f, out, tmp_path / "work", workers=1, quiet=True)
    assert res2["plants"]["paper"]["campaigns"]["grid"] == camp


def test_largest_converged_reads_a_grid() -> None:
    import pyarrow as pa

    t = pa.table({"a": [0.0, 0.0, 1.0, 1.0, 2.0, 2.0], "b": [0.0, 1.0, 0.0, 1.0, 0.0, 1.0],
                  "converged": [True, True, True, False, False, False], "failed": [False] * 6})  # fmt: skip
    assert largest_converged(t, "a", {"b": 0.0}) == 1.0
    assert largest_converged(t, "a") == 0.0
    assert largest_converged(t, "b", {"a": 2.0}) != largest_converged(t, "b", {"a": 2.0})  # NaN: none
