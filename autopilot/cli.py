"""heli-autopilot: the TLC autopilot process (sim link to the plant; GCS link to ground stations)."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
import time
from pathlib import Path

import numpy as np

from autopilot.controller_names import CONTROLLER_HELP
from autopilot.controllers import FlyingController, build_controller, controller_arg
from autopilot.estimation.config import EstimatorConfig
from autopilot.flight.commands import Arm, FlyTrajectory
from autopilot.flight.manager import FlightConfig, FlightManager
from autopilot.flight_log import write_flight_tlog
from autopilot.links.mavlink_gcs import GcsConfig, GcsService
from autopilot.links.mavlink_sim import SimLink
from autopilot.links.world_sync import WorldSync
from autopilot.params_table import ParamTable
from autopilot.pid.controller import PIDController
from autopilot.pid.gains import PidGains, default_pid_gains
from autopilot.runner import Recorder, Runner, RunnerConfig, TickService
from autopilot.scenario import Scenario
from autopilot.tlc.controller import TLController
from heli_common import cli_args as arg
from heli_common.defaults import HOME, Exit, ports
from heli_common.geo import parse_geo_point
from heli_common.process import UsageError, run_main, stop_on_signals
from heli_common.rt_priority import add_rt_priority_arg, check_rt_priority, rt_priority_loop
from heli_common.wire.links import ServoOutput
from heli_common.wire.mavlink.udp import LOOPBACK
from heli_common.wire.mavlink.wire import read_signing_key
from heli_common.wire.servo_link import add_servo_args, load_servo_link, servo_map_for, with_overrides
from heli_common.wire.servo_map import ServoMap, limits_array
from heli_common.world.config import World

log = logging.getLogger("autopilot")
PORTS = ports()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="heli-autopilot", description=__doc__)
    p.add_argument("--mode", choices=("lockstep", "realtime"), default="realtime")
    p.add_argument("--scenario", default="paper", help="airframe, gains and trajectory source")
    p.add_argument("--gains", default=None, metavar="FILE",
                   help="the gain set instead of the scenario's (gains_servo_aware.toml for real servos)")
    p.add_argument("--rate-hz", type=arg.control_rate_hz, default=None, help="control rate (50-1000 Hz)")
    p.add_argument("--feedforward", choices=("pseudo", "exact"), default=None)
    p.add_argument("--duration-s", type=arg.positive, default=None, help="stop after this flight time")
    p.add_argument("--port", type=arg.bind_port, default=None, help="sim link: UDP port to bind")
    p.add_argument("--plant-port", type=arg.port, default=None, help="sim link: the plant's UDP port")
    p.add_argument("--stale-timeout-s", type=arg.positive, default=0.5)
    add_rt_priority_arg(p)
    p.add_argument(
        "--autostart", action="store_true", help="arm and fly the scenario trajectory at once"
    )
    p.add_argument("--out", default=None, help="write run.csv, summary.json, flight.tlog here")
    p.add_argument("--summary-end-s", type=arg.positive, default=None,
                   help="error windows end here (flight time since arming)")
    s = p.add_argument_group("servo link")
    add_servo_args(s)
    s.add_argument("--can-node-id", type=arg.in_range(1, 127, int), default=None, help="DroneCAN node id")
    g = p.add_argument_group(f"GCS link (ground stations on {PORTS.gcs}, API clients on {PORTS.api})")
    g.add_argument("--no-gcs", action="store_true", help="no ground-station link")
    g.add_argument("--world", default=None, metavar="FILE|PRESET",
                   help="the world the plant flies (configs/world/ presets): its SIM_ parameters' "
                        "starting values; give the plant the same --world")
    p.add_argument("--controller", type=controller_arg, default="tlc", metavar="NAME", help=CONTROLLER_HELP)
    p.add_argument("--pid-gains", default=None, metavar="FILE", help="PID gains (TOML) for --controller pid")
    p.add_argument("--estimator", default=None, metavar="FILE",
                   help="estimator tuning (TOML, docs/estimator.md), used when the plant sends "
                        "measurements (a world with [sensors]); default: the documented defaults")
    g.add_argument("--gcs-port", type=arg.port, default=None, help=f"default {PORTS.gcs} + 10 N")
    g.add_argument("--api-port", type=arg.port, default=None, help=f"default {PORTS.api} + 10 N")
    g.add_argument("--local-gcs-port", type=arg.bind_port, default=None,
                   help=f"our end of the GCS link (default {PORTS.local_gcs} + 10 N)")
    g.add_argument("--local-api-port", type=arg.bind_port, default=None,
                   help=f"our end of the API link (default {PORTS.local_api} + 10 N)")
    arg.add_instance_args(g)
    g.add_argument("--home", default=f"{HOME.lat_deg},{HOME.lon_deg},{HOME.alt_amsl_m}",
                   help="home latitude,longitude [deg],altitude AMSL [m]")
    g.add_argument("--signing-key", default=None,
                   help="file with a 32-byte MAVLink 2 signing key (raw or 64 hex digits)")
    p.add_argument("-v", "--verbose", action="store_true")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="heli-autopilot: %(levelname)s %(message)s",
    )
    stop = threading.Event()
    stop_on_signals(stop)
    return run_main("heli-autopilot", lambda: run(args, stop))


def apply_params(ctrl: FlyingController, manager: FlightManager, table: ParamTable) -> None:
    """Between two control steps: new gains (the TLC_ set or the PID_ set, whichever flies),
    pitch limits (integrals and filters kept) and failsafe timeouts."""
    if isinstance(ctrl, TLController):
        ctrl.set_gains(table.gains())
    elif isinstance(ctrl, PIDController):
        ctrl.set_gains(table.pid_gains())
    ctrl.set_limits(table.pitch_limits())
    manager.offboard_timeout_s = table.failsafe().offboard_timeout_s


def make_gcs(
    args: argparse.Namespace, sc: Scenario, ctrl: FlyingController, manager: FlightManager,
    limits: np.ndarray,
    world: World | None = None,
    pid_gains: PidGains | None = None,
    servo_channels: ServoMap | None = None,
) -> GcsService:
    home = manager.cfg.home
    cfg = GcsConfig(
        gcs_port=args.gcs_port, api_port=args.api_port, local_gcs_port=args.local_gcs_port,
        local_api_port=args.local_api_port, home=home,
        signing_key=read_signing_key(args.signing_key) if args.signing_key else None,
        system_id=args.sysid,
    )  # fmt: skip
    table = ParamTable(sc.gains, sc.airframe.limits, ctrl.rate_hz, home=home, system_id=args.sysid,
                       world=world, pid_gains=pid_gains)  # fmt: skip
    return GcsService(cfg, table, lambda t: apply_params(ctrl, manager, t), limits, manager=manager,
                      servo_channels=servo_channels)


AUTOPILOT_PORTS = {"port": "autopilot", "plant_port": "plant", "gcs_port": "gcs", "api_port": "api",
                   "local_gcs_port": "local_gcs", "local_api_port": "local_api"}  # fmt: skip


def run(args: argparse.Namespace, stop: threading.Event) -> int:
    arg.resolve_instance(args, AUTOPILOT_PORTS)
    if args.port == args.plant_port:  # it would only hear its own commands
        raise UsageError(f"--port and --plant-port must differ (both {args.port})")
    check_rt_priority(args.rt_priority, args.mode)
    sc = Scenario.load(args.scenario, gains=args.gains)
    world = World.load(args.world) if args.world else None  # refused before anything starts
    estimator = EstimatorConfig.load(args.estimator) if args.estimator else None
    rate = args.rate_hz or sc.run.rate_hz
    pid_gains = PidGains.load(args.pid_gains) if args.pid_gains else default_pid_gains()
    ff = args.feedforward or sc.run.feedforward
    ctrl = build_controller(args.controller, sc.airframe, sc.gains, rate, ff, pid_gains)
    limits = limits_array(sc.airframe.limits.as_tuple())
    manager = FlightManager(FlightConfig(home=parse_geo_point(args.home, '--home')))
    if args.autostart:
        for cmd in (FlyTrajectory(sc.trajectory), Arm()):
            reply = manager.execute(cmd, 0.0, np.zeros(12))
            assert reply.accepted, reply
    duration = args.duration_s if args.duration_s is not None else (
        sc.run.duration_s if args.autostart else None
    )
    cfg = RunnerConfig(args.mode, rate, duration, args.stale_timeout_s)
    out = Path(args.out) if args.out else None
    # flushed in small pieces (20 a second): each costs a fraction of a period
    recorder = Recorder(stream_csv=out / "run.csv", flush_every=max(5, round(rate / 20))) if out else None
    t0_unix_us = int(time.time() * 1e6)
    servo = with_overrides(load_servo_link(args.links), args.servo_link, args.can_bus, args.actuator_ids)
    servos = servo_map_for(args.ccpm, servo.link, limits)  # the channels: pitches, or CCPM servos
    ccpm = servos if not isinstance(servos, np.ndarray) else None
    gcs = None if args.no_gcs else make_gcs(args, sc, ctrl, manager, limits, world, pid_gains, ccpm)
    can = None
    can_out: ServoOutput | None = None
    if servo.link == "can":  # imported here: python-can and dronecan's DSDL cost 0.3 s to load
        from autopilot.links.can_servo import CanServoOutput, CanServoSender

        can = CanServoSender(servo.can_bus, node_id=args.can_node_id or servo.node_id,
                             actuator_ids=servo.actuator_ids)  # fmt: skip
        can_out = CanServoOutput(can)
    try:
        with SimLink((LOOPBACK, args.port), (LOOPBACK, args.plant_port), servos, manager.cfg.home) as sim:
            servo_out: ServoOutput = can_out if can_out is not None else sim
            services: list[TickService] = [gcs, WorldSync(gcs.params, sim.udp)] if gcs else []
            runner = Runner(ctrl, manager, sim, servo_out, cfg, services, recorder, estimator)
            if gcs is not None:
                gcs.truth = lambda: runner.sample
                gcs.nav = lambda: runner.nav
            with rt_priority_loop(args.rt_priority, args.mode, log) as scheduling:
                stats = runner.run(stop)
            link = sim.udp.stats.as_dict()
            asm = sim.assembler
            link.update(out_of_order=asm.out_of_order, time_jumps=asm.time_jumps,
                        implausible=asm.implausible, resyncs=asm.resyncs, plant_sessions=asm.session)
    finally:
        if gcs is not None:
            gcs.close()
        if can is not None:
            can.close()
    if out and recorder is not None:
        out.mkdir(parents=True, exist_ok=True)
        record = recorder.record(runner.wall_s, {
            "scenario": sc.run.name if manager.flew_duration(sc.run.duration_s) else None,
            "error_windows_s": ([list(w) for w in sc.run.error_windows_s]
                                if manager.flew_duration(sc.run.duration_s) else []),
            "mode": args.mode, "rate_hz": rate,
            "feedforward": ctrl.feedforward.value if isinstance(ctrl, TLController) else None,
            "gains": ctrl.gains.name, "controller": ctrl.kind if ctrl.kind != "user" else args.controller,
            "summary_end_s": args.summary_end_s,
            "loop": stats.summary(), "scheduling": scheduling, "sim_link": link,
            "gcs_link": gcs.stats() if gcs is not None else None,
            "servo_link": servo.link, "can": dict(can.stats) if can is not None else None,
        })  # fmt: skip
        recorder.close()
        record.write_csv(out / "run.csv")  # the whole flight again, at once
        record.write_world_csv(out / "world.csv")
        record.write_est_csv(out / "est.csv")
        if record.t_s.size:
            write_flight_tlog(out / "flight.tlog", record, limits, t0_unix_us)
        summary = record.write_summary(out / "summary.json")
        log.info("summary: %s", json.dumps(summary))
    failed = runner.verdict()
    if failed is not None:  # what was recorded is on disk; the status says it was no flight
        log.error("%s", failed)
        return Exit.FAILURE
    return Exit.OK


if __name__ == "__main__":
    sys.exit(main())
