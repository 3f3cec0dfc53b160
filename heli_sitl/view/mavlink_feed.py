"""The live view's source: a ground-station-like MAVLink listener on loopback, in a thread
of its own, that keeps only the newest state of the vehicle.

It binds a UDP port the vehicle sends its telemetry to (the API link of ``demo --view`` and
``up --view``, the default API port for ``run --view``, an ArduPilot SERIAL port) and decodes
what arrives; it never sends anything a vehicle acts on, so a lockstep flight is the same
with or without it. The view's push loop takes :meth:`MavlinkFeed.snapshot` at its own rate:
whatever arrived in between is folded into the newest values (the trail keeps every
position), so a slow browser or none costs the vehicle nothing.

What it reads (the vehicle's telemetry: autopilot/links/mavlink_gcs.py, ArduPilot's streams):
HEARTBEAT (mode, armed), LOCAL_POSITION_NED and ATTITUDE (the pose, NED/FRD -> NWU/FLU),
POSITION_TARGET_LOCAL_NED (the reference point; the tracking error is taken against the
position of the same control tick, time_boot_ms equal), SERVO_OUTPUT_RAW (the four pitches,
back through the airframe's limits), RAW_RPM (the rotor plant's speed), WIND_COV (the air).

``forward_to``: a relay for ``up --view``. The vehicle's API link then goes through the view:
every datagram from the vehicle is also sent on to ``forward_to`` (where MAVSDK listens) and
every datagram from there goes back to the vehicle, so API clients work as without the view.
"""

from __future__ import annotations

import logging
import math
import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as apm

from heli_common import frames
from heli_common.state import FloatArray
from heli_common.wire import servo_map
from heli_common.wire.mavlink import modes as wm
from heli_common.wire.mavlink.udp import LOOPBACK, Address, MavlinkUdp, Message
from heli_sitl.view.frame import ViewFrame, tracking_error_m

log = logging.getLogger("heli-sitl.view")

POLL_S = 0.1  # the thread's longest wait for a datagram (how soon it sees stop())
RECENT_POSITIONS = 64  # positions kept by time_boot_ms, to pair with a later target
ARDUPILOT = apm.MAV_AUTOPILOT_ARDUPILOTMEGA
STREAM_HZ = 25  # what the view asks ArduPilot for (REQUEST_DATA_STREAM, every stream)


@dataclass(frozen=True)
class FeedStats:
    datagrams: int
    messages: int
    positions: int  # LOCAL_POSITION_NED received (the trail's points)
    snapshots: int  # frames taken by the view
    foreign: int  # datagrams from a sender other than the vehicle followed (dropped)


class MavlinkFeed:
    """Listen on UDP ``127.0.0.1:port`` (0: the kernel's choice, :attr:`port`) for a vehicle's
    telemetry; :meth:`start` the thread, :meth:`snapshot` the newest frame, :meth:`stop`."""

    def __init__(
        self, port: int = 0, limits_rad: FloatArray | None = None, forward_to: Address | None = None,
        system_id: int | None = None,
    ) -> None:  # fmt: skip
        self.link = MavlinkUdp((LOOPBACK, port), None, system_id=255, component_id=190, drop_nonfinite=False)
        self.port: int = self.link.local[1]
        self.limits = servo_map.limits_array(((-0.1, 0.3), (-0.35, 0.35), (-0.14, 0.14), (-0.14, 0.14))) \
            if limits_rad is None else limits_rad  # fmt: skip
        self.forward_to = forward_to
        self.system_id = system_id  # None: the system of the first vehicle HEARTBEAT heard
        self._vehicle: Address | None = None  # the vehicle's end of the link (relay)
        self._from: Address | None = None  # the sender of the datagram being read
        self._ardupilot = False
        # the vehicle followed: the first sender of a vehicle's HEARTBEAT (a port the kernel
        # handed us may be one another program still sends to; its datagrams are dropped)
        self._source: Address | None = None
        self.foreign = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="view-feed", daemon=True)
        self._frame: ViewFrame | None = None
        self._new_points: list[tuple[float, float, float]] = []
        self._new_refs: list[tuple[float, float, float]] = []
        self._positions: deque[tuple[int, tuple[float, float, float]]] = deque(maxlen=RECENT_POSITIONS)
        self._t_arm_ms: int | None = None  # the vehicle time of the arming tick (run.csv's t = 0)
        self._armed = False
        self._arming_pending = False
        self._att: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._pending_target: tuple[int, tuple[float, float, float]] | None = None
        self._fields: dict[str, object] = {}
        self.datagrams = 0
        self.messages = 0
        self.positions = 0
        self.snapshots = 0

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> MavlinkFeed:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)
        self.link.close()

    def stats(self) -> FeedStats:
        return FeedStats(self.datagrams, self.messages, self.positions, self.snapshots, self.foreign)

    # -- what the view takes ---------------------------------------------------------------
    def snapshot(self) -> tuple[ViewFrame | None, list[tuple[float, float, float]]]:
        """The newest frame (None before the first position) and the positions received
        since the last snapshot (for the trail)."""
        with self._lock:
            pts, self._new_points = self._new_points, []
            if self._frame is not None:
                self.snapshots += 1
            return self._frame, pts

    def take_references(self) -> list[tuple[float, float, float]]:
        """The reference points received since the last call (a path drawn as it comes)."""
        with self._lock:
            refs, self._new_refs = self._new_refs, []
            return refs

    # -- the thread --------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                datagrams = self.link.recv_datagrams(timeout_s=POLL_S, max_datagrams=256)
            except OSError:  # closed under us
                return
            for data, addr in datagrams:
                self.datagrams += 1
                if self.forward_to is not None and self._relay(data, addr):
                    continue
                if self._source is not None and addr != self._source:
                    self.foreign += 1  # another sender: a second vehicle's telemetry is not ours to mix
                    continue
                self._from = addr
                for m in self.link._parse(data):
                    self.messages += 1
                    try:
                        self.on_message(m)
                    except Exception:  # a malformed field must not end the view
                        log.debug("view: message %s not shown", m.get_type(), exc_info=True)

    def _relay(self, data: bytes, addr: Address) -> bool:
        """Pass a datagram on (see the module docstring); True if it came from the API client
        side (nothing to show)."""
        assert self.forward_to is not None
        if addr == self.forward_to or (self._vehicle is not None and addr != self._vehicle):
            if self._vehicle is not None:
                self.link.send_bytes(data, to=self._vehicle)
            return True
        self._vehicle = addr
        self.link.send_bytes(data, to=self.forward_to)
        return False

    def on_message(self, m: Message) -> None:
        """Fold one message into the newest state (public: the tests feed it directly)."""
        name = m.get_type()
        if self.system_id is None:  # nothing before the vehicle's first HEARTBEAT says who it is
            if name != "HEARTBEAT" or (m.get_srcComponent() != 1 and m.autopilot != ARDUPILOT):
                return
            self.system_id = m.get_srcSystem()
            self._source = self._from
        if m.get_srcSystem() != self.system_id:
            return
        if name == "HEARTBEAT":
            if m.get_srcComponent() != 1 and m.autopilot != ARDUPILOT:
                return
            if m.autopilot == ARDUPILOT:
                self._ardupilot = True
                if self.positions == 0:
                    self._request_streams()
            armed = bool(m.base_mode & apm.MAV_MODE_FLAG_SAFETY_ARMED)
            if armed and not self._armed:
                self._arming_pending = True  # the next position is the arming tick's
            self._armed = armed
            self._set(mode=_mode_name(m), armed=armed)
        elif name == "ATTITUDE":
            self._att = _vec3(frames.euler_frd_to_flu((m.roll, m.pitch, m.yaw)))
        elif name == "LOCAL_POSITION_NED":
            self._on_position(m)
        elif name == "POSITION_TARGET_LOCAL_NED":
            ref = _vec3(frames.ned_to_nwu((m.x, m.y, m.z)))
            with self._lock:
                self._new_refs.append(ref)
            err = None
            for t_ms, pos in reversed(self._positions):
                if t_ms == m.time_boot_ms:
                    err = tracking_error_m(pos, ref)
                    break
            if err is None:  # no position of its tick: interpolated when the next one comes
                self._pending_target = (m.time_boot_ms, ref)
                self._set(ref_nwu_m=ref)
            else:
                self._pending_target = None
                self._set(ref_nwu_m=ref, err_m=err, err_t_s=self._flight_t(m.time_boot_ms), err_exact=True)
        elif name == "SERVO_OUTPUT_RAW" and not self._ardupilot:  # ArduPilot's are swash servos
            pwm = np.array([m.servo1_raw, m.servo2_raw, m.servo3_raw, m.servo4_raw], dtype=float)
            n = (pwm - servo_map.PWM_CENTRE_US) / servo_map.PWM_HALF_RANGE_US
            self._set(pitches_rad=tuple(float(v) for v in servo_map.from_normalized(n, self.limits)))
        elif name == "RAW_RPM":
            self._set(rotor_speed_rad_s=float(m.frequency) * 2.0 * math.pi / 60.0)
        elif name == "WIND_COV":
            self._set(wind_nwu_m_s=_vec3(frames.ned_to_nwu((m.wind_x, m.wind_y, m.wind_z))))

    def _request_streams(self) -> None:
        """ArduPilot streams on a serial port only what a ground station asks for (MAVProxy
        asks the same way); sent once a heartbeat until positions arrive. Never sent to this
        bench's autopilot, whose telemetry needs no asking."""
        if self._from is None or self.system_id is None:
            return
        req = apm.MAVLink_request_data_stream_message(self.system_id, 1, apm.MAV_DATA_STREAM_ALL,
                                                      STREAM_HZ, 1)  # fmt: skip
        self.link.send(req, to=self._from)

    def _flight_t(self, t_boot_ms: int) -> float:
        return (t_boot_ms - (self._t_arm_ms or 0)) / 1000.0

    def _on_position(self, m: Message) -> None:
        if self._arming_pending:
            self._t_arm_ms, self._arming_pending = m.time_boot_ms, False
        pos = _vec3(frames.ned_to_nwu((m.x, m.y, m.z)))
        self._interpolate_pending(m.time_boot_ms, pos)
        self._positions.append((m.time_boot_ms, pos))
        self.positions += 1
        with self._lock:
            self._new_points.append(pos)
            base = self._frame or ViewFrame(0.0, pos, self._att)
            base = replace(base, **self._fields)  # type: ignore[arg-type]
            self._frame = replace(base, t_s=self._flight_t(m.time_boot_ms), pos_nwu_m=pos,
                                  euler_flu_rad=_vec3(self._att))  # fmt: skip

    def _interpolate_pending(self, t_ms: int, pos: tuple[float, float, float]) -> None:
        """A target between two positions: the error against the position interpolated
        linearly to its tick (50 ms apart at most: ~0.3 mm at 1 m/s^2), marked not exact."""
        if self._pending_target is None or not self._positions:
            return
        t_ref, ref = self._pending_target
        t_a, pos_a = self._positions[-1]
        if not t_a < t_ref < t_ms:
            if t_ref <= t_a or t_ms - t_a > 1000:  # a stale target: never paired
                self._pending_target = None
            return
        w = (t_ref - t_a) / (t_ms - t_a)
        p = _vec3([(1.0 - w) * a + w * b for a, b in zip(pos_a, pos, strict=True)])
        self._pending_target = None
        self._set(err_m=tracking_error_m(p, ref), err_t_s=self._flight_t(t_ref), err_exact=False)

    def _set(self, **fields: object) -> None:
        """Fields that are not the pose: into the frame (kept for the first pose if none yet)."""
        with self._lock:
            self._fields.update(fields)
            if self._frame is not None:
                self._frame = replace(self._frame, **self._fields)  # type: ignore[arg-type]


def _vec3(v: Sequence[float] | FloatArray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])


def _mode_name(hb: Message) -> str:
    """The vehicle's mode as it names it (this bench's modes; ArduPilot's by pymavlink's map)."""
    if hb.autopilot == ARDUPILOT:
        from pymavlink import mavutil

        return str(mavutil.mode_string_v10(hb))
    mode = wm.BY_CUSTOM.get(hb.custom_mode)
    if mode is not None:
        return mode.name
    if hb.custom_mode == 0:
        return "IDLE"
    main, sub = wm.main_sub(hb.custom_mode)
    return f"mode {main}.{sub}"
