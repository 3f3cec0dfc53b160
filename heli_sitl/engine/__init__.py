"""The simulation engine: the compiled in-process loop, its linearisation, the in-process CAN
loop, and a flight record from ArduPilot's files."""
