"""The live view: a viser server, the scene, a :class:`MavlinkFeed` and the loop that pushes the
newest frame to the browsers at its own rate (default 30 Hz), in threads of the launching
process. The vehicle never waits for it: the feed only listens, and a frame not pushed in time
is replaced by the next (a browser that is closed, slow or absent changes nothing).

``open_live_view(...)`` starts it and returns the handle; the launcher passes
``handle.feed.port`` to the autopilot as its telemetry destination and calls ``close()``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from heli_common.state import FloatArray
from heli_common.wire.mavlink.udp import Address
from heli_sitl.view.mavlink_feed import MavlinkFeed
from heli_sitl.view.scene import HeliScene, SceneOptions
from heli_sitl.view.server import start_server

DEFAULT_RATE_HZ = 30.0


@dataclass(frozen=True)
class PushStats:
    """What the push loop did: frames pushed to the browsers, over which wall time."""

    frames: int
    first_to_last_s: float

    @property
    def rate_hz(self) -> float:
        if self.frames < 2 or self.first_to_last_s <= 0.0:
            return 0.0
        return (self.frames - 1) / self.first_to_last_s


class LiveView:
    """The feed, the scene and the push loop (see the module docstring)."""

    def __init__(
        self, scene: HeliScene, feed: MavlinkFeed, rate_hz: float = DEFAULT_RATE_HZ,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:  # fmt: skip
        self.scene = scene
        self.feed = feed
        self.period_s = 1.0 / rate_hz
        self._clock = clock
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="view-push", daemon=True)
        self._first: float | None = None
        self._last_push: float | None = None
        self.frames = 0
        self.draw_path = False  # no path known in advance: draw the targets as they come

    @property
    def url(self) -> str:
        s = self.scene.server
        return f"http://{s.get_host()}:{s.get_port()}/"

    def start(self) -> LiveView:
        self.feed.start()
        self._thread.start()
        return self

    def close(self) -> PushStats:
        """Stop the loop, the feed and the server; what was pushed."""
        self._stop.set()
        self._thread.join(2.0)
        self.feed.stop()
        self.scene.server.stop()
        return self.stats()

    def hold_last_frame(self, quiet_s: float = 0.3, timeout_s: float = 10.0) -> None:
        """The flight is over (its vehicle has ended): once the feed has read everything
        (no datagram for ``quiet_s``, at most ``timeout_s``), show its last frame and make it
        where a browser that connects from now on starts looking (its initial camera), so
        the page it opens is the flight's end wherever its camera reports come in."""
        end = self._clock() + timeout_s
        seen, quiet_since = -1, self._clock()
        while self._clock() < end:
            n = self.feed.datagrams
            if n != seen:
                seen, quiet_since = n, self._clock()
            elif self._clock() - quiet_since >= quiet_s:
                break
            self._stop.wait(0.05)
        frame, points = self.feed.snapshot()
        for p in points:
            self.scene.add_trail_point(p)
        if frame is not None:
            self.scene.show(frame)
            self.scene.hold(frame)

    def stats(self) -> PushStats:
        if self._first is None or self._last_push is None:
            return PushStats(self.frames, 0.0)
        return PushStats(self.frames, self._last_push - self._first)

    def _run(self) -> None:
        shown = None
        next_t = self._clock()
        while not self._stop.is_set():
            frame, points = self.feed.snapshot()
            for p in points:
                self.scene.add_trail_point(p)
            refs = self.feed.take_references()
            if refs and self.draw_path:
                self.scene.extend_reference_path(refs)
            if frame is not None and frame is not shown:
                self.scene.show(frame)
                shown = frame
                now = self._clock()
                self._first = now if self._first is None else self._first
                self._last_push = now
                self.frames += 1
            # a fixed grid; after a stall (a slow push) start again from now: never catch up
            next_t += self.period_s
            wait = next_t - self._clock()
            if wait < 0.0:
                next_t, wait = self._clock(), 0.0
            self._stop.wait(wait)


def open_live_view(
    view_port: int, *, limits_rad: FloatArray | None = None, path_nwu_m: FloatArray | None = None,
    title: str = "heli-tlc-sitl", feed_port: int = 0, forward_to: Address | None = None,
    rate_hz: float = DEFAULT_RATE_HZ,
) -> LiveView:  # fmt: skip
    """Serve the live page on 127.0.0.1:``view_port`` and listen for telemetry on UDP
    ``feed_port`` (0: the kernel's choice; ``.feed.port`` says which); started."""
    server = start_server(view_port)
    limits = tuple((float(lo), float(hi)) for lo, hi in limits_rad) if limits_rad is not None else None
    opts = SceneOptions(title=title, limits_rad=limits) if limits else SceneOptions(title=title)
    scene = HeliScene(server, opts)
    if path_nwu_m is not None:
        scene.set_reference_path(path_nwu_m)
        start = np.asarray(path_nwu_m)[0]
        scene.set_initial_camera((float(start[0]), float(start[1]), float(start[2])))
    scene.on_connect()
    feed = MavlinkFeed(feed_port, limits_rad, forward_to=forward_to)
    view = LiveView(scene, feed, rate_hz)
    view.draw_path = path_nwu_m is None
    return view.start()
