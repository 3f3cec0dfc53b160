"""The plant's links. ``can_bus``: python-can buses; ``dronecan_codec``: DroneCAN encoding
and checked reassembly, shared with the autopilot; ``can_servo``: the CAN servo input."""
