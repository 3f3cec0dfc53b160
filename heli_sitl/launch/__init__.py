"""The launchers: the bench's processes (plant, autopilot, ground station, ArduPilot's
firmware) started, their ports handed down, stopped."""
