"""The MAVLink parameter table: the TLC gains and limits as named, range-checked parameters.

Names (at most 16 characters, the MAVLink param_id limit), in this stable index order;
all REAL32 (see "Encoding" below):

  TLC_L{1,2}_W_{X,Y,Z}   loops 1-2 (position) omega per NWU channel [rad/s]
  TLC_L{1,2}_Z_{X,Y,Z}   loops 1-2 zeta per channel
  TLC_L{3,4}_W_{R,P,Y}   loops 3-4 (attitude) omega per roll/pitch/yaw channel [rad/s]
  TLC_L{3,4}_Z_{R,P,Y}   loops 3-4 zeta per channel
  TLC_DIFF_W, TLC_DIFF_Z pseudo-differentiator omega [rad/s] and zeta
  TLC_TILT_MAX           tilt command limit [rad]
  TLC_YAW_HOLD_V         hold the yaw command below this horizontal speed [m/s]
  TLC_MAX_SPEED          loop 1's horizontal correction speed limit [m/s] (0: none)
  TLC_RATE_HZ            control rate [Hz]; settable only while disarmed
  LIM_{TM,TT,EPS,ETA}_{MIN,MAX}  blade pitch limits [rad]; settable only while disarmed
  FS_STATE_TMO           state-link timeout [s] before the failsafe
  FS_OFFB_TMO            offboard setpoint timeout [s] before the failsafe
  MAV_SYS_ID             MAVLink system id (read-only)
  HOME_LAT, HOME_LON     home [deg] (read-only; float32 on the wire: ~1e-6 deg, ~0.1 m)
  HOME_ALT               home altitude AMSL [m] (read-only)
  PID_*                  the cascaded PID baseline's gains (autopilot/pid/gains.py; PID_PARAMS
                         below), used when the vehicle flies --controller pid
  SIM_*                  the world's live knobs (heli_common.world.config.SIM_PARAMS: wind, gust,
                         turbulence, servos), forwarded to the plant; see docs/world.md

Ranges come from the ``spec`` metadata of the dataclasses the values end up in (Gains,
PitchLimits, Run.rate_hz), so the table cannot accept what a config file would refuse;
cross-field rules (a pitch minimum below its maximum) are enforced by building the
dataclass with the candidate value. A refused set leaves the value unchanged, and the
PARAM_VALUE answer carries that unchanged value (spec: "the Drone must acknowledge the
PARAM_SET by broadcasting a PARAM_VALUE even if the write operation fails").

The pitch limits are disarmed-only because the sim link normalises servo commands by
them: changing them in flight would change what a given normalised command means.

Encoding. Values travel in PARAM_VALUE.param_value, a float32, and the ground stations
disagree about integer types for a MAV_AUTOPILOT_GENERIC vehicle: QGroundControl and MAVSDK
decode INT32 byte-wise, MAVProxy by C cast (it decodes byte-wise only for PX4). A REAL32
value reads the same in all three, so every parameter here is REAL32 (whole numbers, such
as MAV_SYS_ID, are exact in float32 up to 2**24), and AUTOPILOT_VERSION advertises
MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST alone (true of REAL32, and of any INT32 a
later version might add).

The autopilot applies changes between control steps: compare :attr:`ParamTable.generation`
with the last one applied, then take :meth:`gains`, :meth:`pitch_limits`,
:meth:`rate_hz`, :meth:`failsafe` (new frozen dataclasses built with dataclasses.replace).
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import ClassVar

from pymavlink.dialects.v20 import development as mavlink

from autopilot.pid.gains import PID_SECTIONS, PidGains, default_pid_gains
from autopilot.tlc.gains import CommandLimits, DifferentiatorGains, Gains, LoopGains
from heli_common.config import spec
from heli_common.geo import GeoPoint
from heli_common.vehicle.airframe import PitchLimits
from heli_common.wire.mavlink.udp import (
    Message,
    addressed_to,
)
from heli_common.wire.mavlink.wire import decode_param, encode_param, f32
from heli_common.world.config import SIM_PARAMS, World, sim_values, with_sim_param

REAL32: int = mavlink.MAV_PARAM_TYPE_REAL32
INT32: int = mavlink.MAV_PARAM_TYPE_INT32
PARAM_ID_LEN = 16

LOOP_FIELDS = (
    "loop1_position_kinematics",
    "loop2_position_dynamics",
    "loop3_attitude_kinematics",
    "loop4_attitude_dynamics",
)
LOOP_CHANNELS = (("X", "Y", "Z"), ("X", "Y", "Z"), ("R", "P", "Y"), ("R", "P", "Y"))
PITCH_FIELDS = (
    ("TM", "theta_m_rad"),
    ("TT", "theta_t_rad"),
    ("EPS", "eps_rad"),
    ("ETA", "eta_rad"),
)

XYZ, RPY = ("X", "Y", "Z"), ("R", "P", "Y")
#: the PID gains as parameters: name (with _<channel> per element when channels are given),
#: section of PidGains, field, channels
PID_PARAMS: tuple[tuple[str, str, str, tuple[str, ...]], ...] = (
    ("PID_POS_P", "position", "kp", XYZ),
    ("PID_SPEED_MAX", "position", "max_speed_m_s", ()),
    ("PID_VEL_P", "velocity", "kp", XYZ),
    ("PID_VEL_I", "velocity", "ki", XYZ),
    ("PID_VEL_IMAX", "velocity", "i_max_m_s2", ()),
    ("PID_ACC_MAX_Z", "velocity", "accel_max_z_m_s2", ()),
    ("PID_ATT_P", "attitude", "kp", RPY),
    ("PID_RMAX", "attitude", "max_rate_rad_s", RPY),
    ("PID_HOVR_ROL_TRM", "attitude", "hover_roll_trim_rad", ()),  # ArduPilot's ATC_HOVR_ROL_TRM
    ("PID_RATE_P", "rate", "kp", RPY),
    ("PID_RATE_I", "rate", "ki", RPY),
    ("PID_RATE_D", "rate", "kd", RPY),
    ("PID_RATE_FF", "rate", "ff", RPY),  # ArduPilot's ATC_RAT_*_FF
    ("PID_RATE_DHZ", "rate", "d_filter_hz", ()),
    ("PID_RATE_IMAX", "rate", "i_max_rad_s2", ()),
    ("PID_TILT_MAX", "limits", "tilt_max_rad", ()),
    ("PID_YAW_HOLD_V", "limits", "yaw_hold_speed_m_s", ()),
)


def _pid_names(name: str, channels: tuple[str, ...]) -> list[str]:
    return [f"{name}_{ch}" for ch in channels] if channels else [name]


@dataclass(frozen=True)
class FailsafeTimeouts:
    """Link-loss timeouts (defaults: state link as the runner's stale timeout, offboard as
    PX4's COM_OF_LOSS_T)."""

    state_link_timeout_s: float = spec("s", 0.01, 10.0, lo_open=True, default=0.5)
    offboard_timeout_s: float = spec("s", 0.05, 60.0, lo_open=True, default=1.0)


# Run.rate_hz's range (autopilot.scenario) and the controller's own check (make_constants).
RATE_HZ_RANGE = (50.0, 1000.0)


class Access(enum.Enum):
    READ_WRITE = "rw"
    DISARMED_ONLY = "disarmed"  # refused while armed
    READ_ONLY = "ro"


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name, MAV_PARAM_TYPE, admissible range, unit, access, description."""

    name: str
    param_type: int
    lo: float
    hi: float
    unit: str
    access: Access
    description: str
    lo_open: bool = False

    def __post_init__(self) -> None:
        if not 0 < len(self.name) <= PARAM_ID_LEN or not self.name.isascii():
            raise ValueError(f"parameter name {self.name!r} must be 1-16 ASCII characters")

    def in_range(self, value: float) -> bool:
        if not math.isfinite(value):
            return False
        above_lo = value > self.lo if self.lo_open else value >= self.lo
        return above_lo and value <= self.hi


@dataclass(frozen=True)
class SetResult:
    accepted: bool
    value: float  # the value now held (unchanged if refused)
    reason: str = ""


def _range(cls: type, field_name: str) -> tuple[float, float, bool, str]:
    """(lo, hi, lo_open, unit) from a dataclass field's ``spec`` metadata."""
    meta = {f.name: f.metadata for f in dataclasses.fields(cls)}[field_name]
    return float(meta["lo"]), float(meta["hi"]), bool(meta["lo_open"]), str(meta["unit"])


def _real(name: str, cls: type, field_name: str, access: Access, description: str) -> ParamSpec:
    lo, hi, lo_open, unit = _range(cls, field_name)
    return ParamSpec(name, REAL32, lo, hi, unit, access, description, lo_open)


def _build_specs() -> tuple[ParamSpec, ...]:
    rw, disarmed, ro = Access.READ_WRITE, Access.DISARMED_ONLY, Access.READ_ONLY
    specs: list[ParamSpec] = []
    for loop, channels in enumerate(LOOP_CHANNELS, start=1):
        for ch in channels:
            specs.append(
                _real(f"TLC_L{loop}_W_{ch}", LoopGains, "omega_rad_s", rw, f"loop {loop} omega, {ch}")
            )
        for ch in channels:
            specs.append(_real(f"TLC_L{loop}_Z_{ch}", LoopGains, "zeta", rw, f"loop {loop} zeta, {ch}"))
    specs += [
        _real("TLC_DIFF_W", DifferentiatorGains, "omega_rad_s", rw, "pseudo-differentiator omega"),
        _real("TLC_DIFF_Z", DifferentiatorGains, "zeta", rw, "pseudo-differentiator zeta"),
        _real("TLC_TILT_MAX", CommandLimits, "tilt_max_rad", rw, "tilt command limit"),
        _real("TLC_YAW_HOLD_V", CommandLimits, "yaw_hold_speed_m_s", rw, "yaw hold below speed"),
        _real("TLC_MAX_SPEED", CommandLimits, "max_speed_m_s", rw, "correction speed limit (0: none)"),
        ParamSpec("TLC_RATE_HZ", REAL32, *RATE_HZ_RANGE, "Hz", disarmed, "control rate"),
    ]
    for short, field_name in PITCH_FIELDS:
        lo, hi, _, unit = _range(PitchLimits, field_name)
        for end in ("MIN", "MAX"):
            specs.append(
                ParamSpec(f"LIM_{short}_{end}", REAL32, lo, hi, unit, disarmed, f"{field_name} {end}")
            )
    specs += [
        _real("FS_STATE_TMO", FailsafeTimeouts, "state_link_timeout_s", rw, "state link timeout"),
        _real("FS_OFFB_TMO", FailsafeTimeouts, "offboard_timeout_s", rw, "offboard timeout"),
        ParamSpec("MAV_SYS_ID", REAL32, 1, 255, "", ro, "MAVLink system id"),
        ParamSpec("HOME_LAT", REAL32, -90.0, 90.0, "deg", ro, "home latitude"),
        ParamSpec("HOME_LON", REAL32, -180.0, 180.0, "deg", ro, "home longitude"),
        ParamSpec("HOME_ALT", REAL32, -1e4, 1e5, "m", ro, "home altitude AMSL"),
    ]
    for name, section, field_name, chans in PID_PARAMS:
        for n in _pid_names(name, chans):
            specs.append(_real(n, PID_SECTIONS[section], field_name, rw, f"PID {section} {field_name}"))
    specs += [ParamSpec(p.name, REAL32, p.lo, p.hi, p.unit, rw, p.description) for p in SIM_PARAMS]
    return tuple(specs)


SPECS: tuple[ParamSpec, ...] = _build_specs()


class ParamTable:
    """The parameter values, their checks, and the PARAM_* message handling."""

    def __init__(
        self,
        gains: Gains,
        pitch_limits: PitchLimits,
        rate_hz: float,
        failsafe: FailsafeTimeouts | None = None,
        home: GeoPoint | None = None,
        system_id: int = 1,
        component_id: int = 1,
        world: World | None = None,
        pid_gains: PidGains | None = None,
    ) -> None:
        self._gains = gains
        self._pid = pid_gains or default_pid_gains()
        self._world = world or World()
        self._world_now, self._world_at = self._world, 0
        self._pitch = pitch_limits
        self._failsafe = failsafe or FailsafeTimeouts()
        self.system_id = system_id
        self.component_id = component_id
        self.generation = 0  # bumps on every accepted change
        self._specs = SPECS
        self._index = {s.name: i for i, s in enumerate(self._specs)}
        values: dict[str, float] = {}
        for loop, (field_name, channels) in enumerate(zip(LOOP_FIELDS, LOOP_CHANNELS, strict=True), 1):
            lg: LoopGains = getattr(gains, field_name)
            for k, ch in enumerate(channels):
                values[f"TLC_L{loop}_W_{ch}"] = lg.omega_rad_s[k]
                values[f"TLC_L{loop}_Z_{ch}"] = lg.zeta[k]
        values["TLC_DIFF_W"] = gains.differentiator.omega_rad_s
        values["TLC_DIFF_Z"] = gains.differentiator.zeta
        values["TLC_TILT_MAX"] = gains.limits.tilt_max_rad
        values["TLC_YAW_HOLD_V"] = gains.limits.yaw_hold_speed_m_s
        values["TLC_MAX_SPEED"] = gains.limits.max_speed_m_s
        values["TLC_RATE_HZ"] = rate_hz
        for short, field_name in PITCH_FIELDS:
            lo, hi = getattr(pitch_limits, field_name)
            values[f"LIM_{short}_MIN"] = lo
            values[f"LIM_{short}_MAX"] = hi
        values["FS_STATE_TMO"] = self._failsafe.state_link_timeout_s
        values["FS_OFFB_TMO"] = self._failsafe.offboard_timeout_s
        values["MAV_SYS_ID"] = system_id
        home_values = (home.lat_deg, home.lon_deg, home.alt_amsl_m) if home else (0.0, 0.0, 0.0)
        values["HOME_LAT"], values["HOME_LON"], values["HOME_ALT"] = home_values
        for name, section, field_name, chans in PID_PARAMS:
            v = getattr(getattr(self._pid, section), field_name)
            values.update(zip(_pid_names(name, chans), v if chans else (v,), strict=True))
        values.update(sim_values(self._world))
        for s in self._specs:
            v = float(values[s.name])
            if not s.in_range(v):
                raise ValueError(f"{s.name}: initial value {v} outside [{s.lo}, {s.hi}] {s.unit}")
        self._values = {name: float(v) for name, v in values.items()}

    # ----------------------------------------------------------------- table

    @property
    def specs(self) -> tuple[ParamSpec, ...]:
        return self._specs

    def __len__(self) -> int:
        return len(self._specs)

    def index(self, name: str) -> int:
        """Index of ``name`` (KeyError if unknown); stable for the life of the table."""
        return self._index[name]

    def spec(self, key: str | int) -> ParamSpec:
        return self._specs[key if isinstance(key, int) else self._index[key]]

    def get(self, key: str | int) -> float:
        """Value by name or index (KeyError / IndexError if unknown)."""
        return self._values[self.spec(key).name]

    def set(self, name: str, value: float, armed: bool = False) -> SetResult:
        """Set ``name`` to ``value``; refused (value unchanged) if unknown, read-only,
        disarmed-only while armed, non-finite, out of range, or inconsistent."""
        if name not in self._index:
            return SetResult(False, math.nan, f"unknown parameter {name!r}")
        s = self.spec(name)
        current = self._values[name]
        if s.access is Access.READ_ONLY:
            return SetResult(False, current, f"{name} is read-only")
        if s.access is Access.DISARMED_ONLY and armed:
            return SetResult(False, current, f"{name} can only be set while disarmed")
        v = float(value)
        # Values arrive as float32: one that rounds to the float32 of the current value
        # or of a bound means exactly that (1.2 arrives as 1.2000000477 > 1.2).
        # An open bound is excluded, so nothing snaps to it.
        for exact in (current, s.hi) if s.lo_open else (current, s.lo, s.hi):
            if math.isfinite(v) and f32(v) == f32(exact):
                v = exact
        if s.param_type == INT32 and not (math.isfinite(v) and v.is_integer()):
            return SetResult(False, current, f"{name} must be an integer")
        if not s.in_range(v):
            return SetResult(False, current, f"{name} must be in [{s.lo}, {s.hi}] {s.unit}")
        if v == current:
            return SetResult(True, current)
        old = self._values[name]
        self._values[name] = v
        try:
            self.gains()
            self.pid_gains()
            self.pitch_limits()
            self.failsafe()
        except ValueError as exc:
            self._values[name] = old
            return SetResult(False, old, f"{name}: {exc}")
        self.generation += 1
        return SetResult(True, v)

    # ----------------------------------------------------------------- typed views

    def gains(self) -> Gains:
        """The gains with the table's values (dataclasses.replace on the loaded Gains)."""
        v = self._values
        loops: list[LoopGains] = []
        for loop, (field_name, channels) in enumerate(zip(LOOP_FIELDS, LOOP_CHANNELS, strict=True), 1):
            w = tuple(v[f"TLC_L{loop}_W_{ch}"] for ch in channels)
            z = tuple(v[f"TLC_L{loop}_Z_{ch}"] for ch in channels)
            loops.append(
                replace(
                    getattr(self._gains, field_name),
                    omega_rad_s=(w[0], w[1], w[2]),
                    zeta=(z[0], z[1], z[2]),
                )
            )
        return replace(
            self._gains,
            differentiator=replace(
                self._gains.differentiator, omega_rad_s=v["TLC_DIFF_W"], zeta=v["TLC_DIFF_Z"]
            ),
            limits=replace(
                self._gains.limits,
                tilt_max_rad=v["TLC_TILT_MAX"],
                yaw_hold_speed_m_s=v["TLC_YAW_HOLD_V"],
                max_speed_m_s=v["TLC_MAX_SPEED"],
            ),
            loop1_position_kinematics=loops[0],
            loop2_position_dynamics=loops[1],
            loop3_attitude_kinematics=loops[2],
            loop4_attitude_dynamics=loops[3],
        )

    def pid_gains(self) -> PidGains:
        """The PID baseline's gains with the table's PID_ values."""
        changed: dict[str, dict[str, object]] = {}
        for name, section, field_name, channels in PID_PARAMS:
            vals = tuple(self._values[n] for n in _pid_names(name, channels))
            changed.setdefault(section, {})[field_name] = vals if channels else vals[0]
        return replace(
            self._pid, **{sec: replace(getattr(self._pid, sec), **kw) for sec, kw in changed.items()}
        )

    def pitch_limits(self) -> PitchLimits:
        """The pitch limits (raises ValueError if a minimum is not below its maximum)."""
        v = self._values
        return replace(
            self._pitch,
            **{f: (v[f"LIM_{s}_MIN"], v[f"LIM_{s}_MAX"]) for s, f in PITCH_FIELDS},
        )

    def rate_hz(self) -> float:
        return self._values["TLC_RATE_HZ"]

    def world(self) -> World:
        """The world the SIM_ parameters describe (the loaded one with the table's values);
        rebuilt only after a change (telemetry asks for it twice a second)."""
        if self._world_at != self.generation:
            w = self._world
            for p in SIM_PARAMS:
                w = with_sim_param(w, p.name, self._values[p.name])
            self._world_now, self._world_at = w, self.generation
        return self._world_now

    def sim_values(self) -> dict[str, float]:
        return {p.name: self._values[p.name] for p in SIM_PARAMS}

    def failsafe(self) -> FailsafeTimeouts:
        return replace(
            self._failsafe,
            state_link_timeout_s=self._values["FS_STATE_TMO"],
            offboard_timeout_s=self._values["FS_OFFB_TMO"],
        )

    # ----------------------------------------------------------------- wire encoding

    def encode_value(self, key: str | int) -> float:
        """The float32 ``param_value`` carrying the parameter (C cast)."""
        s = self.spec(key)
        return encode_param(self._values[s.name], s.param_type, bytewise=False)

    def decode_value(self, param_value: float, param_type: int) -> float:
        """A received ``param_value`` of ``param_type`` -> the number it stands for."""
        return decode_param(param_value, param_type, bytewise=False)

    def param_value_message(self, key: str | int) -> Message:
        """PARAM_VALUE for one parameter (param_count and param_index filled in)."""
        s = self.spec(key)
        return mavlink.MAVLink_param_value_message(
            s.name.encode("ascii"),
            self.encode_value(s.name),
            s.param_type,
            len(self._specs),
            self._index[s.name],
        )

    def all_param_values(self) -> list[Message]:
        """PARAM_VALUE for every parameter, in index order (the link should pace them)."""
        return [self.param_value_message(i) for i in range(len(self._specs))]

    # ----------------------------------------------------------------- messages

    def handle(self, msg: Message, armed: bool = False) -> list[Message]:
        """PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET -> messages to send."""
        handler = self._HANDLERS.get(msg.get_type())
        if handler is None or not self._addressed_to_me(msg):
            return []
        return handler(self, msg, armed)

    def _on_request_list(self, msg: Message, armed: bool) -> list[Message]:
        return self.all_param_values()

    def _on_request_read(self, msg: Message, armed: bool) -> list[Message]:
        index = int(msg.param_index)
        if index >= 0:  # spec: -1 means "use param_id"
            if index < len(self._specs):
                return [self.param_value_message(index)]
            return [_text(f"Param index {index} out of range")]
        name = _param_name(msg.param_id)
        if name in self._index:
            return [self.param_value_message(name)]
        return [_text(f"Unknown param {name}")]

    def _on_set(self, msg: Message, armed: bool) -> list[Message]:
        name = _param_name(msg.param_id)
        if name not in self._index:
            return [_text(f"Unknown param {name}")]
        value = self.decode_value(float(msg.param_value), int(msg.param_type))
        result = self.set(name, value, armed)
        out = [self.param_value_message(name)]
        if not result.accepted:
            out.append(_text(result.reason))
        return out

    _HANDLERS: ClassVar[dict[str, Callable[[ParamTable, Message, bool], list[Message]]]] = {
        "PARAM_REQUEST_LIST": _on_request_list,
        "PARAM_REQUEST_READ": _on_request_read,
        "PARAM_SET": _on_set,
    }

    def _addressed_to_me(self, msg: Message) -> bool:
        # Spec: components answer requests addressed to them or to MAV_COMP_ID_ALL (0).
        return addressed_to(msg, self.system_id, self.component_id)


def _param_name(param_id: str | bytes) -> str:
    """param_id as received: 16 bytes, NUL-padded unless exactly 16 characters long."""
    raw = param_id.encode("latin-1") if isinstance(param_id, str) else bytes(param_id)
    return raw.split(b"\0", 1)[0].decode("ascii", "replace")


def _text(text: str) -> Message:
    return mavlink.MAVLink_statustext_message(
        mavlink.MAV_SEVERITY_WARNING, text.encode("ascii", "replace")[:50]
    )
