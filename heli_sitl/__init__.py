"""heli_sitl: the composing layer on top of the plant (``heli_plant``), the autopilot and the
ground tools: the public Python API (:mod:`heli_sitl.api`, ``import heli_sitl as hs``), the
``heli-sitl`` command, the in-process closed loop, campaigns, comparison, tuning and the
launchers that start plant, autopilot and ground script as processes."""

from typing import Any

import heli_common  # noqa: F401  (first: one BLAS thread, before numpy loads)

# The Python API (heli_sitl/api.py), imported on first use: `heli-sitl --help` and the
# launchers need none of its imports (pandas, the compiled loop).
_API = ("PID", "TLC", "CampaignCounts", "CampaignResult", "ComparisonResult", "Envelope", "ExitStatus",
        "FlightResult", "FlightMetrics", "Linearization", "Trim", "campaign", "compare", "simulate", "trim",
        "linearize", "STATE_LABELS", "REF_LABELS")  # fmt: skip


def __getattr__(name: str) -> Any:
    if name in _API:
        from heli_sitl import api

        return getattr(api, name)
    raise AttributeError(f"module 'heli_sitl' has no attribute {name!r}")


__all__ = list(_API)
