"""Which servo link closes the loop: MAVLink HIL_ACTUATOR_CONTROLS or DroneCAN on python-can.

Loaded from ``configs/links.toml`` ``[servo]`` (both processes read the same file, so they
agree), each value overridable on the command line.
"""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass
from pathlib import Path

from heli_common.config import ConfigError, build, read_toml, spec
from heli_common.state import FloatArray
from heli_common.vehicle.swashplate import Swashplate
from heli_common.wire.servo_map import CcpmMap, ServoMap

DEFAULT_SWASHPLATE = "swashplate/xcell60-h3-120.toml"


@dataclass(frozen=True)
class ServoLinkConfig:
    link: str = spec(choices=("mavlink", "can"), default="mavlink")
    # bus spec: "mcast[:N]" (DroneCAN's UDP multicast, bus N: what ArduPilot SITL, AP_Periph,
    # libcanard and pydronecan / the DroneCAN GUI tool speak), "virtual[:channel]",
    # "udp_multicast[:group[:port]]" (python-can's), "socketcan[:iface]"
    can_bus: str = spec(default="mcast:0")
    node_id: int = spec("", 1, 127, default=10)  # the autopilot's DroneCAN node id
    actuator_ids: tuple[int, int, int, int] = spec("", 0, 255, default=(1, 2, 3, 4))
    timeout_s: float = spec("s", 0.01, 10.0, lo_open=True, default=0.5)  # plant: silent bus

    def __post_init__(self) -> None:
        if len(set(self.actuator_ids)) != 4:
            raise ValueError(f"actuator_ids must be 4 distinct ids, got {self.actuator_ids}")


def add_servo_args(p: argparse._ActionsContainer) -> None:
    """The servo-link options both processes take (they override configs/links.toml)."""
    p.add_argument("--links", default="links.toml", help="links config (configs/links.toml)")
    p.add_argument("--servo-link", choices=("mavlink", "can"), default=None,
                   help="servo commands over MAVLink or DroneCAN (default: links config)")
    p.add_argument("--can-bus", default=None,
                   help="CAN bus: mcast[:N] (DroneCAN's UDP multicast, the field's tools; default mcast:0), "
                        "virtual[:ch], udp_multicast[:group[:port]], socketcan[:iface]")
    p.add_argument("--actuator-ids", default=None, help="DroneCAN actuator ids, e.g. 1,2,3,4")
    p.add_argument("--ccpm", nargs="?", const=DEFAULT_SWASHPLATE, default=None, metavar="SWASHPLATE",
                   help="CCPM: the MAVLink servo channels are the head's swash servos 1-3 and the tail "
                        f"servo, mixed and read through SWASHPLATE (default {DEFAULT_SWASHPLATE}); give "
                        "it to both processes")


def servo_map_for(ccpm: str | None, link: str, limits: FloatArray) -> FloatArray | ServoMap:
    """The servo channels' meaning: the airframe's limits (one channel per blade pitch), or
    CCPM through a swashplate file (docs/swashplate.md); ConfigError for CCPM over DroneCAN
    (its actuator commands carry blade pitches)."""
    if ccpm is None:
        return limits
    if link != "mavlink":
        raise ConfigError("--ccpm: the swashplate's servos travel on the MAVLink sim link only; DroneCAN's "
                          "actuator commands carry blade pitches (--servo-link mavlink)")
    return CcpmMap(Swashplate.load(ccpm))


def load_servo_link(path: str | Path = "links.toml") -> ServoLinkConfig:
    p, table = read_toml(path)
    servo = table.get("servo", {})
    if not isinstance(servo, dict):
        raise ConfigError(f"{p}: [servo] must be a table")
    return build(ServoLinkConfig, servo, f"{p}: servo")


def with_overrides(
    cfg: ServoLinkConfig, link: str | None, can_bus: str | None, actuator_ids: str | None
) -> ServoLinkConfig:
    """Command-line values win over the file (``actuator_ids`` as "1,2,3,4")."""
    ids = cfg.actuator_ids
    if actuator_ids:
        try:
            a, b, c, d = (int(v) for v in actuator_ids.split(","))
        except ValueError as exc:
            raise ConfigError(f"--actuator-ids {actuator_ids!r}: expected 4 integers") from exc
        ids = (a, b, c, d)
    return dataclasses.replace(cfg, link=link or cfg.link, can_bus=can_bus or cfg.can_bus, actuator_ids=ids)
