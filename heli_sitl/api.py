"""The bench from Python: one call flies a flight and returns it typed.

>>> import heli_sitl as hs
>>> f = hs.simulate()                                     # the paper's scenario, plant, TLC
>>> round(f.metrics.rms_m["45-120"], 4)
0.0402
>>> f.status
<ExitStatus.COMPLETED: 'completed'>
>>> g = hs.simulate("position_step", plant="gavrilets", world="breezy",
...                 controller=hs.TLC("gains_tlc_rotor.toml"), seed=3)
>>> g.metrics.lost
False

Every argument takes a preset name, a file path or the object itself (a
:class:`~autopilot.scenario.Scenario`, :class:`~heli_common.vehicle.plant_model.PlantModel`,
:class:`~heli_common.world.config.World`, :class:`~autopilot.estimation.config.EstimatorConfig`);
a bad one raises :class:`~heli_common.config.ConfigError` naming it. The flight itself never
raises: a flight whose numerics fail is returned with ``status`` FAILED and its ``error``.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from autopilot.envelope import DEFAULT as DEFAULT_ENVELOPE
from autopilot.envelope import Envelope
from autopilot.estimation.config import EstimatorConfig
from autopilot.flight_metrics import FlightMetrics
from autopilot.metrics import FlightRecord
from autopilot.pid.gains import PidGains
from autopilot.reference import N_REF
from autopilot.scenario import Scenario
from autopilot.tlc.gains import Gains
from autopilot.trajectory.csv_table import trajectory_from_csv
from autopilot.user_controller import BUILT_IN, load_class, normalise_spec, user_traceback
from heli_common.config import ConfigError
from heli_common.state import PITCH_LABELS, STATE_NAMES, FloatArray
from heli_common.vehicle.airframe import Airframe
from heli_common.vehicle.plant_model import PlantModel
from heli_common.vehicle.scenario_file import load_vehicle
from heli_common.world.config import World
from heli_common.world.sensors import SEED_MAX
from heli_plant.trim import Linearization, Trim
from heli_plant.trim import linearize as _linearize
from heli_plant.trim import trim as _trim
from heli_sitl.engine.closed_loop import SimOptions
from heli_sitl.engine.closed_loop import simulate as _simulate
from heli_sitl.studies.campaigns.counts import CampaignCounts

if TYPE_CHECKING:
    import pandas as pd
    import pyarrow as pa
    from matplotlib.axes import Axes

# the reference in earth NWU (velocity and acceleration as a trajectory table names them);
# run.csv's and every table's names (autopilot.metrics.CSV_HEADER: one schema)
REF_LABELS = ("x_ref_m", "y_ref_m", "z_ref_m", "vx_ref_m_s", "vy_ref_m_s", "vz_ref_m_s",
              "ax_ref_m_s2", "ay_ref_m_s2", "az_ref_m_s2")  # fmt: skip


class ExitStatus(enum.Enum):
    """How a flight ended; printed as its value (``completed``, ``lost``, ``failed``)."""

    COMPLETED = "completed"  # flown to the end, not lost
    LOST = "lost"  # flown, but the vehicle left the safety envelope (autopilot.envelope), back or not
    FAILED = "failed"  # the simulation itself raised (see FlightResult.error)

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class TLC:
    """The trajectory linearization controller with a gain file (or :class:`Gains`)."""

    gains: str | Path | Gains = "gains_paper.toml"
    feedforward: str | None = None  # "pseudo" or "exact"; None: the scenario's

    def load(self) -> Gains:
        return self.gains if isinstance(self.gains, Gains) else Gains.load(self.gains)


@dataclass(frozen=True)
class PID:
    """The cascaded PID baseline with a gain file (or :class:`PidGains`)."""

    gains: str | Path | PidGains = "gains_pid.toml"

    def load(self) -> PidGains:
        return self.gains if isinstance(self.gains, PidGains) else PidGains.load(self.gains)


Controller = TLC | PID


@dataclass(frozen=True)
class FlightResult:
    """One flight: its time, named state, reference and command arrays, its metrics and how
    it ended. ``record`` is the simulator's own record (every array it keeps)."""

    scenario: str
    plant: str
    world: str
    controller: str
    status: ExitStatus
    metrics: FlightMetrics | None  # None when the flight FAILED
    record: FlightRecord | None
    error: str = ""

    @property
    def t_s(self) -> FloatArray:
        return self._rec.t_s

    @property
    def state(self) -> FloatArray:
        """(N, 12) plant state, columns :data:`STATE_LABELS` (earth NWU position, body FLU
        velocity and rates, ZYX Euler angles)."""
        return self._rec.x

    @property
    def reference(self) -> FloatArray:
        """(N, 9) commanded position, velocity, acceleration, columns :data:`REF_LABELS`."""
        return self._rec.ref

    @property
    def pitches(self) -> FloatArray:
        """(N, 4) commanded blade pitches [rad], columns :data:`PITCH_LABELS`."""
        return self._rec.pitches

    @property
    def _rec(self) -> FlightRecord:
        if self.record is None:
            raise ValueError(f"this flight failed and has no arrays: {self.error}")
        return self.record

    def columns(self) -> dict[str, FloatArray]:
        """Every per-tick array by its label: time, state, reference, pitches, error."""
        r = self._rec
        out: dict[str, FloatArray] = {"t_s": r.t_s}
        out.update({n: r.x[:, i] for i, n in enumerate(STATE_NAMES)})
        out.update({n: r.ref[:, i] for i, n in enumerate(REF_LABELS)})
        out.update({n: r.pitches[:, i] for i, n in enumerate(PITCH_LABELS)})
        out["psi_ref_rad"] = r.psi_cmd
        if r.att_cmd is not None:  # the commanded roll and pitch, as run.csv names them
            out["phi_ref_rad"], out["theta_ref_rad"] = r.att_cmd[:, 0], r.att_cmd[:, 1]
        out["pos_err_m"] = r.pos_err_m
        out["saturated"] = np.asarray(r.saturated, dtype=float)
        return out

    def to_pandas(self) -> pd.DataFrame:
        import pandas as pd

        return pd.DataFrame(self.columns()).set_index("t_s")

    def to_arrow(self) -> pa.Table:
        import pyarrow as pa

        return pa.table(self.columns())

    def to_mcap(self, path: str | Path) -> Path:
        """The flight as an MCAP file (run.csv's columns; Foxglove's /tf, /pose, /scene, /fix
        and the /run rows: :mod:`autopilot.mcap_log`) at ``path``; returns it."""
        from autopilot.mcap_log import write_mcap

        return write_mcap(self._rec.columns(), path)

    def plot(self, ax: Axes | None = None) -> Axes:
        """The 3-D position error against time (the figure every comparison starts from)."""
        if ax is None:
            import matplotlib.pyplot as plt

            _, ax = plt.subplots(figsize=(7, 3))
        ax.plot(self.t_s, self._rec.pos_err_m, lw=0.8)
        ax.set_xlabel("t [s]")
        ax.set_ylabel("position error [m]")
        ax.set_title(f"{self.scenario}, {self.plant} plant, {self.world}, {self.controller}: "
                     f"{self.status.value}")  # fmt: skip
        return ax

    def save(self, directory: str | Path) -> Path:
        """``flight.parquet`` (every column) and ``flight.json`` (what flew, how it ended,
        the metrics) in ``directory``; returns the directory."""
        import pyarrow.parquet as pq

        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        if self.record is not None:
            pq.write_table(self.to_arrow(), d / "flight.parquet")
        meta: dict[str, Any] = {
            "scenario": self.scenario, "plant": self.plant, "world": self.world,
            "controller": self.controller, "status": self.status.value, "error": self.error,
            "metrics": None if self.metrics is None else dataclasses.asdict(self.metrics),
        }  # fmt: skip
        (d / "flight.json").write_text(json.dumps(meta, indent=2, default=float) + "\n")
        return d


def _scenario(scenario: str | Path | Scenario, controller: object) -> Scenario:
    sc = scenario if isinstance(scenario, Scenario) else Scenario.load(scenario)
    if isinstance(controller, TLC):
        sc = dataclasses.replace(sc, gains=controller.load())
        if controller.feedforward is not None:
            sc = dataclasses.replace(sc, run=dataclasses.replace(sc.run, feedforward=controller.feedforward))
    return sc


class TrajectoryLike(Protocol):
    """What a trajectory must offer the bench: the reference rows at the given times."""

    def sample(self, t_s: FloatArray) -> FloatArray: ...


def _trajectory(trajectory: str | Path | TrajectoryLike) -> TrajectoryLike:
    if isinstance(trajectory, (str, Path)):
        return trajectory_from_csv(trajectory)
    if not callable(getattr(trajectory, "sample", None)):
        raise ConfigError(f"trajectory: expected a CSV file or an object with sample(t), got {trajectory!r}")
    probe = np.asarray(trajectory.sample(np.array([0.0, 0.01])), dtype=float)
    if probe.shape != (2, N_REF):
        raise ConfigError(f"trajectory: sample(t) must return ({N_REF},) reference rows per time (position, "
                          f"velocity, acceleration, earth NWU), got {probe.shape} for 2 times")  # fmt: skip
    return trajectory


def _name(v: object, default: str) -> str:
    if v is None:
        return default
    if isinstance(v, (str, Path)):
        return Path(v).stem if Path(v).suffix else str(v)
    return str(getattr(v, "name", type(v).__name__))


def simulate(
    scenario: str | Path | Scenario = "paper",
    plant: str | Path | PlantModel = "paper",
    world: str | Path | World | None = None,
    controller: Controller | str | type[Any] | None = None,
    estimator: str | Path | EstimatorConfig | None = None,
    duration_s: float | None = None,
    seed: int | None = None,
    trajectory: str | Path | TrajectoryLike | None = None,
    envelope: Envelope = DEFAULT_ENVELOPE,
) -> FlightResult:
    """Fly ``scenario`` in-process on ``plant`` in ``world`` (None: the paper's ideal world)
    with ``controller``: a :class:`TLC` or :class:`PID`, "tlc"/"pid" with their shipped
    gains, or your own class (the class, or "package.module:Class" / "path/file.py:Class";
    contract in :mod:`autopilot.user_controller`); None: the scenario's TLC. ``seed`` seeds
    the world's turbulence and sensors. ``estimator`` tunes the navigation filter where the
    world has sensors. An exception raised by your controller's code returns the flight
    FAILED with the traceback in ``error``. ``trajectory`` replaces the scenario's, and the
    flight starts on its first point (position, velocity, heading): a CSV
    table (``t_s, x_m, y_m, z_m`` earth NWU, optional ``vx_m_s``..., ``ax_m_s2``...,
    ``yaw_rad``; :mod:`autopilot.trajectory.csv_table`) or any object with ``sample(t)``
    returning the (N, 9) reference rows (and ``duration_s``, the flight's length unless
    ``duration_s`` is given). The flight is LOST when it leaves ``envelope`` (an error beyond
    10 m after 10 s, a tilt beyond 60 deg, a ground strike, a non-finite state: whether or not
    it comes back; :class:`autopilot.envelope.Envelope`)."""
    if not isinstance(envelope, Envelope):
        raise ConfigError(f"envelope: expected an autopilot.envelope.Envelope, got {envelope!r}")
    user: str | type[Any] | None = None
    if isinstance(controller, str):
        user = normalise_spec(controller)  # raises, naming the forms
        user = None if user in BUILT_IN else user
    elif isinstance(controller, type):
        missing = [m for m in ("update", "reset") if not callable(getattr(controller, m, None))]
        if missing:
            raise ConfigError(f"controller {controller.__name__}: lacks {' and '.join(missing)}() "
                              "(see autopilot.user_controller for the contract)")  # fmt: skip
        user = controller
    elif controller is not None and not isinstance(controller, (TLC, PID)):
        raise ConfigError(f"controller: expected hs.TLC(...), hs.PID(...), 'tlc', 'pid', 'module:Class', "
                          f"'file.py:Class' or a class, got {controller!r}")  # fmt: skip
    # checked here: a replaced seed or an odd duration would pass no config file's checks
    finite_positive = isinstance(duration_s, (int, float)) and 0.0 < duration_s < math.inf
    if duration_s is not None and not finite_positive:
        raise ConfigError(f"duration_s: expected a positive finite number of seconds, got {duration_s!r}")
    good_seed = isinstance(seed, int) and not isinstance(seed, bool) and 0 <= seed <= SEED_MAX
    if seed is not None and not good_seed:
        raise ConfigError(f"seed: expected an integer in [0, {SEED_MAX}], got {seed!r}")
    sc = _scenario(scenario, controller)
    if trajectory is not None:
        traj = _trajectory(trajectory)
        sc = sc.flying(traj)  # type: ignore[arg-type]  # (from its first point)
        end = getattr(traj, "duration_s", None)
        if duration_s is None and isinstance(end, (int, float)) and 0.0 < end < math.inf:
            duration_s = float(end)
    pm = plant if isinstance(plant, PlantModel) else PlantModel.load(plant)
    w = world if isinstance(world, World) or world is None else World.load(world)
    if seed is not None:
        w = w or World()
        w = dataclasses.replace(w, seed=seed, sensors=dataclasses.replace(w.sensors, seed=seed))
    est = estimator if isinstance(estimator, EstimatorConfig) or estimator is None else (
        EstimatorConfig.load(estimator))
    use_pid = isinstance(controller, PID) or controller == "pid"
    opts = SimOptions(
        duration_s=duration_s, world=w, estimator=est or EstimatorConfig(), plant=pm,
        controller=user if user is not None else "pid" if use_pid else "tlc",
        pid_gains=controller.load() if isinstance(controller, PID) else None,
    )  # fmt: skip
    label = "PID" if use_pid else "TLC"
    gains = controller.gains if isinstance(controller, (TLC, PID)) else None
    ctl = f"{label} ({_name(gains, 'shipped gains')})" if gains is not None else label
    if user is not None:
        cls = user if isinstance(user, type) else load_class(user)
        ctl = str(getattr(cls, "name", cls.__name__))
    plant_name = pm.kind if pm.vehicle is not None else _name(plant, "paper")  # a model by its name
    what = dict(scenario=_name(scenario, "paper"), plant=plant_name, world=_name(world, "ideal"),
                controller=ctl)  # fmt: skip
    try:
        rec = _simulate(sc, opts)
    except (FloatingPointError, np.linalg.LinAlgError, ZeroDivisionError, OverflowError) as exc:
        return FlightResult(**what, status=ExitStatus.FAILED, metrics=None, record=None,
                      error=f"{type(exc).__name__}: {exc}")  # fmt: skip
    except Exception as exc:
        if user is None:  # the bench's own fault: not to be dressed up as a flight's end
            raise
        return FlightResult(**what, status=ExitStatus.FAILED, metrics=None, record=None,
                      error=user_traceback(exc))  # fmt: skip
    m = FlightMetrics.of(rec, envelope=envelope)
    status = ExitStatus.LOST if m.lost else ExitStatus.COMPLETED
    return FlightResult(**what, status=status, metrics=m, record=rec)


def _airframe(airframe: str | Path | Airframe | None) -> Airframe:
    if isinstance(airframe, Airframe):
        return airframe
    return Airframe.load(airframe) if airframe is not None else load_vehicle("paper")[0]


def _plant(plant: str | Path | PlantModel) -> PlantModel:
    return plant if isinstance(plant, PlantModel) else PlantModel.load(plant)


def trim(
    plant: str | Path | PlantModel = "paper",
    speed_m_s: float = 0.0,
    airframe: str | Path | Airframe | None = None,
) -> Trim:
    """Steady level flight north at ``speed_m_s`` (0: hover) at 20 m, out of ground effect:
    the attitude, the four pitches (and on the rotor plant the flapping and the governor)
    that hold it. ``airframe``: the design parameters (default the paper scenario's X-Cell).

    >>> tr = hs.trim()
    >>> [round(float(v), 4) for v in tr.u]                # theta_m, theta_t, eps, eta [rad]
    [0.0959, 0.1521, -0.0076, -0.0187]
    """
    return _trim(_plant(plant), _airframe(airframe), speed_m_s=speed_m_s)


def linearize(
    plant: str | Path | PlantModel = "paper",
    speed_m_s: float = 0.0,
    airframe: str | Path | Airframe | None = None,
) -> Linearization:
    """``dx' = A dx + B du`` about :func:`trim` (central differences of the very derivative
    the plant integrates), with named states, inputs and modes; ``.to_control()`` gives a
    python-control ``StateSpace`` with those labels.

    >>> lin = hs.linearize("gavrilets")
    >>> lin.a.shape, lin.input_names
    ((16, 16), ('theta_m', 'theta_t', 'eps', 'eta'))
    >>> [m.name for m in lin.modes][-2:]                 # the fastest: the rotor-body modes
    ['rotor-body pitch (flapping a1, q)', 'rotor-body roll (flapping b1, p)']
    """
    pm, af = _plant(plant), _airframe(airframe)
    return _linearize(_trim(pm, af, speed_m_s=speed_m_s), pm, af)


@dataclass(frozen=True)
class CampaignResult:
    """A campaign's rows (one per flight: its settings, seed, metrics, or its error) and how
    its flights ended; ``summary`` is campaign.json as written in ``out``."""

    name: str
    out: Path
    counts: CampaignCounts
    table: pa.Table
    summary: dict[str, Any]

    def to_pandas(self) -> pd.DataFrame:
        return self.table.to_pandas()


def campaign(
    spec: str | Path = "robustness",
    samples: int | None = None,
    controller: str | None = None,
    out: str | Path | None = None,
    workers: int | None = None,
    quiet: bool = True,
    figures: bool = True,
) -> CampaignResult:
    """Fly a campaign file (or a name in configs/campaigns/) on an embedded Dask cluster;
    ``out`` keeps the rows and figures (a re-run resumes it; None: a fresh temporary
    directory; ``figures=False``: no figures, about 2 s of CPU each). ``controller``: "tlc",
    "pid" or your class as "module:Class" / "file.py:Class" (a name, so the workers can
    load it).

    >>> c = hs.campaign("robustness", samples=4, workers=1)  # doctest: +SKIP
    >>> c.counts.flights, c.counts.failed                   # doctest: +SKIP
    (4, 0)
    """
    import tempfile

    import pyarrow.parquet as pq

    from heli_sitl.studies.campaigns.run import run_campaign

    if controller is not None and not isinstance(controller, str):
        raise ConfigError("controller: a campaign's workers load the controller by name: give 'tlc', 'pid', "
                          f"'module:Class' or 'file.py:Class', got {controller!r}")  # fmt: skip
    d = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="heli-campaign-"))
    summary = run_campaign(spec, d, samples=samples, workers=workers, quiet=quiet, controller=controller,
                           figures=figures)  # fmt: skip
    table = pq.read_table(d / "results.parquet")
    return CampaignResult(str(summary["campaign"].get("name", spec)), d, CampaignCounts.of(table), table,
                          summary)  # fmt: skip


@dataclass(frozen=True)
class ComparisonResult:
    """A comparison's report (``report.md``), its numbers (``comparison.json``, as
    ``summary``) and figures, in ``out``."""

    out: Path
    summary: dict[str, Any]

    @property
    def report(self) -> str:
        return (self.out / "report.md").read_text()


def compare(
    spec: str | Path = "compare.toml",
    out: str | Path | None = None,
    work: str | Path | None = None,
    samples: int | None = None,
    seeds: int | None = None,
    workers: int | None = None,
    quiet: bool = True,
) -> ComparisonResult:
    """Fly a comparison file (configs/compare.toml, or yours: contenders may be your own
    classes, ``controller = "file.py:Class"``): every contender the same flights, paired,
    with intervals. ``work`` keeps the campaigns' rows (a re-run resumes); None for either
    directory: a fresh temporary one."""
    import tempfile

    from heli_sitl.studies.comparison import run_compare

    d = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="heli-compare-"))
    w = Path(work) if work is not None else d / "work"
    summary = run_compare(spec, d, w, samples=samples, workers=workers, quiet=quiet, seeds=seeds,
                          command=f"hs.compare({str(spec)!r})")  # fmt: skip
    return ComparisonResult(d, summary)


STATE_LABELS = STATE_NAMES

__all__ = [
    "PID",
    "REF_LABELS",
    "STATE_LABELS",
    "TLC",
    "CampaignCounts",
    "CampaignResult",
    "Envelope",
    "ExitStatus",
    "FlightMetrics",
    "FlightResult",
    "Linearization",
    "Trim",
    "campaign",
    "linearize",
    "simulate",
    "trim",
]
