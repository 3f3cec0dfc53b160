"""Trajectory linearization control (Zhu & Huo 2013), as specified in shared/docs/tlc-model.md."""

from autopilot.tlc.controller import Feedforward, TLController
from autopilot.tlc.gains import Gains

__all__ = ["Feedforward", "Gains", "TLController"]
