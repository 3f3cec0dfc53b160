"""Opening a CAN bus: a small, typed, context-managed wrapper over python-can.

Four python-can interfaces are supported, one per deployment:

* ``virtual``: every bus opened on the same channel name *in one process* sees the
  frames the others send (in-process closed loop, tests). Delivery is synchronous: a
  frame sent is in every other bus's queue when ``send`` returns.
* ``mcast``: DroneCAN's UDP multicast CAN (:mod:`heli_common.wire.can.mcast`), processes
  on one host, bus N on 239.65.82.N:57732: the format ArduPilot's SITL and AP_Periph
  nodes, libcanard, pydronecan's ``mcast:N`` driver and so the DroneCAN GUI tool speak.
  Opened with the bench's own python-can interface (``dronecan_mcast``). Multicast, so
  only inside a private network namespace in tests, as ``udp_multicast``.
* ``udp_multicast``: processes on one host, one UDP multicast group per CAN bus. This
  needs ``msgpack`` (``pip install 'python-can[multicast]'``). The default group is
  python-can's IPv4 one (239.74.163.2, port 43113). Multicast leaves the loopback
  interface unless routed otherwise: tests open it only inside a private network
  namespace (``unshare --net``, ``ip link set lo up``, ``ip route add 224.0.0.0/4 dev lo``).
* ``socketcan``: a Linux kernel CAN interface, normally the virtual ``vcan0``::

      sudo modprobe vcan
      sudo ip link add dev vcan0 type vcan
      sudo ip link set up vcan0

  (``candump vcan0`` from can-utils then shows the servo traffic.)

A bus spec string selects one of them on a command line: ``mcast[:N]`` (pydronecan's
name; N = 0..9, default 0), ``virtual[:CHANNEL]``, ``udp_multicast[:GROUP[:PORT]]`` or
``socketcan[:IFACE]`` (see :func:`parse_bus_spec`).

Sending never blocks by default (``send_timeout_s = 0``): a control loop must not stall
on a full queue; the failure is raised as :class:`CanSendError` for the caller to count.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal, cast, get_args

import can

from heli_common.closing import Closing
from heli_common.wire.can.mcast import MCAST_PORT, DroneCanMcastBus, parse_channel

Interface = Literal["virtual", "udp_multicast", "socketcan", "mcast"]
INTERFACES: tuple[str, ...] = get_args(Interface)

#: python-can's IPv4 fallback group (``UdpMulticastBus.DEFAULT_GROUP_IPv4``). IPv4 on
#: purpose: the test namespaces route 224.0.0.0/4 over ``lo``; IPv6 is not set up there.
UDP_MULTICAST_GROUP_IPV4 = "239.74.163.2"
UDP_MULTICAST_PORT = 43113

DEFAULT_CHANNELS: dict[str, str] = {
    "virtual": "heli-sitl-servo",
    "udp_multicast": UDP_MULTICAST_GROUP_IPV4,
    "socketcan": "vcan0",
    "mcast": "0",  # the bus number N of 239.65.82.N
}
DEFAULT_PORTS: dict[str, int] = {"udp_multicast": UDP_MULTICAST_PORT, "mcast": MCAST_PORT}

CAN_EXTENDED_ID_MASK = 0x1FFFFFFF


class CanBusError(Exception):
    """The bus could not be opened, or an operation on it failed."""


class CanSendError(CanBusError):
    """A frame was not sent (queue full, interface down, driver error)."""


@dataclass(frozen=True)
class CanBusConfig:
    """Which bus to open. ``channel`` empty means the interface's default (see module doc)."""

    interface: Interface = "virtual"
    channel: str = ""
    port: int = 0  # udp_multicast and mcast; 0: the interface's (43113, 57732)
    send_timeout_s: float = 0.0  # 0: never block the control loop on a full queue
    rx_queue_size: int = 0  # virtual only; 0 = unbounded (python-can's default)

    def __post_init__(self) -> None:
        if self.interface not in INTERFACES:
            raise ValueError(f"CAN interface must be one of {INTERFACES}, got {self.interface!r}")
        if self.port == 0:
            object.__setattr__(self, "port", DEFAULT_PORTS.get(self.interface, UDP_MULTICAST_PORT))
        if not 0 < self.port < 65536:
            raise ValueError(f"UDP port must be in 1..65535, got {self.port}")
        if self.send_timeout_s < 0.0:
            raise ValueError("send_timeout_s must be >= 0")
        if self.rx_queue_size < 0:
            raise ValueError("rx_queue_size must be >= 0")
        if not self.channel:
            object.__setattr__(self, "channel", DEFAULT_CHANNELS[self.interface])
        if self.interface == "mcast":  # "0".."9", as the spec writes it
            object.__setattr__(self, "channel", str(parse_channel(self.channel)))

    def describe(self) -> str:
        if self.interface == "udp_multicast":
            return f"udp_multicast:{self.channel}:{self.port}"
        if self.interface == "mcast" and self.port != MCAST_PORT:
            return f"mcast:{self.channel}:{self.port}"
        return f"{self.interface}:{self.channel}"


def parse_bus_spec(spec: str) -> CanBusConfig:
    """``mcast[:N]``, ``virtual[:CHANNEL]``, ``udp_multicast[:GROUP[:PORT]]``,
    ``socketcan[:IFACE]``; ValueError naming the forms otherwise."""
    head, _, rest = spec.strip().partition(":")
    if head not in INTERFACES:
        raise ValueError(f"unknown CAN bus {spec!r}; expected mcast[:N], virtual[:channel], "
                         f"udp_multicast[:group[:port]] or socketcan[:iface]")  # fmt: skip
    interface = cast(Interface, head)
    if interface == "mcast":
        bus, _, port = rest.partition(":")  # the port only for tests (the field's is 57732)
        if port and not port.isdigit():
            raise ValueError(f"CAN bus {spec!r}: the port must be a number")
        return CanBusConfig("mcast", str(parse_channel(bus)), int(port) if port else MCAST_PORT)
    if interface == "udp_multicast" and rest:
        group, _, port = rest.partition(":")
        cfg = CanBusConfig(interface, group)
        return replace(cfg, port=int(port)) if port else cfg
    return CanBusConfig(interface, rest)


def _open(config: CanBusConfig) -> can.BusABC:
    try:
        if config.interface == "virtual":
            return can.Bus(
                interface="virtual", channel=config.channel, rx_queue_size=config.rx_queue_size
            )
        if config.interface == "udp_multicast":
            return can.Bus(interface="udp_multicast", channel=config.channel, port=config.port)
        if config.interface == "mcast":  # the class itself: no dependence on installed entry points
            return DroneCanMcastBus(int(config.channel), port=config.port)
        return can.Bus(interface="socketcan", channel=config.channel)
    except (can.CanError, OSError, ImportError, RuntimeError, ValueError) as exc:
        # udp_multicast raises RuntimeError without msgpack; socketcan OSError without vcan0
        raise CanBusError(f"cannot open CAN bus {config.describe()}: {exc}") from exc


class CanBus(Closing):
    """One open python-can bus: ``send`` extended frames, ``recv`` with a timeout in seconds.

    Either opens the bus described by ``config`` or wraps an already open ``bus`` (tests
    inject a faulty one that way). Either way this object owns it: ``close`` (or leaving
    the ``with`` block) shuts it down.
    """

    def __init__(
        self, config: CanBusConfig | None = None, *, bus: can.BusABC | None = None
    ) -> None:
        if bus is not None and config is not None:
            raise ValueError("give a config or an open bus, not both")
        self.config = config if config is not None else CanBusConfig()
        self.bus: can.BusABC = bus if bus is not None else _open(self.config)
        self.closed = False

    def send(self, can_id: int, data: bytes) -> None:
        """Send one 29-bit (extended) CAN 2.0 frame; :class:`CanSendError` if it was not sent."""
        msg = can.Message(
            arbitration_id=can_id & CAN_EXTENDED_ID_MASK, is_extended_id=True, data=data
        )
        try:
            self.bus.send(msg, timeout=self.config.send_timeout_s)
        except Exception as exc:
            # Any driver failure (CanOperationError for a full virtual queue, OSError ENOBUFS
            # on socketcan, a third-party driver's own exception) becomes one error type, so
            # the control loop can count it and go on instead of dying on a bus fault.
            raise CanSendError(f"{type(exc).__name__}: {exc}") from exc

    def recv(self, timeout_s: float | None = 0.0) -> can.Message | None:
        """The next frame, or None after ``timeout_s`` seconds (None: wait for one);
        :class:`CanBusError` on failure."""
        try:
            return self.bus.recv(timeout=timeout_s)
        except Exception as exc:
            # as in send: a receive fault is reported, counted and survived by the caller
            raise CanBusError(f"{type(exc).__name__}: {exc}") from exc

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.bus.shutdown()


def open_bus(config: CanBusConfig | str) -> CanBus:
    """Open a bus from a config or a spec string (``virtual:chan`` ...)."""
    return CanBus(parse_bus_spec(config) if isinstance(config, str) else config)
