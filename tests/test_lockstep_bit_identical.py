"""Lockstep is the in-process flight, bit for bit: the in-process loop rounds what crosses
the sim link as the link rounds it (the float32 state the controller flies on, the float32
normalised pitches the plant holds, the sensors' samples), so plant and autopilot as two
processes fly the very same numbers over the whole 120 s (docs/architecture.md, "Lockstep
and in-process").

The comparison is of what the link carried: run.csv's positions are the float32 the
autopilot received (its 9 significant digits read back to that very float32), the
in-process truth rounded to float32 is what the plant would have sent. Any difference in
the doubles behind them grows, tick by tick, into those float32 within seconds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from autopilot.estimation.config import EstimatorConfig
from autopilot.metrics import EST_CSV_STATE, FlightRecord
from autopilot.scenario import Scenario
from ground.plots import read_csv_columns
from heli_common.state import EULER, N_PITCH, N_STATE, OMEGA, PITCH_LABELS, POS, VEL, FloatArray
from heli_common.vehicle.plant_model import PlantModel
from heli_common.wire import servo_map
from heli_common.wire.mavlink.fast import HilActuatorControls, SimCodec
from heli_common.wire.mavlink.sim_protocol import (
    StateAssembler,
    decode_command,
    encode_state,
    pitches_as_received,
    state_as_received,
)
from heli_common.world.config import World
from heli_plant.model import accept_pitches
from heli_sitl.engine.closed_loop import SimOptions, simulate
from heli_sitl.launch.demo import DemoOptions, run_demo

POSITION = ("x_m", "y_m", "z_m")
WIRE_TOL_M = 1e-9  # the bound; measured: 0.0 for every shipped preset and gain set


def _f32(v: FloatArray) -> FloatArray:
    return np.asarray(v, dtype=float).astype(np.float32).astype(float)


def wire_position_difference(run_csv: Path, rec: FlightRecord) -> FloatArray:
    """|lockstep - in-process| per tick, the largest of the three axes, of the positions as
    the sim link carries them (float32)."""
    cols = read_csv_columns(run_csv)
    ref = rec.columns()
    assert cols["t_s"].size == ref["t_s"].size
    d = np.stack([_f32(cols[k]) - _f32(ref[k]) for k in POSITION], axis=1)
    return np.asarray(np.abs(d).max(axis=1))


def same_pitches(run_csv: Path, rec: FlightRecord, tmp_path: Path) -> bool:
    """The controller's pitches of every tick, equal in run.csv's own number format."""
    rec.write_csv(tmp_path / "in_process.csv")
    a, b = read_csv_columns(run_csv), read_csv_columns(tmp_path / "in_process.csv")
    return all(np.array_equal(a[k], b[k]) for k in PITCH_LABELS)


# -- the link's rounding, reproduced exactly ------------------------------------------------
_finite = st.floats(-1.0, 1.0, allow_nan=False)


@given(st.lists(_finite, min_size=N_STATE, max_size=N_STATE))
def test_the_state_as_received_is_what_the_autopilot_decodes(v: list[float]) -> None:
    x = np.zeros(N_STATE)
    # metres from home, speeds, angles past +-pi (the yaw is wrapped on the link), rates
    for block, scale in ((POS, 40.0), (VEL, 12.0), (EULER, 3.5), (OMEGA, 3.0)):
        x[block] = np.asarray(v[block]) * scale
    codec, asm = SimCodec(system_id=1, component_id=51), StateAssembler()
    got = [s for m in codec.decode(encode_state(codec, 120_000, x)) if (s := asm.feed(m)) is not None]
    assert len(got) == 1
    np.testing.assert_array_equal(state_as_received(x), got[0].x)


@given(st.lists(st.floats(-1.2, 1.2, allow_nan=False), min_size=N_PITCH, max_size=N_PITCH))
def test_the_pitches_as_received_are_what_the_plant_holds(n: list[float]) -> None:
    """SimLink.send_pitches -> HIL_ACTUATOR_CONTROLS -> decode_command -> accept_pitches,
    against the compiled rounding: the same pitches held, or the same command refused."""
    sc = Scenario.load("paper")
    limits = servo_map.limits_array(sc.airframe.limits.as_tuple())
    lo, hi = limits[:, 0], limits[:, 1]
    u = lo + (np.asarray(n) + 1.0) * 0.5 * (hi - lo)
    codec = SimCodec(system_id=1, component_id=1)
    controls = [0.0] * 16
    controls[:N_PITCH] = servo_map.as_map(limits).to_normalized(u).tolist()
    (msg,) = codec.decode(codec.encode_actuators(10_000, controls, 0))
    assert isinstance(msg, HilActuatorControls)
    link_held, held = np.full(N_PITCH, 0.1), np.full(N_PITCH, 0.1)
    cmd = decode_command(msg, limits)
    link_ok = cmd is not None and accept_pitches(cmd[1], lo, hi, link_held)
    assert pitches_as_received(u, lo, hi, held) == link_ok
    np.testing.assert_array_equal(held, link_held)


# -- whole flights: every effect the bench has, one representative each ----------------------
# (the table of every shipped preset and gain set: docs/architecture.md)
@pytest.mark.slow
@pytest.mark.parametrize(("world", "plant", "gains", "estimator"), [
    ("consumer", "paper", None, None),  # sensors and the navigation filter, with the default tuning
    ("noisy", "paper", None, "noisy"),  # rejections and resets: a chaotic flight if one bit differed
    ("everything", "paper", None, None),  # servos, air, turbulence, mismatch
    ("servos-default", "gavrilets", "gains_tlc_rotor.toml", None),  # the rotor plant, rotor-aware TLC
])  # fmt: skip
def test_lockstep_is_the_in_process_flight_to_the_bit(
    tmp_path: Path, world: str, plant: str, gains: str | None, estimator: str | None
) -> None:
    est = EstimatorConfig.load(estimator) if estimator else EstimatorConfig()
    opts = SimOptions(world=World.load(world), estimator=est, plant=PlantModel.load(plant))
    rec = simulate(Scenario.load("paper", gains=gains), opts)
    extra = (("--gains", gains) if gains else ()) + (("--estimator", estimator) if estimator else ())
    run_demo(DemoOptions(mode="lockstep", out=tmp_path, timeout_s=600, via_ground=False, world=world,
                         extra_autopilot_args=extra, extra_plant_args=("--plant", plant)))  # fmt: skip
    run_csv = tmp_path / "run.csv"
    d = wire_position_difference(run_csv, rec)
    assert d.size == 12001  # the whole 120 s, t = 0 to 120 s inclusive
    print(f"{world} ({plant}): lockstep vs in-process max {d.max():.2e} m over 120 s")
    assert float(d.max()) <= WIRE_TOL_M
    assert same_pitches(run_csv, rec, tmp_path)
    if rec.x_hat is not None:  # flying from sensors: the estimate the controller flew on, too
        assert rec.write_est_csv(tmp_path / "in_process_est.csv")
        a, b = read_csv_columns(tmp_path / "est.csv"), read_csv_columns(tmp_path / "in_process_est.csv")
        for k in EST_CSV_STATE:
            np.testing.assert_array_equal(a[k], b[k])
