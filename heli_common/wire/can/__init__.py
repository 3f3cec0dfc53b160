"""CAN: python-can buses (``bus``) and the DroneCAN codec with checked reassembly."""
