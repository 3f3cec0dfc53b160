"""Controller gains (paper Table 2) and command limits, loaded from TOML."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from heli_common.config import load, spec


@dataclass(frozen=True)
class DifferentiatorGains:
    zeta: float = spec("", 0.05, 5.0)
    omega_rad_s: float = spec("rad/s", 0.1, 200.0)


@dataclass(frozen=True)
class LoopGains:
    """Per-channel damping and bandwidth of one loop's error dynamics e'' + 2 z w e' + w^2 e = 0."""

    zeta: tuple[float, float, float] = spec("", 0.05, 5.0)
    omega_rad_s: tuple[float, float, float] = spec("rad/s", 0.001, 200.0)


@dataclass(frozen=True)
class CommandLimits:
    tilt_max_rad: float = spec("rad", 0.01, 1.2)
    yaw_hold_speed_m_s: float = spec("m/s", 0.0, 10.0)


@dataclass(frozen=True)
class Gains:
    name: str = spec()
    differentiator: DifferentiatorGains = spec()
    loop1_position_kinematics: LoopGains = spec()
    loop2_position_dynamics: LoopGains = spec()
    loop3_attitude_kinematics: LoopGains = spec()
    loop4_attitude_dynamics: LoopGains = spec()
    limits: CommandLimits = spec()

    @classmethod
    def load(cls, path: str | Path = "gains_paper.toml") -> Gains:
        return load(cls, path)

    def loops(self) -> tuple[LoopGains, LoopGains, LoopGains, LoopGains]:
        return (
            self.loop1_position_kinematics,
            self.loop2_position_dynamics,
            self.loop3_attitude_kinematics,
            self.loop4_attitude_dynamics,
        )
