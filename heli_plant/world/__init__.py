"""The world around the vehicle: air, wind, servos (compiled)."""
