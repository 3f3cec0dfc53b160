"""The Python API (heli_sitl/api.py): one call, typed results, the same numbers as the CLI
and the campaigns."""

from __future__ import annotations

import doctest
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import heli_sitl as hs
from autopilot.scenario import Scenario
from heli_common.config import ConfigError
from heli_sitl import api
from heli_sitl.engine.closed_loop import SimOptions, simulate
from heli_sitl.studies.campaigns.flight import metrics as campaign_metrics
from heli_sitl.studies.campaigns.spec import CampaignSpec


def test_the_module_examples_run() -> None:
    result = doctest.testmod(api, optionflags=doctest.ELLIPSIS, extraglobs={"hs": hs})
    assert result.attempted >= 5 and result.failed == 0


def test_one_line_from_a_shell_prints_the_papers_figure() -> None:
    code = "import heli_sitl as hs; f = hs.simulate(); print(round(f.metrics.rms_m['45-120'], 4))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         check=True)  # fmt: skip
    assert out.stdout.strip() == "0.0402"


@pytest.fixture(scope="module")
def paper() -> hs.FlightResult:
    return hs.simulate()


def test_a_flight_is_the_simulators_flight_with_named_arrays(paper: hs.FlightResult) -> None:
    rec = simulate(Scenario.load("paper"), SimOptions())
    np.testing.assert_array_equal(paper.state, rec.x)
    np.testing.assert_array_equal(paper.pitches, rec.pitches)
    df = paper.to_pandas()
    assert df.index.name == "t_s" and len(df) == rec.t_s.size == 12001
    assert {"x_m", "psi_rad", "r_rad_s", "x_ref_m", "theta_m_rad", "eta_rad", "pos_err_m"} <= set(df.columns)
    np.testing.assert_array_equal(df["q_rad_s"].to_numpy(), rec.x[:, 10])
    assert paper.to_arrow().num_rows == 12001
    assert paper.status is hs.ExitStatus.COMPLETED and paper.controller == "TLC" and paper.world == "ideal"


def test_the_metrics_are_the_campaigns_row_and_the_summarys(paper: hs.FlightResult) -> None:
    """One parser: the API's metrics, a campaign's columns and the summary agree exactly."""
    m = paper.metrics
    assert m is not None and paper.record is not None
    spec = CampaignSpec(name="x")
    assert campaign_metrics(paper.record, spec) == {k: v for k, v in m.row().items() if k in spec.metrics}
    s = paper.record.summary()
    assert m.rms_m == s["rms_pos_err_m"] and m.rms_45_m == s["rms_pos_err_m"]["45-120"]
    assert m.max_err_after_10_s_m == s["max_pos_err_m"]["10-120"]
    assert m.converged and not m.lost and 0.0 <= m.saturated_fraction < 0.01


def test_save_writes_the_columns_and_what_flew(paper: hs.FlightResult, tmp_path: Path) -> None:
    import pyarrow.parquet as pq

    d = paper.save(tmp_path / "f")
    meta = json.loads((d / "flight.json").read_text())
    assert meta["status"] == "completed"
    assert meta["metrics"]["rms_m"]["45-120"] == pytest.approx(0.0402, abs=5e-5)
    assert pq.read_table(d / "flight.parquet").num_rows == 12001
    ax = paper.plot()
    assert ax.get_ylabel() == "position error [m]"


def test_objects_names_and_paths_fly_the_same() -> None:
    """The PID by name and by object with its shipped file; a world with a seed; a plant by
    name: the same flight either way."""
    a = hs.simulate("position_step", controller="pid", duration_s=20.0)
    b = hs.simulate("position_step", controller=hs.PID("gains_pid.toml"), duration_s=20.0)
    np.testing.assert_array_equal(a.state, b.state)
    c = hs.simulate("position_step", world="light-turbulence", seed=4, duration_s=20.0)
    d = hs.simulate("position_step", world="light-turbulence", seed=4, duration_s=20.0)
    e = hs.simulate("position_step", world="light-turbulence", seed=5, duration_s=20.0)
    np.testing.assert_array_equal(c.state, d.state)
    assert not np.array_equal(c.state, e.state)


def test_a_lost_flight_says_so() -> None:
    """The rotor-aware gains on the paper's plant (unstable there, 6 rad/s: docs/comparison.md)
    through the aggressive turn: lost, with the reason."""
    f = hs.simulate("aggressive_turn", controller=hs.TLC("gains_tlc_rotor.toml"))
    assert f.status is hs.ExitStatus.LOST and f.metrics is not None
    assert f.metrics.lost_reason == "tilt > 60 deg (61 deg at t = 2.61 s)"  # deterministic: pinned


@pytest.mark.parametrize(("kwargs", "expected"), [
    ({"scenario": "nowhere"}, "nowhere"),
    ({"plant": "gavrilet"}, "gavrilet"),
    ({"world": "stormy"}, "stormy"),
    ({"controller": "lqr"}, "controller"),
    ({"controller": hs.TLC("no_such_gains.toml")}, "no_such_gains.toml"),
    ({"estimator": "nope"}, "nope"),
    ({"seed": -1}, "seed"),
    ({"seed": 2**60}, "seed"),
    ({"duration_s": -5.0}, "duration_s"),
    ({"duration_s": float("nan")}, "duration_s"),
])  # fmt: skip
def test_bad_arguments_raise_a_config_error_naming_them(kwargs: dict[str, object], expected: str) -> None:
    with pytest.raises(ConfigError, match=expected):
        hs.simulate(**kwargs)  # type: ignore[arg-type]


def test_a_trajectory_from_a_csv_table_or_any_object_with_sample(tmp_path: Path) -> None:
    root = Path(__file__).resolve().parent.parent
    f = hs.simulate(trajectory=root / "docs/examples/trajectory_box.csv")
    assert f.status is hs.ExitStatus.COMPLETED and f.t_s[-1] == pytest.approx(80.0)  # the table's length
    assert f.metrics is not None and f.metrics.rms_m["45-80"] == pytest.approx(0.162, abs=0.002)

    class Hover:  # any object with the contract's sample(t): hold 3 m above (3, -3)
        duration_s = 20.0

        def sample(self, t: np.ndarray) -> np.ndarray:
            out = np.zeros((np.size(t), 9))
            out[:, 0:3] = (3.0, -3.0, 3.0)
            return out

    g = hs.simulate(trajectory=Hover())
    assert g.t_s[-1] == pytest.approx(20.0) and g.metrics is not None
    assert g.metrics.max_err_after_10_s_m == pytest.approx(0.155, abs=0.005)  # the paper TLC settling slowly
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,x_m,y_m,z_m\n0,0,0,1\n1,0,0,nan\n")
    with pytest.raises(ConfigError, match=r"line 3 \(data row 2\)"):
        hs.simulate(trajectory=bad)
    with pytest.raises(ConfigError, match="an object with sample"):
        hs.simulate(trajectory=42)  # type: ignore[arg-type]
