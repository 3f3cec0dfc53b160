"""The estimator as the autopilot runs it: the vehicle's measurements in, a state out.

The component beside the controller: the runner hands it what the sim link delivered (the
measurement layout of :mod:`heli_common.wire.measurements`, a mask of what is new, the sensors'
time) and flies on what it returns. It calls the same compiled tick as the in-process loop
(:func:`~autopilot.estimation.nav.nav_tick`), so a lockstep flight and an in-process one
see the same estimates. It keeps the estimator's log for est.csv and reports its health.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from autopilot.estimation.config import EstimatorConfig
from autopilot.estimation.log import N_EST_LOG
from autopilot.estimation.nav import (
    NavStatus,
    make_nav_params,
    nav_health,
    nav_init,
    nav_log,
    nav_state_size,
    nav_status,
    nav_tick,
)
from heli_common.geo import GeoPoint
from heli_common.state import N_STATE, FloatArray
from heli_common.wire.measurements import N_OUT, OUT_ACCEL


class NavHealth(NamedTuple):
    """What the flight manager's failsafes read."""

    gps_lost: bool
    time_since_fix_s: float
    n_rejected: int
    n_resets: int
    last_nis: float
    diverged: bool = False


class OnboardEstimator:
    """One :meth:`update` per control tick; a measurement whose time did not advance (a
    re-sent datagram, a held vehicle) changes nothing."""

    def __init__(
        self, config: EstimatorConfig, rate_hz: float, x0: FloatArray, home: GeoPoint | None = None
    ) -> None:
        self.config = config
        self.params = make_nav_params(config, rate_hz, home)
        self.state = np.zeros(nav_state_size(self.params))
        x = np.asarray(x0, dtype=float)
        if x.shape != (N_STATE,) or not np.all(np.isfinite(x)):
            raise ValueError(f"x0 must be a finite ({N_STATE},) state")
        nav_init(self.params, self.state, x)
        self.x_hat = x.copy()
        self.log_row = np.full(N_EST_LOG, math.nan)
        self.meas = np.full(N_OUT, math.nan)  # the sensors' latest samples (the receiver's status)
        self._t_s = -math.inf

    def warm_up(self) -> None:
        """Load the compiled tick (numba loads code on a first call) on throwaway copies."""
        meas = np.zeros(N_OUT)
        meas[OUT_ACCEL + 2] = self.config.gravity_m_s2
        st, row = self.state.copy(), np.zeros(N_EST_LOG)
        for t in (0.0, 0.01):
            nav_log(self.params, st, nav_tick(self.params, st, t, meas, 0, np.zeros(N_STATE)), row)

    def update(self, t_s: float, meas: FloatArray, mask: int) -> FloatArray:
        """The estimate after this tick's measurements (valid at ``t_s``, the sensors' time);
        the previous one if ``t_s`` did not advance."""
        if t_s > self._t_s:
            self._t_s = t_s
            self.meas = meas
            gps = nav_tick(self.params, self.state, t_s, meas, mask, self.x_hat)
            nav_log(self.params, self.state, gps, self.log_row)
        return self.x_hat

    @property
    def health(self) -> NavHealth:
        return NavHealth(*nav_health(self.params, self.state))

    @property
    def status(self) -> NavStatus:
        return nav_status(self.params, self.state)

    @property
    def t_s(self) -> float:
        """The sensors' time of the last update (-inf before the first)."""
        return self._t_s
