"""The autopilot's end of the sim link: plant state in (NED/FRD -> NWU/FLU), pitches out."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from heli_common import frames
from heli_common.closing import Closing
from heli_common.defaults import HOME
from heli_common.geo import GeoPoint
from heli_common.state import FloatArray
from heli_common.wire import servo_map
from heli_common.wire.mavlink.fast import ActuatorOutputStatus, Ahrs2, HilGps, HilSensor, SimCodec, WindCov
from heli_common.wire.mavlink.sim_protocol import (
    MAV_MODE_FLAG_SAFETY_ARMED,
    ROTOR_TRUTH_CHANNELS,
    StateAssembler,
    StateSample,
    receive,
)
from heli_common.wire.mavlink.udp import Address, MavlinkUdp
from heli_common.wire.measurements import (
    N_OUT,
    NEW_ATT,
    NEW_BARO,
    NEW_GPS,
    NEW_IMU,
    NEW_MAG,
    OUT_ACCEL,
    OUT_ATT,
    OUT_ATT_T,
    OUT_BARO_ALT,
    OUT_BARO_T,
    OUT_GPS_EPH_M,
    OUT_GPS_EPV_M,
    OUT_GPS_FIX_TYPE,
    OUT_GPS_POS,
    OUT_GPS_SATS,
    OUT_GPS_T,
    OUT_GPS_VEL,
    OUT_GYRO,
    OUT_IMU_T,
    OUT_MAG,
    OUT_MAG_T,
)
from heli_common.wire.sensor_wire import (
    BARO_FIELD,
    IMU_FIELDS,
    MAG_FIELDS,
    gps_from_wire,
    gps_status_from_wire,
    home_array,
)


class Measurements:
    """The vehicle's sensors as the sim link brings them (HIL_SENSOR: IMU, magnetometer and
    baro; HIL_GPS: a fix and the receiver's status; AHRS2; the plant's frames and units: body
    FRD, NED, lat/lon about ``home``, eph/epv in cm), gathered into the
    measurement layout of :mod:`heli_common.wire.measurements` (NWU/FLU, SI). New samples
    accumulate in ``mask`` until a state takes them (:meth:`take`)."""

    def __init__(self, home: GeoPoint) -> None:
        self.home = home_array(home)
        self.meas = np.full(N_OUT, math.nan)
        self.mask = 0
        self.t_s = 0.0
        self.seen = False
        self._taken_us = -1  # the sensors' time of the last state handed out
        self._stale = False  # the datagram being read repeats one already handed out
        self._t_us = -1

    def feed(self, msg: object) -> bool:
        """Take one message if it is a sensor's; False otherwise. A datagram the plant sent
        again (lockstep re-sends a state it got no answer to) repeats samples already
        handed out: they are dropped, or a fix would be fused twice."""
        m = self.meas
        if isinstance(msg, HilSensor):
            self._stale = msg.time_usec <= self._taken_us and self.seen
            if self._stale:
                return True
            self.seen = True
            self._t_us = msg.time_usec
            self.t_s = msg.time_usec / 1e6
            if msg.fields_updated & IMU_FIELDS == IMU_FIELDS:
                m[OUT_IMU_T] = self.t_s
                m[OUT_ACCEL : OUT_ACCEL + 3] = frames.frd_to_flu((msg.xacc, msg.yacc, msg.zacc))
                m[OUT_GYRO : OUT_GYRO + 3] = frames.frd_to_flu((msg.xgyro, msg.ygyro, msg.zgyro))
                self.mask |= NEW_IMU
            if msg.fields_updated & MAG_FIELDS == MAG_FIELDS:
                m[OUT_MAG_T] = self.t_s
                m[OUT_MAG : OUT_MAG + 3] = frames.frd_to_flu((msg.xmag, msg.ymag, msg.zmag))
                self.mask |= NEW_MAG
            if msg.fields_updated & BARO_FIELD:
                m[OUT_BARO_T] = self.t_s
                m[OUT_BARO_ALT] = msg.pressure_alt
                self.mask |= NEW_BARO
            return True
        if isinstance(msg, (HilGps, Ahrs2)) and self._stale:
            return True
        if isinstance(msg, HilGps):
            m[OUT_GPS_T] = msg.time_usec / 1e6
            gps_from_wire(msg.lat, msg.lon, msg.alt, msg.vn, msg.ve, msg.vd, self.home,
                          m[OUT_GPS_POS : OUT_GPS_POS + 3], m[OUT_GPS_VEL : OUT_GPS_VEL + 3])  # fmt: skip
            status = gps_status_from_wire(msg.fix_type, msg.satellites_visible, msg.eph, msg.epv)
            m[OUT_GPS_FIX_TYPE], m[OUT_GPS_SATS], m[OUT_GPS_EPH_M], m[OUT_GPS_EPV_M] = status
            self.mask |= NEW_GPS
            return True
        if isinstance(msg, Ahrs2):
            m[OUT_ATT_T] = self.t_s
            # (roll, pitch, yaw) -> (phi, theta, psi): the same sign change as a vector's
            m[OUT_ATT : OUT_ATT + 3] = frames.frd_to_flu((msg.roll, msg.pitch, msg.yaw))
            self.mask |= NEW_ATT
            return True
        return False

    def take(self, s: StateSample) -> StateSample:
        """``s`` with the measurements (once the plant has sent any); the mask restarts."""
        if not self.seen:
            return s
        out = dataclasses.replace(s, meas=self.meas.copy(), meas_mask=self.mask, meas_t_s=self.t_s)
        self.mask = 0
        self._taken_us = self._t_us
        return out


class SimLink(Closing):
    def __init__(
        self, local: Address, plant: Address, limits: FloatArray | servo_map.ServoMap, home: GeoPoint = HOME
    ) -> None:
        self.udp = MavlinkUdp(local, plant, system_id=1, component_id=1, accept_system=1)
        self.codec = SimCodec(system_id=1, component_id=1)
        self.servos = servo_map.as_map(limits)  # one channel per pitch, or CCPM servos
        self.assembler = StateAssembler()
        # the world's truth of the latest state (see StateSample), by its time stamp
        self._air: tuple[int, tuple[float, float, float]] | None = None
        self._servo: tuple[int, tuple[float, float, float, float]] | None = None
        self._rotor: tuple[int, tuple[float, float, float, float]] | None = None
        self.measurements = Measurements(home)

    def latest_state(self, timeout_s: float = 0.0, spin_s: float = 0.0) -> StateSample | None:
        """The newest complete state queued (waiting up to ``timeout_s`` for one)."""
        newest: StateSample | None = None
        for msg in receive(self.udp, self.codec, timeout_s, spin_s):
            if isinstance(msg, WindCov):
                self._air = (msg.time_usec, frames.ned_to_nwu(msg.wind_ned_m_s))
                continue
            if isinstance(msg, ActuatorOutputStatus):
                a = msg.actuator
                self._servo = (msg.time_usec, (a[0], a[1], a[2], a[3]))
                if msg.active & ROTOR_TRUTH_CHANNELS:
                    self._rotor = (msg.time_usec, (a[4], a[5], a[6], a[7]))
                continue
            if self.measurements.feed(msg):
                continue
            s = self.assembler.feed(msg)
            if s is not None:
                newest = s
        if newest is not None and self._air is not None and self._air[0] == newest.t_us:
            servo = self._servo[1] if self._servo is not None and self._servo[0] == newest.t_us else None
            rotor = self._rotor[1] if self._rotor is not None and self._rotor[0] == newest.t_us else None
            newest = dataclasses.replace(newest, air_nwu_m_s=self._air[1], servo_rad=servo, rotor=rotor)
        if newest is not None:
            newest = self.measurements.take(newest)
        return newest

    def send_pitches(self, t_us: int, pitches_rad: FloatArray, armed: bool) -> None:
        controls = [0.0] * 16
        controls[:4] = self.servos.to_normalized(pitches_rad).tolist()
        mode = MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
        self.udp.send_bytes(self.codec.encode_actuators(t_us, controls, mode))
        self.udp.stats.tx_messages += 1

    def close(self) -> None:
        self.udp.close()


