"""The swashplate: servo PWM <-> blade pitches, mirroring ArduPilot's helicopter mixing.

Two halves, which agree by construction (docs/swashplate.md derives every line):

* **The firmware's side** (:class:`ArduPilotHeli`, :func:`ardupilot_mix`, :func:`ardupilot_tail_pwm`,
  :func:`ardupilot_rsc_pwm`): what ``arducopter-heli`` (``FRAME_CLASS 6``, single rotor) writes
  on SERVO1-4 and SERVO8 for its roll, pitch, collective and yaw outputs, following ArduPilot
  master at commit :data:`AP_COMMIT` (July 2025, Copter 4.7.0-dev): ``AP_MotorsHeli_Single::
  move_actuators`` (cyclic limit, collective scaling), ``AP_MotorsHeli_Swash::
  calculate_roll_pitch_collective_factors`` / ``add_servo_angle`` / ``add_servo_raw`` /
  ``calculate`` / ``get_linear_servo_output`` / ``rc_write`` and ``SRV_Channels::
  set_output_pwm_trimmed`` (trim, reversal, the 1000..2000 endpoints the swash forces),
  ``AP_MotorsHeli_Single::output_to_motors`` with ``SRV_Channel::pwm_from_angle`` (tail) and
  ``AP_MotorsHeli_RSC::write_rsc`` with ``SRV_Channel::pwm_from_range`` (channel 8).
* **The plant's side** (:class:`Swashplate`): a physical head. Three servos (PWM -> arm angle ->
  ball travel) move a plate; the plate's height sets the collective ``theta_m`` and its tilt,
  through the head's phase, the cyclic ``eps`` (forward) and ``eta`` (right); a fourth servo sets
  the tail pitch ``theta_t``. The inverse (pitches -> PWM) lets this bench's own autopilot drive
  the same hardware. :meth:`Swashplate.from_ardupilot_params` builds the head from a ``.parm``.

Sign mapping (bench: body FLU, pitch vector ``(theta_m, theta_t, eps, eta)`` [rad]; ArduPilot:
``roll > 0`` right, ``pitch > 0`` nose up, ``yaw > 0`` nose right, collective 0..1 up):

* ``eps = -k * pitch``: ArduPilot's forward (nose-down) stick, ``pitch < 0``, gives ``eps > 0``;
* ``eta = +k * roll``: roll right gives ``eta > 0``;
* ``theta_m`` rises with ArduPilot's collective (``H_SW_COL_DIR`` only says which way the plate
  moves for it);
* ``yaw > 0`` (nose right) lowers ``theta_t`` for a counter-clockwise main rotor (the paper's and
  ``heli_plant.dynamics``'s frame, where ``theta_t > 0`` yaws the nose left) and raises it for a
  clockwise one; the tail file gives ``theta_t`` at each end of the servo's travel.

Bad input never yields NaN: a non-finite PWM is replaced by the servo's neutral, one outside
its travel is clipped to it, and each such channel counts in ``refused``; pitches beyond the
head's mechanical limits are clipped and count in ``saturated``.
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from heli_common.config import ConfigError, load, spec
from heli_common.jit import njit
from heli_common.layout import Layout
from heli_common.state import EPS, ETA, N_PITCH, THETA_M, THETA_T, FloatArray

AP_COMMIT = "90700977c553d2dfd95a305acf1c3e098e4d9477"  # ArduPilot master, July 2025, Copter 4.7.0-dev

# AP_MotorsHeli_Swash::add_servo_raw: _rollFactor = roll * 0.45, _pitchFactor = pitch * 0.45
CYCLIC_SCALE = 0.45
# AP_MotorsHeli_Single.cpp: #define YAW_SERVO_MAX_ANGLE 4500 (rc_write_angle's range, centidegrees)
YAW_SERVO_MAX_ANGLE = 4500
# AP_MotorsHeli_Swash::add_servo_raw: SRV_Channels::set_output_min_max(function, 1000, 2000)
SWASH_PWM_MIN, SWASH_PWM_MAX = 1000, 2000
# AP_MotorsHeli_Swash::get_linear_servo_output: safe_asin(0.766044f * input) * 1.145916,
# i.e. sin(50 deg) and 1 / (50 deg in rad): the servo arm swings +-50 deg over +-500 us.
LIN_SVO_SIN = 0.766044
LIN_SVO_GAIN = 1.145916
LIN_SVO_ARM_DEG = 50.0
# AP_MotorsHeli.h defaults (used when a .parm leaves a parameter out)
AP_COLLECTIVE_MIN, AP_COLLECTIVE_MAX = 1250, 1750
AP_SWASH_CYCLIC_MAX = 2500
AP_COLLECTIVE_HOVER_DEFAULT = 0.5
AP_COLLECTIVE_MIN_DEG, AP_COLLECTIVE_MAX_DEG = -90.0, 90.0  # the arming check refuses these two
# SRV_Channel's defaults for SERVOn_MIN/MAX/TRIM
AP_SERVO_MIN, AP_SERVO_MAX, AP_SERVO_TRIM = 1100, 1900, 1500
# The output functions ArduPilot gives a single heli's channels (SRV_Channel::Function): Motor1-4
# (33-36) on SERVO1-4, HeliRSC (31) on SERVO8.
AP_SERVO_FUNCTIONS = {1: 33, 2: 34, 3: 35, 4: 36, 8: 31}

ROTATIONS = ("counter-clockwise", "clockwise")
_DEG = math.pi / 180.0


class SwashType(enum.IntEnum):
    """``H_SW_TYPE`` (AP_MotorsHeli_Swash.h ``SwashPlateType``); the 4-servo H4_90 (4) and H4_45
    (5) are not modelled."""

    H3 = 0  # generic: servo azimuths H_SW_H3_SV1..3_POS and phase angle H_SW_H3_PHANG
    H1 = 1  # non-CCPM: one servo each for roll, pitch, collective
    H3_140 = 2  # servo 1 left, 2 right, 3 rear; 1:1 mixing
    H3_120 = 3  # servo 1 left-front (-60 deg), 2 right-front (+60 deg), 3 rear (180 deg)


def _f32(x: float) -> float:
    """Round to IEEE single precision. One float32 operation emulated in float64 and rounded
    once is the correctly rounded float32 result (53 >= 2 * 24 + 2 bits), so chaining this
    after every + - * / reproduces the firmware's single-precision arithmetic."""
    return float(np.float32(x))


def _id(x: float) -> float:
    return x


def _radians_cos(angle_deg: float, f: Callable[[float], float]) -> float:
    """``cosf(radians(angle))``: radians() multiplies by ``M_PI / 180.0f`` (a double) and returns
    a float; cosf is taken as correctly rounded (glibc's errs below an ulp)."""
    return f(math.cos(f(f(angle_deg) * _DEG)))


# ---------------------------------------------------------------------------------------------
# The firmware's side
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MixFactors:
    """Per swash servo (1, 2, 3), the factors ArduPilot passes to ``add_servo_raw`` (before its
    ``* 0.45`` on roll and pitch): the servo's output is
    ``0.45 (roll_f roll + pitch_f pitch) + coll_f collective``."""

    roll: tuple[float, float, float]
    pitch: tuple[float, float, float]
    collective: tuple[float, float, float]

    def matrix(self) -> FloatArray:
        """Rows: servos 1-3; columns: (collective, pitch, roll) factors."""
        return np.array([self.collective, self.pitch, self.roll], dtype=float).T


def ardupilot_factors(
    swash_type: SwashType,
    servo_pos_deg: tuple[float, float, float] = (-60.0, 60.0, 180.0),
    phase_deg: float = 0.0,
    *,
    float32: bool = False,
) -> MixFactors:
    """``AP_MotorsHeli_Swash::calculate_roll_pitch_collective_factors`` (commit :data:`AP_COMMIT`).

    ``add_servo_angle(num, angle, coll)`` is ``add_servo_raw(num, cosf(radians(angle + 90)),
    cosf(radians(angle)), coll)``. H3: ``angle = H_SW_H3_SVn_POS - H_SW_H3_PHANG``; H3_120:
    angles -60, 60, 180 (no phase angle); H3_140: raw (1, 1, 1), (-1, 1, 1), (0, -1, 1) as
    (roll, pitch, collective); H1: raw (1, 0, 0), (0, 1, 0), (0, 0, 1).
    ``float32`` rounds as the firmware does (single precision)."""
    f = _f32 if float32 else _id
    t = SwashType(swash_type)
    if t == SwashType.H1:
        return MixFactors((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    if t == SwashType.H3_140:
        return MixFactors((1.0, -1.0, 0.0), (1.0, 1.0, -1.0), (1.0, 1.0, 1.0))
    if t == SwashType.H3_120:
        angles: tuple[float, ...] = (-60.0, 60.0, 180.0)
    else:  # H3 generic: AP_Int16 servo position minus AP_Int16 phase angle
        angles = tuple(float(p - phase_deg) for p in servo_pos_deg)
    roll = tuple(_radians_cos(f(a + 90.0), f) for a in angles)
    pitch = tuple(_radians_cos(a, f) for a in angles)
    return MixFactors(
        (roll[0], roll[1], roll[2]), (pitch[0], pitch[1], pitch[2]), (1.0, 1.0, 1.0)
    )


def _param_int(value: float) -> int:
    """``AP_Param::set_float`` for an integer parameter: add 0.01 (away from zero), truncate."""
    return int(value + math.copysign(0.01, value))


@dataclass(frozen=True)
class ServoChannel:
    """``SERVOn_MIN``, ``SERVOn_MAX``, ``SERVOn_TRIM`` [us] and ``SERVOn_REVERSED``."""

    min_us: int = AP_SERVO_MIN
    max_us: int = AP_SERVO_MAX
    trim_us: int = AP_SERVO_TRIM
    reversed: bool = False

    def __post_init__(self) -> None:
        if not self.min_us <= self.trim_us <= self.max_us or self.min_us >= self.max_us:
            raise ValueError(f"servo needs MIN < MAX and MIN <= TRIM <= MAX, got "
                             f"{self.min_us}, {self.max_us}, {self.trim_us}")  # fmt: skip


@dataclass(frozen=True)
class ArduPilotHeli:
    """The parameters of ``arducopter-heli`` that set its servo outputs (names in
    :meth:`from_params`). Integer parameters are ints, as the firmware stores them."""

    sw_type: SwashType = SwashType.H3_120
    sw_col_dir: int = 0  # H_SW_COL_DIR: 1 = the plate moves down for more collective pitch
    sw_lin_svo: bool = False  # H_SW_LIN_SVO
    sw_h3_sv_pos_deg: tuple[int, int, int] = (-60, 60, 180)  # H_SW_H3_SV1..3_POS
    sw_h3_phang_deg: int = 0  # H_SW_H3_PHANG
    col_min_us: int = AP_COLLECTIVE_MIN  # H_COL_MIN
    col_max_us: int = AP_COLLECTIVE_MAX  # H_COL_MAX
    col_ang_min_deg: float = AP_COLLECTIVE_MIN_DEG  # H_COL_ANG_MIN
    col_ang_max_deg: float = AP_COLLECTIVE_MAX_DEG  # H_COL_ANG_MAX
    col_zero_thrst_deg: float = 0.0  # H_COL_ZERO_THRST (feed-forward only: not in the mix)
    col_hover: float = AP_COLLECTIVE_HOVER_DEFAULT  # H_COL_HOVER (likewise)
    cyc_max: int = AP_SWASH_CYCLIC_MAX  # H_CYC_MAX
    servos: tuple[ServoChannel, ServoChannel, ServoChannel, ServoChannel] = (
        ServoChannel(), ServoChannel(), ServoChannel(), ServoChannel()
    )  # SERVO1..4
    rsc: ServoChannel = ServoChannel()  # SERVO8 (HeliRSC)
    rsc_idle_pct: float = 0.0  # H_RSC_IDLE
    rsc_setpoint_pct: float = 70.0  # H_RSC_SETPOINT

    def __post_init__(self) -> None:
        object.__setattr__(self, "sw_type", SwashType(self.sw_type))
        if self.sw_col_dir not in (0, 1):
            raise ValueError(f"H_SW_COL_DIR must be 0 or 1, got {self.sw_col_dir}")
        if self.col_min_us >= self.col_max_us:
            raise ValueError(f"H_COL_MIN {self.col_min_us} must be below H_COL_MAX {self.col_max_us} "
                             "(the firmware would silently reset both to 1250, 1750)")  # fmt: skip
        if not self.col_ang_min_deg < self.col_ang_max_deg:
            raise ValueError(f"H_COL_ANG_MIN {self.col_ang_min_deg} must be below H_COL_ANG_MAX "
                             f"{self.col_ang_max_deg}")  # fmt: skip
        if not 0 <= self.cyc_max <= 4500:
            raise ValueError(f"H_CYC_MAX must be in [0, 4500], got {self.cyc_max}")
        if self.sw_type == SwashType.H3 and not -30 <= self.sw_h3_phang_deg <= 30:
            raise ValueError(f"H_SW_H3_PHANG must be in [-30, 30] (arming check), got {self.sw_h3_phang_deg}")

    @classmethod
    def from_params(cls, params: Mapping[str, float]) -> ArduPilotHeli:
        """From ArduPilot parameter names (a ``.parm`` read by :func:`read_parm`); a parameter
        left out takes the firmware's default. Refuses the 4-servo plates, a tail other than
        ``H_TAIL_TYPE 0`` (servo only) and channel functions moved off SERVO1-4 / SERVO8."""
        for k, v in params.items():
            if not math.isfinite(float(v)):
                raise ValueError(f"{k}: not a finite number: {v!r}")

        def get(name: str, default: float) -> float:
            return float(params.get(name, default))

        def geti(name: str, default: int) -> int:
            return _param_int(get(name, default))

        sw = geti("H_SW_TYPE", int(SwashType.H3_120))
        if sw not in {int(t) for t in SwashType}:
            raise ValueError(f"H_SW_TYPE {sw}: only 0 (H3), 1 (H1), 2 (H3_140), 3 (H3_120) are modelled")
        tail = geti("H_TAIL_TYPE", 0)
        if tail != 0:
            raise ValueError(f"H_TAIL_TYPE {tail}: only 0 (servo only) is modelled")
        for n, fn in AP_SERVO_FUNCTIONS.items():
            key = f"SERVO{n}_FUNCTION"
            if key in params and geti(key, fn) != fn:
                raise ValueError(f"{key} {geti(key, fn)}: the heli mixing needs {fn} on SERVO{n}")

        def servo(n: int) -> ServoChannel:
            lo, hi = geti(f"SERVO{n}_MIN", AP_SERVO_MIN), geti(f"SERVO{n}_MAX", AP_SERVO_MAX)
            trim = geti(f"SERVO{n}_TRIM", AP_SERVO_TRIM)
            return ServoChannel(lo, hi, trim, geti(f"SERVO{n}_REVERSED", 0) != 0)

        return cls(
            sw_type=SwashType(sw),
            sw_col_dir=geti("H_SW_COL_DIR", 0),
            sw_lin_svo=geti("H_SW_LIN_SVO", 0) != 0,
            sw_h3_sv_pos_deg=(
                geti("H_SW_H3_SV1_POS", -60), geti("H_SW_H3_SV2_POS", 60), geti("H_SW_H3_SV3_POS", 180)
            ),
            sw_h3_phang_deg=geti("H_SW_H3_PHANG", 0),
            col_min_us=geti("H_COL_MIN", AP_COLLECTIVE_MIN),
            col_max_us=geti("H_COL_MAX", AP_COLLECTIVE_MAX),
            col_ang_min_deg=_f32(get("H_COL_ANG_MIN", AP_COLLECTIVE_MIN_DEG)),
            col_ang_max_deg=_f32(get("H_COL_ANG_MAX", AP_COLLECTIVE_MAX_DEG)),
            col_zero_thrst_deg=_f32(get("H_COL_ZERO_THRST", 0.0)),
            col_hover=_f32(get("H_COL_HOVER", AP_COLLECTIVE_HOVER_DEFAULT)),
            cyc_max=geti("H_CYC_MAX", AP_SWASH_CYCLIC_MAX),
            servos=(servo(1), servo(2), servo(3), servo(4)),
            rsc=servo(8),
            rsc_idle_pct=get("H_RSC_IDLE", 0.0),
            rsc_setpoint_pct=get("H_RSC_SETPOINT", 70.0),
        )

    def factors(self, *, float32: bool = False) -> MixFactors:
        p = self.sw_h3_sv_pos_deg
        pos = (float(p[0]), float(p[1]), float(p[2]))
        return ardupilot_factors(self.sw_type, pos, float(self.sw_h3_phang_deg), float32=float32)

    def swash_outputs(
        self, roll: float, pitch: float, collective_scaled: float, *, float32: bool = False
    ) -> tuple[float, float, float]:
        """``AP_MotorsHeli_Swash::calculate``: each servo's ``_output`` in -1..1 (0 = trim) for
        the cyclic ``roll``, ``pitch`` (after the ``H_CYC_MAX`` limit) and the scaled collective
        (``move_actuators``'s ``collective_out_scaled``)::

            coll = 1 - collective_scaled if H_SW_COL_DIR == 1 else collective_scaled
            out_i = 0.45 roll_f_i roll + 0.45 pitch_f_i pitch + coll_f_i coll  (+ 0.5 for H1's 1, 2)
            out_i = 2 out_i - 1;  out_i = asin(0.766044 clip(out_i)) 1.145916  if H_SW_LIN_SVO
        """
        f = _f32 if float32 else _id
        fac = self.factors(float32=float32)
        coll = f(1.0 - collective_scaled) if self.sw_col_dir == 1 else f(collective_scaled)
        out: list[float] = []
        for i in range(3):
            rf, pf = f(fac.roll[i] * CYCLIC_SCALE), f(fac.pitch[i] * CYCLIC_SCALE)
            o = f(f(f(rf * roll) + f(pf * pitch)) + f(fac.collective[i] * coll))
            if self.sw_type == SwashType.H1 and i < 2:
                o = f(o + 0.5)
            o = f(f(2.0 * o) - 1.0)
            if self.sw_lin_svo:
                o = linear_servo_output(o, float32=float32)
            out.append(o)
        return (out[0], out[1], out[2])

    def unmix(self, outputs: Sequence[float]) -> tuple[float, float, float]:
        """The inverse of :meth:`swash_outputs` (float64): ``(roll, pitch, collective_scaled)``
        from the three servo outputs."""
        o = np.array([float(v) for v in outputs[:3]])
        if self.sw_lin_svo:
            o = np.sin(o / LIN_SVO_GAIN) / LIN_SVO_SIN
        s = (o + 1.0) / 2.0
        if self.sw_type == SwashType.H1:
            s[:2] -= 0.5
        m = self.factors().matrix() * np.array([1.0, CYCLIC_SCALE, CYCLIC_SCALE])
        coll, pitch, roll = np.linalg.solve(m, s)
        if self.sw_col_dir == 1:
            coll = 1.0 - coll
        return float(roll), float(pitch), float(coll)

    def collective_scaled(self, collective: float, *, float32: bool = False) -> float:
        """``move_actuators``: ``collective (H_COL_MAX - H_COL_MIN) 0.001 + (H_COL_MIN - 1000) 0.001``."""
        f = _f32 if float32 else _id
        scalar = f(float(self.col_max_us - self.col_min_us) * f(0.001))
        return f(f(collective * scalar) + f(float(self.col_min_us - 1000) * f(0.001)))

    def collective_for_pitch(self, theta_m_rad: float) -> float:
        """The collective (0..1) whose blade pitch is ``theta_m_rad`` on a head calibrated by
        ``H_COL_ANG_MIN``/``MAX`` (for ``H_COL_HOVER`` from a trim)."""
        span = self.col_ang_max_deg - self.col_ang_min_deg
        return (math.degrees(theta_m_rad) - self.col_ang_min_deg) / span


def linear_servo_output(x: float, *, float32: bool = False) -> float:
    """``AP_MotorsHeli_Swash::get_linear_servo_output``: ``safe_asin(0.766044 clip(x)) * 1.145916``."""
    f = _f32 if float32 else _id
    x = min(max(x, -1.0), 1.0)
    return f(f(math.asin(f(f(LIN_SVO_SIN) * x))) * LIN_SVO_GAIN)


@dataclass(frozen=True)
class ArduPilotMix:
    """One ``move_actuators`` call's swash outputs.

    ``roll``, ``pitch``: after the ``H_CYC_MAX`` limit; ``collective``: clipped to 0..1;
    ``outputs``: the swash's ``_output[i]`` (-1..1, 0 = trim); ``pwm_exact``: the PWM of ``outputs``
    without the firmware's integer truncation; ``pwm``: SERVO1-3 as the firmware writes them."""

    roll: float
    pitch: float
    collective: float
    collective_scaled: float
    outputs: tuple[float, float, float]
    pwm_exact: tuple[float, float, float]
    pwm: tuple[int, int, int]
    cyclic_limited: bool
    collective_limited: bool


def _trimmed(pwm: float, servo: ServoChannel) -> float:
    """``SRV_Channels::set_output_pwm_trimmed``: about 1500 to the trim, mirrored if reversed,
    clipped to the 1000..2000 endpoints the swash forces on its servos."""
    v = 1500.0 - pwm + servo.trim_us if servo.reversed else pwm - 1500.0 + servo.trim_us
    return min(max(v, float(SWASH_PWM_MIN)), float(SWASH_PWM_MAX))


def ardupilot_mix(
    roll_in: float, pitch_in: float, coll_in: float, heli: ArduPilotHeli, *, float32: bool = True
) -> ArduPilotMix:
    """SERVO1-3 for ``AP_MotorsHeli_Single::move_actuators(roll_in, pitch_in, coll_in, ...)``.

    * ``H_CYC_MAX``: if ``|(pitch, roll)| > H_CYC_MAX / 4500`` both are scaled onto that circle;
    * collective clipped to 0..1 and scaled between ``H_COL_MIN`` and ``H_COL_MAX``;
    * :meth:`ArduPilotHeli.swash_outputs`, then ``rc_write``: ``pwm = (uint16)(1500 + 500 out)``,
      then trim/reversal/endpoints (``set_output_pwm_trimmed``).

    Not modelled: the landing-collective floor (``H_COL_LAND_MIN`` while the firmware's
    landing flag is set), servo test and manual servo modes. ``float32`` (the default)
    reproduces the firmware's single-precision arithmetic, so ``pwm`` matches it to the us."""
    f = _f32 if float32 else _id
    for name, v in (("roll_in", roll_in), ("pitch_in", pitch_in), ("coll_in", coll_in)):
        if not math.isfinite(v):
            raise ValueError(f"{name} must be finite, got {v!r}")
    roll, pitch = f(roll_in), f(pitch_in)
    total = f(math.sqrt(f(f(pitch * pitch) + f(roll * roll))))
    cmax = f(heli.cyc_max / 4500.0)
    limited = total > cmax
    if limited:
        ratio = f(cmax / total)
        roll, pitch = f(roll * ratio), f(pitch * ratio)
    coll = f(coll_in)
    coll_limited = coll <= 0.0 or coll >= 1.0
    coll = min(max(coll, 0.0), 1.0)
    scaled = heli.collective_scaled(coll, float32=float32)
    out = heli.swash_outputs(roll, pitch, scaled, float32=float32)
    pairs = list(zip(out, heli.servos[:3], strict=True))
    exact = [_trimmed(1500.0 + 500.0 * o, s) for o, s in pairs]
    # rc_write: (uint16_t)(1500 + 500 * swash_in), a truncation
    pwm = [int(_trimmed(float(int(f(1500.0 + f(500.0 * o)))), s)) for o, s in pairs]
    return ArduPilotMix(
        roll, pitch, coll, scaled, out, (exact[0], exact[1], exact[2]), (pwm[0], pwm[1], pwm[2]),
        limited, coll_limited,
    )


def ardupilot_tail_pwm(yaw_out: float, heli: ArduPilotHeli) -> int:
    """SERVO4 for ``H_TAIL_TYPE 0``: ``move_yaw`` clips to -1..1, ``output_to_motors`` writes
    ``rc_write_angle(4, yaw * 4500)`` (an int16 centidegree angle) and
    ``SRV_Channel::pwm_from_angle`` maps it about ``SERVO4_TRIM`` to ``SERVO4_MAX`` (positive,
    nose right) or ``SERVO4_MIN``, mirrored if reversed. Not modelled: ``H_COL2YAW``'s
    feed-forward (``get_yaw_offset``), zero by default."""
    if not math.isfinite(yaw_out):
        raise ValueError(f"yaw_out must be finite, got {yaw_out!r}")
    s = heli.servos[3]
    y = min(max(_f32(yaw_out), -1.0), 1.0)
    angle = float(int(_f32(y * YAW_SERVO_MAX_ANGLE)))  # int16 truncation toward zero
    if s.reversed:
        angle = -angle
    angle = min(max(angle, -YAW_SERVO_MAX_ANGLE), YAW_SERVO_MAX_ANGLE)
    if angle > 0:
        return s.trim_us + int(_f32(_f32(angle * float(s.max_us - s.trim_us)) / YAW_SERVO_MAX_ANGLE))
    return s.trim_us - int(_f32(_f32(-angle * float(s.trim_us - s.min_us)) / YAW_SERVO_MAX_ANGLE))


def ardupilot_rsc_pwm(throttle: float, heli: ArduPilotHeli) -> int:
    """SERVO8 (HeliRSC): ``AP_MotorsHeli_RSC::write_rsc(out)`` sets ``out * 1000`` on a range of
    1000 and ``SRV_Channel::pwm_from_range`` maps it: ``SERVO8_MIN + out (MAX - MIN)``,
    mirrored if reversed (0: rotor stopped; ``H_RSC_IDLE`` %: idle; the setpoint when running)."""
    if not math.isfinite(throttle):
        raise ValueError(f"throttle must be finite, got {throttle!r}")
    s = heli.rsc
    v = min(max(_f32(throttle * 1000.0), 0.0), 1000.0)
    if s.reversed:
        v = 1000.0 - v
    return s.min_us + int(_f32(_f32(v * float(s.max_us - s.min_us)) / 1000.0))


@dataclass(frozen=True)
class RotorRequest:
    """Channel 8 read back: ``throttle`` in [0, 1] (the RSC output), ``interlock`` true when the
    rotor is asked to run (above the idle output), ``refused`` 1 when the PWM was not finite or
    outside SERVO8's range (then clipped; a non-finite one reads as 0, rotor off)."""

    throttle: float
    interlock: bool
    refused: int


def rsc_request(
    pwm_us: float, *, pwm_min_us: float = 1000.0, pwm_max_us: float = 2000.0, reversed: bool = False,
    idle: float = 0.0,
) -> RotorRequest:  # fmt: skip
    """The throttle/interlock a HeliRSC PWM asks for: the inverse of :func:`ardupilot_rsc_pwm`
    (``(pwm - MIN) / (MAX - MIN)``, ``1 -`` that if reversed). ``idle`` is ``H_RSC_IDLE / 100``;
    the firmware writes 0 when disarmed and ``idle`` while the interlock is off, so the
    interlock reads as engaged above ``idle`` by more than half a microsecond."""
    if not pwm_min_us < pwm_max_us:
        raise ValueError(f"need pwm_min_us < pwm_max_us, got {pwm_min_us}, {pwm_max_us}")
    if not math.isfinite(pwm_us):
        return RotorRequest(0.0, False, 1)
    refused = int(not pwm_min_us <= pwm_us <= pwm_max_us)
    span = pwm_max_us - pwm_min_us
    t = (min(max(pwm_us, pwm_min_us), pwm_max_us) - pwm_min_us) / span
    if reversed:
        t = 1.0 - t
    return RotorRequest(t, t > idle + 0.5 / span, refused)


def read_parm(path: str | Path) -> dict[str, float]:
    """An ArduPilot ``.parm`` file (``NAME VALUE`` or ``NAME,VALUE`` a line, ``#`` comments) as a
    dict; a later line overrides an earlier one, as when the firmware loads it."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read: {exc}") from exc
    out: dict[str, float] = {}
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].replace(",", " ").split()
        if not line:
            continue
        if len(line) != 2:
            raise ConfigError(f"{p}:{n}: expected NAME VALUE, got {raw.strip()!r}")
        try:
            value = float(line[1])
        except ValueError as exc:
            raise ConfigError(f"{p}:{n}: {line[0]}: not a number: {line[1]!r}") from exc
        if not math.isfinite(value):
            raise ConfigError(f"{p}:{n}: {line[0]}: not a finite number: {line[1]!r}")
        out[line[0]] = value
    return out


# ---------------------------------------------------------------------------------------------
# The plant's side: a physical head
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SwashServos:
    """The three swash servos (SERVO1-3): PWM travel, the neutral (arm level, ball at mid
    travel: ArduPilot's ``SERVOn_TRIM``), the mounting (``reversed``: PWM above neutral lowers
    the ball) and the arm: with ``arm_max_deg`` > 0 the arm turns linearly with PWM,
    ``arm_max_deg`` at 500 us from neutral, and the ball rises with the arm angle's sine
    (``H_SW_LIN_SVO`` compensates 50 deg); 0 makes the ball's travel linear in PWM."""

    pwm_min_us: tuple[float, float, float] = spec("us", 500.0, 2500.0, default=(1000.0, 1000.0, 1000.0))
    pwm_max_us: tuple[float, float, float] = spec("us", 500.0, 2500.0, default=(2000.0, 2000.0, 2000.0))
    pwm_neutral_us: tuple[float, float, float] = spec("us", 500.0, 2500.0, default=(1500.0, 1500.0, 1500.0))
    reversed: tuple[bool, bool, bool] = spec(default=(False, False, False))
    arm_max_deg: float = spec("deg", 0.0, 80.0, default=0.0)

    def __post_init__(self) -> None:
        for i in range(3):
            lo, mid, hi = self.pwm_min_us[i], self.pwm_neutral_us[i], self.pwm_max_us[i]
            if not lo < mid < hi:
                raise ValueError(f"servo {i + 1}: need pwm_min_us < pwm_neutral_us < pwm_max_us, "
                                 f"got {lo}, {mid}, {hi}")  # fmt: skip


@dataclass(frozen=True)
class Head:
    """Plate -> blades. The plate's height ``H`` and tilt are in microseconds of servo travel at
    the servo ring (ArduPilot's units: ``H = 1000 collective_scaled - 500``, a tilt of
    ``450 roll`` / ``450 pitch``). ``theta_m = theta_m_at_neutral + s k H`` (``s = -1`` when
    ``collective_reversed``, ``k = theta_m_per_us_rad``); the cyclic is ``cyclic_ratio k`` times
    the tilt after the head's phase lag ``phase_deg`` (the azimuth, toward the right, by which
    the plate's high point leads the disc's: what ``H_SW_H3_PHANG`` compensates). Mechanical
    limits clip each pitch."""

    theta_m_at_neutral_rad: float = spec("rad", -0.6, 0.6)
    theta_m_per_us_rad: float = spec("rad/us", 0.0, 0.01, lo_open=True)
    theta_m_rad: tuple[float, float] = spec("rad", -0.6, 0.6)
    eps_rad: tuple[float, float] = spec("rad", -0.5, 0.5)
    eta_rad: tuple[float, float] = spec("rad", -0.5, 0.5)
    collective_reversed: bool = spec(default=False)
    cyclic_ratio: float = spec("", 0.0, 10.0, lo_open=True, default=1.0)
    phase_deg: float = spec("deg", -90.0, 90.0, default=0.0)

    def __post_init__(self) -> None:
        for name in ("theta_m_rad", "eps_rad", "eta_rad"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"{name}: lower limit {lo} must be below upper limit {hi}")


@dataclass(frozen=True)
class TailServo:
    """SERVO4: its travel ``pwm_us`` (the pitch slider's ends) and ``theta_t`` at each end,
    linear between; a non-finite PWM reads as mid travel."""

    theta_t_rad: tuple[float, float] = spec("rad", -0.8, 0.8)
    pwm_us: tuple[float, float] = spec("us", 500.0, 2500.0, default=(1000.0, 2000.0))

    def __post_init__(self) -> None:
        if not self.pwm_us[0] < self.pwm_us[1]:
            raise ValueError(f"pwm_us: {self.pwm_us[0]} must be below {self.pwm_us[1]}")
        if self.theta_t_rad[0] == self.theta_t_rad[1]:
            raise ValueError("theta_t_rad: the two ends must differ")


@dataclass(frozen=True)
class RotorSpeedInput:
    """Channel 8 (HeliRSC) at the rotor: an external governor (ArduPilot's ``H_RSC_MODE 2``,
    "setpoint": the firmware ramps its output to ``H_RSC_SETPOINT`` and a governor in the ESC
    or on the engine holds the speed). The output is read back over ``pwm_us`` (``SERVO8_MIN``
    .. ``MAX``, ``reversed``); at ``idle`` (``H_RSC_IDLE``) or below the interlock is off and
    the engine stops; above it the governor holds ``throttle / full_speed_throttle`` of the
    design speed, all of it from ``full_speed_throttle`` (``H_RSC_SETPOINT``) up, as an
    ESC's governor mode maps throttle to head speed."""

    pwm_us: tuple[float, float] = spec("us", 500.0, 2500.0, default=(1000.0, 2000.0))
    reversed: bool = spec(default=False)
    idle: float = spec("", 0.0, 0.5, default=0.0)
    full_speed_throttle: float = spec("", 0.05, 1.0, default=0.66)

    def __post_init__(self) -> None:
        if not self.pwm_us[0] < self.pwm_us[1]:
            raise ValueError(f"pwm_us: {self.pwm_us[0]} must be below {self.pwm_us[1]}")
        if not self.idle < self.full_speed_throttle:
            raise ValueError(f"idle {self.idle} must be below full_speed_throttle {self.full_speed_throttle}")

    def speed_fraction(self, pwm_us: float) -> tuple[float, bool, int]:
        """``(fraction of the design speed the governor holds, interlock, refused)`` for a
        channel 8 PWM; 0 with the interlock off (the engine stopped)."""
        r = rsc_request(pwm_us, pwm_min_us=self.pwm_us[0], pwm_max_us=self.pwm_us[1], reversed=self.reversed,
                        idle=self.idle)  # fmt: skip
        if not r.interlock:
            return 0.0, False, r.refused
        return min(r.throttle / self.full_speed_throttle, 1.0), True, r.refused


@dataclass(frozen=True)
class PitchReading:
    """Blade pitches read from servo PWMs, in the bench's order ``(theta_m, theta_t, eps, eta)``
    [rad], with ``refused``: channels whose PWM was non-finite or outside the servo's travel, and
    ``saturated``: pitches clipped at the head's mechanical limits."""

    pitches_rad: tuple[float, float, float, float]
    refused: int
    saturated: int

    def as_array(self) -> FloatArray:
        return np.array(self.pitches_rad, dtype=float)


SWASH_TYPES = tuple(t.name for t in SwashType)

# The head's numbers that PWM -> pitches needs, flat for the compiled kernel (built once by
# Swashplate._kernel_params): the backend reads a servo frame 400 times a second
SWASH_PARAMS = Layout(
    "swashplate parameters",
    ("pwm_min_us", 3), ("pwm_max_us", 3), ("pwm_neutral_us", 3),
    ("direction", 3),  # +1, or -1 for a reversed servo (PWM above neutral lowers the ball)
    ("arm_max_rad", 1), ("sin_arm_max", 1),  # the arm's swing at 500 us; 0: linear ball travel
    ("plate_from_servos", 9),  # (height, front-up tilt, left-up tilt) from the travels, row-major
    ("theta_m_at_neutral_rad", 1),
    ("collective_rad_per_us", 1),  # signed: negative when the collective is reversed
    ("cyclic_rad_per_us", 1), ("cos_phase", 1), ("sin_phase", 1),
    ("blade_min_rad", 3), ("blade_max_rad", 3),  # the mechanical limits of (theta_m, eps, eta)
)  # fmt: skip
SP_PWM_MIN = SWASH_PARAMS.offset("pwm_min_us")
SP_PWM_MAX = SWASH_PARAMS.offset("pwm_max_us")
SP_PWM_NEUTRAL = SWASH_PARAMS.offset("pwm_neutral_us")
SP_DIRECTION = SWASH_PARAMS.offset("direction")
SP_ARM_MAX = SWASH_PARAMS.offset("arm_max_rad")
SP_SIN_ARM_MAX = SWASH_PARAMS.offset("sin_arm_max")
SP_PLATE = SWASH_PARAMS.offset("plate_from_servos")
SP_THETA_M0 = SWASH_PARAMS.offset("theta_m_at_neutral_rad")
SP_COLLECTIVE = SWASH_PARAMS.offset("collective_rad_per_us")
SP_CYCLIC = SWASH_PARAMS.offset("cyclic_rad_per_us")
SP_COS_PHASE = SWASH_PARAMS.offset("cos_phase")
SP_SIN_PHASE = SWASH_PARAMS.offset("sin_phase")
SP_BLADE_MIN = SWASH_PARAMS.offset("blade_min_rad")
SP_BLADE_MAX = SWASH_PARAMS.offset("blade_max_rad")
N_SWASH_PARAMS = SWASH_PARAMS.size
N_SWASH_SERVOS = 3
# the plate's coordinates in its travel vector, and the blades' in theirs
PLATE_HEIGHT, PLATE_TILT_FRONT, PLATE_TILT_LEFT = range(3)
BLADE_THETA_M, BLADE_EPS, BLADE_ETA = range(3)
# a servo's ball travel [us] per unit of normalised arm travel: +-500 us from neutral
_HALF_TRAVEL_US = 500.0


@njit
def clip_blades(blades: FloatArray, prm: FloatArray) -> int:
    """Clip ``(theta_m, eps, eta)`` [rad] to the head's limits in place; how many were clipped."""
    clipped = 0
    for i in range(N_SWASH_SERVOS):
        c = min(max(blades[i], prm[SP_BLADE_MIN + i]), prm[SP_BLADE_MAX + i])
        clipped += c != blades[i]
        blades[i] = c
    return clipped


@njit
def swash_pitches_kernel(pwm_us: FloatArray, prm: FloatArray) -> tuple[float, float, float, int, int]:
    """SERVO1-3 PWM [us] -> ``(theta_m, eps, eta [rad], refused, saturated)`` for the head
    ``prm`` (layout :data:`SWASH_PARAMS`): each servo's PWM (a non-finite one read as its
    neutral, one outside its travel clipped: both refused) -> ball travel [us] (through the
    arm's sine if it has one) -> plate height and tilt -> blade pitches after the head's
    phase, clipped at its limits (saturated)."""
    travel = np.empty(N_SWASH_SERVOS)
    refused = 0
    for i in range(N_SWASH_SERVOS):
        lo, hi, mid = prm[SP_PWM_MIN + i], prm[SP_PWM_MAX + i], prm[SP_PWM_NEUTRAL + i]
        p = pwm_us[i]
        if not math.isfinite(p):
            p = mid
            refused += 1
        elif p < lo or p > hi:
            refused += 1
        p = min(max(p, lo), hi)
        u = (p - mid) / _HALF_TRAVEL_US * prm[SP_DIRECTION + i]
        if prm[SP_ARM_MAX] > 0.0:
            u = math.sin(prm[SP_ARM_MAX] * u) / prm[SP_SIN_ARM_MAX]
        travel[i] = _HALF_TRAVEL_US * u
    plate = np.zeros(N_SWASH_SERVOS)
    for row in range(N_SWASH_SERVOS):
        for col in range(N_SWASH_SERVOS):
            plate[row] += prm[SP_PLATE + N_SWASH_SERVOS * row + col] * travel[col]
    height, tilt_p, tilt_r = plate[PLATE_HEIGHT], plate[PLATE_TILT_FRONT], plate[PLATE_TILT_LEFT]
    c, s = prm[SP_COS_PHASE], prm[SP_SIN_PHASE]
    disc_p, disc_r = tilt_p * c - tilt_r * s, tilt_r * c + tilt_p * s
    kc = prm[SP_CYCLIC]
    blades = np.empty(N_SWASH_SERVOS)
    blades[BLADE_THETA_M] = prm[SP_THETA_M0] + prm[SP_COLLECTIVE] * height
    blades[BLADE_EPS] = -kc * disc_p
    blades[BLADE_ETA] = kc * disc_r
    saturated = clip_blades(blades, prm)
    return blades[BLADE_THETA_M], blades[BLADE_EPS], blades[BLADE_ETA], refused, saturated


@dataclass(frozen=True)
class Swashplate:
    """A helicopter's swashplate, head and tail servo (TOML: ``configs/swashplate/``).

    ``swash_type`` names the servo layout as ``H_SW_TYPE`` does; ``servo_azimuth_deg`` (H3 only)
    places servos 1-3 on the ring, 0 = front, positive toward the right."""

    name: str = spec()
    swash_type: str = spec(choices=SWASH_TYPES)
    servos: SwashServos = spec()
    head: Head = spec()
    tail: TailServo = spec()
    servo_azimuth_deg: tuple[float, float, float] | None = spec("deg", -180.0, 180.0, default=None)
    rsc: RotorSpeedInput = spec(default=RotorSpeedInput())

    def __post_init__(self) -> None:
        if self.swash_type == "H3" and self.servo_azimuth_deg is None:
            raise ValueError("swash_type H3 needs servo_azimuth_deg")
        if self.swash_type != "H3" and self.servo_azimuth_deg is not None:
            raise ValueError(f"servo_azimuth_deg is for swash_type H3 only ({self.swash_type} has its own)")
        if np.linalg.cond(self.servo_matrix) > 1e6:
            raise ValueError(f"servo_azimuth_deg {self.servo_azimuth_deg}: the servos do not span a plane")

    @classmethod
    def load(cls, path: str | Path = "swashplate/xcell60-h3-120.toml") -> Swashplate:
        return load(cls, path)

    @property
    def kind(self) -> SwashType:
        return SwashType[self.swash_type]

    @functools.cached_property
    def servo_matrix(self) -> FloatArray:
        """Rows: servos 1-3; columns: the ball's travel [us] per unit of plate height, of
        front-up tilt and of left-up tilt (ArduPilot's collective, pitch and roll factors
        without the phase angle: the physical layout)."""
        az = self.servo_azimuth_deg if self.servo_azimuth_deg is not None else (-60.0, 60.0, 180.0)
        return ardupilot_factors(self.kind, az, 0.0).matrix()

    @functools.cached_property
    def _plate_from_servos(self) -> FloatArray:
        return np.asarray(np.linalg.inv(self.servo_matrix))

    @functools.cached_property
    def _kernel_params(self) -> FloatArray:
        """The head as :data:`SWASH_PARAMS`, for :func:`swash_pitches_kernel`."""
        s, h = self.servos, self.head
        prm = np.zeros(N_SWASH_PARAMS)
        n = N_SWASH_SERVOS
        prm[SP_PWM_MIN : SP_PWM_MIN + n] = s.pwm_min_us
        prm[SP_PWM_MAX : SP_PWM_MAX + n] = s.pwm_max_us
        prm[SP_PWM_NEUTRAL : SP_PWM_NEUTRAL + n] = s.pwm_neutral_us
        prm[SP_DIRECTION : SP_DIRECTION + n] = [-1.0 if r else 1.0 for r in s.reversed]
        if s.arm_max_deg > 0.0:
            prm[SP_ARM_MAX] = math.radians(s.arm_max_deg)
            prm[SP_SIN_ARM_MAX] = math.sin(prm[SP_ARM_MAX])
        prm[SP_PLATE : SP_PLATE + n * n] = self._plate_from_servos.reshape(-1)
        k = h.theta_m_per_us_rad
        prm[SP_THETA_M0] = h.theta_m_at_neutral_rad
        prm[SP_COLLECTIVE] = (-1.0 if h.collective_reversed else 1.0) * k
        prm[SP_CYCLIC] = h.cyclic_ratio * k
        prm[SP_COS_PHASE] = math.cos(math.radians(h.phase_deg))
        prm[SP_SIN_PHASE] = math.sin(math.radians(h.phase_deg))
        prm[SP_BLADE_MIN : SP_BLADE_MIN + n] = (h.theta_m_rad[0], h.eps_rad[0], h.eta_rad[0])
        prm[SP_BLADE_MAX : SP_BLADE_MAX + n] = (h.theta_m_rad[1], h.eps_rad[1], h.eta_rad[1])
        prm.flags.writeable = False  # shared by every call: a kernel must not change it
        return prm

    @property
    def cyclic_max_rad(self) -> float:
        """The largest cyclic (eps, eta) radius inside the head's limits."""
        h = self.head
        return float(min(-h.eps_rad[0], h.eps_rad[1], -h.eta_rad[0], h.eta_rad[1]))

    # --- ball travel -> servo PWM (PWM -> travel -> blades: swash_pitches_kernel) --------------

    def _servo_pwm(self, travel_us: FloatArray) -> FloatArray:
        s = self.servos
        h = travel_us / 500.0
        if s.arm_max_deg > 0.0:
            a = math.radians(s.arm_max_deg)
            h = np.arcsin(np.clip(math.sin(a) * h, -1.0, 1.0)) / a
        p = np.array(s.pwm_neutral_us) + 500.0 * h * np.where(np.array(s.reversed), -1.0, 1.0)
        return np.asarray(np.clip(p, s.pwm_min_us, s.pwm_max_us))

    # --- blades -> plate -----------------------------------------------------------------------

    def _plate_from_blades(self, theta_m: float, eps: float, eta: float) -> FloatArray:
        h = self.head
        k = h.theta_m_per_us_rad
        sign = -1.0 if h.collective_reversed else 1.0
        kc = h.cyclic_ratio * k
        disc_p, disc_r = -eps / kc, eta / kc
        c, s = math.cos(math.radians(h.phase_deg)), math.sin(math.radians(h.phase_deg))
        return np.array([sign * (theta_m - h.theta_m_at_neutral_rad) / k, disc_p * c + disc_r * s,
                         disc_r * c - disc_p * s])  # fmt: skip

    # --- public mappings -------------------------------------------------------------------------

    def swash_pitches(self, pwm_us: npt.ArrayLike) -> tuple[tuple[float, float, float], int, int]:
        """SERVO1-3 PWM [us] -> ``((theta_m, eps, eta) [rad], refused, saturated)``."""
        pwm = np.asarray(pwm_us, dtype=float).reshape(-1)[:3]
        if pwm.shape != (3,):
            raise ValueError(f"need 3 swash servo PWMs, got {pwm.size}")
        theta_m, eps, eta, refused, saturated = swash_pitches_kernel(pwm, self._kernel_params)
        return (theta_m, eps, eta), refused, saturated

    def tail_pitch(self, pwm_us: float) -> tuple[float, int]:
        """SERVO4 PWM [us] -> ``(theta_t [rad], refused)``."""
        (lo, hi), (t_lo, t_hi) = self.tail.pwm_us, self.tail.theta_t_rad
        p = float(pwm_us)
        if not math.isfinite(p):
            p, refused = 0.5 * (lo + hi), 1
        else:
            refused = int(not lo <= p <= hi)
            p = min(max(p, lo), hi)
        return t_lo + (p - lo) / (hi - lo) * (t_hi - t_lo), refused

    def pitches_from_pwm(self, pwm_us: npt.ArrayLike) -> PitchReading:
        """A servo frame (channels 1-4 first: swash 1-3, tail; more are ignored) -> the bench's
        pitch vector ``(theta_m, theta_t, eps, eta)`` [rad]."""
        pwm = np.asarray(pwm_us, dtype=float).reshape(-1)
        if pwm.size < 4:
            raise ValueError(f"need at least 4 channels, got {pwm.size}")
        (theta_m, eps, eta), refused, saturated = self.swash_pitches(pwm[:3])
        theta_t, tail_refused = self.tail_pitch(float(pwm[3]))
        out = [0.0] * N_PITCH
        out[THETA_M], out[THETA_T], out[EPS], out[ETA] = theta_m, theta_t, eps, eta
        return PitchReading((out[0], out[1], out[2], out[3]), refused + tail_refused, saturated)

    def pwm_from_pitches(self, pitches_rad: npt.ArrayLike) -> FloatArray:
        """The inverse: the bench's pitch vector (clipped to the head's and the tail's limits)
        -> PWM [us, float] for channels 1-4 (CCPM mixing for this bench's own autopilot)."""
        u = np.asarray(pitches_rad, dtype=float).reshape(-1)
        if u.shape != (N_PITCH,) or not np.all(np.isfinite(u)):
            raise ValueError(f"need {N_PITCH} finite pitches (theta_m, theta_t, eps, eta), got {u!r}")
        blades = np.array([u[THETA_M], u[EPS], u[ETA]])
        clip_blades(blades, self._kernel_params)
        plate = self._plate_from_blades(float(blades[0]), float(blades[1]), float(blades[2]))
        swash = self._servo_pwm(self.servo_matrix @ plate)
        (lo, hi), (t_lo, t_hi) = self.tail.pwm_us, self.tail.theta_t_rad
        tt = min(max(float(u[THETA_T]), min(t_lo, t_hi)), max(t_lo, t_hi))
        tail = lo + (tt - t_lo) / (t_hi - t_lo) * (hi - lo)
        return np.array([swash[0], swash[1], swash[2], tail])

    @classmethod
    def from_ardupilot_params(
        cls, params: Mapping[str, float], *, tail_theta_t_rad: tuple[float, float],
        main_rotor_rotation: str = "counter-clockwise", cyclic_ratio: float = 1.0,
        name: str = "from ArduPilot parameters",
    ) -> Swashplate:  # fmt: skip
        """The head a ``.parm`` describes, so that the firmware and the plant agree:

        * layout: ``H_SW_TYPE`` (and ``H_SW_H3_SV1..3_POS`` for H3); head phase ``H_SW_H3_PHANG``
          for H3 (the firmware compensates it only there), 0 otherwise;
        * servos 1-3: travel 1000..2000 us (the endpoints the swash forces, whatever
          ``SERVOn_MIN/MAX`` say), neutral ``SERVOn_TRIM``, mounting ``SERVOn_REVERSED``; arm of
          50 deg when ``H_SW_LIN_SVO`` is set (the mechanics its compensation assumes), linear
          travel otherwise;
        * collective: ``H_COL_MIN`` / ``H_COL_MAX`` give ``H_COL_ANG_MIN`` / ``H_COL_ANG_MAX``
          (``k = (ANG_MAX - ANG_MIN) / (COL_MAX - COL_MIN)``), reversed with ``H_SW_COL_DIR``;
          mechanical limits ``[ANG_MIN, ANG_MAX]``;
        * cyclic: ``cyclic_ratio k`` per us of tilt; limits ``+-cyclic_ratio k 450 H_CYC_MAX /
          4500``: the box around the circle ``H_CYC_MAX`` keeps the firmware's cyclic in;
        * tail: ``SERVO4_MIN..MAX`` span ``tail_theta_t_rad`` (the plant's limits), the end the
          firmware's nose-right yaw drives to giving the nose-right pitch: the lower one for
          a counter-clockwise main rotor (this bench's default), the upper for a clockwise one;
        * rotor: ``SERVO8_MIN..MAX`` and ``SERVO8_REVERSED``, ``H_RSC_IDLE`` and
          ``H_RSC_SETPOINT`` (:class:`RotorSpeedInput`).
        """
        ap = ArduPilotHeli.from_params(params)
        if main_rotor_rotation not in ROTATIONS:
            raise ValueError(f"main_rotor_rotation must be one of {ROTATIONS}, got {main_rotor_rotation!r}")
        t_lo, t_hi = tail_theta_t_rad
        if not t_lo < t_hi:
            raise ValueError(f"tail_theta_t_rad: {t_lo} must be below {t_hi}")
        k = math.radians(ap.col_ang_max_deg - ap.col_ang_min_deg) / (ap.col_max_us - ap.col_min_us)
        cyc = cyclic_ratio * k * 1000.0 * CYCLIC_SCALE * ap.cyc_max / 4500.0
        if cyc <= 0.0:
            raise ValueError("H_CYC_MAX 0 leaves no cyclic")
        sv = ap.servos[:3]
        servos = SwashServos(
            pwm_min_us=(float(SWASH_PWM_MIN), float(SWASH_PWM_MIN), float(SWASH_PWM_MIN)),
            pwm_max_us=(float(SWASH_PWM_MAX), float(SWASH_PWM_MAX), float(SWASH_PWM_MAX)),
            pwm_neutral_us=(float(sv[0].trim_us), float(sv[1].trim_us), float(sv[2].trim_us)),
            reversed=(sv[0].reversed, sv[1].reversed, sv[2].reversed),
            arm_max_deg=LIN_SVO_ARM_DEG if ap.sw_lin_svo else 0.0,
        )
        head = Head(
            theta_m_at_neutral_rad=math.radians(ap.col_ang_min_deg) + k * (1500 - ap.col_min_us),
            theta_m_per_us_rad=k,
            theta_m_rad=(math.radians(ap.col_ang_min_deg), math.radians(ap.col_ang_max_deg)),
            eps_rad=(-cyc, cyc),
            eta_rad=(-cyc, cyc),
            collective_reversed=ap.sw_col_dir == 1,
            cyclic_ratio=cyclic_ratio,
            phase_deg=float(ap.sw_h3_phang_deg) if ap.sw_type == SwashType.H3 else 0.0,
        )
        s4 = ap.servos[3]
        # the firmware's yaw > 0 (nose right) drives SERVO4 toward MAX, or MIN when reversed
        nose_right_at_max = not s4.reversed
        # counter-clockwise main rotor: nose right is the lower theta_t
        low_at_max = nose_right_at_max == (main_rotor_rotation == "counter-clockwise")
        tail = TailServo(pwm_us=(float(s4.min_us), float(s4.max_us)),
                         theta_t_rad=(t_hi, t_lo) if low_at_max else (t_lo, t_hi))  # fmt: skip
        azimuth = None
        if ap.sw_type == SwashType.H3:
            p = ap.sw_h3_sv_pos_deg
            azimuth = (float(p[0]), float(p[1]), float(p[2]))
        r = ap.rsc
        rsc = RotorSpeedInput(pwm_us=(float(r.min_us), float(r.max_us)), reversed=r.reversed,
                              idle=ap.rsc_idle_pct / 100.0,
                              full_speed_throttle=ap.rsc_setpoint_pct / 100.0)  # fmt: skip
        return cls(name=name, swash_type=ap.sw_type.name, servos=servos, head=head, tail=tail,
                   servo_azimuth_deg=azimuth, rsc=rsc)  # fmt: skip
