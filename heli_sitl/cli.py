"""heli-sitl: simulate in-process, or run the plant process (and the demo that starts them all).

The vehicle modules never import ``autopilot``; this entry point is the one place that
composes the vehicle with the controller for the in-process ``simulate`` command.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from heli_common import cli_args as arg
from heli_common.config import ConfigError
from heli_common.defaults import HOME, Exit, ports
from heli_common.geo import parse_geo_point
from heli_common.process import UsageError, run_main, stop_on_signals
from heli_common.rt_priority import add_rt_priority_arg, check_rt_priority, rt_priority_loop
from heli_common.vehicle.plant_model import PLANT_HELP
from heli_common.wire.servo_link import add_servo_args, servo_map_for
from heli_common.wire.servo_map import limits_array
from heli_common.world.config import World

if TYPE_CHECKING:
    from autopilot.flight_metrics import FlightMetrics
    from autopilot.pid.gains import PidGains
    from autopilot.scenario import Scenario
    from heli_common.wire.links import ServoInput
    from heli_sitl.launch.children import Child
    from heli_sitl.view.live import LiveView

GAINS_HELP = ("the controller's gain set instead of the scenario's (configs/: gains_paper.toml, "
              "gains_servo_aware.toml for real servos, see docs/servo-aware-gains.md)")
WORLD_HELP = ("the world around the vehicle: a TOML file or a preset of configs/world/ (calm, breezy, "
              "gusty, servos-default, sloppy-servos, heavy-10pct, everything); default: the paper's "
              "ideal world (no air, ideal servos, the design airframe)")

PORTS = ports()


def _simulate(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from autopilot.estimation.config import EstimatorConfig
    from autopilot.pid.gains import PidGains
    from autopilot.scenario import Scenario
    from autopilot.user_controller import is_user_spec, user_traceback
    from ground.plots import plot_attitude_estimate, plot_estimate, plot_figures, plot_rotor, plot_world
    from heli_common.vehicle.plant_model import PlantModel
    from heli_sitl.engine.closed_loop import SimOptions, simulate

    scenario = Scenario.load(args.scenario, gains=args.gains)
    if args.trajectory:  # flown from its first point, as hs.simulate(trajectory=...) flies it
        from autopilot.trajectory.csv_table import trajectory_from_csv

        traj = trajectory_from_csv(args.trajectory)
        scenario = scenario.flying(traj)
        if args.duration_s is None:
            args.duration_s = traj.duration_s
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    opts = SimOptions(
        rate_hz=args.rate_hz,
        feedforward=args.feedforward,
        plant_substeps=args.plant_substeps,
        duration_s=args.duration_s,
        world=World.load(args.world) if args.world else None,
        estimator=EstimatorConfig.load(args.estimator) if args.estimator else EstimatorConfig(),
        controller=args.controller,
        pid_gains=PidGains.load(args.pid_gains) if args.pid_gains else None,
        plant=PlantModel.load(args.plant),
    )
    with tqdm(
        total=100, desc=f"simulate {scenario.run.name}", unit="%",
        disable=True if args.quiet else None,  # None: off where not a terminal (a log)
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}",
    ) as bar:  # fmt: skip
        def progress(k: int, n: int) -> None:
            bar.n = round(100 * k / max(n, 1))
            bar.refresh()

        try:
            record = simulate(scenario, opts, progress)
        except Exception as exc:
            # a user's controller raised: their file and line, not the bench's frames
            if isinstance(opts.controller, str) and is_user_spec(opts.controller):
                print(f"heli-sitl simulate: controller {opts.controller} raised:\n{user_traceback(exc)}",
                      file=sys.stderr, end="")  # fmt: skip
                return Exit.FAILURE
            raise
    record.write_csv(out / "run.csv", mcap=not args.no_mcap)
    summary = record.write_summary(out / "summary.json")
    title = f"{scenario.run.name}, {record.extra['feedforward'] or record.extra['controller']}"
    figs = plot_figures(record.columns(), out, title=title)
    rotor_fig = plot_rotor(record.columns(), out, title=f"{title}, {opts.plant.kind} plant")
    if rotor_fig is not None:
        figs.append(rotor_fig)
    if record.air_nwu_m_s is not None and record.servo_rad is not None:
        figs.append(plot_world(record.t_s, record.air_nwu_m_s, record.pitches, record.servo_rad, out,
                               title=f"{title}, world {opts.world.name if opts.world else ''}"))  # fmt: skip
        record.write_world_csv(out / "world.csv")
        figs.append(out / "world.csv")
    if record.x_hat is not None and record.est_log is not None and record.write_est_csv(out / "est.csv"):
        world_name = opts.world.name if opts.world else ""
        figs.append(plot_estimate(record.t_s, record.x[:, 0:3], record.x_hat[:, 0:3], record.est_log[:, 0:3],
                                  out, title=f"{title}, world {world_name}"))  # fmt: skip
        figs.append(out / "est.csv")
        from autopilot.estimation.log import EST_LOG_COLUMNS

        log = record.est_log

        def block(name: str) -> Any:
            i = EST_LOG_COLUMNS.index(f"{name}_x")
            return log[:, i : i + 3]

        fig = plot_attitude_estimate(record.t_s, block("att_err"), block("sd_att"), block("gyro_bias_err"),
                                     block("sd_gyro_bias"), out,
                                     title=f"{title}, world {world_name}")  # fmt: skip
        if fig is not None:
            figs.append(fig)
    from autopilot.flight_metrics import FlightMetrics

    print(rms_line(FlightMetrics.of(record)))
    jump = summary["max_pos_err_40_45_m"]  # the paper's slope jump: its scenario only
    print(
        (f"max error in [40, 45] s: {jump:.3f} m; " if jump is not None else "")
        + f"saturated ticks: {summary['saturated_ticks']}; "
        f"real-time factor: {summary['realtime_factor']:.0f}x"
    )
    print(f"wrote {out / 'run.csv'}, {out / 'summary.json'}")
    for f in figs:
        print(f"wrote {f}")
    if args.view:  # in-process, the flight is over before a browser opens: its replay
        from heli_common.process import terminate_on_sigterm
        from heli_sitl.view.commands import replay_after

        terminate_on_sigterm()
        replay_after("heli-sitl simulate", out / "run.csv", args.view_port)
    return 0


def _tune(args: argparse.Namespace) -> int:
    from autopilot.pid.gains import PidGains
    from autopilot.scenario import Scenario
    from heli_sitl.studies.comparison import command_line
    from heli_sitl.studies.tune import MarginConstraint, tune, write_gains

    scenario = Scenario.load(args.scenario, gains=args.gains if args.controller == "tlc" else None)
    start = PidGains.load(args.gains) if args.controller == "pid" and args.gains else None
    last = [0]

    def progress(n: int, best: float) -> None:
        if not args.quiet and n >= last[0] + 50:
            last[0] = n
            print(f"  {n} evaluations, best cost {best:.4f} m", flush=True)

    constraint = None
    if args.min_disk_margin is not None:
        constraint = MarginConstraint(args.min_disk_margin, args.margin_plant, args.margin_servos)
    also = [Scenario.load(n, gains=args.gains if args.controller == "tlc" else None) for n in args.also]
    r = tune(scenario, args.controller, args.budget, args.feedforward, start, progress, seed=args.seed,
             plant=args.plant, constraint=constraint, also=also)  # fmt: skip
    print(f"{args.controller}: cost {r.cost(r.start_flights):.4f} m -> {r.cost(r.best_flights):.4f} m "
          f"in {r.evaluations} evaluations, {r.wall_s:.0f} s")  # fmt: skip
    if r.best_shortfall > 0.0:
        print(f"the margin constraint is NOT met: the tuned gains fall {r.best_shortfall:.2f} short "
              f"({r.rejected} of {r.evaluations} candidates rejected)")  # fmt: skip
    print(f"{'knob':34s} {'start':>10s} {'tuned':>10s}")
    for k, a, b in zip(r.knobs, r.start, r.best, strict=True):
        print(f"{k.name:34s} {a:10.4g} {b:10.4g}")
    for f in r.best_flights:
        print(f"  {f.describe()}")
    out = Path(args.out)
    write_gains(r, out, command_line())
    print(f"wrote {out}")
    return 0


def _trim(args: argparse.Namespace) -> int:
    from heli_common.vehicle.plant_model import PlantModel
    from heli_common.vehicle.scenario_file import load_vehicle
    from heli_plant.trim import linearize, trim

    design = load_vehicle(args.scenario)[0]
    model = PlantModel.load(args.plant)
    out = []
    for v in args.speed_m_s or [0.0]:
        tr = trim(model, design, speed_m_s=v)
        lin = linearize(tr, model, design)
        out.append({"trim": tr.as_dict(), "modes": [
            {"name": m.name, "eigenvalue": [m.eigenvalue.real, m.eigenvalue.imag],
             "natural_frequency_rad_s": m.natural_frequency_rad_s, "damping": m.damping,
             "dominant": list(m.dominant)} for m in lin.modes]})  # fmt: skip
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    for item in out:
        t = item["trim"]
        assert isinstance(t, dict)
        print(f"{model.kind} plant, level flight at {t['speed_m_s']:g} m/s "
              f"(residual {t['residual_max']:.1e}):")  # fmt: skip
        for k, v in t.items():
            if k not in ("plant", "speed_m_s", "residual_max"):
                print(f"  {k:18s} {v: .5f}")
        print(f"  {'mode':36s} {'eigenvalue':>22s} {'w_n rad/s':>10s} {'damping':>8s}  dominant")
        for m in item["modes"]:
            assert isinstance(m, dict)
            ev = complex(*m["eigenvalue"])
            print(f"  {m['name']:36s} {ev.real:10.3f} {ev.imag:+10.3f}j {m['natural_frequency_rad_s']:10.3f} "
                  f"{m['damping']:8.3f}  {', '.join(m['dominant'])}")  # fmt: skip
    return 0


def _margins(args: argparse.Namespace) -> int:
    from autopilot.controllers import build_kernel_controller
    from autopilot.pid.gains import PidGains
    from autopilot.scenario import Scenario
    from heli_common.vehicle.plant_model import PlantModel
    from heli_sitl.engine.loop_linear import linearize_loop, servo_model

    scenario = Scenario.load(args.scenario, gains=args.gains if args.controller == "tlc" else None)
    from autopilot.design_point import MIN_DISK_MARGIN

    pid = PidGains.load(args.gains or "gains_pid.toml") if args.controller == "pid" else None
    if args.loops:
        return _loop_margins(args, scenario, pid)
    if args.envelope or args.speed_m_s or args.out:
        return _envelope_margins(args, scenario, pid)
    design = (pid or scenario.gains).design
    if args.design and (args.plant or args.servos):
        raise UsageError("--design checks the gain file's [design] plant and servos: no --plant, --servos")
    plants = [design.plant] if args.design else args.plant or ["paper", "gavrilets"]
    rows = []
    for plant in plants:
        for servos in [design.servos] if args.design else args.servos or ["servos-default"]:
            c = build_kernel_controller(args.controller, scenario.airframe, scenario.gains,
                                        scenario.run.rate_hz, pid_gains=pid)  # fmt: skip
            name, sv = servo_model(servos)
            lin = linearize_loop(c, PlantModel.load(plant), scenario.airframe, sv, name)
            rows.append(lin)
            print(f"# {lin.summary()}")
            if args.all:
                for b in (*lin.break_points, lin.input_multiloop):
                    print(f"#   {b.name:22s} {b.disk_margin:6.3f} {b.gain_margin_db:6.1f} dB "
                          f"{b.phase_margin_deg:5.1f} deg")  # fmt: skip
    if args.design:
        ok = rows[0].stable and rows[0].worst().disk_margin >= MIN_DISK_MARGIN
        limit = MIN_DISK_MARGIN
        verdict = f"passes {limit} at every break point" if ok else f"FAILS: unstable or below {limit}"
        print(f"# design point ({design.plant} plant, servos {design.servos}): {verdict}")
        return 0 if ok else 1
    return 0


def _envelope_margins(args: argparse.Namespace, scenario: Scenario, pid: PidGains | None) -> int:
    """``heli-sitl margins --envelope``: the closed loop linearised in trimmed level flight at each
    speed, a computation delay in it; disk margins loop at a time and all at once
    (heli_sitl/engine/loop_linear.py, autopilot/analysis/envelope_margins.py)."""
    from autopilot.analysis.envelope_margins import envelope_csv
    from autopilot.controllers import build_kernel_controller
    from heli_common.vehicle.plant_model import PlantModel
    from heli_sitl.engine.loop_linear import DEFAULT_SPEEDS_M_S, envelope_margins, servo_model

    if args.design or args.all:
        raise UsageError("--envelope takes the gain file's design plant and servos unless --plant, --servos "
                         "name others: no --design, --all")  # fmt: skip
    if args.delay_ticks < 0:
        raise UsageError("--delay-ticks must be >= 0")
    design = (pid or scenario.gains).design
    speeds = args.speed_m_s or list(DEFAULT_SPEEDS_M_S)
    if any(not (0.0 <= v <= 30.0) for v in speeds):
        raise UsageError("--speed-m-s: level-flight speeds from 0 to 30 m/s")
    gains_name = args.gains or ("gains_pid.toml" if pid is not None else scenario.gains.name)
    tables = []
    for plant in args.plant or [design.plant]:
        model = PlantModel.load(plant)
        for servos in args.servos or [design.servos]:
            name, sv = servo_model(servos)

            def make() -> Any:
                return build_kernel_controller(args.controller, scenario.airframe, scenario.gains,
                                               scenario.run.rate_hz, pid_gains=pid)  # fmt: skip

            t = envelope_margins(make, model, scenario.airframe, sv, speeds_m_s=speeds,
                                 delay_ticks=args.delay_ticks, gains_name=gains_name,
                                 servos_name=name)  # fmt: skip
            tables.append(t)
            print(t.markdown())
            print()
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "margins_envelope.csv").write_text(envelope_csv(tables))
        (out / "margins_envelope.md").write_text("\n\n".join(t.markdown() for t in tables) + "\n")
        print(f"wrote {out / 'margins_envelope.csv'} and {out / 'margins_envelope.md'}")
    return 0


def _loop_margins(args: argparse.Namespace, scenario: Scenario, pid: PidGains | None) -> int:
    """``heli-sitl margins --loops``: each loop and channel opened alone about hover, the
    servo model in it (autopilot.analysis.margins; the PID's by autopilot.analysis.pid_margins)."""
    import dataclasses

    from autopilot.analysis.margins import SERVO_MODELS, format_table, loop_margins
    from autopilot.analysis.pid_margins import pid_loop_margins

    if args.design or args.plant or args.servos:
        raise UsageError("--loops takes the servo models ideal, default and sloppy on the linear plant: "
                         "no --design, --plant, --servos")  # fmt: skip
    reports = []
    for sv in SERVO_MODELS.values():
        servo = dataclasses.replace(sv, rate_hz=scenario.run.rate_hz)
        if pid is not None:
            reports.append(pid_loop_margins(pid, servo))
        else:
            reports.append(loop_margins(scenario.gains, servo))
    print(format_table(reports))
    return 0


def _compare(args: argparse.Namespace) -> int:
    from heli_sitl.studies.comparison import command_line, run_compare

    run_compare(args.file, Path(args.out), Path(args.work), samples=args.samples, seeds=args.seeds,
                ardupilot_bin=args.ardupilot_bin,
                workers=args.workers,
                quiet=args.quiet, command=command_line())  # fmt: skip
    return 0


def _run_ardupilot_json(args: argparse.Namespace) -> int:
    """``heli-sitl run --backend ardupilot-json``: the plant as ArduPilot SITL's external
    physics (``--model JSON``), listening on UDP 9002 + 10 N (docs/ardupilot-json.md); with
    ``--servo-link can`` its servos take ArduPilot's DroneCAN commands (docs/can.md)."""
    import dataclasses
    import threading

    from heli_common.vehicle.plant_model import PlantModel
    from heli_common.vehicle.scenario_file import load_vehicle
    from heli_common.vehicle.swashplate import Swashplate
    from heli_common.wire.mavlink.udp import PortBusyError
    from heli_plant.ardupilot_backend import ArduPilotBackend, open_record
    from heli_plant.ardupilot_link import ArduPilotJsonLink, port_for_instance
    from heli_plant.model import Plant
    from heli_plant.pacer import PACE_PORT_OFFSET, Pacer

    stop = threading.Event()
    stop_on_signals(stop)
    airframe, x0, _ = load_vehicle(args.scenario, on_ground=not args.in_air)
    world = World.load(args.world) if args.world else None
    model = PlantModel.load(args.plant)
    home = parse_geo_point(args.home, "--home")
    swash = Swashplate.load(args.swashplate)
    port = args.port if args.port is not None else port_for_instance(args.instance)
    record = open_record(Path(args.out) if args.out else None)

    def make_plant() -> Plant:
        # the firmware's frame period (1200 Hz) is the sensors' sampling step, where a world has any
        # on the ground the rotor starts at rest: the firmware's RSC runs it up (channel 8)
        return Plant(airframe, x0, substeps=args.plant_substeps, world=world, step_s=1.0 / 1200.0, home=home,
                     model=model, rotor_at_rest=not args.in_air)  # fmt: skip

    can = None
    if args.servo_link == "can":  # the servos from ArduPilot's DroneCAN ArrayCommand (docs/can.md)
        from heli_plant.ardupilot_can import ArduPilotCanServos, servo_ranges
        from heli_sitl.launch.ardupilot import can_parm_files

        parms = args.ardupilot_parms.split(",") if args.ardupilot_parms else can_parm_files(args.plant)
        try:
            can = ArduPilotCanServos(args.can_bus or "mcast:0", servo_ranges(parms))
        except (ConfigError, ValueError) as exc:
            raise UsageError(f"--servo-link can: {exc}") from None
    elif args.servo_link not in (None, "mavlink"):
        raise UsageError(f"--backend ardupilot-json: no servo link {args.servo_link!r}")
    try:
        link = ArduPilotJsonLink(port)
        pacer = Pacer(port + PACE_PORT_OFFSET)
    except PortBusyError as exc:
        if can is not None:
            can.close()
        print(f"heli-sitl: {exc.strerror}", file=sys.stderr)
        return Exit.PORT_BUSY
    with link, pacer:
        try:
            stats = ArduPilotBackend(make_plant, swash, link, record, pacer, can).run(stop, args.duration_s)
        finally:
            if record is not None:
                record.close()
            if can is not None:
                can.close()
    summary = json.dumps(dataclasses.asdict(stats), default=str)
    if args.out:  # the counts, the CAN cross-check's among them, beside plant.csv
        (Path(args.out) / "plant-stats.json").write_text(summary + "\n")
    if args.verbose:
        print(summary, file=sys.stderr)
    return 0


def _run(args: argparse.Namespace) -> int:
    import logging
    import threading

    if args.backend == "ardupilot-json":
        return _run_ardupilot_json(args)

    from heli_common.vehicle.plant_model import PlantModel
    from heli_common.vehicle.scenario_file import load_vehicle
    from heli_common.wire.mavlink.udp import LOOPBACK, MavlinkUdp, PortBusyError
    from heli_common.wire.servo_link import load_servo_link, with_overrides
    from heli_plant.model import Plant
    from heli_plant.server import PlantServer, SimConfig

    arg.resolve_instance(args, {"port": "plant", "autopilot_port": "autopilot"})
    if args.port == args.autopilot_port:  # it would only hear its own states
        raise UsageError(f"--port and --autopilot-port must differ (both {args.port})")
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="heli-sitl: %(levelname)s %(message)s",
    )
    check_rt_priority(args.rt_priority, args.mode)
    stop = threading.Event()
    stop_on_signals(stop)
    view = _run_view(args) if args.view else None  # a process of its own: never in the plant's loop
    airframe, x0, rate = load_vehicle(args.scenario, on_ground=args.on_ground)
    cfg = SimConfig(args.mode, args.rate_hz or rate, args.duration_s, args.timeout_s,
                    hold_until_armed=args.hold_until_armed)  # fmt: skip
    world = World.load(args.world) if args.world else None
    plant = Plant(airframe, x0, substeps=args.plant_substeps, world=world, step_s=1.0 / cfg.rate_hz,
                  home=parse_geo_point(args.home, "--home"), model=PlantModel.load(args.plant))  # fmt: skip
    try:
        # the plant is component 51 of the vehicle; it takes commands from system 1 only
        link = MavlinkUdp((LOOPBACK, args.port), (LOOPBACK, args.autopilot_port), system_id=1,
                          component_id=51, accept_system=1)  # fmt: skip
    except PortBusyError as exc:
        print(f"heli-sitl: {exc.strerror}", file=sys.stderr)
        return Exit.PORT_BUSY
    with link:  # closed however this ends, and so is the CAN bus: no shutdown warnings
        servo = with_overrides(load_servo_link(args.links), args.servo_link, args.can_bus, args.actuator_ids)
        can = None
        servo_in: ServoInput | None = None
        if servo.link == "can":
            from heli_plant.can_endpoint import CanServoEndpoint
            from heli_plant.servo_inputs import CanServoInput

            can = CanServoEndpoint(servo.can_bus, limits=airframe.limits, actuator_ids=servo.actuator_ids,
                                   timeout_s=servo.timeout_s)  # fmt: skip
            servo_in = CanServoInput(can)
        try:
            servos = servo_map_for(args.ccpm, servo.link, limits_array(airframe.limits.as_tuple()))
        except ConfigError as exc:
            raise UsageError(str(exc)) from None
        if servo_in is None and args.ccpm is not None:
            from heli_common.wire.mavlink.fast import SimCodec
            from heli_plant.servo_inputs import MavlinkServoInput

            servo_in = MavlinkServoInput(link, SimCodec(system_id=1, component_id=51), servos)
        try:
            # SCHED_FIFO for the loop only: the start-up above and the record after run under
            # the default policy
            with rt_priority_loop(args.rt_priority, args.mode, logging.getLogger("heli-sitl")):
                stats = PlantServer(plant, link, cfg, servo_in).run(stop)
            if can is not None:
                stats.extra["can"] = dict(can.stats)
        finally:
            if can is not None:
                can.close()
    if view is not None:
        view.stop()
    if args.verbose:
        print(json.dumps({**stats.__dict__, "link": link.stats.as_dict()}), file=sys.stderr)
    if stats.lost:
        print(f"heli-sitl: {stats.lost}", file=sys.stderr)
        return Exit.FAILURE
    if stats.commands == 0:  # it never flew: say why rather than end as a clean run
        print("heli-sitl: no command ever came from the autopilot: the plant never stepped",
              file=sys.stderr)  # fmt: skip
        return Exit.FAILURE
    return 0


def _run_view(args: argparse.Namespace) -> Child:
    """``run --view``: ``heli-sitl view --listen`` on the API port the autopilot sends to by
    default (ports + 10 N), as a child process (the plant's loop keeps its core and the GIL)."""
    from heli_sitl.launch.children import spawn

    api = ports(args.instance).api
    cmd = [sys.executable, "-m", "heli_sitl.cli", "view", "--listen", str(api), "--port", str(args.view_port),
           "--scenario", args.scenario]  # fmt: skip
    return spawn(cmd, "view", echo=True)


def _up_ardupilot(args: argparse.Namespace) -> int:
    from heli_sitl.launch import ardupilot

    can = args.servo_link == "can"
    if args.can_bus is not None and not can:
        raise UsageError("--can-bus: only with --servo-link can")
    try:
        firmware = ardupilot.find_firmware(args.ardupilot_bin, can=can)
    except ardupilot.FirmwareNotFoundError as exc:
        raise UsageError(str(exc)) from exc
    view = _open_view(args, "heli-sitl up") if args.view else None
    opts = ardupilot.ArduPilotOptions(
        firmware=firmware, instance=args.instance, plant=args.plant, world=args.world, scenario=args.scenario,
        home=args.home, speedup=args.speedup, out=Path(args.out or "out/ardupilot"),
        servo_link="can" if can else "json", can_bus=args.can_bus or "mcast:0",
        view_port=None if view is None else view.feed.port,
    )  # fmt: skip
    try:
        ardupilot.serve(opts)
    except RuntimeError as exc:
        print(f"heli-sitl up: {exc}", file=sys.stderr)
        return Exit.FAILURE
    finally:
        _close_view(view, "heli-sitl up")
    return Exit.OK


def _open_view(args: argparse.Namespace, prog: str, *, path: bool = False,
               forward_to: tuple[str, int] | None = None) -> LiveView:  # fmt: skip
    """``--view``: the live view (threads of this launcher), listening for the vehicle's
    telemetry on a port of its own (``.feed.port``: the launcher sends the telemetry there);
    ``path``: the scenario's reference path drawn in advance (the vehicle flies it)."""
    from heli_sitl.view.commands import announce, live_for_scenario

    view = live_for_scenario(args.view_port, args.scenario, forward_to=forward_to, draw_path=path,
                             duration_s=getattr(args, "duration_s", None))  # fmt: skip
    announce(prog, view.url, "live view")
    return view


def _close_view(view: LiveView | None, prog: str) -> None:
    if view is not None:
        from heli_sitl.view.commands import report

        view.close()
        report(prog, view)


def _up(args: argparse.Namespace) -> int:
    from heli_common.process import terminate_on_sigterm
    from heli_common.wire.mavlink.udp import LOOPBACK
    from heli_sitl.launch.demo import DemoError, UpOptions, serve

    terminate_on_sigterm()
    if args.firmware == "ardupilot":
        return _up_ardupilot(args)
    if args.servo_link is not None or args.can_bus is not None:
        raise UsageError("up: --servo-link/--can-bus are for --firmware ardupilot; the bench's own "
                         "servo link is configs/links.toml's [servo] (or demo --servo-link)")
    arg.resolve_instance(args, {"gcs_port": "gcs", "api_port": "api", "local_gcs_port": "local_gcs",
                                "local_api_port": "local_api"})  # fmt: skip
    # --view: the API link goes through the view, which relays it to --api-port (MAVSDK still works)
    view = _open_view(args, "heli-sitl up", forward_to=(LOOPBACK, args.api_port)) if args.view else None
    opts = UpOptions(
        mode=args.mode, rate_hz=args.rate_hz, scenario=args.scenario, in_air=args.in_air,
        gcs_port=args.gcs_port, api_port=args.api_port if view is None else view.feed.port,
        local_gcs_port=args.local_gcs_port,
        local_api_port=args.local_api_port, signing_key=args.signing_key, out=args.out,
        sysid=args.sysid, world=args.world, extra_autopilot_args=controller_args(args), plant=args.plant,
        ccpm=args.ccpm, rt_priority=args.rt_priority,
        view_relays_api_to=None if view is None else args.api_port,
    )  # fmt: skip
    try:
        serve(opts)
    except DemoError as exc:
        print(f"heli-sitl up: {exc}", file=sys.stderr)
        return Exit.FAILURE
    finally:
        _close_view(view, "heli-sitl up")
    return Exit.OK


def _demo(args: argparse.Namespace) -> int:
    from heli_common.process import terminate_on_sigterm

    terminate_on_sigterm()

    out = Path(args.out)
    view = _open_view(args, "heli-sitl demo", path=True) if args.view else None
    try:
        return _demo_flight(args, out, view)
    finally:
        _close_view(view, "heli-sitl demo")


def _demo_flight(args: argparse.Namespace, out: Path, view: LiveView | None) -> int:
    import numpy as np

    from autopilot.metrics import WORLD_CSV_HEADER
    from ground.plots import plot_figures, plot_rotor, plot_world, read_csv_columns
    from heli_common.state import PITCH_LABELS
    from heli_sitl.launch.demo import DemoError, DemoOptions, run_demo

    # --view: the autopilot's API link (telemetry only; nothing the view sends flies) goes to it
    view_args = () if view is None else ("--api-port", str(view.feed.port))
    opts = DemoOptions(mode=args.mode, rate_hz=args.rate_hz, scenario=args.scenario, out=out,
                       duration_s=args.duration_s, servo_link=args.servo_link,
                       can_bus=args.can_bus, via_ground=not args.autostart, world=args.world,
                       extra_autopilot_args=(("--gains", args.gains) if args.gains else ())
                       + controller_args(args) + view_args, extra_plant_args=("--plant", args.plant),
                       rt_priority=args.rt_priority)  # fmt: skip
    try:
        summary = run_demo(opts)
    except DemoError as exc:
        print(f"heli-sitl demo: {exc}", file=sys.stderr)
        return 1
    cols = read_csv_columns(out / "run.csv")
    figs = plot_figures(cols, out, title=f"{args.mode} {args.rate_hz:g} Hz")
    rotor_fig = plot_rotor(cols, out, title=f"{args.mode}, {args.plant} plant")
    if rotor_fig is not None:
        figs.append(rotor_fig)
    if (out / "world.csv").is_file():  # the plant flew a world: the air and the servos it reported
        w = read_csv_columns(out / "world.csv")
        air = np.column_stack([w["air_n_m_s"], w["air_w_m_s"], w["air_u_m_s"]])
        reached = np.column_stack([w[k] for k in WORLD_CSV_HEADER[4:]])
        commanded = np.column_stack([cols[k] for k in PITCH_LABELS])
        title = f"{args.mode}, world {args.world}"
        figs.append(plot_world(w["t_s"], air, commanded, reached, out, title=title))
    from autopilot.flight_metrics import FlightMetrics

    print(rms_line(FlightMetrics.from_summary(summary)))
    loop = summary.get("loop", {})
    assert isinstance(loop, dict)
    print(
        f"loop: p50/p99/max lateness {loop.get('jitter_p50_ms', 0):.3f}/"
        f"{loop.get('jitter_p99_ms', 0):.3f}/{loop.get('jitter_max_ms', 0):.3f} ms, "
        f"overruns {loop.get('overruns')}, stale ticks {loop.get('stale_ticks')}; "
        f"wall {summary['wall_s']:.1f} s"
    )
    tlogs = [out / n for n in ("flight.tlog", "ground.tlog") if (out / n).exists()]
    for f in [out / "run.csv", out / "summary.json", *tlogs, *figs]:
        print(f"wrote {f}")
    if view is not None:  # the flight is over: its last frame and trail stay up until Ctrl-C
        from heli_sitl.view.commands import announce, serve_until_interrupted

        view.hold_last_frame()  # the last frame is up before the page's address is announced
        announce("heli-sitl demo", view.url,
                 "the flight is over; the view keeps its last frame (Ctrl-C to stop)")
        serve_until_interrupted()
    return 0


def _campaign(args: argparse.Namespace) -> int:
    from heli_sitl.studies.campaigns.run import run_campaign

    summary = run_campaign(args.file, Path(args.out), samples=args.samples, workers=args.workers,
                           scheduler=args.scheduler, quiet=args.quiet,
                           controller=args.controller, figures=not args.no_figures)  # fmt: skip
    if args.via == "processes":
        from heli_sitl.studies.campaigns.via_processes import compare

        compare(args.file, Path(args.out), args.limit, samples=args.samples, quiet=args.quiet,
                controller=args.controller)  # fmt: skip
    counts = summary["counts"]
    assert isinstance(counts, dict)
    if counts["failed"]:  # a flight that raised is a fault of the bench, not of the controller
        print(f"heli-sitl: {counts['failed']} of {counts['flights']} flights failed (raised an error; "
              f"their rows in {args.out}/results.parquet say why): exit 3", file=sys.stderr)
        return 3
    return 0


VIEW_PORT = 8080  # viser's default (heli_sitl.view.server.DEFAULT_PORT)


def add_view_args(p: argparse.ArgumentParser, what: str) -> None:
    """``--view`` and ``--view-port`` (the page on 127.0.0.1; no browser is opened)."""
    p.add_argument("--view", action="store_true", help=f"{what} (docs/view.md)")
    p.add_argument("--view-port", type=arg.bind_port, default=VIEW_PORT,
                   help=f"--view: the page's TCP port on 127.0.0.1 (default {VIEW_PORT})")


def _view(args: argparse.Namespace) -> int:
    from heli_sitl.view.commands import view_command

    return view_command(args)


def rms_line(m: FlightMetrics) -> str:
    line = "RMS 3-D position error: " + ", ".join(f"[{k}] s {v:.4f} m" for k, v in m.rms_m.items())
    if m.rms_windows_m:  # the scenario's own windows
        line += "; scenario windows: " + ", ".join(f"[{k}] s {v:.4f} m" for k, v in m.rms_windows_m.items())
    return line


def add_controller_args(p: argparse.ArgumentParser) -> None:
    from autopilot.controller_names import CONTROLLER_HELP

    p.add_argument("--controller", type=controller_arg, default="tlc", metavar="NAME", help=CONTROLLER_HELP)
    p.add_argument("--pid-gains", default=None, metavar="FILE", help="PID gains (TOML) for --controller pid")


def controller_args(args: argparse.Namespace) -> tuple[str, ...]:
    """The autopilot process's arguments for the controller chosen on this command line."""
    return ("--controller", args.controller) + (("--pid-gains", args.pid_gains) if args.pid_gains else ())


def controller_arg(value: str) -> str:
    """``--controller``'s type, importing the controllers only when a command flies one (the
    plant process, ``heli-sitl run``, imports nothing of the autopilot)."""
    from autopilot.controllers import controller_arg as check

    return check(value)


def _is_listed(type_name: str, types: list[str]) -> bool:
    """``--type``: the full DroneCAN name, or its last parts (``actuator.ArrayCommand``)."""
    return any(type_name == t or type_name.endswith("." + t) for t in types)


def _can_monitor(args: argparse.Namespace) -> int:
    """``heli-sitl can monitor [BUS]``: every DroneCAN transfer on the bus, one line each."""
    import threading
    import time

    from heli_common.wire.can.bus import CanBusError, open_bus, parse_bus_spec
    from heli_common.wire.can.monitor import TransferMonitor, frame_line, transfer_line

    try:
        config = parse_bus_spec(args.bus)
    except ValueError as exc:
        raise UsageError(f"can monitor: {exc}") from None
    stop = threading.Event()
    stop_on_signals(stop)
    try:
        bus = open_bus(config)
    except CanBusError as exc:
        print(f"heli-sitl can monitor: {exc}", file=sys.stderr)
        return Exit.FAILURE
    name = config.describe()
    mon = TransferMonitor()
    printed = 0
    t0 = time.time()
    deadline = None if args.duration_s is None else time.monotonic() + args.duration_s
    print(f"heli-sitl can monitor: listening on {name} (Ctrl-C to stop)", file=sys.stderr, flush=True)
    with bus:
        while not stop.is_set() and (args.count is None or printed < args.count):
            wait = 0.2
            if deadline is not None:
                wait = min(wait, deadline - time.monotonic())
                if wait <= 0.0:
                    break
            try:
                msg = bus.recv(wait)
            except CanBusError as exc:
                print(f"heli-sitl can monitor: {exc}", file=sys.stderr)
                return Exit.FAILURE
            if msg is None:
                continue
            if args.frames:
                print(frame_line(msg, name, t0), flush=True)
            tr = mon.feed(msg)
            if tr is not None and (not args.types or _is_listed(tr.type_name, args.types)):
                print(transfer_line(tr, t0), flush=True)
                printed += 1
    print(f"heli-sitl can monitor: {mon.frames} frames, {mon.transfers} transfers, {mon.errors} "
          f"undecodable, {mon.skipped} not DroneCAN", file=sys.stderr)  # fmt: skip
    return Exit.OK


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="heli-sitl", description=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("simulate", help="closed loop in one process; writes CSV, summary, figures")
    s.add_argument("--scenario", default="paper", help="name (configs/scenario_NAME.toml) or path")
    s.add_argument("--rate-hz", type=arg.control_rate_hz, default=None, help="control rate, 50-1000 Hz")
    s.add_argument("--feedforward", choices=("pseudo", "exact"), default=None)
    s.add_argument("--plant-substeps", type=arg.count, default=None, help="RK4 sub-steps per tick")
    s.add_argument("--duration-s", type=arg.positive, default=None)
    s.add_argument("--trajectory", default=None, metavar="FILE.csv",
                   help="fly this table instead of the scenario's trajectory, from its first point "
                        "(t_s,x_m,y_m,z_m[,...] or t,x,y,z[,yaw], or a run.csv)")
    s.add_argument("--out", required=True, help="output directory")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.add_argument("--no-mcap", action="store_true", help="write no flight.mcap beside run.csv")
    s.add_argument("--world", default=None, metavar="FILE|PRESET", help=WORLD_HELP)
    s.add_argument("--plant", default="paper", metavar="paper|gavrilets|FILE", help=PLANT_HELP)
    s.add_argument("--gains", default=None, metavar="FILE", help=GAINS_HELP)
    s.add_argument("--estimator", default=None, metavar="FILE",
                   help="estimator tuning (TOML, docs/estimator.md) for a world with [sensors]")
    add_controller_args(s)
    add_view_args(s, "after the flight, replay it in the browser (an in-process flight is over in a "
                     "fraction of a second); Ctrl-C to stop")
    s.set_defaults(func=_simulate)

    r = sub.add_parser("run", help="the plant process (sim link on UDP loopback)")
    r.add_argument("--mode", choices=("lockstep", "realtime"), default="realtime")
    r.add_argument("--scenario", default="paper", help="airframe and initial state")
    r.add_argument("--on-ground", action="store_true", help="start on the ground at home")
    r.add_argument("--rate-hz", type=arg.physics_rate_hz, default=None,
                   help="lockstep: control rate; realtime: physics rate")
    r.add_argument("--plant-substeps", type=arg.count, default=1)
    r.add_argument("--duration-s", type=arg.positive, default=None)
    r.add_argument("--port", type=arg.bind_port, default=None,
                   help=f"UDP port to bind (default {PORTS.plant} + 10 N)")
    r.add_argument("--autopilot-port", type=arg.port, default=None,
                   help=f"the autopilot's sim-link port (default {PORTS.autopilot} + 10 N)")
    arg.add_instance_args(r, sysid=False)
    r.add_argument("--timeout-s", type=arg.positive, default=1.0, help="autopilot silent after this")
    add_rt_priority_arg(r)
    add_servo_args(r)
    r.add_argument("--hold-until-armed", action="store_true",
                   help="in-air start: do not step until the autopilot arms")
    r.add_argument("--world", default=None, metavar="FILE|PRESET", help=WORLD_HELP)
    r.add_argument("--plant", default="paper", metavar="paper|gavrilets|FILE", help=PLANT_HELP)
    r.add_argument("--home", default=f"{HOME.lat_deg},{HOME.lon_deg},{HOME.alt_amsl_m}",
                   help="lat,lon,alt the GPS reports about (give heli-autopilot the same --home)")
    r.add_argument("--backend", choices=("mavlink", "ardupilot-json"), default="mavlink",
                   help="mavlink: this bench's sim link to heli-autopilot; ardupilot-json: ArduPilot "
                        "SITL's external physics (--model JSON), UDP 9002 + 10 N (docs/ardupilot-json.md)")
    r.add_argument("--swashplate", default="swashplate/xcell60-h3-120.toml",
                   help="ardupilot-json: the head between the servos and the blades (docs/swashplate.md)")
    r.add_argument("--in-air", action="store_true",
                   help="ardupilot-json: start at the scenario's initial state (default: on the ground)")
    r.add_argument("--out", default=None,
                   help="ardupilot-json: write plant.csv (the truth, 100 Hz) and plant-stats.json here")
    r.add_argument("--ardupilot-parms", default=None, metavar="FILE[,FILE...]",
                   help="ardupilot-json with --servo-link can: the firmware's parameter files, in load "
                        "order, for SERVOn_MIN/TRIM/MAX (default: those `up --firmware ardupilot` gives it)")
    r.add_argument("-v", "--verbose", action="store_true")
    add_view_args(r, "a live 3-D view in the browser of the vehicle sending its telemetry to the API port "
                     "(14540 + 10 N), as a process of its own (heli-sitl view --listen)")
    r.set_defaults(func=_run)

    u = sub.add_parser("up", help="plant + autopilot, disarmed on the ground, serving ground stations")
    u.add_argument("--ccpm", nargs="?", const="swashplate/xcell60-h3-120.toml", default=None,
                   metavar="SWASHPLATE", help="CCPM servo channels through this swashplate (both processes)")
    u.add_argument("--mode", choices=("lockstep", "realtime"), default="realtime")
    u.add_argument("--rate-hz", type=arg.control_rate_hz, default=100.0)
    u.add_argument("--scenario", default="paper", help="airframe and gains")
    u.add_argument("--in-air", action="store_true",
                   help="start at the scenario's initial state, clock held until armed")
    u.add_argument("--gcs-port", type=arg.port, default=None,
                   help=f"where ground stations listen (default {PORTS.gcs} + 10 N)")
    u.add_argument("--api-port", type=arg.port, default=None,
                   help=f"where API clients (MAVSDK) listen (default {PORTS.api} + 10 N)")
    u.add_argument("--local-gcs-port", type=arg.bind_port, default=None,
                   help=f"the vehicle's end of the ground-station link (default {PORTS.local_gcs} + 10 N)")
    u.add_argument("--local-api-port", type=arg.bind_port, default=None,
                   help=f"the vehicle's end of the API link (default {PORTS.local_api} + 10 N)")
    arg.add_instance_args(u)
    u.add_argument("--signing-key", default=None)
    u.add_argument("--out", default=None, help="autopilot writes run.csv/summary/tlog here on exit")
    u.add_argument("--world", default=None, metavar="FILE|PRESET", help=WORLD_HELP)
    u.add_argument("--plant", default="paper", metavar="paper|gavrilets|FILE", help=PLANT_HELP)
    add_controller_args(u)
    add_rt_priority_arg(u)
    u.add_argument("--firmware", choices=("bench", "ardupilot"), default="bench",
                   help="bench: this bench's autopilot (the TLC); ardupilot: ArduPilot's arducopter-heli "
                        "SITL flies the plant (JSON backend; ground stations on TCP 5760 + 10 N)")
    u.add_argument("--ardupilot-bin", default=None, metavar="PATH",
                   help="the arducopter-heli SITL binary (default: $ARDUPILOT_HELI_BIN)")
    u.add_argument("--speedup", type=arg.positive, default=1.0, help="ardupilot: SITL's --speedup")
    u.add_argument("--servo-link", choices=("json", "can"), default=None,
                   help="ardupilot: where the plant takes the servos from: json (default), the JSON "
                        "frame's PWMs; can, ArduPilot's DroneCAN ArrayCommand (the firmware built with "
                        "DroneCAN: arducopter-heli-can; docs/can.md)")
    u.add_argument("--can-bus", default=None,
                   help="ardupilot --servo-link can: the bus the plant listens on (default mcast:0, the "
                        "firmware's CAN bus 1)")
    u.add_argument("--home", default=f"{HOME.lat_deg},{HOME.lon_deg},{HOME.alt_amsl_m}",
                   help="ardupilot: lat,lon,alt of home")
    add_view_args(u, "a live 3-D view in the browser; the API link goes through it to --api-port "
                     "(ArduPilot: its SERIAL2 sends to the view)")
    u.set_defaults(func=_up)

    d = sub.add_parser("demo", help="plant + autopilot as processes, fly the scenario")
    d.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    d.add_argument("--rate-hz", type=arg.control_rate_hz, default=100.0)
    d.add_argument("--scenario", default="paper")
    d.add_argument("--duration-s", type=arg.positive, default=None)
    d.add_argument("--autostart", action="store_true",
                   help="the autopilot starts the scenario itself (no ground script process)")
    d.add_argument("--servo-link", choices=("mavlink", "can"), default=None)
    d.add_argument("--can-bus", default=None,
                   help="CAN bus spec for --servo-link can: mcast[:N] (DroneCAN's UDP multicast; the "
                        "links config's default mcast:0), virtual[:ch], udp_multicast[:group[:port]], "
                        "socketcan[:iface]")
    d.add_argument("--out", required=True)
    d.add_argument("--world", default=None, metavar="FILE|PRESET", help=WORLD_HELP)
    d.add_argument("--plant", default="paper", metavar="paper|gavrilets|FILE", help=PLANT_HELP)
    d.add_argument("--gains", default=None, metavar="FILE", help=GAINS_HELP)
    add_rt_priority_arg(d)
    add_controller_args(d)
    add_view_args(d, "a live 3-D view in the browser (the autopilot's API link goes to it); after the "
                     "flight it keeps the last frame until Ctrl-C")
    d.set_defaults(func=_demo)

    vw = sub.add_parser("view", help="replay a recorded flight in the browser, or view a live one "
                        "(docs/view.md)")
    vw.add_argument("recording", nargs="?", default=None, metavar="DIR|FILE",
                    help="a run directory (run.csv, flight.parquet, flight.mcap, flight.tlog) or one "
                         "such file")
    vw.add_argument("--port", type=arg.bind_port, default=VIEW_PORT,
                    help=f"the page's TCP port on 127.0.0.1 (default {VIEW_PORT})")
    vw.add_argument("--listen", type=arg.bind_port, default=None, metavar="UDP_PORT",
                    help="a live view instead: of the vehicle sending its MAVLink telemetry to this UDP port")
    vw.add_argument("--scenario", default=None,
                    help="the airframe whose pitch limits the panels show (and, live, its path)")
    vw.add_argument("--paused", action="store_true", help="replay: start paused at the first row")
    vw.set_defaults(func=_view)

    t = sub.add_parser("tune", help="tune a controller's gains on the paper scenario (docs/comparison.md)")
    t.add_argument("--controller", choices=("tlc", "pid"), required=True)
    t.add_argument("--out", required=True, metavar="FILE", help="the tuned gains (TOML) to write")
    t.add_argument("--budget", type=arg.count, default=2000,
                   help="cost evaluations (three worlds x each scenario's flights)")
    t.add_argument("--scenario", default="paper")
    t.add_argument("--also", nargs="*", default=["figure_eight"], metavar="SCENARIO",
                   help="more trajectories every candidate flies (default: figure_eight; none: --also)")
    t.add_argument("--gains", default=None, metavar="FILE", help="start from these gains (default: shipped)")
    t.add_argument("--feedforward", choices=("pseudo", "exact"), default=None,
                   help="the TLC's feed-forward (default: the scenario's)")
    t.add_argument("--plant", default="paper", metavar="paper|gavrilets|FILE", help="the plant flown")
    t.add_argument("--seed", type=int, default=1, help="the optimiser's seed (run several: the spread)")
    t.add_argument("--min-disk-margin", type=float, default=None, metavar="ALPHA",
                   help="reject candidates whose closed loop has a smaller disk margin at any break "
                        "point (0.66: +/- 6 dB, +/- 36 deg); default: no constraint")
    t.add_argument("--margin-plant", default="gavrilets", help="the constraint's plant")
    t.add_argument("--margin-servos", default="servos-default", help="the constraint's servos (a preset)")
    t.add_argument("--quiet", action="store_true")
    t.set_defaults(func=_tune)

    k = sub.add_parser("compare", help="the controllers side by side, paired; report")
    k.add_argument("file", nargs="?", default="compare.toml",
                   help="comparison TOML (default: configs/compare.toml)")
    k.add_argument("--out", required=True, help="report, figures and numbers (e.g. docs/comparison)")
    k.add_argument("--work", default="out/compare", help="the campaigns' Parquet rows (a re-run resumes)")
    k.add_argument("--ardupilot-bin", default=None,
                   help="an ArduPilot contender's arducopter-heli SITL binary (default: $ARDUPILOT_HELI_BIN, "
                        "../shared/ardupilot)")
    k.add_argument("--samples", type=arg.count, default=None, help="Monte Carlo campaigns: flights each")
    k.add_argument("--seeds", type=arg.count, default=None,
                   help="paired Monte Carlo sets: flights each (default: the file's seeds)")
    k.add_argument("--workers", type=arg.count, default=None, help="embedded cluster size (default: cores)")
    k.add_argument("--quiet", action="store_true")
    k.set_defaults(func=_compare)

    tr = sub.add_parser("trim", help="trim (hover, level flight) and the linearised model's modes")
    tr.add_argument("--plant", default="paper", metavar="paper|gavrilets|FILE", help=PLANT_HELP)
    tr.add_argument("--speed-m-s", type=float, action="append", default=None,
                    help="level-flight airspeed (repeat for several; default: hover)")
    tr.add_argument("--scenario", default="paper", help="the design airframe (the paper plant's)")
    tr.add_argument("--json", action="store_true", help="trims and modes as JSON")
    tr.set_defaults(func=_trim)

    mg = sub.add_parser("margins", help="the closed loop linearised at hover: disk margins per break point")
    mg.add_argument("--controller", choices=("tlc", "pid"), default="tlc")
    mg.add_argument("--gains", default=None, help="gain file (default: the scenario's; pid: gains_pid.toml)")
    mg.add_argument("--plant", action="append", default=None, metavar="paper|gavrilets|FILE",
                    help="repeat for several (default: both)")
    mg.add_argument("--servos", action="append", default=None, metavar="PRESET|ideal",
                    help="a world preset's servos (default: servos-default)")
    mg.add_argument("--design", action="store_true",
                    help="check the gain file's design point ([design] plant and servos): exit 1 below 0.66")
    mg.add_argument("--scenario", default="paper", help="the design airframe and control rate")
    mg.add_argument("--all", action="store_true", help="every break point, not only the worst")
    mg.add_argument("--loops", action="store_true",
                    help="loop at a time instead: each loop and channel opened alone (crossover, phase, gain "
                         "and delay margins) behind the servo models ideal, default and sloppy")  # fmt: skip
    mg.add_argument("--envelope", action="store_true",
                    help="over the envelope instead: trimmed level flight at each --speed-m-s, a computation "
                         "delay in the loop, margins loop at a time and all inputs / all states at once")
    mg.add_argument("--speed-m-s", type=float, action="append", default=None,
                    help="level-flight speed for --envelope (repeat; default 0 2.5 5 7.5 10; "
                         "implies --envelope)")
    mg.add_argument("--delay-ticks", type=int, default=1,
                    help="--envelope: control ticks of computation delay in the loop (default 1)")
    mg.add_argument("--out", default=None, metavar="DIR",
                    help="--envelope: write DIR/margins_envelope.csv and .md (implies --envelope)")
    mg.set_defaults(func=_margins)

    c = sub.add_parser("campaign", help="fly a campaign of flights in-process on Dask; Parquet, figures")
    c.add_argument("file", help="campaign TOML, or a name in configs/campaigns/ (robustness, ...)")
    c.add_argument("--out", required=True, help="output directory (re-running resumes it)")
    c.add_argument("--samples", type=arg.count, default=None, help="override the file's sample count")
    c.add_argument("--workers", type=arg.count, default=None, help="embedded cluster size (default: cores)")
    c.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT", help="a running Dask scheduler")
    c.add_argument("--via", choices=("inprocess", "processes"), default="inprocess",
                   help="processes: also fly the first --limit samples through the process stack and compare")
    c.add_argument("--limit", type=arg.count, default=3, help="samples flown through processes (--via)")
    c.add_argument("--controller", type=controller_arg, default=None, metavar="NAME",
                   help="fly every sample with this controller: tlc, pid or package.module:Class / "
                        "file.py:Class (default: the file's, else tlc)")
    c.add_argument("--no-figures", action="store_true",
                   help="rows and campaign.json only, no figures (~2 s of CPU each); "
                        "a re-run over --out draws them")
    c.add_argument("--quiet", action="store_true", help="no progress bar, no table")
    c.set_defaults(func=_campaign)

    cb = sub.add_parser("can", help="DroneCAN tools: monitor a bus (docs/can.md)")
    can_sub = cb.add_subparsers(dest="can_cmd", required=True)
    cm = can_sub.add_parser("monitor", help="list a CAN bus live, decoded as DroneCAN (like candump)")
    cm.add_argument("bus", nargs="?", default="mcast:0",
                    help="bus spec: mcast[:N] (DroneCAN's UDP multicast, default mcast:0), virtual[:ch], "
                         "udp_multicast[:group[:port]], socketcan[:iface]")
    cm.add_argument("--type", dest="types", action="append", default=[], metavar="NAME",
                    help="list only this DroneCAN type (full name, or its last parts: ArrayCommand); "
                         "repeat for more")
    cm.add_argument("--count", type=arg.count, default=None, metavar="N",
                    help="stop after N listed transfers")
    cm.add_argument("--duration", dest="duration_s", type=arg.positive, default=None, metavar="S",
                    help="stop after S seconds")
    cm.add_argument("--frames", action="store_true", help="also list every frame (id, length, bytes)")
    cm.set_defaults(func=_can_monitor)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_main("heli-sitl", lambda: int(args.func(args)), usage=(ValueError,))


if __name__ == "__main__":
    sys.exit(main())
