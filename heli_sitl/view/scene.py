"""The page the view serves (viser): the helicopter, its path, and the panels; one
:meth:`HeliScene.show` per frame pushed to the browsers.

The scene is in the paper's frames: earth NWU with z up (viser's +z up), the vehicle posed
by its ZYX Euler angles (body FLU). Colours (docs/view.md):

* fuselage and tail boom: signal orange :data:`FUSELAGE_RGB`, nothing else is that colour
  (the browser test looks for it where the camera looks);
* main rotor disc: translucent grey, tilted on the hub by the flapping a1 (forward) and b1
  (right) where the source knows them (the rotor plant's run.csv, a recording); tail rotor
  disc: translucent grey on the boom's end;
* reference path: blue; flown trail: green; reference point: red ball; wind: cyan arrow
  from the vehicle (1 m per m/s).
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import viser
import viser.transforms as vtf

from heli_common.state import PITCH_NAMES, FloatArray
from heli_sitl.view.frame import ViewFrame

FUSELAGE_RGB = (255, 102, 0)  # signal orange
DISC_RGB = (90, 90, 100)
PATH_RGB = (40, 90, 230)
TRAIL_RGB = (20, 170, 60)
REF_RGB = (220, 20, 40)
WIND_RGB = (0, 200, 220)

# the X-Cell 60's size (m), near enough to read the attitude and the disc at a glance
FUSELAGE_DIM_M = (0.75, 0.18, 0.30)
BOOM_DIM_M = (0.75, 0.05, 0.05)
BOOM_X_M = -0.65
MAIN_RADIUS_M = 0.775
HUB_Z_M = 0.30  # hub above the centre of gravity
TAIL_RADIUS_M = 0.13
TAIL_X_M = -1.05
# the follow camera, from the vehicle in earth NWU: behind-left and a little above, so the ray
# to the fuselage passes under the main disc
CAMERA_OFFSET_M = (-3.2, 2.4, 0.9)
TRAIL_POINTS = 4000  # the newest flown positions drawn (older ones drop off)
TRAIL_EVERY = 3  # the trail (a whole polyline) is re-sent every this many frames


def wxyz_of(euler_flu_rad: tuple[float, float, float]) -> FloatArray:
    """Body -> earth rotation (ZYX Euler, NWU/FLU: heli_common.kinematics.rot_body_to_earth,
    without its compiled code) as viser's quaternion (w, x, y, z)."""
    phi, theta, psi = euler_flu_rad
    r = vtf.SO3.from_z_radians(psi) @ vtf.SO3.from_y_radians(theta) @ vtf.SO3.from_x_radians(phi)
    return np.asarray(r.wxyz)


def disc_wxyz(a1_rad: float, b1_rad: float) -> FloatArray:
    """The main disc on the hub (body FLU): tilted forward by a1, to the right by b1."""
    return np.asarray((vtf.SO3.from_y_radians(a1_rad) @ vtf.SO3.from_x_radians(b1_rad)).wxyz)


def _segments(points: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """A polyline (N, 3) as viser's line segments (N - 1, 2, 3)."""
    points = np.asarray(points, dtype=np.float32)
    return np.stack([points[:-1], points[1:]], axis=1).astype(np.float32)


@dataclass(frozen=True)
class SceneOptions:
    title: str = "heli-tlc-sitl"
    # each pitch's (lo, hi) [rad], theta_m, theta_t, eps, eta: the panels' ranges
    limits_rad: tuple[tuple[float, float], ...] = ((-0.1, 0.3), (-0.35, 0.35), (-0.14, 0.14), (-0.14, 0.14))


class HeliScene:
    """The scene and the panels on one viser server; :meth:`show` poses everything for a frame.
    Thread-safe: one lock around every push (the live loop and GUI callbacks may race)."""

    def __init__(self, server: viser.ViserServer, opts: SceneOptions | None = None) -> None:
        self.server = server
        self.opts = opts or SceneOptions()
        self.frames_pushed = 0
        self._lock = threading.Lock()
        self._trail: deque[tuple[float, float, float]] = deque(maxlen=TRAIL_POINTS)
        self._last: ViewFrame | None = None
        self._ref_path: deque[tuple[float, float, float]] = deque(maxlen=TRAIL_POINTS)
        self._ref_path_dirty = False
        sc = server.scene
        sc.set_up_direction("+z")
        sc.add_grid("/ground", width=60.0, height=60.0, cell_size=1.0, section_size=5.0)
        self.body = sc.add_frame("/vehicle", show_axes=False)
        sc.add_box("/vehicle/fuselage", color=FUSELAGE_RGB, dimensions=FUSELAGE_DIM_M)
        sc.add_box("/vehicle/boom", color=FUSELAGE_RGB, dimensions=BOOM_DIM_M, position=(BOOM_X_M, 0.0, 0.05))
        self.hub = sc.add_frame("/vehicle/hub", show_axes=False, position=(0.0, 0.0, HUB_Z_M))
        # viser's cylinder has its axis along z: the main disc lies in the hub's x-y plane
        sc.add_cylinder("/vehicle/hub/disc", radius=MAIN_RADIUS_M, height=0.015, color=DISC_RGB, opacity=0.35,
                        side="double")  # fmt: skip
        sc.add_cylinder("/vehicle/tail_disc", radius=TAIL_RADIUS_M, height=0.01, color=DISC_RGB, opacity=0.5,
                        side="double", position=(TAIL_X_M, -0.06, 0.08),
                        wxyz=tuple(vtf.SO3.from_x_radians(math.pi / 2).wxyz))  # fmt: skip
        self.ref_point = sc.add_icosphere("/reference", radius=0.08, color=REF_RGB, visible=False)
        self.wind = sc.add_arrows("/wind", points=np.zeros((1, 2, 3), np.float32), colors=WIND_RGB,
                                  shaft_radius=0.02, head_radius=0.06, head_length=0.15,
                                  visible=False)  # fmt: skip
        self.trail: viser.LineSegmentsHandle | None = None
        self.path: viser.LineSegmentsHandle | None = None
        self._build_gui()

    # -- the panels --------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui = self.server.gui
        gui.configure_theme(titlebar_content=None, control_width="medium")
        self.md_flight = gui.add_markdown(f"**{self.opts.title}**")
        self.md_error = gui.add_markdown("tracking error: -")
        self.pitch_sliders = []
        for name, (lo, hi) in zip(PITCH_NAMES, self.opts.limits_rad, strict=True):
            lo_deg, hi_deg = round(math.degrees(lo), 2), round(math.degrees(hi), 2)
            self.pitch_sliders.append(gui.add_slider(
                f"{name} [deg]", min=lo_deg, max=hi_deg, step=0.01,
                initial_value=round(0.5 * (lo_deg + hi_deg), 2), disabled=True,
                hint=f"blade pitch against its limits [{lo_deg:.1f}, {hi_deg:.1f}] deg"))  # fmt: skip
        self.md_rotor = gui.add_markdown("rotor: -")
        self.follow = gui.add_checkbox("camera follows", True, hint="off: the camera stays where you put it")
        self.md_view = gui.add_markdown("view: 0 frames")

    def set_reference_path(self, points_nwu_m: FloatArray) -> None:
        """The whole reference path (N, 3), where the source knows it in advance."""
        pts = np.asarray(points_nwu_m, dtype=float)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if len(pts) < 2:
            return
        with self._lock:
            self.path = self._polyline("/path", _segments(pts), PATH_RGB, 2.0)

    def extend_reference_path(self, points: list[tuple[float, float, float]]) -> None:
        """A path not known in advance: the reference points as they come (redrawn with the trail)."""
        with self._lock:
            self._ref_path.extend(points)
            self._ref_path_dirty = True

    def reset_trail(self, points_nwu_m: FloatArray | None = None) -> None:
        """Forget the flown trail (a replay seeks), or set it to ``points`` (N, 3)."""
        with self._lock:
            self._trail.clear()
            if points_nwu_m is not None:
                self._trail.extend((float(p[0]), float(p[1]), float(p[2]))
                                   for p in points_nwu_m[-TRAIL_POINTS:])  # fmt: skip

    def add_trail_point(self, pos_nwu_m: tuple[float, float, float]) -> None:
        with self._lock:
            self._trail.append(pos_nwu_m)

    # -- one frame -----------------------------------------------------------------------------
    def show(self, f: ViewFrame, status: str = "") -> None:
        """Pose the scene and fill the panels for ``f`` (one push to every browser)."""
        with self._lock, self.server.atomic():
            self.body.position = f.pos_nwu_m
            self.body.wxyz = wxyz_of(f.euler_flu_rad)
            if f.flapping_rad is not None:
                self.hub.wxyz = disc_wxyz(*f.flapping_rad)
            if f.ref_nwu_m is not None:
                self.ref_point.position = f.ref_nwu_m
                self.ref_point.visible = True
            if f.wind_nwu_m_s is not None and math.hypot(*f.wind_nwu_m_s) > 1e-3:
                self.wind.points = np.array([[f.pos_nwu_m, np.add(f.pos_nwu_m, f.wind_nwu_m_s)]], np.float32)
                self.wind.visible = True
            if self.frames_pushed % TRAIL_EVERY == 0 and len(self._trail) >= 2:
                segs = _segments(np.asarray(self._trail, dtype=np.float32))
                if self.trail is None:
                    self.trail = self._polyline("/trail", segs, TRAIL_RGB, 2.5)
                else:
                    self.trail.points = segs
            if self._ref_path_dirty and self.frames_pushed % TRAIL_EVERY == 0 and len(self._ref_path) >= 2:
                segs = _segments(np.asarray(self._ref_path, dtype=np.float32))
                if self.path is None:
                    self.path = self._polyline("/path", segs, PATH_RGB, 2.0)
                else:
                    self.path.points = segs
                self._ref_path_dirty = False
            self._panels(f, status)
            if self.follow.value:
                self._follow(f.pos_nwu_m)
            self.frames_pushed += 1
            self._last = f

    def _panels(self, f: ViewFrame, status: str) -> None:
        armed = "-" if f.armed is None else ("ARMED" if f.armed else "disarmed")
        self.md_flight.content = (f"**{self.opts.title}**  \nt = {f.t_s:.2f} s  \nmode: {f.mode or '-'}  \n"
                                  f"{armed}")  # fmt: skip
        if f.err_m is not None:
            t_err = f.t_s if f.err_t_s is None else f.err_t_s
            approx = "" if f.err_exact else "≈"  # an interpolated position: frame.py
            self.md_error.content = f"tracking error: {approx}{f.err_m:.4f} m at t = {t_err:.2f} s"
        if f.pitches_rad is not None:
            for s, p in zip(self.pitch_sliders, f.pitches_rad, strict=True):
                # viser's slider handle has the setter its typing hides
                s.value = float(np.clip(round(math.degrees(p), 2), s.min, s.max))  # type: ignore[misc]
        rotor = "-" if f.rotor_speed_rad_s is None else f"{f.rotor_speed_rad_s * 30.0 / math.pi:.0f} rpm"
        flap = ""
        if f.flapping_rad is not None:
            a1, b1 = (math.degrees(v) for v in f.flapping_rad)
            flap = f"  \nflapping a1 {a1:.2f} deg, b1 {b1:.2f} deg"
        self.md_rotor.content = f"rotor: {rotor}{flap}"
        self.md_view.content = f"view: {self.frames_pushed + 1} frames{'  ' + status if status else ''}"

    def _polyline(self, name: str, segs: npt.NDArray[np.float32], rgb: tuple[int, int, int],
                  px: float) -> viser.LineSegmentsHandle:  # fmt: skip
        return self.server.scene.add_line_segments(name, segs, colors=rgb, thickness=px,
                                                   thickness_units="screen")  # fmt: skip

    def _follow(self, pos: tuple[float, float, float]) -> None:
        eye = np.add(pos, CAMERA_OFFSET_M)
        for client in self.server.get_clients().values():
            client.camera.position = eye
            client.camera.look_at = pos

    def set_initial_camera(self, pos_nwu_m: tuple[float, float, float]) -> None:
        """Where a browser that connects first looks (before the first frame follows)."""
        self.server.initial_camera.position = tuple(np.add(pos_nwu_m, CAMERA_OFFSET_M))
        self.server.initial_camera.look_at = pos_nwu_m

    def hold(self, f: ViewFrame) -> None:
        """``f`` stays up (no frame follows): a browser that connects from now on starts with
        its camera on the vehicle (the initial camera), not where the flight began."""
        if self.follow.value:
            self.set_initial_camera(f.pos_nwu_m)

    def on_connect(self) -> None:
        """A new browser: put its camera on the vehicle at once, and again when the browser
        first reports its camera (it starts from the initial camera and would otherwise stay
        there until the next frame: after the flight, none comes)."""

        def place(client: viser.ClientHandle) -> None:
            f = self._last
            if f is not None and self.follow.value:
                client.camera.position = tuple(np.add(f.pos_nwu_m, CAMERA_OFFSET_M))
                client.camera.look_at = f.pos_nwu_m

        def connected(client: viser.ClientHandle) -> None:
            placed = {"n": 0}

            @client.camera.on_update
            def _(_: object) -> None:
                if placed["n"] < 2:  # the browser's first reports; after that the user's moves
                    placed["n"] += 1
                    place(client)

            place(client)

        self.server.on_client_connect(connected)
