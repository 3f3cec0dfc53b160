"""The plant: state, held pitches, RK4 stepping, ground contact and input guards."""

from __future__ import annotations

import numpy as np

from heli_common.defaults import HOME
from heli_common.geo import GeoPoint
from heli_common.jit import njit
from heli_common.state import N_PITCH, N_STATE, FloatArray
from heli_common.vehicle.airframe import Airframe, PlantConstants
from heli_common.vehicle.plant_model import PlantModel
from heli_common.world.config import World, with_sim_param
from heli_plant import rotor
from heli_plant.sensors.sensing import Sensing
from heli_plant.vehicle import VehicleModel, build_vehicle
from heli_plant.world.model import (
    CALM_AIR,
    DIST_NONE,
    N_WP,
    N_WS,
    WP_DIST_KIND,
    WP_SERVOS_ON,
    WP_TURB_ON,
    WS_GOVERNOR_SET,
    WS_ROTOR,
    CalmArrays,
    WorldModel,
    world_plant_step,
)


@njit
def accept_pitches(u: FloatArray, lo: FloatArray, hi: FloatArray, held: FloatArray) -> bool:
    """Copy ``u`` clipped to [lo, hi] into ``held``; refuse (False, ``held`` kept) if any is
    not finite. The only gate between a command and the servos."""
    for i in range(u.shape[0]):
        if not np.isfinite(u[i]):
            return False
    for i in range(u.shape[0]):
        held[i] = min(max(u[i], lo[i]), hi[i])
    return True


@njit
def plant_step(
    t: float, x: FloatArray, u: FloatArray, c: PlantConstants, dt: float, n_sub: int, contact: bool
) -> tuple[FloatArray, bool]:
    """The paper's plant in the ideal world: :func:`world_plant_step` with every effect off
    (RK4 over one hold interval, then ground contact); returns (new state, on ground)."""
    wp = np.zeros(N_WP)
    wp[WP_DIST_KIND] = DIST_NONE
    return world_plant_step(t, x, u, c, CALM_AIR, dt, n_sub, contact, wp, np.zeros(N_WS),
                            np.zeros((N_PITCH, 1)), np.zeros(1), np.zeros(1), rotor.OFF)  # fmt: skip


class Plant:
    """Owns the 6-DOF state; ``step(dt)`` advances it with the held pitches.

    Pitches are clipped to the airframe's servo limits and a non-finite command is refused
    (the previous one is held), so nothing but a finite, in-range pitch reaches the model.
    ``world`` (off: None or a calm one) adds servos, air, mismatch and disturbances; the
    plant then flies the world's airframe, ``airframe`` being the controller's design.
    With the world's sensors on, :attr:`sensing` holds what they measured at :attr:`t_s`
    (sampled at the start and after every step of ``step_s``; GPS about ``home``).
    ``model`` (default: the paper's) chooses the plant: Gavrilets' rotor plant always runs
    in a world (calm if none is given), its rotor starting in hover trim, or stopped
    (``rotor_at_rest``: for a firmware that runs it up, :meth:`set_rotor_speed_command`).
    A ``model`` of the user's (``model.vehicle``, :mod:`heli_plant.vehicle`) is stepped by
    its own derivative, with the same guards and ground, in the ideal world.
    """

    def __init__(
        self,
        airframe: Airframe,
        x0: FloatArray,
        *,
        substeps: int = 1,
        ground_contact: bool = True,
        world: World | None = None,
        step_s: float = 0.01,
        home: GeoPoint = HOME,
        model: PlantModel | None = None,
        rotor_at_rest: bool = False,
    ) -> None:
        if substeps < 1:
            raise ValueError("substeps must be >= 1")
        self.x = np.array(x0, dtype=float)
        if self.x.shape != (N_STATE,) or not np.all(np.isfinite(self.x)):
            raise ValueError("initial state must be 12 finite numbers")
        self.design = airframe
        self.model = model if model is not None else PlantModel("paper")
        self.world_config = world if world is not None else World()
        self.world: WorldModel | None = None
        # a model of the user's (heli_plant.vehicle): stepped by its own derivative, in the
        # ideal world; a world around it is refused, not ignored
        self.vehicle: VehicleModel | None = None
        if self.model.vehicle is not None:
            if world is not None and (world.on or world.sensing):
                raise ValueError(f"plant {self.model.vehicle}: a plant of your own flies the ideal "
                                 f"world (world {world.name!r} asks for air, servos or sensors)")  # fmt: skip
            self.vehicle = build_vehicle(self.model.vehicle, airframe)
        elif self.model.rotor is not None:
            from heli_plant.trim import hover_rotor_state

            trim = hover_rotor_state(self.model, airframe)
            r0 = np.zeros(rotor.N_ROTOR) if rotor_at_rest else np.array(trim)
            self.world = WorldModel.build(self.world_config, airframe, self.x, self.model.rotor, r0)
        elif world is not None and world.on:
            self.world = WorldModel.build(world, airframe, self.x)
        self.calm = CalmArrays()
        self.airframe = airframe if self.world is None else self.world.airframe
        self.constants = self.airframe.constants()
        self.t_s = 0.0
        self.substeps = substeps
        self.ground_contact = ground_contact
        self.lo = np.array([lim[0] for lim in airframe.limits.as_tuple()])
        self.hi = np.array([lim[1] for lim in airframe.limits.as_tuple()])
        self.u = np.zeros(N_PITCH)
        self.rejected_commands = 0
        self.on_ground = False
        self.step_s = step_s
        self.home = home
        self.sensing: Sensing | None = None
        if world is not None and world.sensing:
            self._start_sensing()
        if self.world is not None:  # load the compiled world step now, not on the first step
            w = self.world
            wp = w.wp.copy()
            wp[WP_SERVOS_ON] = wp[WP_TURB_ON] = 0.0  # their arrays are built on the first step
            world_plant_step(0.0, self.x, self.u, self.constants, w.air, 1e-3, 1, False, wp,
                             w.ws.copy(), w.servo_p, w.servo_s.copy(), w.dryden, w.rotor)  # fmt: skip

    def set_pitches(self, u: FloatArray) -> bool:
        """Hold new pitches [rad]; False (and the old ones kept) if any is not finite."""
        u = np.asarray(u, dtype=float)
        if u.shape != (N_PITCH,) or not accept_pitches(u, self.lo, self.hi, self.u):
            self.rejected_commands += 1
            return False
        return True

    @property
    def rotor_design_speed_rad_s(self) -> float:
        """The main rotor's design speed (the governor's set point unless commanded)."""
        w = self.world
        return w.rotor.omega_c if w is not None and w.rotor.on else self.airframe.main_rotor.speed_rad_s

    def set_rotor_speed_command(self, omega_rad_s: float) -> bool:
        """The governor's set point [rad/s] from now on; ``<= 0`` turns the engine off (the
        governor disengaged, its integral reset) and the rotor winds down. False (nothing
        changed) on the paper's plant, whose rotor speed is a constant, or for a non-finite
        value."""
        w = self.world
        if w is None or not w.rotor.on or not np.isfinite(omega_rad_s):
            return False
        w.ws[WS_GOVERNOR_SET] = max(float(omega_rad_s), 0.0)
        if omega_rad_s <= 0.0:
            w.ws[WS_ROTOR + rotor.GOV_INT] = 0.0
        return True

    @property
    def rotor_speed_rad_s(self) -> float:
        """The main rotor's speed now (the design speed on the paper's plant)."""
        w = self.world
        if w is None or not w.rotor.on:
            return self.airframe.main_rotor.speed_rad_s
        return float(w.ws[WS_ROTOR + rotor.OMEGA_R])

    def _start_sensing(self) -> None:
        self.sensing = Sensing.build(self.world_config.sensors, self.step_s, self.constants.gravity_m_s2,
                                     self.home)  # fmt: skip
        self._sense(resting=True)  # what the autopilot measures before the first step

    def _sense(self, resting: bool) -> None:
        s, w = self.sensing, self.world
        if s is not None:
            world = None if w is None else (w.air, w.wp, w.ws)
            g = rotor.OFF if w is None else w.rotor
            s.sample(self.t_s, self.x, self.u, self.constants, resting, world, g)

    def set_sim_param(self, name: str, value: float) -> bool:
        """A live world or sensor setting (a SIM_ parameter): taken from the next step on.
        False (and nothing changed) for an unknown name or a bad value; the same value
        again is a no-op, so a sender may repeat itself."""
        if self.vehicle is not None:  # a plant of your own flies the ideal world
            return False
        try:
            new = with_sim_param(self.world_config, name, value)
        except ValueError:
            return False
        if new == self.world_config:
            return True
        if new.sensors != self.world_config.sensors:
            self.world_config = new
            self._sensors_changed()
            return True
        self.world_config = new
        limits = np.column_stack([self.lo, self.hi])
        if self.world is None:
            if new.on:  # the world switched on in flight: the airframe stays the plant's
                self.world = WorldModel.build(new, self.airframe, self.x)
        else:
            self.world.update(new, limits)
        return True

    def _sensors_changed(self) -> None:
        sensors = self.world_config.sensors
        if self.sensing is not None:
            self.sensing.update(sensors)
        elif sensors.on:  # sensors switched on in flight (a failure): they measure from now on
            self.sensing = Sensing.build(sensors, self.step_s, self.constants.gravity_m_s2, self.home)

    def step(self, dt_s: float) -> FloatArray:
        w = self.world
        if self.vehicle is not None:
            self.x, self.on_ground = self.vehicle.advance(self.t_s, self.x, self.u, dt_s, self.substeps,
                                                          self.ground_contact)  # fmt: skip
        elif w is None:
            k = self.calm
            self.x, self.on_ground = world_plant_step(
                self.t_s, self.x, self.u, self.constants, k.air, dt_s, self.substeps, self.ground_contact,
                k.wp, k.ws, k.servo_p, k.servo_s, k.dryden, rotor.OFF,
            )  # fmt: skip
        else:
            w.prepare(dt_s / self.substeps, self.u, np.column_stack([self.lo, self.hi]))
            self.x, self.on_ground = world_plant_step(
                self.t_s, self.x, self.u, self.constants, w.air, dt_s, self.substeps, self.ground_contact,
                w.wp, w.ws, w.servo_p, w.servo_s, w.dryden, w.rotor,
            )  # fmt: skip
        # on the sim link's microsecond grid: the plant's clock (and its sensors' time stamps)
        # is then exactly the in-process loop's k / rate, whatever the accumulated rounding
        self.t_s = round((self.t_s + dt_s) * 1e6) / 1e6
        self._sense(resting=self.on_ground)
        return self.x
