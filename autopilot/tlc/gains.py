"""Controller gains (paper Table 2) and command limits, loaded from TOML."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from autopilot.design_point import DesignPoint
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
    # loop 1's horizontal correction (the velocity command beyond the trajectory's own) is held
    # to this speed (0 = no limit, the paper's): a far start then closes at this speed instead
    # of tilting to the limit, and a fast trajectory still flies at its own speed
    max_speed_m_s: float = spec("m/s", 0.0, 50.0, default=0.0)


@dataclass(frozen=True)
class RotorObserverGains:
    """How loop 5's flapping estimate is corrected (docs/tlc-rotor.md, "The observer").

    ``open_loop``: the design model's flapping driven by the measured rates and the achieved
    cyclic, with no output injection. ``rate``: a Kalman-Luenberger observer on the design
    model's ``[p, q, a1, b1]`` that predicts the body rates one tick ahead (the hub moment of
    the estimated flapping) and corrects the estimate from the gyro's prediction error, with
    the steady-state Kalman gain of the noise figures below."""

    correction: str = spec(choices=("open_loop", "rate"), default="open_loop")
    # the measured rates' noise, one standard deviation per control tick
    gyro_noise_rad_s: float = spec("rad/s", 0.0, 10.0, lo_open=True, default=0.001)
    # the design model's moment error (turbulence, the stabilizer, blowback), as a white
    # angular acceleration's intensity
    moment_noise_rad_s2_rthz: float = spec("rad/s^2/sqrt(Hz)", 0.0, 1e3, lo_open=True, default=10.0)
    # the design model's flapping error (linkage gains, the bar's time constant), as a white
    # flapping rate's intensity
    flapping_noise_rad_s_rthz: float = spec("rad/s/sqrt(Hz)", 0.0, 1e3, lo_open=True, default=1.0)


@dataclass(frozen=True)
class RotorAwareGains:
    """Loop 5 of the rotor-aware TLC (docs/tlc-rotor.md): the main rotor's flapping as one
    more subsystem of the cascade, and a command filter that models the servos."""

    # the plant file whose flapping the inversion is designed on (hub stiffness, the
    # stabilizer bar's time constant, the cyclic's gains); "gavrilets" or a path
    design_plant: str = spec()
    # loop 5's error regulator: the flapping error decays at 1/tau_e + this rate
    flapping_rate_rad_s: float = spec("rad/s", 0.0, 500.0)
    # the pseudo-differentiator of the flapping command (its derivative feeds the inversion)
    differentiator: DifferentiatorGains = spec()
    # the world preset whose servos the command filter models ("ideal": none); the filter
    # sends only what those servos can follow and feeds the flapping observer what they achieve
    servos: str = spec(default="ideal")
    # the flapping estimate's correction; default: the open-loop model (no correction)
    observer: RotorObserverGains = spec(default=RotorObserverGains())


@dataclass(frozen=True)
class Gains:
    name: str = spec()
    differentiator: DifferentiatorGains = spec()
    loop1_position_kinematics: LoopGains = spec()
    loop2_position_dynamics: LoopGains = spec()
    loop3_attitude_kinematics: LoopGains = spec()
    loop4_attitude_dynamics: LoopGains = spec()
    limits: CommandLimits = spec()
    # present: the rotor-aware TLC (loop 5 and the command filter); absent: the paper's
    rotor: RotorAwareGains | None = spec(default=None)
    # the plant and servos its margins are proven for (autopilot/design_point.py)
    design: DesignPoint = spec(default=DesignPoint())

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
