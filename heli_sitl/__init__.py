"""heli_sitl: the helicopter SITL. ``plant/`` is the vehicle's physics and the plant process;
the modules here compose the layers: the ``heli-sitl`` command, the in-process closed loop,
the launchers that start plant, autopilot and ground script as processes."""

from typing import Any

# The Python API (heli_sitl/api.py), imported on first use: the plant process imports
# heli_plant and must not pay for (or depend on) the composing layer above it.
_API = ("PID", "TLC", "ExitStatus", "Flight", "FlightMetrics", "simulate", "STATE_LABELS", "REF_LABELS")


def __getattr__(name: str) -> Any:
    if name in _API:
        from heli_sitl import api

        return getattr(api, name)
    raise AttributeError(f"module 'heli_sitl' has no attribute {name!r}")


__all__ = list(_API)
