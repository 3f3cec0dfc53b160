"""heli_sitl: the vehicle (airframe, rotor maps, 6-DOF model, integrator) and the plant process."""
