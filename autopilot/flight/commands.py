"""What can be asked of the vehicle, and what it answers: typed, link-independent.

A ground-station link translates its protocol into these commands and the replies and
events back (``autopilot.links.mavlink_gcs`` for MAVLink); the state machine that decides
(:class:`autopilot.flight.manager.FlightManager`) never sees a MAVLink message, so a
second link or a script drives the vehicle through exactly the same checks.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from autopilot.trajectory.base import Trajectory
from heli_common.state import FloatArray


class Result(enum.Enum):
    """The outcome of a command (MAVLink maps these onto MAV_RESULT one to one)."""

    ACCEPTED = "accepted"
    DENIED = "denied"  # valid, but refused in this state or with these values
    UNSUPPORTED = "unsupported"
    FAILED = "failed"


class Severity(enum.Enum):
    INFO = "info"
    WARNING = "warning"
    CRITICAL = "critical"  # a failsafe acted


@dataclass(frozen=True)
class Arm:
    pass


@dataclass(frozen=True)
class Disarm:
    force: bool = False  # also in the air (the rotor stops: the vehicle falls)


@dataclass(frozen=True)
class StartMission:
    first_seq: int = 0


@dataclass(frozen=True)
class SelectMission:
    """Mission mode: the stored mission starts now if armed, on the arming tick if not."""


@dataclass(frozen=True)
class Takeoff:
    alt_above_home_m: float | None = None  # None: the default take-off altitude


@dataclass(frozen=True)
class Land:
    pass


@dataclass(frozen=True)
class ReturnToLaunch:
    pass


@dataclass(frozen=True)
class Hold:
    pass


@dataclass(frozen=True)
class StartOffboard:
    """Follow the streamed setpoints (refused unless a fresh one has arrived)."""


@dataclass(frozen=True)
class Setpoint:
    """An offboard setpoint: NWU position, velocity, acceleration (NaN where not given)."""

    ref_nwu: FloatArray


@dataclass(frozen=True)
class FlyTrajectory:
    """Follow ``trajectory`` from its t = 0 at this tick (the scenario's autostart)."""

    trajectory: Trajectory


Command = (
    Arm | Disarm | StartMission | SelectMission | Takeoff | Land | ReturnToLaunch | Hold
    | StartOffboard | Setpoint | FlyTrajectory
)  # fmt: skip


@dataclass(frozen=True)
class Reply:
    result: Result
    text: str = ""  # for the operator (a STATUSTEXT on MAVLink); empty: nothing to say

    @property
    def accepted(self) -> bool:
        return self.result is Result.ACCEPTED


@dataclass(frozen=True)
class Text:
    """Something the operator should read (a failsafe engaged, landed, ...)."""

    severity: Severity
    text: str


@dataclass(frozen=True)
class ItemReached:
    seq: int


@dataclass(frozen=True)
class CurrentItem:
    seq: int


Event = Text | ItemReached | CurrentItem
