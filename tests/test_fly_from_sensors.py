"""Flying from sensors in-process: the controller flies on the estimator's state, built from
what the plant's sensor models measured (docs/sensors.md, docs/estimator.md).

Off means exactly the paper's flight; on, one seed fixes every stream, and the plant
object (the process's) measures what the compiled loop measures.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from autopilot.scenario import Scenario
from heli_common.wire.mavlink.sim_protocol import pitches_as_received
from heli_common.wire.measurements import NEW_GPS, OUT_GPS_POS
from heli_common.world.config import World, with_sim_param
from heli_common.world.sensors import Gps, Imu, Sensors
from heli_plant.model import Plant
from heli_sitl.engine.closed_loop import SimOptions, simulate

DURATION_S = 30.0  # the climb and the slope change's approach: enough to tell flights apart


@pytest.fixture(scope="module")
def paper() -> Scenario:
    return Scenario.load("paper")


def _fly(sc: Scenario, world: World | None, duration_s: float = DURATION_S):  # type: ignore[no-untyped-def]
    return simulate(sc, SimOptions(world=world, duration_s=duration_s))


def test_sensors_off_is_the_paper_flight_exactly(paper: Scenario) -> None:
    """No sensors, or sensors with numbers but every one off: the same rows, bit for bit,
    and no estimate recorded."""
    base = _fly(paper, None)
    off = Sensors(imu=Imu(gyro_density_rad_s_rthz=0.01, on=False), gps=Gps(noise_h_m=3.0, on=False))
    for world in (World(), World(seed=7, sensors=off)):
        assert not world.sensing
        rec = _fly(paper, world)
        assert rec.x_hat is None and rec.est_log is None
        np.testing.assert_array_equal(rec.rows(), base.rows())


@pytest.mark.parametrize("preset", ["gps-typical", "imu-consumer", "noisy"])
def test_each_preset_flies_from_its_sensors_and_one_seed_fixes_the_flight(
    paper: Scenario, preset: str
) -> None:
    world = World.load(preset)
    a, b = _fly(paper, world), _fly(paper, world)
    np.testing.assert_array_equal(a.rows(), b.rows())  # the same seed: the same flight
    assert a.x_hat is not None and a.est_log is not None
    other = world.seed + 1
    r = dataclasses.replace
    c = _fly(paper, r(world, seed=other, sensors=r(world.sensors, seed=other)))
    assert np.abs(c.x[:, 0:3] - a.x[:, 0:3]).max() > 1e-3  # another seed: another flight
    # the controller flew on the estimate, not the truth: they differ, and the estimate
    # stays within what the sensors allow (the GPS's slow wander is followed, not removed)
    est_err = np.linalg.norm(a.x_hat[:, 0:3] - a.x[:, 0:3], axis=1)
    assert est_err[100:].max() > 1e-4
    gps = world.sensors.gps
    per_axis = np.hypot(gps.noise_h_m, gps.wander_h_m) if gps.on else 0.0
    assert np.sqrt(np.mean(est_err[1000:] ** 2)) < 3.0 * per_axis + 0.5
    s = a.summary()
    assert s["estimate"]["gps_fixes"]["accepted"] > 0 and s["world"]["sensors"]


def test_the_plant_measures_what_the_compiled_loop_measures(paper: Scenario) -> None:
    """Plant (the plant process's model) stepped by hand with the loop's pitches samples the
    same GPS fixes as the in-process loop's own sensing (one code path: sense())."""
    world = World.load("gps-typical")
    rec = _fly(paper, world, 3.0)
    plant = Plant(paper.airframe, paper.initial.state().to_array(), world=world, step_s=0.01)
    assert plant.sensing is not None
    fixes = []
    for i in range(rec.t_s.size - 1):
        if plant.sensing.mask & NEW_GPS:
            fixes.append((i, plant.sensing.meas[OUT_GPS_POS : OUT_GPS_POS + 3].copy()))
        # the pitches as the sim link delivers them to the plant process (float32, normalised)
        held = plant.u.copy()
        assert pitches_as_received(rec.pitches[i], plant.lo, plant.hi, held)
        plant.set_pitches(held)
        plant.step(0.01)
    assert len(fixes) == 15  # 5 Hz, the first delivered 100 ms after t = 0
    assert rec.est_log is not None
    status = rec.est_log[:, 9]
    assert [i for i, _ in fixes] == list(np.flatnonzero(status[:-1] >= 0))
    np.testing.assert_allclose(plant.x, rec.x[-1], atol=1e-9)


def test_sim_gps_disable_stops_the_fixes_live(paper: Scenario) -> None:
    world = World.load("gps-typical")
    plant = Plant(paper.airframe, paper.initial.state().to_array(), world=world, step_s=0.01)
    assert plant.sensing is not None
    fix_t: list[float] = []
    for k in range(300):
        if k == 100:
            assert plant.set_sim_param("SIM_GPS_DISABLE", 1.0)
        if k == 250:
            assert plant.set_sim_param("SIM_GPS_DISABLE", 0.0)
        plant.step(0.01)
        if plant.sensing.mask & NEW_GPS:
            fix_t.append(round(plant.t_s, 6))
    # 5 Hz fixes delivered 0.1 s late; none from the setting at 1.0 s until it is cleared
    # at 2.5 s, then the first fix taken after that (2.6 s) arrives at 2.7 s
    assert fix_t == [0.1, 0.3, 0.5, 0.7, 0.9, 2.7, 2.9]
    assert not plant.set_sim_param("SIM_GPS_DISABLE", 0.5)
    assert with_sim_param(world, "SIM_GPS_HZ", 10.0).sensors.gps.rate_hz == 10.0


def test_a_scripted_gps_outage_withholds_the_fixes_valid_inside_it(paper: Scenario) -> None:
    """[sensors.gps] outage_start_s / outage_s: the fixes valid in [1.0, 2.5) s are not
    delivered (the same fixes SIM_GPS_DISABLE withholds when set at 1.0 s, cleared at 2.5 s)."""
    import dataclasses

    base = World.load("gps-typical")
    gps = dataclasses.replace(base.sensors.gps, outage_start_s=1.0, outage_s=1.5)
    world = dataclasses.replace(base, sensors=dataclasses.replace(base.sensors, gps=gps))
    assert world.sensors.faults_on
    plant = Plant(paper.airframe, paper.initial.state().to_array(), world=world, step_s=0.01)
    assert plant.sensing is not None
    fix_t: list[float] = []
    for _ in range(300):
        plant.step(0.01)
        if plant.sensing.mask & NEW_GPS:
            fix_t.append(round(plant.t_s, 6))
    assert fix_t == [0.1, 0.3, 0.5, 0.7, 0.9, 2.7, 2.9]


@pytest.mark.slow
def test_sensor_study_finds_where_gps_errors_cost_half_a_metre(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """python -m heli_sitl.studies.sensor_study (one seed), on the navigation filter told each GPS:
    it averages white GPS noise (9.4 m of it before the paper flight's RMS[45,120] reaches
    0.5 m, measured), re-propagation absorbs latency (2 s costs 0.10 m against 0.09 m at
    none), and a slow wander goes through until the filter, dead-reckoning on an ideal IMU,
    tells the wander's motion from the vehicle's (0.53 m of wander reaches 0.5 m; beyond a
    metre the error levels off at 0.53-0.58 m)."""
    import json

    from heli_sitl.studies.sensor_study import WANDER_M, main

    assert main(["--out", str(tmp_path), "--seeds", "1"]) == 0
    sw = json.loads((tmp_path / "sensor_study.json").read_text())["sweep"]
    assert sw["noise_m_at_threshold"] is not None and sw["noise_m_at_threshold"] > 6.0
    assert sw["wander_m_at_threshold"] is not None and 0.35 < sw["wander_m_at_threshold"] < 0.8
    assert sw["lag_s_at_threshold"] is None and max(sw["lag_s_rms45_m"]) < 0.15
    rising = [r for w, r in zip(WANDER_M, sw["wander_m_rms45_m"], strict=True) if w <= 0.5]
    assert sorted(rising) == rising  # more wander, more error, up to half a metre
    assert max(sw["wander_m_rms45_m"]) < 0.7  # then it levels off
    assert (tmp_path / "fig_sensor_thresholds.png").stat().st_size > 10_000


def test_a_resent_datagram_is_not_fused_twice() -> None:
    """Lockstep re-sends a state it got no answer to; if the copy arrives with the next
    state, its GPS fix, baro and magnetometer samples must not count as new again (a race
    seen under load: the fix was fused twice and lockstep parted from in-process by 5 mm)."""
    from autopilot.links.mavlink_sim import Measurements
    from heli_common.defaults import HOME
    from heli_common.wire.mavlink.fast import SimCodec
    from heli_common.wire.mavlink.sim_protocol import StateSample
    from heli_common.wire.measurements import NEW_BARO, NEW_IMU, NEW_MAG
    from heli_common.wire.sensor_wire import BARO_FIELD, IMU_FIELDS, MAG_FIELDS

    codec = SimCodec(1, 51)
    imu = (0.0, 0.0, -9.81, 0.0, 0.0, 0.0)
    fix = (10_000, 473_977_420, 85_455_940, 500_000, 0, 0, 0)
    k = codec.encode_sensors(10_000, imu, 5.0, IMU_FIELDS | BARO_FIELD | MAG_FIELDS, fix, None,
                             mag=(0.2, 0.05, 0.44))  # fmt: skip
    k1 = codec.encode_sensors(20_000, imu, 5.0, IMU_FIELDS, None, None)
    m = Measurements(HOME)
    s = StateSample(0, np.zeros(12))
    for msg in codec.decode(k):
        assert m.feed(msg)
    assert m.take(s).meas_mask == NEW_IMU | NEW_GPS | NEW_BARO | NEW_MAG
    for msg in codec.decode(k + k1):  # the copy of k, then k + 1, in one read
        assert m.feed(msg)
    assert m.take(s).meas_mask == NEW_IMU  # only what k + 1 brought
