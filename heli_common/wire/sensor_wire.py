"""What the sim link can carry of a sensor sample, exactly, in compiled code.

The plant sends its sensors in the MAVLink messages an autopilot reads in HIL: HIL_SENSOR
(IMU, magnetometer [gauss] and barometric altitude as float32, body FRD), HIL_GPS (latitude
and longitude in 1e-7 deg, altitude in mm, velocity in cm/s, and the receiver's status:
fix type, satellites, and its position accuracies ``eph``/``epv``) and AHRS2 (the attitude
source's Euler angles, float32). A real receiver reports at that resolution too. The
in-process loop rounds its samples with :func:`to_wire_resolution`, the plant encodes with
:func:`gps_to_wire` and :func:`gps_status_to_wire` and the autopilot decodes with
:func:`gps_from_wire` and :func:`gps_status_from_wire`: the estimator then gets the same
numbers, bit for bit, whether it runs in the plant's process or across the link.

HIL_GPS ``eph`` and ``epv`` carry the receiver's 1-sigma horizontal (per axis) and vertical
position accuracy in centimetres (uint16), as PX4's simulator bridge reads them
(``SimulatorMavlink::handle_message_hil_gps``: ``gps.eph = (float)hil_gps.eph * 1e-2f; //
cm -> m``); the MAVLink common.xml text calls them HDOP/VDOP * 100, which no simulator
fills. ``UINT16_MAX`` means unknown (decoded as NaN); a larger accuracy is sent as 65534 cm.

GPS positions are about a home (``home`` array: :data:`HOME_LAT_DEG`, :data:`HOME_LON_DEG`,
:data:`HOME_ALT_M`, :data:`HOME_M_PER_DEG_LAT`, :data:`HOME_M_PER_DEG_LON`), with the same
tangent-plane map as :mod:`heli_common.geo` (without its longitude wrap: the bench flies
within kilometres of home).
"""

from __future__ import annotations

import math

import numpy as np

from heli_common.geo import GeoPoint, _radii_m
from heli_common.jit import njit
from heli_common.layout import Layout
from heli_common.state import FloatArray
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

HOME = Layout(
    "home",
    ("lat_deg", 1),
    ("lon_deg", 1),
    ("alt_m", 1),  # AMSL
    ("m_per_deg_lat", 1),  # the tangent plane's scale at home [m/deg]
    ("m_per_deg_lon", 1),
)
HOME_LAT_DEG = HOME.offset("lat_deg")
HOME_LON_DEG = HOME.offset("lon_deg")
HOME_ALT_M = HOME.offset("alt_m")
HOME_M_PER_DEG_LAT = HOME.offset("m_per_deg_lat")
HOME_M_PER_DEG_LON = HOME.offset("m_per_deg_lon")
N_HOME = HOME.size

# HIL_SENSOR.fields_updated (MAVLink HIL_SENSOR_UPDATED_FLAGS): the IMU's six (acc x y z,
# gyro x y z), the magnetometer's three (xmag, ymag, zmag: bits 6-8) and pressure_alt
IMU_FIELDS = 0x3F
MAG_FIELDS = 0x1C0
BARO_FIELD = 1 << 11

INT16_MAX = 32767
INT32_MAX = 2**31 - 1
UINT8_MAX = 255
# HIL_GPS eph/epv [cm]: UINT16_MAX is "unknown", so a known accuracy stops one below it
ACCURACY_UNKNOWN = 0xFFFF
ACCURACY_CM_MAX = 0xFFFE


def home_array(home: GeoPoint) -> FloatArray:
    """The ``home`` array of a home position."""
    m_lat, m_lon = _radii_m(home.lat_deg)
    deg = math.pi / 180.0
    h = np.empty(N_HOME)
    h[HOME_LAT_DEG], h[HOME_LON_DEG], h[HOME_ALT_M] = home.lat_deg, home.lon_deg, home.alt_amsl_m
    h[HOME_M_PER_DEG_LAT], h[HOME_M_PER_DEG_LON] = m_lat * deg, m_lon * deg
    return h


@njit
def _clamp_round(v: float, limit: int) -> int:
    if not math.isfinite(v):
        return 0
    return int(max(-limit, min(limit, round(v))))


@njit
def gps_to_wire(
    pos_nwu: FloatArray, vel_nwu: FloatArray, home: FloatArray
) -> tuple[int, int, int, int, int, int]:
    """(lat_e7, lon_e7, alt_mm AMSL, vn, ve, vd [cm/s]) of a fix, as HIL_GPS carries them."""
    lat = home[HOME_LAT_DEG] + pos_nwu[0] / home[HOME_M_PER_DEG_LAT]
    lon = home[HOME_LON_DEG] - pos_nwu[1] / home[HOME_M_PER_DEG_LON]
    alt = home[HOME_ALT_M] + pos_nwu[2]
    return (
        _clamp_round(lat * 1e7, INT32_MAX),
        _clamp_round(lon * 1e7, INT32_MAX),
        _clamp_round(alt * 1e3, INT32_MAX),
        _clamp_round(vel_nwu[0] * 100.0, INT16_MAX),
        _clamp_round(-vel_nwu[1] * 100.0, INT16_MAX),
        _clamp_round(-vel_nwu[2] * 100.0, INT16_MAX),
    )


@njit
def gps_from_wire(
    lat_e7: int, lon_e7: int, alt_mm: int, vn: int, ve: int, vd: int, home: FloatArray,
    pos_nwu: FloatArray, vel_nwu: FloatArray,
) -> None:  # fmt: skip
    """The inverse of :func:`gps_to_wire`, into ``pos_nwu`` and ``vel_nwu``."""
    pos_nwu[0] = (lat_e7 * 1e-7 - home[HOME_LAT_DEG]) * home[HOME_M_PER_DEG_LAT]
    pos_nwu[1] = -(lon_e7 * 1e-7 - home[HOME_LON_DEG]) * home[HOME_M_PER_DEG_LON]
    pos_nwu[2] = alt_mm * 1e-3 - home[HOME_ALT_M]
    vel_nwu[0] = vn * 0.01
    vel_nwu[1] = -ve * 0.01
    vel_nwu[2] = -vd * 0.01


@njit
def _accuracy_to_wire(acc_m: float) -> int:
    if math.isnan(acc_m):
        return ACCURACY_UNKNOWN
    return int(max(0.0, min(float(ACCURACY_CM_MAX), round(acc_m * 100.0))))


@njit
def _accuracy_from_wire(acc_cm: int) -> float:
    if acc_cm == ACCURACY_UNKNOWN:
        return math.nan
    return acc_cm * 0.01


@njit
def gps_status_to_wire(
    fix_type: float, satellites: float, eph_m: float, epv_m: float
) -> tuple[int, int, int, int]:
    """(fix_type, satellites_visible, eph [cm], epv [cm]) of the receiver's status, as HIL_GPS
    carries them (uint8, uint8, uint16, uint16)."""
    return (
        int(max(0.0, min(float(UINT8_MAX), fix_type))) if math.isfinite(fix_type) else 0,
        int(max(0.0, min(float(UINT8_MAX), satellites))) if math.isfinite(satellites) else UINT8_MAX,
        _accuracy_to_wire(eph_m),
        _accuracy_to_wire(epv_m),
    )


@njit
def gps_status_from_wire(
    fix_type: int, satellites: int, eph_cm: int, epv_cm: int
) -> tuple[float, float, float, float]:
    """The inverse of :func:`gps_status_to_wire`: (fix type, satellites, eph [m], epv [m]);
    an accuracy of UINT16_MAX (unknown) is NaN."""
    return float(fix_type), float(satellites), _accuracy_from_wire(eph_cm), _accuracy_from_wire(epv_cm)


@njit
def _f32(out: FloatArray, i: int, n: int) -> None:
    for k in range(i, i + n):
        out[k] = np.float32(out[k])


@njit
def to_wire_resolution(out: FloatArray, mask: int, home: FloatArray) -> None:
    """Round the new samples of ``out`` (the measurement layout) to what the sim link
    carries: float32 for the IMU, magnetometer, attitude and baro, HIL_GPS's integers for a
    fix and the receiver's status. The times are kept (the link carries them in
    microseconds)."""
    if mask & NEW_IMU:
        _f32(out, OUT_GYRO, 3)
        _f32(out, OUT_ACCEL, 3)
    if mask & NEW_MAG:
        _f32(out, OUT_MAG, 3)
    if mask & NEW_ATT:
        _f32(out, OUT_ATT, 3)
    if mask & NEW_BARO:
        _f32(out, OUT_BARO_ALT, 1)
    if mask & NEW_GPS and math.isfinite(out[OUT_GPS_T]):
        pos = out[OUT_GPS_POS : OUT_GPS_POS + 3]
        vel = out[OUT_GPS_VEL : OUT_GPS_VEL + 3]
        la, lo, al, vn, ve, vd = gps_to_wire(pos, vel, home)
        gps_from_wire(la, lo, al, vn, ve, vd, home, pos, vel)
        ft, ns, eh, ev = gps_status_to_wire(out[OUT_GPS_FIX_TYPE], out[OUT_GPS_SATS], out[OUT_GPS_EPH_M],
                                            out[OUT_GPS_EPV_M])  # fmt: skip
        (out[OUT_GPS_FIX_TYPE], out[OUT_GPS_SATS], out[OUT_GPS_EPH_M],
         out[OUT_GPS_EPV_M]) = gps_status_from_wire(ft, ns, eh, ev)  # fmt: skip
