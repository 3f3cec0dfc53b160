"""The plant contract (heli_plant/vehicle.py): a model defined outside the package flies
in-process and in lockstep, by ``file.py:Class`` and by the name its package registers,
and trims; the paper's model through the contract is the compiled plant's."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

import heli_sitl as hs
from heli_common.config import ConfigError
from heli_common.state import THETA_M, FloatArray
from heli_common.vehicle.airframe import Airframe
from heli_common.vehicle.plant_model import PLANT_ENTRY_POINT_GROUP, PlantModel
from heli_plant import dynamics
from heli_plant.vehicle import VehicleModel
from heli_sitl.launch.demo import DemoOptions, run_demo

HEAVY = f"{Path(__file__).resolve()}:HeavyXCell"
REGISTERED = "heavy-xcell"


class HeavyXCell(VehicleModel):
    """A third plant: the paper's equations on an X-Cell 20 % heavier than the controller's
    design (the TLC is not told)."""

    name = "X-Cell, 20 % heavier"

    def __init__(self, airframe: Airframe) -> None:
        super().__init__(airframe)
        body = dataclasses.replace(airframe.body, mass_kg=1.2 * airframe.body.mass_kg)
        self.constants = dataclasses.replace(airframe, body=body).constants()

    def derivative(self, t_s: float, x: FloatArray, u: FloatArray) -> FloatArray:
        return np.asarray(dynamics.derivative(t_s, x, u, self.constants))


@pytest.fixture
def heavy_package(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An installed package that registers this file's model by name (its module and its
    distribution's entry point), on this process's path and on its children's."""
    site = tmp_path / "site"
    info = site / "heavy_plants-0.1.dist-info"
    info.mkdir(parents=True)
    (site / "heavy_plants.py").write_text(Path(__file__).read_text())
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: heavy-plants\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{PLANT_ENTRY_POINT_GROUP}]\n{REGISTERED} = "
                                           "heavy_plants:HeavyXCell\n")
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")]))
    return site


def test_the_paper_model_through_the_contract_is_the_compiled_plant() -> None:
    """PaperPlant steps the compiled derivative with the contract's Python RK4: the flight
    the compiled world step flies, to the last bits the sums' order leaves."""
    compiled = hs.simulate(duration_s=20.0)
    python = hs.simulate(plant="heli_plant.vehicle:PaperPlant", duration_s=20.0)
    assert compiled.record is not None and python.record is not None
    d = float(np.abs(compiled.record.x - python.record.x).max())
    print(f"paper, compiled vs through the contract: max |state difference| {d:.1e}")
    assert d <= 2e-11  # measured 6.4e-12 m (deterministic)
    assert python.plant == "heli_plant.vehicle:PaperPlant"


def test_a_plant_of_your_own_flies_trims_and_is_registered_by_name(heavy_package: Path) -> None:
    heavy = hs.simulate(plant=HEAVY, duration_s=30.0)
    assert heavy.status is hs.ExitStatus.COMPLETED and heavy.metrics is not None
    # deterministic, pinned: the TLC's integrators take up the 20 % (converged, within 0.5 m,
    # from 19.2 s; RMS [10, 30] s 0.590 m, where the design plant flies it at 0.04 m)
    assert heavy.metrics.rms_10_m == pytest.approx(0.5902975555, rel=1e-6), heavy.metrics.rms_m
    assert heavy.metrics.converged and heavy.metrics.converge_s == pytest.approx(19.19)
    by_name = hs.simulate(plant=REGISTERED, duration_s=30.0)
    assert by_name.record is not None and heavy.record is not None
    np.testing.assert_array_equal(by_name.record.x, heavy.record.x)
    # trim: the heavier vehicle hovers on more collective; linearisation names its modes
    paper, own = hs.trim(), hs.trim(REGISTERED)
    assert own.residual_max < 1e-8 and own.plant == REGISTERED
    assert own.u[THETA_M] > paper.u[THETA_M] + 0.005, (own.u, paper.u)
    assert hs.linearize(HEAVY).a.shape == (12, 12)
    with pytest.raises(ConfigError, match=r"a registered plant \(heavy-xcell\)"):
        PlantModel.load("heavy-xcel")


def test_a_world_around_a_plant_of_your_own_is_refused_not_ignored() -> None:
    with pytest.raises(ValueError, match=r"flies the ideal world \(world 'breezy' asks for air"):
        hs.simulate(plant=HEAVY, world="breezy", duration_s=1.0)
    with pytest.raises(ConfigError, match=r"is not a heli_plant\.vehicle\.VehicleModel"):
        hs.simulate(plant="heli_common.vehicle.airframe:Airframe")


@pytest.mark.processes
def test_a_plant_of_your_own_flies_in_lockstep_as_in_process(tmp_path: Path, heavy_package: Path) -> None:
    """The plant process builds the model from --plant (here its registered name): the
    lockstep flight is the in-process flight, bit for bit in what the sim link carries."""
    in_process = hs.simulate(plant=REGISTERED, duration_s=10.0)
    summary = run_demo(DemoOptions(mode="lockstep", out=tmp_path / "run", timeout_s=300, via_ground=False,
                                   duration_s=10.0, extra_plant_args=("--plant", REGISTERED)))  # fmt: skip
    assert in_process.record is not None
    from ground.plots import read_csv_columns

    cols = read_csv_columns(tmp_path / "run" / "run.csv")
    assert cols["t_s"].size == in_process.record.t_s.size == 1001
    f32 = np.float32
    d = max(float(np.abs(cols[k].astype(f32) - in_process.record.x[:, i].astype(f32)).max())
            for i, k in enumerate(("x_m", "y_m", "z_m")))  # fmt: skip
    assert d <= 1e-9, f"lockstep vs in-process {d:.2e} m"
    assert summary["loop"]["bad_outputs"] == 0  # type: ignore[index]
