"""Missions on the vehicle: what is accepted (``checks``) and the MAVLink mission protocol
server (``server``). The items themselves, as the wire carries them, are shared with the
ground tools: :mod:`heli_common.wire.mavlink.mission_items`."""
