"""The earth's magnetic field at a place: the IGRF's tilted dipole (its degree-1 terms).

The plant's magnetometer reads this field (rotated into the body) and the autopilot uses the
same function to know the declination, as ArduPilot derives ``COMPASS_DEC`` from its own
table of the field (``AP_Declination``, ``COMPASS_AUTODEC``): both ends agree on the world's
field, so a heading from the magnetometer is consistent with the truth whatever the model's
error against the real earth. A dipole is a first approximation: at the bench's default home
(Zurich) its declination is about 17 degrees off the full IGRF/WMM value (docs/sensors.md,
which also gives the other errors and the sources).

The model (Schmidt semi-normalised, degree 1, on the reference sphere ``r = a``, so
``(a/r)^3 = 1``)::

    V = a [g10 cos(theta) + (g11 cos(phi) + h11 sin(phi)) sin(theta)]
    X (north) = -g10 sin(theta) + (g11 cos(phi) + h11 sin(phi)) cos(theta)
    Y (east)  =  g11 sin(phi) - h11 cos(phi)
    Z (down)  = -2 [g10 cos(theta) + (g11 cos(phi) + h11 sin(phi)) sin(theta)]

``theta`` the colatitude, ``phi`` the east longitude. The latitude is taken as geocentric
(a spherical earth): at 47 deg the geodetic latitude differs from it by 0.19 deg, far below
the dipole's own error.

Coefficients: IGRF-14, main field at epoch 2025.0 (IAGA Working Group V-MOD, "International
Geomagnetic Reference Field - 14th generation", 2024, doi:10.5281/zenodo.14012302; the
coefficient file ``igrf14coeffs``): g10 = -29350.0, g11 = -1410.3, h11 = 4545.5 nT. Reference
radius a = 6371.2 km.
"""

from __future__ import annotations

import math

from heli_common import frames

#: epoch of the coefficients (IGRF-14's main field model; secular variation not applied)
IGRF_EPOCH_YEAR = 2025.0
#: degree-1 Gauss coefficients, IGRF-14 at 2025.0 [nT]
G10_NT = -29350.0
G11_NT = -1410.3
H11_NT = 4545.5
#: the IGRF's reference radius [km]; the field is evaluated on this sphere
REFERENCE_RADIUS_KM = 6371.2
NT_PER_GAUSS = 1e5

#: the dipole moment's strength on the reference sphere, B0 = sqrt(g10^2 + g11^2 + h11^2) [nT]
#: (the field is B0 at the geomagnetic equator, horizontal, and 2 B0 at its poles, vertical)
DIPOLE_B0_NT = math.sqrt(G10_NT**2 + G11_NT**2 + H11_NT**2)
#: where the dipole's axis leaves the northern hemisphere (the geomagnetic north pole, where
#: the field points straight down) [deg]: 80.79 N, 72.76 W for these coefficients
GEOMAGNETIC_NORTH_POLE_LAT_DEG = 90.0 - math.degrees(math.acos(-G10_NT / DIPOLE_B0_NT))
GEOMAGNETIC_NORTH_POLE_LON_DEG = math.degrees(math.atan2(-H11_NT, -G11_NT))


def _north_east_down_nt(lat_deg: float, lon_deg: float) -> tuple[float, float, float]:
    """The dipole's (X north, Y east, Z down) at a place on the reference sphere [nT]."""
    if not (math.isfinite(lat_deg) and -90.0 <= lat_deg <= 90.0 and math.isfinite(lon_deg)):
        raise ValueError(f"latitude must be in [-90, 90] deg and longitude finite, got {lat_deg}, {lon_deg}")
    theta = math.radians(90.0 - lat_deg)
    phi = math.radians(lon_deg)
    c = G11_NT * math.cos(phi) + H11_NT * math.sin(phi)
    north = -G10_NT * math.sin(theta) + c * math.cos(theta)
    east = G11_NT * math.sin(phi) - H11_NT * math.cos(phi)
    down = -2.0 * (G10_NT * math.cos(theta) + c * math.sin(theta))
    return north, east, down


def earth_field_nwu_gauss(lat_deg: float, lon_deg: float) -> tuple[float, float, float]:
    """The earth's magnetic field at a place, earth NWU [gauss] (tilted dipole, IGRF-14
    2025.0). ValueError for a latitude outside [-90, 90] or a non-finite longitude."""
    n, w, u = frames.ned_to_nwu(_north_east_down_nt(lat_deg, lon_deg))
    return (n / NT_PER_GAUSS, w / NT_PER_GAUSS, u / NT_PER_GAUSS)


def declination_rad(lat_deg: float, lon_deg: float) -> float:
    """The angle from true north to the field's horizontal part, east positive:
    ``atan2(east, north)`` [rad] (the dipole's; see the module docstring for its error)."""
    north, east, _ = _north_east_down_nt(lat_deg, lon_deg)
    return math.atan2(east, north)


def inclination_rad(lat_deg: float, lon_deg: float) -> float:
    """The field's dip below the horizontal, positive when it points down into the earth
    (the northern hemisphere): ``atan2(down, horizontal)`` [rad]."""
    north, east, down = _north_east_down_nt(lat_deg, lon_deg)
    return math.atan2(down, math.hypot(north, east))
