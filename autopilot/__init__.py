"""autopilot: the TLC (pure, no I/O, no clock), trajectories, the fixed-rate runner, and links."""

import heli_common  # noqa: F401  (first: one BLAS thread, before numpy loads)
