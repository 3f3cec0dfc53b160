"""heli_common: what every layer shares. Named state and frames, the airframe's parameters and
rotor maps (the plant's model and the controller's design model use the same ones), TOML
configs, the compiled-code helper, and the wire formats: MAVLink (UDP link, sim-link codec,
mission items) and CAN (bus, DroneCAN codec). It imports nothing of the project above it."""

from heli_common.threads import one_blas_thread

one_blas_thread()  # before anything loads numpy: see heli_common/threads.py
