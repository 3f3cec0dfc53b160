"""``heli-sitl up --firmware ardupilot``: ArduPilot's helicopter firmware flies this bench's plant.

Two processes: the plant as ArduPilot's external physics (``heli-sitl run --backend
ardupilot-json``, UDP 9002 + 10 N) and ArduPilot's SITL (``arducopter-heli --model JSON``),
started with ArduPilot's own helicopter defaults, the X-Cell head
(``configs/swashplate/xcell60-h3-120.parm``) and the X-Cell's tuning
(``configs/ardupilot/xcell60.parm``). Ground stations connect where ArduPilot users expect:
TCP 5760 + 10 N (SERIAL0), e.g. ``mavproxy.py --master tcp:127.0.0.1:5760``; and SERIAL1
sends to the bench's ground-station UDP port (14550 for instance 0, as ``heli-ground`` and
QGroundControl expect: ``heli-ground fly --guided``). The firmware writes its eeprom and logs
into ``--out`` (default: a directory of its own under out/ardupilot).

``--servo-link can`` starts the firmware built with DroneCAN (``arducopter-heli-can``: the
path given, $ARDUPILOT_HELI_CAN_BIN or ../shared/ardupilot) with ``can-servos.parm`` loaded
last (its servo outputs also as DroneCAN ArrayCommand on its CAN bus 1, SITL's multicast
``mcast:0``), and the plant with ``--servo-link can``: its servos then take the bus's
commands, the JSON frame's PWMs are only cross-checked (docs/can.md, "ArduPilot on the bus").
The multicast bus is one per host (network namespace), whatever the instance: run one
CAN-linked flight per namespace.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

from heli_common.config import CONFIG_DIR
from heli_common.defaults import HOME, ports
from heli_common.wire.ardupilot_json import PACE_PORT_OFFSET
from heli_plant.ardupilot_link import port_for_instance
from heli_sitl.launch.children import Child, spawn, stop_all

ENV_BIN = "ARDUPILOT_HELI_BIN"  # where the firmware is, if not given on the command line
ENV_CAN_BIN = "ARDUPILOT_HELI_CAN_BIN"  # the same, built with DroneCAN (--servo-link can)
# this workplace keeps a build beside the repository (../shared/ardupilot, its README)
# the repository's parent: heli_sitl/launch/ardupilot.py -> launch, heli_sitl, the repository, its parent
SHARED_BIN = Path(__file__).resolve().parents[3] / "shared" / "ardupilot" / "arducopter-heli"
SHARED_CAN_BIN = SHARED_BIN.with_name("arducopter-heli-can")
ARDUPILOT_CONFIGS = CONFIG_DIR / "ardupilot"
# --servo-link can: the servo outputs also as DroneCAN ArrayCommand on CAN bus 1 = mcast:0
CAN_SERVOS_PARM = ARDUPILOT_CONFIGS / "can-servos.parm"
SERVO_LINKS = ("json", "can")


class FirmwareNotFoundError(RuntimeError):
    pass


def find_firmware(path: str | None, can: bool = False) -> Path:
    """The ``arducopter-heli`` SITL binary: ``path``, else $ARDUPILOT_HELI_BIN, else the shared
    build; a clear error naming all three when none exists. ``can``: the build with DroneCAN
    (``path``, else $ARDUPILOT_HELI_CAN_BIN, else the shared ``arducopter-heli-can``)."""
    env, shared = (ENV_CAN_BIN, SHARED_CAN_BIN) if can else (ENV_BIN, SHARED_BIN)
    for candidate in (path, os.environ.get(env), str(shared)):
        if candidate and Path(candidate).is_file() and os.access(candidate, os.X_OK):
            return Path(candidate).resolve()
    if can:
        raise FirmwareNotFoundError(
            f"--servo-link can needs arducopter-heli built with DroneCAN, and there is none: give "
            f"--ardupilot-bin PATH or set {ENV_CAN_BIN} (not found: {shared}; build it from ArduPilot's "
            "source with DroneCAN on for the SITL board: ./waf configure --board sitl && ./waf heli; "
            "docs/can.md, \"ArduPilot on the bus\")"
        )
    raise FirmwareNotFoundError(
        f"no arducopter-heli SITL binary: give --ardupilot-bin PATH or set {ENV_BIN} (build it "
        "from ArduPilot's source: ./waf configure --board sitl && ./waf heli; docs/ardupilot-json.md)"
    )


def default_parm_files(plant: str) -> list[Path]:
    """ArduPilot's heli defaults, the X-Cell head, the X-Cell tuning (for the rotor plant its
    own file where there is one), in load order: a later file overrides an earlier one."""
    tuning = ARDUPILOT_CONFIGS / ("xcell60-gavrilets.parm" if plant == "gavrilets" else "xcell60.parm")
    if not tuning.is_file():
        tuning = ARDUPILOT_CONFIGS / "xcell60.parm"
    files = [ARDUPILOT_CONFIGS / "copter-heli.parm", CONFIG_DIR / "swashplate" / "xcell60-h3-120.parm"]
    return files + ([tuning] if tuning.is_file() else [])


def can_parm_files(plant: str) -> list[Path]:
    """The parameter files of ``--servo-link can``, in load order: the defaults, then
    ``can-servos.parm`` (the plant reads SERVOn_MIN/TRIM/MAX from the same list)."""
    return [*default_parm_files(plant), CAN_SERVOS_PARM]


@dataclass(frozen=True)
class ArduPilotOptions:
    firmware: Path
    instance: int = 0
    plant: str = "paper"
    world: str | None = None
    scenario: str = "paper"
    home: str = f"{HOME.lat_deg},{HOME.lon_deg},{HOME.alt_amsl_m}"
    heading_deg: float = 0.0
    speedup: float = 1.0
    out: Path = Path("out/ardupilot")
    extra_parm: tuple[Path, ...] = ()
    wipe: bool = True  # -w: start from the parameter files, not the last run's eeprom
    servo_link: str = "json"  # json: the plant flies the JSON frame's PWMs; can: the DroneCAN bus's
    can_bus: str = "mcast:0"  # where the plant listens (the firmware's CAN bus 1 is mcast:0)
    view_port: int | None = None  # --view: SERIAL2 sends MAVLink to this UDP port (the live view's)


def commands(opts: ArduPilotOptions) -> list[tuple[str, list[str], Path | None]]:
    """(name, command, working directory) of the plant and the firmware."""
    import sys

    plant = [sys.executable, "-m", "heli_sitl.cli", "run", "--backend", "ardupilot-json",
             "--instance", str(opts.instance), "--plant", opts.plant, "--scenario", opts.scenario,
             "--home", opts.home, "--out", str(opts.out)]  # fmt: skip
    if opts.world:
        plant += ["--world", opts.world]
    if opts.servo_link not in SERVO_LINKS:
        raise ValueError(f"servo link {opts.servo_link!r} is not one of {SERVO_LINKS}")
    base = can_parm_files(opts.plant) if opts.servo_link == "can" else default_parm_files(opts.plant)
    files = [*base, *opts.extra_parm]
    if opts.servo_link == "can":
        plant += ["--servo-link", "can", "--can-bus", opts.can_bus,
                  "--ardupilot-parms", ",".join(str(p) for p in files)]  # fmt: skip
    parms = ",".join(str(p) for p in files)
    firmware = [str(opts.firmware), "--model", "JSON", "--speedup", f"{opts.speedup:g}", "--defaults", parms,
                "-I", str(opts.instance), "--home", f"{opts.home},{opts.heading_deg:g}",
                # SERIAL0 without :wait, so the physics runs before a ground station connects
                "--serial0", "tcp:0",
                # SERIAL1 to the bench's ground-station port, where heli-ground and
                # QGroundControl listen (what MAVProxy's --out 14550 gives sim_vehicle.py users)
                "--serial1", f"udpclient:127.0.0.1:{ports(opts.instance).gcs}"]  # fmt: skip
    if opts.view_port is not None:  # the live view listens there (heli_sitl/view)
        firmware += ["--serial2", f"udpclient:127.0.0.1:{opts.view_port}"]
    if opts.wipe:
        firmware.insert(1, "-w")
    fw_dir = opts.out / "firmware"
    return [("plant", plant, None), ("arducopter-heli", firmware, fw_dir)]


def start(opts: ArduPilotOptions, echo: bool = True) -> list[Child]:
    """Start the plant first (the firmware's first frame needs a listener), then the firmware
    (their stderr echoed on ours if ``echo``; always in their logs)."""
    children = []
    for name, cmd, cwd in commands(opts):
        if cwd is not None:
            cwd.mkdir(parents=True, exist_ok=True)
        children.append(spawn(cmd, name, opts.out / "logs" / f"{name}.log", echo=echo, cwd=cwd))
        if name == "plant":
            time.sleep(1.0)  # its socket is bound after the imports; a frame before is lost
    return children


def serve(opts: ArduPilotOptions, stop_after_s: float | None = None) -> None:
    """Run both until Ctrl-C (or ``stop_after_s``), then stop both."""
    children = start(opts)
    port = 5760 + 10 * opts.instance
    pace = port_for_instance(opts.instance) + PACE_PORT_OFFSET
    print(f"heli-sitl up --firmware ardupilot: ArduPilot serves ground stations on TCP 127.0.0.1:{port} "
          f"(mavproxy.py --master tcp:127.0.0.1:{port}) and sends to UDP {ports(opts.instance).gcs} "
          f"(heli-ground fly --guided FILE --pace-port {pace}); the plant's truth goes to "
          f"{opts.out}/plant.csv; Ctrl-C to stop", flush=True)  # fmt: skip
    t0 = time.monotonic()
    try:
        while stop_after_s is None or time.monotonic() - t0 < stop_after_s:
            for c in children:
                if c.proc.poll() is not None:
                    raise RuntimeError(f"{c.name} ended ({c.proc.returncode}): {c.last_error_line()}")
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        stop_all(children)
