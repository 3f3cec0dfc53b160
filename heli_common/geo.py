"""Home (latitude, longitude, altitude AMSL) <-> local metres about home.

The bench flies inside a few hundred metres of home, so the earth is treated as the
plane tangent to the WGS-84 ellipsoid at home (an equirectangular projection about
home): north = dlat * M(lat0), east = dlon * N(lat0) cos(lat0), down = -(alt - alt0),
with M and N the meridian and prime-vertical radii of curvature *at home*. The map and
its inverse are exact inverses of each other (round trips are lossless up to float
rounding); the distortion against true geodesy grows as ~ d^2 / R: about 0.2 m at 1 km
and 20 m at 10 km, which is why :data:`MAX_RANGE_M` bounds its use. PX4 and ArduPilot
use the same kind of local linearisation for their local position.

The local origin is home at ground level; NED is what MAVLink carries (LOCAL_POSITION_NED,
MAV_FRAME_LOCAL_NED), NWU what the controller uses. The NED <-> NWU change goes through
:func:`heli_common.frames.flip`, the only place frames change.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from heli_common.frames import Vec3, flip

# WGS-84 ellipsoid
WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)

# Beyond this horizontal distance from home the flat-earth error exceeds a few metres.
MAX_RANGE_M = 10_000.0

# Polar homes make east/longitude singular (cos(lat0) -> 0); refuse them.
MAX_HOME_ABS_LAT_DEG = 89.0


@dataclass(frozen=True)
class GeoPoint:
    """A WGS-84 position: latitude and longitude [deg], altitude above mean sea level [m]."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float

    def __post_init__(self) -> None:
        for name in ("lat_deg", "lon_deg", "alt_amsl_m"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)!r}")
        if not -90.0 <= self.lat_deg <= 90.0:
            raise ValueError(f"lat_deg must be in [-90, 90], got {self.lat_deg}")
        if not -180.0 <= self.lon_deg <= 180.0:
            raise ValueError(f"lon_deg must be in [-180, 180], got {self.lon_deg}")


def _radii_m(lat_deg: float) -> tuple[float, float]:
    """(M, N cos(lat)): metres per radian of latitude and of longitude at ``lat_deg``."""
    phi = math.radians(lat_deg)
    s2 = math.sin(phi) ** 2
    w = math.sqrt(1.0 - WGS84_E2 * s2)
    meridian_m = WGS84_A_M * (1.0 - WGS84_E2) / w**3
    prime_vertical_m = WGS84_A_M / w
    return meridian_m, prime_vertical_m * math.cos(phi)


def _check_home(home: GeoPoint) -> None:
    if abs(home.lat_deg) > MAX_HOME_ABS_LAT_DEG:
        raise ValueError(f"home latitude {home.lat_deg} deg is too close to a pole for the flat-earth map")


def _wrap_dlon_deg(dlon_deg: float) -> float:
    """Longitude difference in [-180, 180): homes near the antimeridian still work."""
    return (dlon_deg + 180.0) % 360.0 - 180.0


def _wrap_lon_deg(lon_deg: float) -> float:
    """Longitude in [-180, 180]; +180 is kept as is (it is a valid longitude)."""
    if -180.0 <= lon_deg <= 180.0:
        return lon_deg
    return (lon_deg + 180.0) % 360.0 - 180.0


def geo_to_ned_m(home: GeoPoint, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> Vec3:
    """A WGS-84 position -> local NED [m] about home (origin at home, ground level)."""
    _check_home(home)
    m_per_rad_lat, m_per_rad_lon = _radii_m(home.lat_deg)
    north_m = math.radians(lat_deg - home.lat_deg) * m_per_rad_lat
    east_m = math.radians(_wrap_dlon_deg(lon_deg - home.lon_deg)) * m_per_rad_lon
    down_m = -(alt_amsl_m - home.alt_amsl_m)
    return (north_m, east_m, down_m)


def ned_to_geo(home: GeoPoint, pos_ned_m: Sequence[float]) -> GeoPoint:
    """Local NED [m] about home -> WGS-84 position (inverse of :func:`geo_to_ned_m`)."""
    _check_home(home)
    m_per_rad_lat, m_per_rad_lon = _radii_m(home.lat_deg)
    north_m, east_m, down_m = (float(v) for v in pos_ned_m)
    lat_deg = home.lat_deg + math.degrees(north_m / m_per_rad_lat)
    lon_deg = _wrap_lon_deg(home.lon_deg + math.degrees(east_m / m_per_rad_lon))
    return GeoPoint(lat_deg, lon_deg, home.alt_amsl_m - down_m)


def geo_to_nwu_m(home: GeoPoint, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> Vec3:
    """A WGS-84 position -> local NWU [m] about home (the controller's frame)."""
    return flip(geo_to_ned_m(home, lat_deg, lon_deg, alt_amsl_m))


def nwu_to_geo(home: GeoPoint, pos_nwu_m: Sequence[float]) -> GeoPoint:
    """Local NWU [m] about home -> WGS-84 position."""
    return ned_to_geo(home, flip(pos_nwu_m))


def horizontal_distance_m(home: GeoPoint, lat_deg: float, lon_deg: float) -> float:
    """Flat-earth horizontal distance from home [m]."""
    north_m, east_m, _ = geo_to_ned_m(home, lat_deg, lon_deg, home.alt_amsl_m)
    return math.hypot(north_m, east_m)


def parse_geo_point(text: str, what: str = "position") -> GeoPoint:
    """``lat,lon,alt`` (deg, deg, m AMSL), as a command line gives it; ConfigError if not."""
    from heli_common.config import ConfigError

    try:
        lat, lon, alt = (float(v) for v in text.split(","))
        return GeoPoint(lat, lon, alt)
    except ValueError as exc:
        raise ConfigError(f"{what} {text!r}: expected lat,lon,alt ({exc})") from exc
