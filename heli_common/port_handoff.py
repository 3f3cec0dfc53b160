"""UDP ports a launcher binds once and hands to its children: no port is ever picked by
closing a probe socket.

A probe (bind port 0, read the port, close) races: the kernel may hand the same port to the
next probe or to anyone else before the child binds it (seen: two probes of one launcher got
the same port, and the plant refused ``--port`` equal to ``--autopilot-port``). Here the
launcher binds every socket itself (:class:`HeldPorts`), keeps it bound, and starts each
child with the sockets it needs inherited (``pass_fds``) and named in the environment
variable :data:`ENV` as ``host:port=fd`` pairs. A child that binds one of those addresses
(:func:`heli_common.wire.mavlink.udp.bind_udp`) adopts the inherited socket instead: the port
was never free in between, and whatever was sent to it before the child was ready waits in
the socket's queue. Explicit ports (``--port 4560``) bind as before.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Iterable, Mapping

from heli_common.closing import Closing

ENV = "HELI_SITL_UDP_SOCKETS"
Address = tuple[str, int]


class HeldPorts(Closing):
    """UDP sockets bound by the launcher on ``host``, held until :meth:`close` (after the
    children that adopt them have started: each has its own copy then)."""

    def __init__(self, host: str = "127.0.0.1") -> None:
        self.host = host
        self._socks: dict[int, socket.socket] = {}

    def new(self) -> int:
        """A port bound now (port 0: the kernel's choice) and held: distinct from every
        other port held, and from any other process's."""
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind((self.host, 0))
        port = int(s.getsockname()[1])
        self._socks[port] = s
        return port

    def fds(self, ports: Iterable[int]) -> tuple[int, ...]:
        """The file descriptors of the held ``ports`` (for ``subprocess.Popen(pass_fds=...)``)."""
        return tuple(self._socks[p].fileno() for p in ports if p in self._socks)

    def env(self, ports: Iterable[int], base: Mapping[str, str] | None = None) -> dict[str, str]:
        """``base`` (default: this process's environment) with :data:`ENV` naming the held
        ``ports``' sockets; ports not held here are left to bind as usual."""
        pairs = [f"{self.host}:{p}={self._socks[p].fileno()}" for p in ports if p in self._socks]
        out = dict(os.environ if base is None else base)
        out.pop(ENV, None)  # a grandchild must not adopt what its parent already has
        if pairs:
            out[ENV] = ",".join(pairs)
        return out

    def close(self) -> None:
        for s in self._socks.values():
            s.close()
        self._socks.clear()


def _inherited() -> dict[Address, int]:
    """The sockets this process was handed, by address (malformed entries ignored: a bad
    environment must not stop a process that can still bind its ports itself)."""
    out: dict[Address, int] = {}
    for item in os.environ.get(ENV, "").split(","):
        addr, _, fd = item.rpartition("=")
        host, _, port = addr.rpartition(":")
        if host and port.isdigit() and fd.isdigit():
            out[(host, int(port))] = int(fd)
    return out


_adopted: set[Address] = set()  # each inherited socket is adopted once


def adopt(local: Address) -> socket.socket | None:
    """The socket inherited for ``local`` (bound, as the launcher bound it), or None: then
    bind it yourself. A descriptor that is not a UDP socket bound to ``local`` is refused
    (None), so a stale variable can never make a process listen somewhere else."""
    if local in _adopted:
        return None
    fd = _inherited().get(local)
    if fd is None:
        return None
    try:
        sock = socket.socket(fileno=fd)
    except OSError:
        return None
    try:
        ok = sock.type == socket.SOCK_DGRAM and sock.getsockname() == local
    except OSError:
        ok = False
    if not ok:
        sock.detach()  # not ours to close
        return None
    _adopted.add(local)
    return sock
