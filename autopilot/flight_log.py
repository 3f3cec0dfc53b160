"""The flight as a pymavlink .tlog, written after the flight from the recorded ticks.

Writing it after the flight keeps MAVLink packing out of the control loop. Per tick:
ATTITUDE, LOCAL_POSITION_NED, POSITION_TARGET_LOCAL_NED (the commanded position,
velocity, acceleration) and SERVO_OUTPUT_RAW; a HEARTBEAT every second of flight time; on
the rotor plant, RAW_RPM (main rotor speed) every tick.
Stamps are ``t0_unix_us`` + flight time, so ``mavlogdump.py`` shows flight time.
"""

from __future__ import annotations

import math
from pathlib import Path

from autopilot import telemetry
from autopilot.metrics import ROTOR_RECORD, FlightRecord
from heli_common.state import FloatArray
from heli_common.wire.mavlink.udp import TlogWriter, mavlink2


def heartbeat(armed: bool) -> mavlink2.MAVLink_heartbeat_message:
    base = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if armed:
        base |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
    state = mavlink2.MAV_STATE_ACTIVE if armed else mavlink2.MAV_STATE_STANDBY
    return mavlink2.MAVLink_heartbeat_message(
        mavlink2.MAV_TYPE_HELICOPTER, mavlink2.MAV_AUTOPILOT_GENERIC, base, 0, state, 3
    )


def write_flight_tlog(path: Path, record: FlightRecord, limits: FloatArray, t0_unix_us: int) -> None:
    next_hb_s = float("-inf")
    rpm = None
    if record.rotor is not None:
        rpm = record.rotor[:, ROTOR_RECORD.index("omega_rad_s")] * 60.0 / (2.0 * math.pi)
    with TlogWriter(path) as w:
        for k, t_s in enumerate(record.t_s):
            t_us = int(round(float(t_s) * 1e6))
            msgs = telemetry.attitude_and_position(t_us, record.x[k])
            msgs.append(telemetry.position_target(t_us, record.ref[k], float(record.psi_cmd[k])))
            msgs.append(telemetry.servo_output(t_us, record.pitches[k], limits))
            if rpm is not None and math.isfinite(rpm[k]):
                msgs.append(mavlink2.MAVLink_raw_rpm_message(0, float(rpm[k])))
            if t_s >= next_hb_s:
                next_hb_s = float(t_s) + 1.0
                msgs.insert(0, heartbeat(True))
            w.write(t0_unix_us + t_us, msgs)
