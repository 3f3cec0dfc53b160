"""CCPM on this bench's own servo outputs (heli_common.wire.servo_map.CcpmMap, ``--ccpm``): the
autopilot mixes blade pitches to the head's four servos (swash 1-3, tail) and the plant reads
them back through the same swashplate ArduPilot's servo frames go through."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from heli_common.config import ConfigError
from heli_common.vehicle.swashplate import Swashplate
from heli_common.wire.servo_link import DEFAULT_SWASHPLATE, servo_map_for
from heli_common.wire.servo_map import CcpmMap, DirectMap, limits_array, to_pwm_us
from heli_sitl.launch.demo import DemoOptions, run_demo

LIMITS = limits_array(((-0.1, 0.3), (-0.35, 0.35), (-0.14, 0.14), (-0.14, 0.14)))


def test_ccpm_mixing_and_reading_are_inverse_inside_the_head() -> None:
    swash = Swashplate.load(DEFAULT_SWASHPLATE)
    ccpm = CcpmMap(swash)
    rng = np.random.default_rng(3)
    r = swash.cyclic_max_rad / np.sqrt(2.0)  # inside the cyclic ring on both axes
    for _ in range(500):
        cyclic = rng.uniform(-r, r, size=2)
        p = np.array([rng.uniform(-0.1, 0.3), rng.uniform(-0.35, 0.35), *cyclic])
        n = ccpm.to_normalized(p)
        assert np.all(np.abs(n) <= 1.0)  # servo travel: 1000..2000 us
        assert np.allclose(ccpm.from_normalized(n), p, atol=1e-12)
    # the same pitches on the two maps: the channels differ (servos mix all three swash inputs)
    p = np.array([0.1, 0.0, 0.05, 0.0])
    assert not np.allclose(ccpm.to_normalized(p), DirectMap(LIMITS).to_normalized(p))
    assert np.allclose(to_pwm_us(p, ccpm), np.round(1500.0 + 500.0 * ccpm.to_normalized(p)))


def test_the_option_picks_the_map_and_refuses_dronecan() -> None:
    assert servo_map_for(None, "mavlink", LIMITS) is LIMITS
    assert isinstance(servo_map_for(DEFAULT_SWASHPLATE, "mavlink", LIMITS), CcpmMap)
    with pytest.raises(ConfigError, match="MAVLink sim link only"):
        servo_map_for(DEFAULT_SWASHPLATE, "can", LIMITS)


@pytest.mark.slow
@pytest.mark.processes
def test_a_ccpm_flight_through_processes_is_the_direct_flight(tmp_path: Path) -> None:
    """Lockstep, the paper scenario for 10 s, both processes with ``--ccpm`` and without: the
    same flight (the mixing is inverted exactly; only the float32 channels round differently):
    measured 1.5e-9 m apart in RMS over 30 s."""
    runs = {}
    for name, extra in (("direct", ()), ("ccpm", ("--ccpm",))):
        s = run_demo(DemoOptions(mode="lockstep", out=tmp_path / name, via_ground=False, duration_s=10.0,
                                 extra_plant_args=extra, extra_autopilot_args=extra))  # fmt: skip
        runs[name] = s["rms_pos_err_m"]["0-10"]
    print(runs)
    assert runs["direct"] > 0.1  # a flight with something to track (the start off the path)
    assert abs(runs["ccpm"] - runs["direct"]) < 1e-6
