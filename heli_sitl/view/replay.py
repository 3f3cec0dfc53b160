"""The replay: a recorded flight in the live view's page, with a time slider, a speed and
play/pause (``heli-sitl view DIR|FILE``, and ``simulate --view``, whose flight is over before
a browser could open). A thread advances the time at the chosen speed while playing, at
:data:`RATE_HZ`; moving the slider seeks (the trail is redrawn up to that time)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from heli_sitl.view.recording import Recording
from heli_sitl.view.scene import HeliScene, SceneOptions
from heli_sitl.view.server import start_server, url_of

RATE_HZ = 30.0
SPEEDS = ("0.25", "0.5", "1", "2", "5", "10")


class Replay:
    """A recording served on a viser page (see the module docstring); :meth:`start`, :meth:`close`."""

    def __init__(
        self, rec: Recording, port: int, *, options: SceneOptions | None = None,
        clock: Callable[[], float] = time.monotonic, playing: bool = True,
    ) -> None:  # fmt: skip
        self.rec = rec
        server = start_server(port)
        self.scene = HeliScene(server, options or SceneOptions(title=f"replay: {rec.source.name}"))
        ref = rec.reference()
        if ref is not None:
            self.scene.set_reference_path(ref)
        p0 = rec.positions()[0]
        self.scene.set_initial_camera((float(p0[0]), float(p0[1]), float(p0[2])))
        self.scene.on_connect()
        gui = server.gui
        t0, t1 = float(rec.t_s[0]), float(rec.t_s[-1])
        step = max((t1 - t0) / max(len(rec.t_s) - 1, 1), 1e-3)
        with gui.add_folder("replay"):
            self.slider = gui.add_slider("t [s]", min=t0, max=max(t1, t0 + step), step=step, initial_value=t0)
            self.speed = gui.add_dropdown("speed", SPEEDS, initial_value="1")
            self.play = gui.add_button("pause" if playing else "play")
        self.playing = playing
        self.t_s = t0
        self._clock = clock
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="view-replay", daemon=True)
        self._shown = -1
        self._setting = False  # the loop moves the slider: not a seek

        @self.slider.on_update
        def _(_: object) -> None:
            if not self._setting:
                self.seek(float(self.slider.value))

        @self.play.on_click
        def _(_: object) -> None:
            self.playing = not self.playing
            self.play.label = "pause" if self.playing else "play"
            if self.playing and self.t_s >= t1:
                self.seek(t0)

    @property
    def url(self) -> str:
        return url_of(self.scene.server)

    def start(self) -> Replay:
        self.show_at(self.t_s)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.scene.server.stop()

    def seek(self, t_s: float) -> None:
        """Jump to ``t_s``: the trail is the flight up to there."""
        with self._lock:
            self.t_s = t_s
            i = self.rec.index_at(t_s)
            self.scene.reset_trail(self.rec.positions()[: i + 1])
            self._shown = -1
            self.show_at(t_s)

    def show_at(self, t_s: float) -> None:
        i = self.rec.index_at(t_s)
        if i == self._shown:
            return
        if i > self._shown >= 0:
            for p in self.rec.positions()[self._shown + 1 : i + 1]:
                self.scene.add_trail_point((float(p[0]), float(p[1]), float(p[2])))
        self.scene.show(self.rec.frame(i), status="playing" if self.playing else "paused")
        self._shown = i

    def _run(self) -> None:
        period = 1.0 / RATE_HZ
        last = self._clock()
        t_end = float(self.rec.t_s[-1])
        while not self._stop.wait(period):
            now = self._clock()
            dt, last = now - last, now
            if not self.playing:
                continue
            with self._lock:
                self.t_s = min(self.t_s + dt * float(self.speed.value), t_end)
                if self.t_s >= t_end:  # the end: paused there (play starts over)
                    self.playing = False
                    self.play.label = "play"
                self.show_at(self.t_s)
                self._setting = True
                try:
                    self.slider.value = round(self.t_s, 3)  # type: ignore[misc]  # (a setter: viser's typing)
                finally:
                    self._setting = False
