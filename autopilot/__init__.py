"""autopilot: the TLC (pure, no I/O, no clock), trajectories, the fixed-rate runner, and links."""
