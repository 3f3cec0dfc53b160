"""heli-sitl demo: plant and autopilot as separate OS processes on loopback, flying a scenario.

Every process started here is stopped on success, error or Ctrl-C; a failure exits
non-zero with a one-line reason (busy port, a process died, timeout).
"""

from __future__ import annotations

import json
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from heli_common.defaults import ports
from heli_common.port_handoff import HeldPorts
from heli_common.vehicle.scenario_file import load_vehicle
from heli_common.world.config import World
from heli_sitl.launch.children import Child, describe_exit, spawn, stop_all

PORTS = ports()


class DemoError(RuntimeError):
    """One-line reason the demo failed."""


@dataclass(frozen=True)
class DemoOptions:
    mode: str = "lockstep"
    rate_hz: float = 100.0
    scenario: str = "paper"
    out: Path = Path("out/demo")
    duration_s: float | None = None
    plant_port: int = 0  # 0: pick free ports
    autopilot_port: int = 0
    timeout_s: float | None = None  # whole-demo wall-clock limit
    # fly through the ground script (a third process: upload, arm, fly, land) instead of
    # an autopilot that starts the scenario by itself
    via_ground: bool = True
    servo_link: str | None = None  # None: configs/links.toml
    can_bus: str | None = None
    world: str | None = None  # a world file or preset name (the plant's)
    extra_plant_args: tuple[str, ...] = ()
    extra_autopilot_args: tuple[str, ...] = ()
    rt_priority: int = 0  # real time: both loops under SCHED_FIFO at this priority (0: off)


def _cmd(module: str) -> list[str]:
    return [sys.executable, "-m", module]


def run_demo(opts: DemoOptions) -> dict[str, object]:
    opts.out.mkdir(parents=True, exist_ok=True)
    with HeldPorts() as held:  # bound here, handed to the children: never probed and freed
        return _run_demo(opts, held)


def _run_demo(opts: DemoOptions, held: HeldPorts) -> dict[str, object]:
    pp = opts.plant_port or held.new()
    ap = opts.autopilot_port or held.new()
    common = ["--mode", opts.mode, "--rate-hz", str(opts.rate_hz), "--scenario", opts.scenario]
    if opts.servo_link:
        common += ["--servo-link", opts.servo_link]
    if opts.can_bus:
        common += ["--can-bus", opts.can_bus]
    if opts.duration_s is not None and not opts.via_ground:
        common += ["--duration-s", str(opts.duration_s)]
    common += rt_args(opts.rt_priority)
    plant_cmd = _cmd("heli_sitl.cli") + ["run", *common, "--port", str(pp),
                                         "--autopilot-port", str(ap), *opts.extra_plant_args]
    if opts.world:  # the plant flies it; the autopilot serves its SIM_ parameters
        plant_cmd += ["--world", opts.world]
    ground_cmd: list[str] | None = None
    gcs_port, local_gcs, local_api = held.new(), held.new(), held.new()
    if opts.via_ground:
        plant_cmd.append("--hold-until-armed")  # in the air, held until the ground arms
        ground_cmd = _cmd("ground.cli") + [
            "fly", str(scenario_file(opts.scenario)), "--gcs-port", str(gcs_port),
            "--tlog", str(opts.out / "ground.tlog"), "--quiet", "--connect-timeout-s", "120",
        ]  # fmt: skip
    # the GCS link binds free local ports; it still sends to 14550/14540, so a running
    # QGroundControl shows the demo flight
    ap_cmd = _cmd("autopilot.cli") + [*common, "--port", str(ap), "--plant-port", str(pp),
                                      "--local-gcs-port", str(local_gcs),
                                      "--local-api-port", str(local_api),
                                      "--out", str(opts.out),
                                      *opts.extra_autopilot_args]  # fmt: skip
    if opts.world:
        ap_cmd += ["--world", opts.world]
    if opts.via_ground:
        ap_cmd += ["--gcs-port", str(gcs_port), "--summary-end-s",
                   str(opts.duration_s or scenario_duration_s(opts.scenario))]  # fmt: skip
    else:
        ap_cmd += ["--autostart"]
    procs: list[tuple[str, Child]] = []
    try:
        for name, cmd, own in (("plant", plant_cmd, (pp,)), ("autopilot", ap_cmd, (ap, local_gcs, local_api)),
                               ("ground", ground_cmd, (gcs_port,))):  # fmt: skip
            if cmd is not None:
                procs.append((name, spawn(cmd, name, opts.out / "logs" / f"{name}.log", echo=True,
                                          handoff=(held, own))))  # fmt: skip
        held.close()  # each child has its sockets now
        limit = opts.timeout_s or (600.0 if opts.mode == "lockstep" else 400.0)
        deadline = time.monotonic() + limit
        # the flight is over when the ground script has landed (or the autopilot is done)
        leader = procs[2][1] if opts.via_ground else procs[1][1]
        while leader.poll() is None:
            for name, p in procs:
                if p.poll() is not None and p.returncode != 0:
                    raise DemoError(f"{name} died ({describe_exit(p.returncode)}): {p.last_error_line()}")
            if time.monotonic() > deadline:
                raise DemoError(f"timeout: the flight did not finish within {limit:.0f} s")
            time.sleep(0.05)
        if leader.returncode != 0:
            who = "ground script" if opts.via_ground else "autopilot"
            raise DemoError(f"{who} failed ({describe_exit(leader.returncode)}): {leader.last_error_line()}")
        if opts.via_ground:  # the autopilot writes its record when told to stop
            autopilot = procs[1][1]
            autopilot.send_signal(signal.SIGTERM)
            if autopilot.wait(timeout=120) != 0:
                raise DemoError(f"autopilot failed ({describe_exit(autopilot.returncode)}): "
                                f"{autopilot.last_error_line()}")
    finally:
        stop_all([p for _, p in procs])
    summary_path = opts.out / "summary.json"
    if not summary_path.is_file():
        raise DemoError("autopilot wrote no summary.json")
    summary: dict[str, object] = json.loads(summary_path.read_text())
    if opts.world:  # the world is the plant's: the autopilot's summary does not know it
        summary["world"] = World.load(opts.world).describe(load_vehicle(opts.scenario)[0])
        summary_path.write_text(json.dumps(summary, indent=2) + "\n")
    return summary


@dataclass(frozen=True)
class UpOptions:
    mode: str = "realtime"
    rate_hz: float = 100.0
    scenario: str = "paper"
    in_air: bool = False
    gcs_port: int = PORTS.gcs
    api_port: int = PORTS.api
    local_gcs_port: int = PORTS.local_gcs
    local_api_port: int = PORTS.local_api
    signing_key: str | None = None
    out: str | None = None
    plant_port: int = 0
    autopilot_port: int = 0
    sysid: int = 1
    world: str | None = None
    extra_autopilot_args: tuple[str, ...] = ()  # e.g. the controller: ("--controller", "pid")
    plant: str = "paper"  # the plant model (--plant)
    ccpm: str | None = None  # a swashplate file: CCPM servo channels (heli_common.wire.servo_map)
    rt_priority: int = 0  # real time: both loops under SCHED_FIFO at this priority (0: off)
    # --view: api_port is the live view's, which relays the API link on to this port
    view_relays_api_to: int | None = None


def up_commands(opts: UpOptions, held: HeldPorts) -> list[tuple[str, list[str], tuple[int, ...]]]:
    """The plant's and the autopilot's command lines, each with the ports ``held`` binds for
    it (the sim link's, where ``opts`` leaves them 0)."""
    pp = opts.plant_port or held.new()
    ap = opts.autopilot_port or held.new()
    # realtime: the plant integrates at twice the control rate, so every tick sees a fresh state
    plant_rate = opts.rate_hz * (2 if opts.mode == "realtime" else 1)
    plant = _cmd("heli_sitl.cli") + [
        "run", "--mode", opts.mode, "--rate-hz", str(plant_rate), "--scenario", opts.scenario,
        "--port", str(pp), "--autopilot-port", str(ap), "--timeout-s", "2",
    ] + rt_args(opts.rt_priority) + (["--hold-until-armed"] if opts.in_air else ["--on-ground"]) + (
        ["--world", opts.world] if opts.world else []
    ) + ["--plant", opts.plant] + ccpm_args(opts.ccpm)  # fmt: skip
    autopilot = _cmd("autopilot.cli") + [
        "--mode", opts.mode, "--rate-hz", str(opts.rate_hz), "--scenario", opts.scenario,
        "--port", str(ap), "--plant-port", str(pp),
        "--gcs-port", str(opts.gcs_port), "--api-port", str(opts.api_port),
        "--local-gcs-port", str(opts.local_gcs_port), "--local-api-port", str(opts.local_api_port),
        "--sysid", str(opts.sysid),
    ] + rt_args(opts.rt_priority) + (["--world", opts.world] if opts.world else []) + (
        ["--signing-key", opts.signing_key] if opts.signing_key else []) + (
        ["--out", opts.out] if opts.out else []
    ) + list(opts.extra_autopilot_args) + ccpm_args(opts.ccpm)  # fmt: skip
    return [("plant", plant, (pp,)), ("autopilot", autopilot, (ap,))]


def rt_args(rt_priority: int) -> list[str]:
    """Both real-time loops get the same scheduling request."""
    return ["--rt-priority", str(rt_priority)] if rt_priority else []


def ccpm_args(ccpm: str | None) -> list[str]:
    """Both processes get the same swashplate (the autopilot mixes, the plant reads back)."""
    return [] if ccpm is None else ["--ccpm", ccpm]


def serve(opts: UpOptions, stop_after_s: float | None = None) -> None:
    """Start plant and autopilot and keep them serving until Ctrl-C (or ``stop_after_s``)."""
    logs = Path(opts.out) / "logs" if opts.out else None
    with HeldPorts() as held:  # the children's own copies outlive ours
        procs = [(name, spawn(cmd, name, logs / f"{name}.log" if logs else None, echo=True,
                              handoff=(held, own)))
                 for name, cmd, own in up_commands(opts, held)]  # fmt: skip
    api = opts.api_port if opts.view_relays_api_to is None else opts.view_relays_api_to
    print(
        f"heli-sitl up: the vehicle sends to UDP 127.0.0.1:{opts.gcs_port} (ground stations) from "
        f":{opts.local_gcs_port} and to :{api} (API clients"
        f"{'' if opts.view_relays_api_to is None else ', through the view'}) from :{opts.local_api_port}; "
        "Ctrl-C to stop",
        flush=True,
    )
    t0 = time.monotonic()
    try:
        while stop_after_s is None or time.monotonic() - t0 < stop_after_s:
            for name, p in procs:
                if p.poll() is not None:
                    raise DemoError(f"{name} died ({describe_exit(p.returncode)}): {p.last_error_line()}")
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        stop_all([p for _, p in procs])
    for name, p in procs:  # on our SIGTERM a child exits 0 (or dies of it while starting up)
        if p.returncode not in (0, -signal.SIGTERM):
            raise DemoError(f"{name} failed ({describe_exit(p.returncode)}): {p.last_error_line()}")
    print(f"heli-sitl up: stopped; {_written(opts.out)}", flush=True)


def _written(out: str | Path | None) -> str:
    """What a stopped ``up`` leaves behind, said in one line."""
    if not out:
        return "nothing written (--out DIR keeps the flight's record and the processes' logs)"
    d = Path(out)
    files = sorted(p.name + ("/" if p.is_dir() else "") for p in d.iterdir()) if d.is_dir() else []
    return f"wrote {out}: {', '.join(files)}" if files else f"nothing in {out}"


def scenario_file(name_or_path: str) -> Path:
    from heli_common.config import resolve
    from heli_common.vehicle.scenario_file import scenario_path

    return resolve(scenario_path(name_or_path)).resolve()


def scenario_duration_s(name_or_path: str) -> float:
    from heli_common.config import read_toml

    _, table = read_toml(scenario_file(name_or_path))
    return float(table["run"]["duration_s"])
