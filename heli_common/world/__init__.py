"""The world around the vehicle as both processes configure it: the world's settings (air, servos,
mismatch, disturbances), the sensors', the gust shape and the magnetic field."""
