"""The vehicle's sensors in the plant's step: IMU, GPS, attitude source, barometer (compiled)."""
