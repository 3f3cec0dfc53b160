"""What a link is, as the loops see it: small typed contracts that MAVLink and CAN both meet.

The autopilot's runner reads plant states from a :class:`StateSource` and sends pitches
to a :class:`ServoOutput`; the plant server reads commands from a :class:`ServoInput`.
Each receives its links already built, so neither loop knows (or branches on) which
medium carries them: a new medium is a new class here, not an ``if`` in a loop.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from heli_common.state import FloatArray
from heli_common.wire.mavlink.sim_protocol import StateSample


class StateSource(Protocol):
    """The plant's state as the autopilot receives it."""

    def latest_state(self, timeout_s: float = 0.0, spin_s: float = 0.0) -> StateSample | None:
        """The newest complete state queued, waiting up to ``timeout_s`` for one."""
        ...


class ServoOutput(Protocol):
    """Where the autopilot's commands go."""

    def send_pitches(self, t_us: int, pitches_rad: FloatArray, armed: bool) -> None:
        """Send the pitches answering the state stamped ``t_us`` (never blocks)."""
        ...


@dataclass(frozen=True)
class ServoCommand:
    """One command as the plant received it (already range-checked by the link)."""

    t_us: int  # the state it answers (a medium without time stamps: the current state)
    pitches_rad: FloatArray
    armed: bool


class ServoInput(Protocol):
    """The plant's end of the servo link."""

    #: whether commands carry the arming state (an in-air start waits for it)
    carries_arming: bool

    def receive(self, current_t_us: int, wait_s: float = 0.0) -> list[ServoCommand]:
        """Commands that arrived (waiting up to ``wait_s`` for the first), oldest first.
        ``current_t_us`` stamps commands of a medium that carries no time."""
        ...

    @property
    def refused(self) -> int:
        """Commands dropped as malformed or out of range so far."""
        ...
