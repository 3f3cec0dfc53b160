"""heli_sitl: the helicopter SITL. ``plant/`` is the vehicle's physics and the plant process;
the modules here compose the layers: the ``heli-sitl`` command, the in-process closed loop,
the launchers that start plant, autopilot and ground script as processes."""
