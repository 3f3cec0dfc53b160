"""The vehicle as both processes know it: the airframe's parameters, the swashplate's mixing, the servos'
model, which plant flies, and the scenario's vehicle files."""
