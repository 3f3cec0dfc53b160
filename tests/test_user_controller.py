"""Your own controller (autopilot/user_controller.py): one class flies in-process, in the
autopilot process and in a campaign; a faulty one never reaches a servo with a bad command."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import heli_sitl as hs
from autopilot.controller_names import ENTRY_POINT_GROUP, registered
from autopilot.scenario import Scenario
from autopilot.user_controller import UserController, is_user_spec, load_class, normalise_spec
from heli_common.config import ConfigError
from heli_common.world.config import World
from heli_sitl.engine.closed_loop import SimOptions, simulate
from heli_sitl.launch.demo import DemoOptions, run_demo

ROOT = Path(__file__).resolve().parent.parent
HERE = Path(__file__).resolve().parent
LQR = f"{ROOT / 'docs/examples/lqr_hover.py'}:LqrHover"
USER = f"{HERE / 'user_controllers.py'}"
LQR_RMS_45_M = 0.0294  # the paper scenario, ideal world, in-process (README, docs/controllers.md)
REGISTERED = "lqr-hover"  # the name the package of the fixture below registers


@pytest.fixture
def lqr_package(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An installed package outside the bench that registers the LQR example by name: its
    module and its distribution's entry point (what ``pip install`` of a package whose
    pyproject.toml has ``[project.entry-points."heli_tlc_sitl.controllers"]`` leaves), on
    this process's path and on its children's."""
    site = tmp_path / "site"
    info = site / "toy_laws-0.1.dist-info"
    info.mkdir(parents=True)
    (site / "toy_laws.py").write_text((ROOT / "docs/examples/lqr_hover.py").read_text())
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-laws\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(
        f"[{ENTRY_POINT_GROUP}]\n{REGISTERED} = toy_laws:LqrHover\ntlc = toy_laws:LqrHover\n")
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")]))
    return site


def test_a_registered_controller_flies_by_its_name(lqr_package: Path) -> None:
    """The entry point group is the registry's third source, beside the built-in names and
    module:Class: the name flies the very flight its class does; a built-in name is never
    shadowed (the package's ``tlc`` entry is ignored); an unknown name lists the registered."""
    assert registered() == {REGISTERED: "toy_laws:LqrHover"}
    assert normalise_spec(REGISTERED) == REGISTERED and is_user_spec(REGISTERED) and not is_user_spec("tlc")
    by_name = hs.simulate(controller=REGISTERED, duration_s=20.0)
    by_class = hs.simulate(controller=f"{lqr_package / 'toy_laws.py'}:LqrHover", duration_s=20.0)
    assert by_name.record is not None and by_class.record is not None
    np.testing.assert_array_equal(by_name.record.x, by_class.record.x)
    assert by_name.controller == "LQR about hover" and by_name.status is hs.ExitStatus.COMPLETED
    assert hs.simulate(controller="tlc", duration_s=1.0).controller.startswith("TLC")
    with pytest.raises(ConfigError, match=r"a registered name \(lqr-hover\)"):
        normalise_spec("lqr-hovr")


@pytest.mark.parametrize("world", [None, "everything", "noisy"])
def test_a_controller_called_from_python_flies_the_compiled_loop_bit_for_bit(world: str | None) -> None:
    """The Python path calls the same compiled sensing and plant steps: the TLC wrapped as a
    user's class flies exactly the compiled TLC's flight (in a world, and on the estimate from sensors)."""
    sc = Scenario.load("paper")
    w = World.load(world) if world else None
    compiled = simulate(sc, SimOptions(world=w, duration_s=30.0))
    python = simulate(sc, SimOptions(world=w, duration_s=30.0, controller=f"{USER}:WrappedTLC"))
    assert np.array_equal(compiled.x, python.x)
    assert np.array_equal(compiled.pitches, python.pitches)
    if world == "noisy":  # flying on the estimate from the sensors
        assert compiled.x_hat is not None and python.x_hat is not None
        assert np.array_equal(compiled.x_hat, python.x_hat)
    assert python.extra["gains"] == "TLC from Python"


def test_the_lqr_example_flies_the_paper_scenario_in_process() -> None:
    out = subprocess.run([sys.executable, str(ROOT / "docs/examples/lqr_hover.py")], capture_output=True,
                         text=True, timeout=300, check=True, cwd=ROOT)  # fmt: skip
    assert out.stdout.strip() == f"LQR about hover: completed, RMS [45, 120] s = {LQR_RMS_45_M:.4f} m"
    f = hs.simulate(controller=LQR)
    assert f.status is hs.ExitStatus.COMPLETED and f.controller == "LQR about hover"
    assert f.metrics is not None and f.metrics.rms_m["45-120"] == pytest.approx(LQR_RMS_45_M, abs=5e-5)


@pytest.mark.processes
def test_the_lqr_example_flies_in_lockstep_processes_as_in_process(tmp_path: Path, lqr_package: Path) -> None:
    """The autopilot process loads the user's class from --controller, here by the name its
    package registers (the file's ``module:Class`` flies over processes in
    test_user_controller_realtime): the same flight."""
    summary = run_demo(DemoOptions(mode="lockstep", out=tmp_path / "run", timeout_s=300, via_ground=False,
                                   extra_autopilot_args=("--controller", REGISTERED)))  # fmt: skip
    assert summary["controller"] == REGISTERED and summary["gains"] == "LQR about hover"
    rms = summary["rms_pos_err_m"]
    assert isinstance(rms, dict)
    assert rms["45-120"] == pytest.approx(LQR_RMS_45_M, abs=2e-4)  # float32 on the sim link
    assert summary["loop"]["bad_outputs"] == 0  # type: ignore[index]


def test_the_lqr_example_flies_a_50_flight_campaign(tmp_path: Path) -> None:
    """50 robustness samples (mismatch, wind, servos), each 20 s, flown on Dask workers that
    load the class from its file: none fails (raises); the linear law leaves the safety envelope
    in 22 (docs/controllers.md: from the scenario's start 5.2 m off the path it banks past 60 deg
    in its first second in 18, and strikes the ground in 4), the other 28 converge within
    0.5 m (under the old rule, which forgave what came back: 1 lost, 49). Without its 17 figures (34 s
    of CPU; test_campaign draws a campaign's figures), which a re-run over the directory
    then draws without flying again."""
    camp = tmp_path / "lqr.toml"
    text = (ROOT / "configs/campaigns/robustness.toml").read_text()
    camp.write_text(text.replace('samples = 1000', 'samples = 50\nduration_s = 20.0'))
    out = subprocess.run(
        [sys.executable, "-m", "heli_sitl.cli", "campaign", str(camp), "--out", str(tmp_path / "out"),
         "--controller", LQR, "--workers", "2", "--quiet", "--no-figures"],
        capture_output=True, text=True, timeout=600, cwd=ROOT,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    summary = json.loads((tmp_path / "out/campaign.json").read_text())
    counts = summary["counts"]
    assert counts["flights"] == 50 and counts["failed"] == 0
    assert counts["diverged"] == 22 and counts["converged"] == 28  # deterministic: pinned
    assert counts["diverged_by_reason"] == {"ground strike": 4, "tilt > 60 deg": 18}
    assert summary["figures"] == [] and not list((tmp_path / "out").glob("*.png"))


def test_a_bad_name_is_refused_with_what_is_wrong() -> None:
    with pytest.raises(ConfigError, match="no file"):
        normalise_spec("nowhere/none.py:Law")
    with pytest.raises(ConfigError, match="has no class 'Nope'"):
        normalise_spec(f"{USER}:Nope")
    with pytest.raises(ConfigError, match=r"lacks reset\(\)"):
        load_class(f"{USER}:NoReset")
    with pytest.raises(ConfigError, match="cannot import no_such_package"):
        normalise_spec("no_such_package.law:Law")
    with pytest.raises(ConfigError, match="'tlc', 'pid'"):
        normalise_spec("lqr")
    out = subprocess.run([sys.executable, "-m", "heli_sitl.cli", "simulate", "--controller", "x.py:Y"],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert out.returncode == 2 and "no file" in out.stderr


def test_in_process_a_raising_controller_ends_the_flight_failed_with_its_traceback() -> None:
    f = hs.simulate(controller=f"{USER}:RaisesAfter5s", duration_s=10.0)
    assert f.status is hs.ExitStatus.FAILED and f.metrics is None
    assert "RuntimeError: a bug in the user's law" in f.error and "user_controllers.py" in f.error
    g = hs.simulate(controller=f"{USER}:WrongShapeAfter5s", duration_s=10.0)
    assert g.status is hs.ExitStatus.FAILED and "shape (3,)" in g.error


@pytest.mark.parametrize("fault", ["Faulty", "RaisesAfter5s", "WrongShapeAfter5s"])
def test_a_flying_autopilot_holds_the_last_valid_command_whatever_the_users_code_does(fault: str) -> None:
    """Not strict (the autopilot process): NaN, an exception or a wrong shape never reach a
    servo; the last valid command is held and the tick is counted as a bad output."""
    sc = Scenario.load("paper")
    c = UserController(f"{USER}:{fault}", sc.airframe, 100.0, strict=False)
    x = sc.initial.state().to_array()
    ref = np.zeros(9)
    ref[0:3] = x[0:3]
    good = c.update(4.99, x, ref)
    assert c.status == 0 and np.all(np.isfinite(good))
    for t in (5.0, 5.01):
        held = c.update(t, x, ref)
        assert np.array_equal(held, good) and c.status == 2  # BAD_OUTPUT
    x_bad = x.copy()
    x_bad[0] = np.nan
    assert np.array_equal(c.update(5.02, x_bad, ref), good) and c.status == 1  # BAD_INPUT: not called
    assert c.errors == (2 if fault == "RaisesAfter5s" else 0)


def test_the_command_is_clipped_to_the_pitch_limits_and_reported_saturated() -> None:
    sc = Scenario.load("paper")

    class Wild:
        def __init__(self, airframe: object, rate_hz: float) -> None:
            pass

        def update(self, t_s: float, state: np.ndarray, reference: np.ndarray) -> np.ndarray:
            return np.array([5.0, 0.0, 0.0, -5.0])

        def reset(self) -> None:
            pass

    c = UserController(Wild, sc.airframe, 100.0, strict=True)
    u = c.update(0.0, sc.initial.state().to_array(), np.zeros(9))
    lim = sc.airframe.limits
    assert u[0] == lim.theta_m_rad[1] and u[3] == lim.eta_rad[0]
    assert c.diag[4] == 0b1001  # D_SAT_MASK: theta_m and eta
