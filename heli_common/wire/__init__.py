"""What crosses a link between the bench's processes and to the field's tools: MAVLink (the
sim link, the ground station's messages), DroneCAN, ArduPilot's JSON, the sensors' and the
servos' wire formats."""
