"""CAN: python-can buses (``bus``), DroneCAN's UDP multicast bus (``mcast``, ``mcast:N``), the
DroneCAN codec with checked reassembly (``dronecan_codec``), what makes a node one the
field's tools list (``node``) and the bus monitor (``monitor``)."""
