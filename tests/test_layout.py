"""The flat array layouts: each declared once (heli_common.layout), its blocks contiguous and
non-overlapping, every block with exactly one exported offset, and the arrays the builders
allocate exactly as long as the layout. A block added without its offset constant, or an
array still allocated at the old size, fails here before it corrupts a neighbour."""

from __future__ import annotations

from types import ModuleType

import numpy as np
import pytest

from autopilot import control, reference, runner
from autopilot.estimation import ins, kf, nav
from autopilot.estimation import log as est_log
from autopilot.estimation.config import EstimatorConfig
from autopilot.pid import controller as pid
from autopilot.tlc import controller as tlc
from heli_common import frames
from heli_common.geo import GeoPoint
from heli_common.layout import Layout
from heli_common.state import N_PITCH, N_STATE
from heli_common.wire import measurements, sensor_wire
from heli_common.world import servo_model
from heli_common.world.config import World
from heli_common.world.sensors import Sensors
from heli_plant import rotor
from heli_plant.sensors import model as sensors
from heli_plant.world import model as world
from heli_plant.world import wind


def _named(module: ModuleType, prefix: str, exclude: tuple[str, ...] = ()) -> dict[str, int]:
    return {
        k: v for k, v in vars(module).items()
        if k.startswith(prefix) and k not in exclude and isinstance(v, int) and not isinstance(v, bool)
    }  # fmt: skip


# (layout, its exported offsets, the size constant the arrays are allocated with)
CASES: list[tuple[Layout, dict[str, int], int]] = [
    (measurements.MEASUREMENTS, _named(measurements, "OUT_"), measurements.N_OUT),
    (sensor_wire.HOME, _named(sensor_wire, "HOME_"), sensor_wire.N_HOME),
    (frames.NED_FIELDS, _named(frames, "NF_"), frames.N_NED_FIELDS),
    (servo_model.SERVO_PARAM, _named(servo_model, "SP_"), servo_model.N_SERVO_PARAM),
    (servo_model.SERVO_STATE, _named(servo_model, "SS_", ("SS_FIFO",)), servo_model.SS_FIFO),
    (wind.BLOCK2, _named(wind, "B_"), wind.N_BLOCK2),
    (wind.DRYDEN_COEFFS, _named(wind, "C_"), wind.N_DRYDEN_COEFFS),
    (wind.DRYDEN_STATE, _named(wind, "S_"), wind.N_DRYDEN_STATE),
    (world.WORLD_PARAMS, _named(world, "WP_"), world.N_WP),
    (world.WORLD_STATE, _named(world, "WS_"), world.N_WS),
    (world.WORK, _named(world, "WK_"), world.WORK.size),
    (world.RK_WORK, _named(world, "RK_", ("RK_WORK",)), world.N_RK_WORK),
    (world.STEP_SCRATCH, _named(world, "SC_"), world.N_STEP_SCRATCH),
    (sensors.SENSOR_PARAMS, _named(sensors, "SNP_"), sensors.N_SNP),
    (sensors.SENSOR_STATE, _named(sensors, "SNS_"), sensors.N_SNS),
    (sensors.GPS_RECORD, _named(sensors, "GR_"), sensors.GPS_REC),
    (sensors.ATT_RECORD, _named(sensors, "AR_"), sensors.ATT_REC),
    (kf.AXIS_STATE, _named(kf, "I_"), kf.N_AX),
    (kf.PARAMS, _named(kf, "K_"), kf.N_PARAMS),
    (kf.FILTER, _named(kf, "E_", ("E_HIST",)), kf.N_FILTER),
    (kf.RECORD, _named(kf, "R_"), kf.N_REC),
    (est_log.EST_LOG, _named(est_log, "L_"), est_log.N_EST_LOG),
    (ins.ERR, _named(ins, "D_"), ins.N_ERR),
    (ins.NOMINAL, _named(ins, "N_", ("N_ERR", "N_NAV", "N_COV", "N_NOM", "N_PARAMS", "N_FILTER", "N_REC")),
     ins.N_NOM),
    (ins.PARAMS, _named(ins, "K_"), ins.N_PARAMS),
    (ins.FILTER, _named(ins, "E_", ("E_HIST",)), ins.N_FILTER),
    (ins.RECORD, _named(ins, "R_"), ins.N_REC),
    (nav.HEADER, _named(nav, "H_"), nav.N_HEADER),
    (kf._INNOV, _named(kf, "_IN_"), kf._N_INNOV),
    (reference.REFERENCE, {"POS_0": reference.POS_0, "VEL_0": reference.VEL_0, "ACC_0": reference.ACC_0},
     reference.N_REF),
    (pid.PID_STATE, _named(pid, "P_"), pid.N_PID_STATE),
    (control.DIAG, _named(control, "D_"), control.N_DIAG),
    (rotor.ROTOR_STATE, {"A1": rotor.A1, "B1": rotor.B1, "OMEGA_R": rotor.OMEGA_R, "GOV_INT": rotor.GOV_INT},
     rotor.N_ROTOR),
    (tlc.STATE, _named(tlc, "S_"), tlc.N_CTRL_STATE),
]  # fmt: skip


@pytest.mark.parametrize(("layout", "named", "n"), CASES, ids=[c[0].name for c in CASES])
def test_blocks_are_contiguous_named_once_and_sized(layout: Layout, named: dict[str, int], n: int) -> None:
    at = layout.start
    for block in layout.names:
        assert layout.offset(block) == at, f"{layout.name}: {block} does not follow its predecessor"
        assert layout.size_of(block) >= 1
        at += layout.size_of(block)
    assert at == layout.end
    assert layout.size == sum(layout.size_of(b) for b in layout.names) == n
    # one exported offset per block, each a plain int (the compiled code reads module ints)
    assert sorted(named.values()) == sorted(layout.offset(b) for b in layout.names), (
        f"{layout.name}: offsets {sorted(named)} do not name its blocks {layout.names} one to one"
    )
    assert all(type(v) is int for v in named.values())


def test_recorder_row_is_its_layout() -> None:
    row = runner.Recorder.ROW
    assert runner.Recorder.WIDTH == row.end == row.size
    assert row.size_of("est") == est_log.N_EST_LOG and row.size_of("diag") == control.N_DIAG


def test_nested_blocks_take_their_size_from_the_inner_layout() -> None:
    assert wind.DRYDEN_COEFFS.size_of("v") == wind.DRYDEN_COEFFS.size_of("w") == wind.BLOCK2.size
    assert world.WORLD_STATE.size_of("turb") == wind.DRYDEN_STATE.size
    assert world.WORLD_STATE.size_of("rotor") == rotor.ROTOR_STATE.size
    assert world.WORLD_STATE.size_of("pitch_rad") == N_PITCH
    assert kf.FILTER.size_of("x") == kf.RECORD.size_of("x0") == kf.N_AXES * kf.AXIS_STATE.size
    assert kf.FILTER.size_of("p") == kf.RECORD.size_of("p0") == kf.N_AXES * kf.N_COV
    assert kf.N_FILTER == kf.E_HIST  # the records start where the filter ends
    assert sensors.SENSOR_STATE.end == sensors.N_SNS


def test_world_arrays_have_the_layout_sizes() -> None:
    from autopilot.scenario import Scenario

    assert world.world_parameters(World()).shape == (world.N_WP,)
    sc = Scenario.load("paper")
    wm = world.WorldModel.build(World(), sc.airframe, sc.initial.state().to_array())
    assert wm.ws.shape == (world.N_WS,)
    c = wind.dryden_coefficients(10.0, 10.0, 5.0, 1.0, 1.0, 0.5, 2.0, 0.01)
    assert c.shape == (wind.N_DRYDEN_COEFFS,)


def test_sensor_arrays_have_the_layout_sizes() -> None:
    m = sensors.SensorModel(Sensors(), 0.0025, 9.81)
    assert m.params.shape == (sensors.N_SNP,)
    assert m.out.shape == (measurements.N_OUT,)
    p = m.params
    assert int(p[sensors.SNP_GPS_QUEUE]) == sensors.N_SNS  # the FIFOs follow the fixed part
    gps_slots, att_slots = int(p[sensors.SNP_GPS_QUEUE_CAP]), int(p[sensors.SNP_ATT_QUEUE_CAP])
    fifos = gps_slots * sensors.GPS_REC + att_slots * sensors.ATT_REC
    assert m.state.shape == (sensors.N_SNS + fifos,)
    assert sensor_wire.home_array(GeoPoint(47.4, 8.5, 400.0)).shape == (sensor_wire.N_HOME,)
    assert frames.state_to_ned_fields(np.zeros(N_STATE)).shape == (frames.N_NED_FIELDS,)


def test_servo_arrays_have_the_layout_sizes() -> None:
    p = servo_model.servo_parameters([0.01] * N_PITCH, [10.0] * N_PITCH, [0.02] * N_PITCH, [-1.0] * N_PITCH,
                                     [1.0] * N_PITCH, [0.0] * N_PITCH, [0.0] * N_PITCH, 0.0025)  # fmt: skip
    assert p.shape == (N_PITCH, servo_model.N_SERVO_PARAM)
    s = servo_model.servo_state(p, np.zeros(N_PITCH))
    assert s.shape == (servo_model.SS_FIFO + servo_model.fifo_slots(p) * N_PITCH,)


def test_estimator_arrays_have_the_layout_sizes_and_the_log_is_written_whole() -> None:
    est = kf.Estimator(EstimatorConfig(), np.zeros(N_STATE), rate_hz=100.0)
    assert est.params.shape == (kf.N_PARAMS,)
    assert est.state.shape == (kf.N_FILTER + est.n_buf * kf.N_REC,)
    assert len(est_log.EST_LOG_COLUMNS) == est_log.N_EST_LOG == len(set(est_log.EST_LOG_COLUMNS))
    sentinel = 1234.5
    row = np.full(est_log.N_EST_LOG, sentinel)
    kf.log_tick(est.state, kf.ACCEPTED, row)
    assert not np.any(row == sentinel), "a log column log_tick never writes"
    # the navigation filter's: its arrays as the layouts say, and its log written whole too
    params = nav.make_nav_params(EstimatorConfig(attitude="ins"), 100.0, GeoPoint(47.4, 8.5, 400.0))
    assert params.shape == (nav.N_HEADER + ins.N_PARAMS,)
    st = nav.nav_state(params, np.zeros(N_STATE))
    assert st.shape == (ins.N_FILTER + int(params[nav.N_HEADER + ins.K_N_BUF]) * ins.N_REC,)
    row[:] = sentinel
    nav.nav_log(params, st, ins.NO_FIX, row)
    assert not np.any(row == sentinel), "a log column the navigation filter's log_tick never writes"
