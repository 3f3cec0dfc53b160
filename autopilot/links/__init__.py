"""The autopilot's links. ``can_servo``: the DroneCAN servo output."""
