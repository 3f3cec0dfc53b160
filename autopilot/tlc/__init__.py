"""Trajectory linearization control (Zhu & Huo 2013), as documented in docs/model.md section 3."""

from autopilot.tlc.controller import Feedforward, TLController
from autopilot.tlc.gains import Gains

__all__ = ["Feedforward", "Gains", "TLController"]
