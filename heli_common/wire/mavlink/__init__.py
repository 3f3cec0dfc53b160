"""MAVLink on loopback UDP: the link (``udp``), the sim link's fast codec (``fast``) and
its datagram layout (``sim_protocol``)."""
