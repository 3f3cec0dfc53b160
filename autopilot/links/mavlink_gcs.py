"""The GCS link: the autopilot as a MAVLink vehicle for ground stations and API clients.

System 1, component 1, MAV_TYPE_HELICOPTER, MAV_AUTOPILOT_GENERIC. Two UDP sockets, as PX4
SITL: one sends to 127.0.0.1:14550 (ground stations: QGroundControl, MAVProxy), one to
127.0.0.1:14540 (API clients: MAVSDK); each answers whoever talks to it. It runs as a tick
hook of the runner, so every handler sees the runner's time ``t_s`` and never a clock.

Modes: :mod:`heli_common.wire.mavlink.modes` (the vehicle's own custom-mode numbers, the
standard modes microservice, DO_SET_MODE, DO_SET_STANDARD_MODE and SET_MODE).
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from autopilot import nav_telemetry, telemetry
from autopilot.estimation.onboard import OnboardEstimator
from autopilot.flight import commands as c
from autopilot.flight.manager import FlightManager, LandedState, MissionState
from autopilot.flight.modes import Mode
from autopilot.flight_log import heartbeat
from autopilot.links.mavlink_modes import COMMAND, REPORTED
from autopilot.mission.server import MissionServer
from autopilot.params_table import ParamTable
from autopilot.reference import N_REF, REF_ACC, REF_POS, REF_VEL
from autopilot.runner import Euler
from autopilot.trajectory.waypoints import FlightLimits
from autopilot.trajectory_codec import check_mission
from heli_common import frames
from heli_common.defaults import HOME, ports
from heli_common.geo import GeoPoint, nwu_to_geo
from heli_common.kinematics import rot_body_to_earth
from heli_common.ratelog import RateLimitedLog
from heli_common.state import EULER, POS, VEL, FloatArray
from heli_common.wire.mavlink import modes as wm
from heli_common.wire.mavlink.mission_items import MissionItem
from heli_common.wire.mavlink.sim_protocol import StateSample
from heli_common.wire.mavlink.udp import LOOPBACK, Address, MavlinkUdp, Message, mavlink2
from heli_common.wire.servo_map import ServoMap

log = logging.getLogger("autopilot.gcs")
m2 = mavlink2
PORTS = ports()

FTP_OPCODE_NAK = 129
FTP_ERR_UNKNOWN_COMMAND = 7


def ftp_nak(msg: Message) -> Message:
    """Answer any MAVLink FTP request with NAK(UnknownCommand): this vehicle has no files.
    Without an answer MAVProxy waits for three FTP timeouts before its parameter fetch."""
    req = bytes(msg.payload)
    seq = int.from_bytes(req[0:2], "little") if len(req) >= 2 else 0
    session = req[2] if len(req) > 2 else 0
    req_opcode = req[3] if len(req) > 3 else 0
    payload = bytearray(251)
    payload[0:2] = ((seq + 1) & 0xFFFF).to_bytes(2, "little")
    payload[2], payload[3], payload[4], payload[5] = session, FTP_OPCODE_NAK, 1, req_opcode
    payload[12] = FTP_ERR_UNKNOWN_COMMAND
    return m2.MAVLink_file_transfer_protocol_message(0, msg.get_srcSystem(), msg.get_srcComponent(),
                                                     list(payload))  # fmt: skip


# Messages accepted unsigned when signing is on: they change nothing on the vehicle.
UNSIGNED_OK = frozenset({
    m2.MAVLINK_MSG_ID_HEARTBEAT, m2.MAVLINK_MSG_ID_PARAM_REQUEST_LIST,
    m2.MAVLINK_MSG_ID_PARAM_REQUEST_READ, m2.MAVLINK_MSG_ID_MISSION_REQUEST_LIST,
    m2.MAVLINK_MSG_ID_TIMESYNC, m2.MAVLINK_MSG_ID_SYSTEM_TIME,
    m2.MAVLINK_MSG_ID_REQUEST_DATA_STREAM,
})  # fmt: skip

MSG_ID_EKF_STATUS_REPORT = 193  # ardupilotmega.xml

DEFAULT_RATES_HZ: dict[int, float] = {
    m2.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    m2.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    m2.MAVLINK_MSG_ID_ATTITUDE: 20.0,
    m2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 20.0,
    m2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    m2.MAVLINK_MSG_ID_GPS_RAW_INT: 5.0,
    m2.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    m2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    m2.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 10.0,
    m2.MAVLINK_MSG_ID_ATTITUDE_TARGET: 10.0,
    m2.MAVLINK_MSG_ID_WIND_COV: 2.0,
    m2.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS: 10.0,  # servo positions, where a world reports them
    m2.MAVLINK_MSG_ID_RAW_RPM: 4.0,  # main rotor speed, where the rotor plant reports it
    m2.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW: 10.0,
    m2.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
    m2.MAVLINK_MSG_ID_VFR_HUD: 4.0,
    m2.MAVLINK_MSG_ID_ESTIMATOR_STATUS: 2.0,  # where the vehicle flies from sensors
    MSG_ID_EKF_STATUS_REPORT: 2.0,  # ArduPilot's, for MAVProxy and Mission Planner
    m2.MAVLINK_MSG_ID_SIM_STATE: 10.0,  # the truth, for logs
    wm.MSG_ID_CURRENT_MODE: 1.0,
    wm.MSG_ID_AVAILABLE_MODES_MONITOR: 0.2,
}

CAPABILITIES = (
    m2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | m2.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | m2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | m2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | m2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | m2.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST  # alone: see autopilot.params_table
)
FORCE_DISARM_MAGIC = 21196
RELATIVE_ALT_FRAMES = (m2.MAV_FRAME_GLOBAL_RELATIVE_ALT, m2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
MAX_DATAGRAMS_PER_POLL = 32  # handled per link and control tick (3200/s at 100 Hz)
# Read from the socket per link and tick, undecoded (2-6 us each, so at most a few ms of a
# tick, and only while flooded): 100k datagrams/s at 100 Hz, faster than a Python socket
# floods, so the kernel's buffer does not fill and drop the other clients' (see _FairInbox)
MAX_READS_PER_POLL = 1024
MAX_SENDERS = 64  # senders with datagrams waiting, per link
# what one sender may have waiting, counted as the kernel counts a socket buffer (each
# datagram's bytes and an overhead): ~400 small requests, room for any client's burst
MAX_WAITING_PER_SENDER = 128 * 1024
DATAGRAM_OVERHEAD = 256
MAV_RESULT = {
    c.Result.ACCEPTED: m2.MAV_RESULT_ACCEPTED, c.Result.DENIED: m2.MAV_RESULT_DENIED,
    c.Result.UNSUPPORTED: m2.MAV_RESULT_UNSUPPORTED, c.Result.FAILED: m2.MAV_RESULT_FAILED,
}  # fmt: skip
MAV_SEVERITY = {
    c.Severity.INFO: m2.MAV_SEVERITY_INFO,
    c.Severity.WARNING: m2.MAV_SEVERITY_WARNING,
    c.Severity.CRITICAL: m2.MAV_SEVERITY_CRITICAL,
}
LANDED_STATE = {
    LandedState.ON_GROUND: m2.MAV_LANDED_STATE_ON_GROUND, LandedState.IN_AIR: m2.MAV_LANDED_STATE_IN_AIR,
    LandedState.LANDING: m2.MAV_LANDED_STATE_LANDING,
}  # fmt: skip
MISSION_STATE = {
    MissionState.NONE: None, MissionState.ACTIVE: m2.MISSION_STATE_ACTIVE,
    MissionState.COMPLETE: m2.MISSION_STATE_COMPLETE,
}  # fmt: skip


@dataclass(frozen=True)
class GcsConfig:
    host: str = LOOPBACK
    gcs_port: int = PORTS.gcs  # ground stations listen here
    api_port: int = PORTS.api  # API clients (MAVSDK) listen here
    local_gcs_port: int = PORTS.local_gcs  # our end of each link
    local_api_port: int = PORTS.local_api
    home: GeoPoint = HOME
    signing_key: bytes | None = None
    system_id: int = 1  # the vehicle's MAVLink system id on this link (component 1)
    offboard_timeout_s: float = 1.0
    rates_hz: dict[int, float] = field(default_factory=lambda: dict(DEFAULT_RATES_HZ))


# a command's answer now (MAV_RESULT, operator text), or a flight command for the next tick
Answer = tuple[int, str] | c.Command


@dataclass
class _Pending:
    command: c.Command
    link: MavlinkUdp | None = None  # where the ACK goes (None: nothing to answer)
    addr: Address | None = None
    msg: Message | None = None
    say: bool = False  # no ACK, but the operator hears the reply's text (SET_MODE)


class _FairInbox:
    """One GCS socket's received datagrams, waiting per sender and handled round-robin.

    The link handles a bounded number of datagrams per tick (decoding costs ~10-25 us each).
    Taken first come first served, one flooding sender filled the socket's kernel buffer
    (8 MiB: ~10,000 datagrams, 3 s of backlog at 3200/s), and while it was full the kernel
    dropped every other client's datagrams: a ground station's PARAM_REQUEST_LIST sent
    after a 20,000-datagram flood was never answered. So the socket is drained quickly
    (undecoded), each sender's datagrams wait in their own queue, bounded (a sender over
    its bound loses its newest datagrams, as a full socket would), and the handling budget
    goes to the senders in turn: a client that asks is answered within a few ticks,
    whatever another socket sends, even with the same system id (senders are told apart
    by their address: a system id is anyone's to claim).
    """

    def __init__(self) -> None:
        self._waiting: OrderedDict[Address, deque[bytes]] = OrderedDict()  # in turn order
        self._cost: dict[Address, int] = {}
        self.dropped = 0  # datagrams read but dropped: their sender was over its bound

    def fill(self, datagrams: list[tuple[bytes, Address]]) -> None:
        for data, addr in datagrams:
            q = self._waiting.get(addr)
            if q is None:
                if len(self._waiting) >= MAX_SENDERS:
                    self._drop_longest()  # many flooding sockets: a newcomer still gets in
                q = self._waiting[addr] = deque()
                self._cost[addr] = 0
            cost = len(data) + DATAGRAM_OVERHEAD
            if q and self._cost[addr] + cost > MAX_WAITING_PER_SENDER:
                self.dropped += 1
                continue
            q.append(data)
            self._cost[addr] += cost

    def take(self, n: int) -> list[tuple[bytes, Address]]:
        """Up to ``n`` datagrams, one per sender in turn (oldest first for each)."""
        out: list[tuple[bytes, Address]] = []
        while self._waiting and len(out) < n:
            addr, q = self._waiting.popitem(last=False)
            data = q.popleft()
            out.append((data, addr))
            if q:
                self._waiting[addr] = q  # to the back of the line
                self._cost[addr] -= len(data) + DATAGRAM_OVERHEAD
            else:
                del self._cost[addr]
        return out

    def _drop_longest(self) -> None:
        addr = max(self._cost, key=self._cost.__getitem__)
        self.dropped += len(self._waiting.pop(addr))
        del self._cost[addr]


class GcsService:
    """Owns the two GCS sockets and translates MAVLink to the flight manager's commands and
    its replies and events back; call it once per control tick (runner hooks)."""

    def __init__(
        self,
        cfg: GcsConfig,
        params: ParamTable,
        apply_params: Callable[[ParamTable], None],
        limits: FloatArray,
        flight_limits: FlightLimits | None = None,
        manager: FlightManager | None = None,
        servo_channels: ServoMap | None = None,
    ) -> None:
        self.cfg = cfg
        self.params = params
        self.apply_params = apply_params
        self.limits = limits
        # SERVO_OUTPUT_RAW's channels: the blade pitches (None), or the CCPM servos
        self.servo_channels: FloatArray | ServoMap = limits if servo_channels is None else servo_channels
        self.flight_limits = flight_limits or FlightLimits()
        self.manager: FlightManager | None = None  # the runner's, set by attach()
        self.links = [
            MavlinkUdp((cfg.host, port), (cfg.host, to), system_id=cfg.system_id, drop_nonfinite=False)
            for port, to in ((cfg.local_gcs_port, cfg.gcs_port), (cfg.local_api_port, cfg.api_port))
        ]
        self._inboxes = [_FairInbox() for _ in self.links]
        if cfg.signing_key is not None:
            for link in self.links:
                link.setup_signing(cfg.signing_key, lambda msg_id: msg_id in UNSIGNED_OK)
        self.missions = MissionServer(
            system_id=cfg.system_id,
            home=cfg.home,
            check_mission=self._check_mission,
        )
        self.intervals_s = {k: 1.0 / v for k, v in cfg.rates_hz.items() if v > 0}
        # each message's telemetry grid in whole microseconds of vehicle time (float sums
        # drift: 0.1 s added up is not 0.05 s added up, and the 10 Hz and 20 Hz messages of
        # one tick parted): the grid's origin (the first send) and its next point
        self.grid_origin_us: dict[int, int] = {}
        self.next_due_us: dict[int, int] = {}
        self.refused = 0
        self._t = 0.0
        self._x: FloatArray = np.zeros(12)
        self._ref: FloatArray | None = None
        self._u: FloatArray = np.zeros(4)
        self._att_cmd: Euler = (0.0, 0.0, 0.0)
        self._broken: set[int] = set()
        self._armed_sent = False
        # the world's truth of the latest tick (set by whoever runs the loop; None: none)
        self.truth: Callable[[], StateSample | None] | None = None
        # the estimator the vehicle flies on, when it flies from sensors (the runner's)
        self.nav: Callable[[], OnboardEstimator | None] | None = None
        self._errors = RateLimitedLog(log, interval_s=10.0)
        self.handler_errors = 0
        self._pending: list[_Pending] = []
        self._params_changed = False
        self._cmd_frame: int | None = None  # COMMAND_INT's frame while its handler runs
        if manager is not None:
            self.attach(manager)

    def attach(self, manager: FlightManager) -> None:
        """Serve this vehicle's flight manager (it reads the stored mission from us)."""
        self.manager = manager
        manager.set_mission_source(lambda: self.missions.mission)

    # -- lifecycle ------------------------------------------------------------------------
    def close(self) -> None:
        for link in self.links:
            link.close()

    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            f"gcs{i}": {**link.stats.as_dict(), "rx_dropped": inbox.dropped}
            for i, (link, inbox) in enumerate(zip(self.links, self._inboxes, strict=True))
        }
        out["handler_errors"] = self.handler_errors
        return out

    # -- the runner's hooks ----------------------------------------------------------------
    def warm_up(self, x: FloatArray) -> None:
        """Build each telemetry message once from ``x``, sending nothing (see TickService)."""
        saved = self._x
        self._x = x
        try:
            for msg_id in list(self.intervals_s):
                with contextlib.suppress(Exception):  # telemetry reports its own faults later
                    self.build(msg_id)
            telemetry.attitude_target(0, (0.0, 0.0, 0.0))  # built only once armed
        finally:
            self._x = saved

    def between_ticks(self, t_s: float, x: FloatArray) -> None:
        """Input, between two ticks: commands, parameters, missions, setpoints (what
        changes the vehicle is queued for the next tick's start)."""
        self._t, self._x = t_s, x
        for link, inbox in zip(self.links, self._inboxes, strict=True):
            # bounded: a flooding client costs at most this much per tick, and it cannot
            # crowd out the others (it waits its turn among the senders: _FairInbox)
            inbox.fill(link.recv_datagrams(max_datagrams=MAX_READS_PER_POLL))
            for data, addr in inbox.take(MAX_DATAGRAMS_PER_POLL):
                for msg in link._parse(data):  # the link's codec: signing, stats
                    try:
                        self._dispatch(link, addr, msg)
                    except Exception:  # a handler bug must not take the vehicle down
                        self._handler_error(msg.get_type())
        self._send_all(self.missions.tick(t_s))

    def after_tick(
        self, t_s: float, x: FloatArray, ref: FloatArray | None, u: FloatArray, att_cmd_rad: Euler
    ) -> None:
        """After the command was sent: the flight's events, and telemetry."""
        self._t, self._x, self._ref, self._u, self._att_cmd = t_s, x, ref, u, att_cmd_rad
        armed = self.manager.armed if self.manager else False
        if armed != self._armed_sent:
            # a change of arming goes out in the tick it happens, with a fresh telemetry
            # grid: the heartbeat, then this tick's ATTITUDE and LOCAL_POSITION_NED, so a
            # log places the arming on its tick (ground.log's time origin, run.csv's t = 0)
            self._armed_sent = armed
            self._restart_grid()
        self._report_events()
        self._telemetry()

    def _report_events(self) -> None:
        if self.manager is None:
            return
        out: list[Message] = []
        for ev in self.manager.take_events():
            if isinstance(ev, c.Text):
                self.statustext(MAV_SEVERITY[ev.severity], ev.text)
            elif isinstance(ev, c.ItemReached):
                out += self.missions.item_reached(ev.seq)
            else:
                out += self.missions.set_current(ev.seq)
        self._send_all(out)

    def _handler_error(self, kind: str) -> None:
        """Count a handler's exception; log it rate-limited (traceback once per kind): a
        client repeating the request must not be able to flood the vehicle's stderr."""
        self.handler_errors += 1
        self._errors(logging.ERROR, kind, self._t, "error handling %s (%d handler errors so far)",
                     kind, self.handler_errors, exc_info=True)  # fmt: skip

    # -- sending --------------------------------------------------------------------------
    def _send_all(self, msgs: list[Message]) -> None:
        if msgs:
            for link in self.links:
                link.send(*msgs)

    def statustext(self, severity: int, text: str) -> None:
        log.info("%s", text)
        self._send_all([m2.MAVLink_statustext_message(severity, text[:50].encode())])

    def _restart_grid(self, msg_id: int | None = None) -> None:
        """Send ``msg_id`` (None: every message) at the next tick, on a grid from there."""
        for d in (self.grid_origin_us, self.next_due_us):
            if msg_id is None:
                d.clear()
            else:
                d.pop(msg_id, None)

    def _due(self, msg_id: int, interval_s: float, t_us: int) -> bool:
        """Whether ``msg_id`` goes out at ``t_us``: on its grid (origin + n * interval), at the
        first tick at or past each point; a tick that skips points sends once and keeps the
        grid. A clock that went back (a lockstep tick after the idle ticks that kept the
        ground's heartbeat while the plant was silent, stamped ahead of it) finds the
        grid's point for its time again, so the flight's telemetry goes on from its tick."""
        interval_us = max(1, round(interval_s * 1e6))
        origin = self.grid_origin_us.setdefault(msg_id, t_us)
        due = self.next_due_us.get(msg_id, t_us)
        if due - t_us > interval_us:  # the clock went back
            due = origin - ((origin - t_us) // interval_us) * interval_us  # first point >= t
        if t_us < due:
            self.next_due_us[msg_id] = due
            return False
        self.next_due_us[msg_id] = origin + ((t_us - origin) // interval_us + 1) * interval_us
        return True

    def _telemetry(self) -> None:
        t_us = round(self._t * 1e6)
        due: list[list[bytes]] = [[] for _ in self.links]  # each link's frames, on its own sequence
        for msg_id, interval in self.intervals_s.items():
            if self._due(msg_id, interval, t_us):
                try:
                    msg = self.build(msg_id)
                    if msg is not None:  # packing checks every field's range (packed once)
                        frames = [link.pack(msg) for link in self.links]
                        for out, frame in zip(due, frames, strict=True):
                            out.append(frame)
                except Exception:  # one bad message must not stop the vehicle
                    if msg_id not in self._broken:
                        log.exception("telemetry message %d not sent", msg_id)
                    self._broken.add(msg_id)
        for link, frames in zip(self.links, due, strict=True):
            link.send_packed(frames)

    def build(self, msg_id: int) -> Message | None:
        """Build one telemetry message from the latest tick, or None if not available."""
        t_us = int(self._t * 1e6)
        t_ms = int(self._t * 1e3)
        x, home, mgr = self._x, self.cfg.home, self.manager
        armed = mgr.armed if mgr else False
        if msg_id == m2.MAVLINK_MSG_ID_HEARTBEAT:
            hb = heartbeat(armed)
            mode = mgr.mode if mgr else Mode.IDLE
            hb.custom_mode = REPORTED[mode].custom_mode
            if mode in (Mode.AUTO, Mode.TAKEOFF):
                hb.base_mode |= m2.MAV_MODE_FLAG_AUTO_ENABLED
            if mode is Mode.GUIDED:
                hb.base_mode |= m2.MAV_MODE_FLAG_GUIDED_ENABLED
            return hb
        if msg_id == m2.MAVLINK_MSG_ID_SYS_STATUS:
            return self._sys_status()
        if msg_id in (m2.MAVLINK_MSG_ID_ATTITUDE, m2.MAVLINK_MSG_ID_LOCAL_POSITION_NED):
            att, lpn = telemetry.attitude_and_position(t_us, x)
            return att if msg_id == m2.MAVLINK_MSG_ID_ATTITUDE else lpn
        vel_ned = self._vel_ned()
        geo = nwu_to_geo(home, x[POS].tolist())
        lat, lon = int(round(geo.lat_deg * 1e7)), int(round(geo.lon_deg * 1e7))
        heading = math.degrees(-x[EULER][2]) % 360.0  # NWU yaw -> compass heading
        if msg_id == wm.MSG_ID_CURRENT_MODE:
            return wm.current_mode(REPORTED[mgr.mode if mgr else Mode.IDLE])
        if msg_id == wm.MSG_ID_AVAILABLE_MODES_MONITOR:
            return wm.available_modes_monitor()
        if msg_id == m2.MAVLINK_MSG_ID_VFR_HUD:
            return self._vfr_hud()
        if msg_id == m2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            return m2.MAVLink_global_position_int_message(
                t_ms, lat, lon, int(geo.alt_amsl_m * 1000), int(x[POS][2] * 1000),
                *(int(round(v * 100)) for v in vel_ned), int(heading * 100) % 36000,
            )  # fmt: skip
        nav = self.nav() if self.nav is not None else None
        if msg_id == m2.MAVLINK_MSG_ID_GPS_RAW_INT:
            if nav is None:
                return nav_telemetry.gps_raw_int(t_us, home, x, None, None)
            return nav_telemetry.gps_raw_int(t_us, home, x, nav.meas, nav.status, nav.t_s)
        if msg_id == m2.MAVLINK_MSG_ID_ESTIMATOR_STATUS:
            return None if nav is None else nav_telemetry.estimator_status(t_us, nav.status)
        if msg_id == MSG_ID_EKF_STATUS_REPORT:
            return None if nav is None else nav_telemetry.ekf_status_report(nav.status)
        if msg_id == m2.MAVLINK_MSG_ID_SIM_STATE:
            sample = self.truth() if self.truth is not None else None
            return None if sample is None else nav_telemetry.sim_state(home, sample.x)
        if msg_id == m2.MAVLINK_MSG_ID_HOME_POSITION:
            return m2.MAVLink_home_position_message(
                int(round(home.lat_deg * 1e7)), int(round(home.lon_deg * 1e7)),
                int(home.alt_amsl_m * 1000), 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
                t_us,
            )  # fmt: skip
        if msg_id == m2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
            landed = mgr.landed_state(x) if mgr else LandedState.ON_GROUND
            return m2.MAVLink_extended_sys_state_message(m2.MAV_VTOL_STATE_UNDEFINED, LANDED_STATE[landed])
        if msg_id == m2.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED:
            if self._ref is None:
                return None
            return telemetry.position_target(t_us, self._ref, self._att_cmd[2])
        if msg_id == m2.MAVLINK_MSG_ID_ATTITUDE_TARGET:
            if self._ref is None:
                return None
            return telemetry.attitude_target(t_us, self._att_cmd)
        if msg_id == m2.MAVLINK_MSG_ID_WIND_COV:
            sample = self.truth() if self.truth is not None else None
            air = sample.air_nwu_m_s if sample is not None else None
            return telemetry.wind_cov(t_us, self.params.world(), air)
        if msg_id == m2.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS:
            sample = self.truth() if self.truth is not None else None
            if sample is None or sample.servo_rad is None:
                return None
            return m2.MAVLink_actuator_output_status_message(t_us, 0xF, [*sample.servo_rad] + [0.0] * 28)
        if msg_id == m2.MAVLINK_MSG_ID_RAW_RPM:
            sample = self.truth() if self.truth is not None else None
            if sample is None or sample.rotor is None:
                return None
            return m2.MAVLink_raw_rpm_message(0, sample.rotor[2] * 60.0 / (2.0 * math.pi))
        if msg_id == m2.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW:
            return telemetry.servo_output(t_us, self._u, self.servo_channels)
        if msg_id == m2.MAVLINK_MSG_ID_MISSION_CURRENT:
            # None: the server's default, NOT_STARTED or NO_MISSION
            state = MISSION_STATE[mgr.mission_state()] if mgr else None
            return self.missions.mission_current_message(state)
        if msg_id == m2.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return m2.MAVLink_autopilot_version_message(
                CAPABILITIES, 0x00010000, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 1, [0] * 18
            )
        return None  # not built by this vehicle (PROTOCOL_VERSION: not in pymavlink's common)

    def _sys_status(self) -> Message:
        """What exists on this vehicle: the plant's state link stands in for the IMU, the
        attitude estimate and GPS (unhealthy while the plant is silent), the servo outputs,
        and the pre-arm check (healthy when arming would be accepted: MAVSDK is_armable,
        QGC). There is no geofence: its bit is set in health only, which MAVLink defines as
        "no error" (MAVProxy reads a clear geofence health bit as a breach)."""
        mgr = self.manager
        nav = self.nav() if self.nav is not None else None
        plant_ok = mgr is None or not mgr.plant_lost
        sensors, sensors_ok = nav_telemetry.sensor_bits(
            None if nav is None else nav.meas, None if nav is None else nav.status, plant_ok)
        outputs = m2.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
        prearm = m2.MAV_SYS_STATUS_PREARM_CHECK
        present = sensors | outputs | prearm
        healthy = outputs | m2.MAV_SYS_STATUS_GEOFENCE | sensors_ok
        if mgr is not None and mgr.armable():
            healthy |= prearm
        return m2.MAVLink_sys_status_message(present, present, healthy, 100, 0xFFFF, -1, -1,
                                             0, 0, 0, 0, 0, 0)  # fmt: skip

    def _vfr_hud(self) -> Message:
        """The HUD every ground station shows: speeds, heading, collective as throttle."""
        vel_ned = self._vel_ned()
        ground = math.hypot(vel_ned[0], vel_ned[1])
        heading = int(round(math.degrees(-self._x[EULER][2]))) % 360  # NWU yaw -> compass
        lo, hi = self.limits[0]
        throttle = int(round(100.0 * min(max((self._u[0] - lo) / (hi - lo), 0.0), 1.0)))
        alt = self.cfg.home.alt_amsl_m + float(self._x[POS][2])
        # the airspeed: the vehicle's velocity through the air the world reports at it (a
        # helicopter has no airspeed sensor; without a world's truth, still air)
        sample = self.truth() if self.truth is not None else None
        air = ground
        if sample is not None and sample.air_nwu_m_s is not None and np.all(np.isfinite(sample.air_nwu_m_s)):
            v = rot_body_to_earth(*sample.x[EULER]) @ sample.x[VEL]
            air = float(np.linalg.norm(v - np.asarray(sample.air_nwu_m_s)))
        return m2.MAVLink_vfr_hud_message(air, ground, heading, throttle, alt, -vel_ned[2])

    def _vel_ned(self) -> tuple[float, float, float]:
        e = self._x[EULER]
        rt = rot_body_to_earth(e[0], e[1], e[2])
        return frames.nwu_to_ned(rt @ self._x[VEL])

    # -- receiving ------------------------------------------------------------------------
    def _dispatch(self, link: MavlinkUdp, addr: Address, msg: Message) -> None:
        kind = msg.get_type()
        if kind in ("COMMAND_LONG", "COMMAND_INT"):
            self._on_command(link, addr, msg)
        elif kind.startswith("PARAM_"):
            self._on_param(link, addr, msg)
        elif kind.startswith("MISSION_"):
            out = self.missions.handle(msg, self._t)
            if out:
                link.send(*out, to=addr)
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._on_setpoint(msg)
        elif kind == "SET_MODE":
            self._on_set_mode(msg)
        elif kind == "FILE_TRANSFER_PROTOCOL":
            link.send(ftp_nak(msg), to=addr)
        elif kind == "TIMESYNC" and msg.tc1 == 0:
            link.send(m2.MAVLink_timesync_message(int(self._t * 1e9), msg.ts1), to=addr)

    def _on_param(self, link: MavlinkUdp, addr: Address, msg: Message) -> None:
        armed = self.manager.armed if self.manager else False
        before = {s.name: self.params.get(s.name) for s in self.params.specs}
        out = self.params.handle(msg, armed=armed)
        changed = any(self.params.get(n) != v for n, v in before.items())
        if changed:  # applied at the next tick's start, between two control steps
            self._params_changed = True
        if msg.get_type() == "PARAM_SET" and changed:
            self._send_all(out)  # every GCS learns of a change
        elif out:
            link.send(*out, to=addr)

    def _on_setpoint(self, msg: Message) -> None:
        if msg.coordinate_frame != m2.MAV_FRAME_LOCAL_NED:
            self.refused += 1
            return
        mask = msg.type_mask
        ref = np.full(N_REF, np.nan)
        groups = (
            (REF_POS, (msg.x, msg.y, msg.z), m2.POSITION_TARGET_TYPEMASK_X_IGNORE),
            (REF_VEL, (msg.vx, msg.vy, msg.vz), m2.POSITION_TARGET_TYPEMASK_VX_IGNORE),
            (REF_ACC, (msg.afx, msg.afy, msg.afz), m2.POSITION_TARGET_TYPEMASK_AX_IGNORE),
        )
        for part, vals, ignore_bit in groups:
            if not mask & ignore_bit:
                if not all(math.isfinite(v) for v in vals):
                    self.refused += 1
                    return
                ref[part] = frames.ned_to_nwu(vals)
        self._pending.append(_Pending(c.Setpoint(ref)))

    # -- commands -------------------------------------------------------------------------
    def _ack(self, link: MavlinkUdp, addr: Address, msg: Message, result: int) -> None:
        link.send(m2.MAVLink_command_ack_message(msg.command, result, 0, 0,
                                                 msg.get_srcSystem(), msg.get_srcComponent()),
                  to=addr)  # fmt: skip

    def _on_command(self, link: MavlinkUdp, addr: Address, msg: Message) -> None:
        if msg.target_system not in (0, self.cfg.system_id) or msg.target_component not in (0, 1):
            return
        p = [msg.param1, msg.param2, msg.param3, msg.param4]
        if msg.get_type() == "COMMAND_INT":
            p += [msg.x, msg.y, msg.z]
            self._cmd_frame = int(msg.frame)
        else:
            p += [msg.param5, msg.param6, msg.param7]
            self._cmd_frame = None
        cmd = msg.command
        handler = self._COMMANDS.get(cmd)
        if handler is None:
            self._ack(link, addr, msg, m2.MAV_RESULT_UNSUPPORTED)
            return
        try:
            answer = handler(self, p, link, addr)
        except Exception:  # every command gets its one ACK, whatever went wrong
            self._handler_error(f"command {cmd}")
            answer = m2.MAV_RESULT_FAILED, ""
        if isinstance(answer, tuple):
            self._answer(link, addr, msg, *answer)
        else:  # a flight command: executed at the start of the next tick, then answered
            self._pending.append(_Pending(answer, link, addr, msg))

    def _answer(self, link: MavlinkUdp, addr: Address, msg: Message, result: int, text: str) -> None:
        if text:
            self.statustext(
                m2.MAV_SEVERITY_INFO if result == m2.MAV_RESULT_ACCEPTED else m2.MAV_SEVERITY_WARNING,
                text,
            )
        self._ack(link, addr, msg, result)

    def at_tick_start(self, t_s: float, x: FloatArray) -> None:
        """Tick-start hook: the flight commands received since the last tick go to the flight
        manager with this tick's time and state (a take-off's trajectory starts at this
        tick), and each gets its ACK."""
        self._t, self._x = t_s, x
        if self._params_changed:
            self._params_changed = False
            self.apply_params(self.params)
        pending, self._pending = self._pending, []
        for p in pending:
            try:
                reply = self._execute(p.command)
            except Exception:
                self._handler_error(f"flight command {type(p.command).__name__}")
                reply = c.Reply(c.Result.FAILED)
            if p.msg is None:  # a setpoint or SET_MODE: no ACK on the wire
                if not reply.accepted:
                    self.refused += 1  # e.g. a velocity-only setpoint: positions are flown
                if p.say and reply.text:
                    ok = reply.accepted
                    self.statustext(m2.MAV_SEVERITY_INFO if ok else m2.MAV_SEVERITY_WARNING, reply.text)
                continue
            assert p.link is not None and p.addr is not None
            self._answer(p.link, p.addr, p.msg, MAV_RESULT[reply.result], reply.text)

    def _execute(self, cmd: c.Command) -> c.Reply:
        if self.manager is None:
            return c.Reply(c.Result.FAILED, "Not ready")
        return self.manager.execute(cmd, self._t, self._x)

    def _fly(self, cmd: c.Command) -> c.Command:
        return cmd

    def _cmd_arm(self, p: list[float], link: MavlinkUdp, addr: Address) -> Answer:
        if p[0] == 1.0:
            return self._fly(c.Arm())
        if p[0] == 0.0:
            return self._fly(c.Disarm(force=p[1] == FORCE_DISARM_MAGIC))
        return m2.MAV_RESULT_DENIED, "Arm: param1 must be 0 or 1"

    def _cmd_mission_start(self, p: list[float], link: MavlinkUdp, addr: Address) -> Answer:
        first = int(p[0]) if math.isfinite(p[0]) and 0 < p[0] < 65536 else 0
        return self._fly(c.StartMission(first))

    def _cmd_takeoff(self, p: list[float], link: MavlinkUdp, addr: Address) -> Answer:
        """param7 is the altitude; NaN means the default. In COMMAND_INT it is in the
        command's frame (AMSL for GLOBAL, above home for GLOBAL_RELATIVE_ALT, up = -z for
        LOCAL_NED); in COMMAND_LONG, which has no frame, above home, as ArduPilot reads it
        and as MAVSDK sends it to a vehicle that is not PX4."""
        if not math.isfinite(p[6]):
            return self._fly(c.Takeoff(None))
        frame = self._cmd_frame
        if frame in (m2.MAV_FRAME_GLOBAL, m2.MAV_FRAME_GLOBAL_INT):
            alt = p[6] - self.cfg.home.alt_amsl_m
        elif frame == m2.MAV_FRAME_LOCAL_NED:
            alt = -p[6]
        elif frame is None or frame in RELATIVE_ALT_FRAMES:
            alt = p[6]
        else:
            return m2.MAV_RESULT_DENIED, f"Takeoff refused: frame {frame}"
        return self._fly(c.Takeoff(alt))

    def _cmd_land(self, p: list[float], link: MavlinkUdp, addr: Address) -> Answer:
        return self._fly(c.Land())

    def _cmd_rtl(self, p: list[float], link: MavlinkUdp, addr: Address) -> Answer:
        return self._fly(c.ReturnToLaunch())

    def _cmd_set_mode(self, p: list[float], link: MavlinkUdp, addr: Address) -> Answer:
        mode = wm.from_do_set_mode(p[1], p[2]) if math.isfinite(p[1]) and math.isfinite(p[2]) else None
        if mode is None:
            return m2.MAV_RESULT_DENIED, f"Mode {p[1]:g}/{p[2]:g} not supported"[:50]
        return self._fly(COMMAND[mode]())

    def _cmd_set_standard_mode(self, p: list[float], link: MavlinkUdp, addr: Address) -> Answer:
        mode = wm.BY_STANDARD.get(int(p[0])) if math.isfinite(p[0]) else None
        if mode is None:  # the microservice's answer for a standard mode the vehicle lacks
            return m2.MAV_RESULT_FAILED, f"Standard mode {p[0]:g} not supported"[:50]
        return self._fly(COMMAND[mode]())

    def _on_set_mode(self, msg: Message) -> None:
        """The SET_MODE message (no ACK): the whole custom mode."""
        if msg.target_system not in (0, self.cfg.system_id):
            return
        mode = wm.BY_CUSTOM.get(int(msg.custom_mode))
        if mode is None:
            self.refused += 1
            self.statustext(m2.MAV_SEVERITY_WARNING, f"Mode {msg.custom_mode} not supported")
            return
        self._pending.append(_Pending(COMMAND[mode](), say=True))

    def _cmd_request_message(self, p: list[float], link: MavlinkUdp, addr: Address) -> tuple[int, str]:
        if math.isfinite(p[0]) and int(p[0]) == wm.MSG_ID_AVAILABLE_MODES:
            # param2: the mode's index (1-based), 0 for all of them
            n = len(wm.MODES)
            index = int(p[1]) if math.isfinite(p[1]) else -1
            if not 0 <= index <= n:
                return m2.MAV_RESULT_DENIED, ""
            for i in range(1, n + 1) if index == 0 else (index,):
                link.send(wm.available_modes(i), to=addr)
            return m2.MAV_RESULT_ACCEPTED, ""
        msg = self.build(int(p[0])) if math.isfinite(p[0]) else None
        if msg is None:
            return m2.MAV_RESULT_DENIED, ""
        link.send(msg, to=addr)
        return m2.MAV_RESULT_ACCEPTED, ""

    def _cmd_capabilities(self, p: list[float], link: MavlinkUdp, addr: Address) -> tuple[int, str]:
        return self._cmd_request_message([float(m2.MAVLINK_MSG_ID_AUTOPILOT_VERSION)] + p[1:], link, addr)

    def _cmd_set_interval(self, p: list[float], link: MavlinkUdp, addr: Address) -> tuple[int, str]:
        if not (math.isfinite(p[0]) and math.isfinite(p[1])):
            return m2.MAV_RESULT_DENIED, ""
        msg_id, interval_us = int(p[0]), p[1]
        if self.build(msg_id) is None and msg_id not in DEFAULT_RATES_HZ:
            return m2.MAV_RESULT_DENIED, ""
        if interval_us == -1:
            self.intervals_s.pop(msg_id, None)
        elif interval_us == 0:
            rate = DEFAULT_RATES_HZ.get(msg_id)
            if rate:
                self.intervals_s[msg_id] = 1.0 / rate
            else:
                self.intervals_s.pop(msg_id, None)
        elif interval_us > 0:
            self.intervals_s[msg_id] = max(interval_us * 1e-6, 0.001)
        else:
            return m2.MAV_RESULT_DENIED, ""
        self._restart_grid(msg_id)  # at once, then at the new rate
        return m2.MAV_RESULT_ACCEPTED, ""

    _COMMANDS: dict[int, Callable[[GcsService, list[float], MavlinkUdp, Address], Answer]] = {
        m2.MAV_CMD_COMPONENT_ARM_DISARM: _cmd_arm,
        m2.MAV_CMD_MISSION_START: _cmd_mission_start,
        m2.MAV_CMD_NAV_TAKEOFF: _cmd_takeoff,
        m2.MAV_CMD_NAV_LAND: _cmd_land,
        m2.MAV_CMD_NAV_RETURN_TO_LAUNCH: _cmd_rtl,
        m2.MAV_CMD_DO_SET_MODE: _cmd_set_mode,
        wm.CMD_DO_SET_STANDARD_MODE: _cmd_set_standard_mode,
        m2.MAV_CMD_REQUEST_MESSAGE: _cmd_request_message,
        m2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: _cmd_capabilities,
        m2.MAV_CMD_SET_MESSAGE_INTERVAL: _cmd_set_interval,
    }

    # -- mission bookkeeping --------------------------------------------------------------
    def _check_mission(self, items: tuple[MissionItem, ...]) -> int:
        """A new upload is refused while it cannot be flown; flying one is replaced only
        by the next explicit start (the running trajectory is kept until then)."""
        return check_mission(items, self.cfg.home, self.flight_limits)
