"""The sensors of a plant, one call per plant step: what the autopilot is sent.

:func:`sense` takes the plant's true state after a step, the acceleration the model gives
there (the dynamics derivative with the pitches and air of the step just flown), samples
every sensor (:func:`~heli_plant.sensors.model.sensor_step`) and rounds the new
samples to what the sim link carries (:mod:`heli_common.wire.sensor_wire`). The plant process
and the in-process loop call this same compiled function, so both give the autopilot's
estimator the same numbers.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from heli_common import frames
from heli_common.geo import GeoPoint
from heli_common.jit import njit
from heli_common.state import N_PITCH, Z_U, FloatArray
from heli_common.vehicle.airframe import PlantConstants
from heli_common.wire.mavlink.fast import SimCodec
from heli_common.wire.measurements import (
    NEW_ATT,
    NEW_BARO,
    NEW_GPS,
    NEW_IMU,
    NEW_MAG,
    OUT_ACCEL,
    OUT_ATT,
    OUT_BARO_ALT,
    OUT_GPS_EPH_M,
    OUT_GPS_EPV_M,
    OUT_GPS_FIX_TYPE,
    OUT_GPS_POS,
    OUT_GPS_SATS,
    OUT_GPS_T,
    OUT_GPS_VEL,
    OUT_GYRO,
    OUT_MAG,
)
from heli_common.wire.sensor_wire import (
    BARO_FIELD,
    IMU_FIELDS,
    MAG_FIELDS,
    gps_status_to_wire,
    gps_to_wire,
    home_array,
    to_wire_resolution,
)
from heli_common.world.config import World
from heli_common.world.sensors import Sensors
from heli_plant import rotor
from heli_plant.contact import GROUND_Z_M
from heli_plant.dynamics import derivative
from heli_plant.rotor import RotorConstants
from heli_plant.sensors.model import SensorModel, earth_accel_from_derivative, sensor_step3
from heli_plant.world.model import (
    N_WS,
    WS_AIR,
    WS_PITCH,
    WS_STEP,
    AirConstants,
    body_derivative_in_air,
    world_parameters,
)


@njit
def sense(
    t_s: float, x: FloatArray, held: FloatArray, c: PlantConstants, resting: bool, in_world: bool,
    air: AirConstants, wp: FloatArray, ws: FloatArray, snp: FloatArray, sns: FloatArray,
    out: FloatArray, home: FloatArray, g: RotorConstants,
) -> int:  # fmt: skip
    """Sample every sensor at ``t_s`` for the true state ``x``; returns the mask of new
    samples (``out`` holds the latest of each). ``held``: the pitches commanded over the
    step just flown; in a world the servos' positions and the air of its last sub-step are
    used instead. ``resting``: on the ground, or before the first command: no acceleration
    (the vehicle is held)."""
    acc = (0.0, 0.0, 0.0)  # values, not an array made each step
    if not resting:
        if in_world and ws[WS_STEP] > 0.0:
            # views, not copies (two arrays a tick): the derivative only reads them
            xdot = body_derivative_in_air(t_s, x, ws[WS_PITCH : WS_PITCH + N_PITCH], c, air,
                                          ws[WS_AIR : WS_AIR + 3], wp, ws, g)  # fmt: skip
        elif in_world:
            xdot = body_derivative_in_air(t_s, x, held, c, air, np.zeros(3), wp, ws, g)
        else:
            xdot = derivative(t_s, x, held, c)
        a = earth_accel_from_derivative(x, xdot)
        # on the ground with a net force into it (thrust short of the weight, the step
        # that set the vehicle down): the ground's reaction holds it, as the contact
        # model will (heli_plant.contact): it measures what a resting vehicle does
        if not (x[Z_U] <= GROUND_Z_M and a[2] < 0.0):
            acc = a
    mask = sensor_step3(t_s, x, acc, snp, sns, out)
    to_wire_resolution(out, mask, home)
    return mask


@dataclass
class Sensing:
    """A plant's configured sensors: the arrays :func:`sense` works on, and the home the
    GPS reports about (and where the magnetometer's earth field is taken)."""

    model: SensorModel
    home: FloatArray
    meas: FloatArray  # the measurement layout (heli_common.wire.measurements), latest samples
    mask: int = 0  # new at the last call

    @classmethod
    def build(cls, config: Sensors, step_s: float, gravity_m_s2: float, home: GeoPoint) -> Sensing:
        model = SensorModel(config, step_s, gravity_m_s2, home)
        return cls(model, home_array(home), model.out)

    def update(self, config: Sensors) -> None:
        """Live settings (SIM_ parameters): see :meth:`SensorModel.update`."""
        self.model.update(config)

    def sample(
        self, t_s: float, x: FloatArray, held: FloatArray, c: PlantConstants, resting: bool,
        world: tuple[AirConstants, FloatArray, FloatArray] | None, g: RotorConstants = rotor.OFF,
    ) -> int:  # fmt: skip
        m = self.model
        if world is None:
            air, wp, ws = _no_world()
        else:
            air, wp, ws = world
        self.mask = sense(t_s, x, held, c, resting, world is not None, air, wp, ws, m.params, m.state,
                          m.out, self.home, g)  # fmt: skip
        return self.mask


def encode_measurements(codec: SimCodec, t_s: float, sensing: Sensing) -> bytes:
    """What the sensors measured at the plant's vehicle time ``t_s``, as HIL_SENSOR (IMU and
    magnetometer, body FRD, and baro; ``fields_updated`` flags the new ones), HIL_GPS (a fix
    delivered now, with the receiver's status; ``time_usec`` its validity time) and AHRS2 (a
    new attitude-source sample, NED/FRD Euler angles, yaw unwrapped), in one piece of the
    state's datagram."""
    m, new = sensing.meas, sensing.mask
    gyro = frames.flu_to_frd(m[OUT_GYRO : OUT_GYRO + 3])
    accel = frames.flu_to_frd(m[OUT_ACCEL : OUT_ACCEL + 3])
    mag = frames.flu_to_frd(m[OUT_MAG : OUT_MAG + 3])
    fields = ((IMU_FIELDS if new & NEW_IMU else 0) | (BARO_FIELD if new & NEW_BARO else 0)
              | (MAG_FIELDS if new & NEW_MAG else 0))  # fmt: skip
    gps = status = None
    if new & NEW_GPS:
        wire = gps_to_wire(m[OUT_GPS_POS : OUT_GPS_POS + 3], m[OUT_GPS_VEL : OUT_GPS_VEL + 3], sensing.home)
        gps = (round(float(m[OUT_GPS_T]) * 1e6), *wire)
        status = gps_status_to_wire(m[OUT_GPS_FIX_TYPE], m[OUT_GPS_SATS], m[OUT_GPS_EPH_M], m[OUT_GPS_EPV_M])
    # (phi, theta, psi) -> (roll, pitch, yaw) is the same sign change as a vector's
    ahrs = frames.flip(m[OUT_ATT : OUT_ATT + 3]) if new & NEW_ATT else None
    return codec.encode_sensors(round(t_s * 1e6), (*accel, *gyro), float(m[OUT_BARO_ALT]), fields, gps, ahrs,
                                mag=mag, gps_status=status)  # fmt: skip


@functools.cache
def _no_world() -> tuple[AirConstants, FloatArray, FloatArray]:
    """Never read (in_world False), only there for the compiled signature; built on first
    use, not at import (world_parameters loads compiled code: 0.2-0.5 s of every plant
    process's start, most of which fly no world)."""
    air = AirConstants(False, False, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0)
    return air, world_parameters(World()), np.zeros(N_WS)
