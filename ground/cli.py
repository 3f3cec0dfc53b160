"""heli-ground: the ground-station script (upload, fly, log, plot, parameters).

Talks to the vehicle of ``heli-sitl up`` (or any MAVLink vehicle that speaks the same
services) on UDP: ``--gcs-port`` is the port heli-ground listens on, i.e. where the vehicle
sends its ground-station link (14550 by default; the API link is 14540). Exit status: 0 on
success, 1 when the vehicle or the link fails, 2 for a bad command line or input file; the
reason is one line on stderr.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

from autopilot.mcap_log import McapMissingError
from ground.client import (
    PX4_MAIN_AUTO,
    PX4_SUB_MISSION,
    CommandRefusedError,
    GroundClient,
    GroundError,
    MissionProgress,
)
from ground.files import FileFormatError, MissionFile, load_mission, load_trajectory
from ground.log import TlogError, tlog_columns, tlog_to_mcap, write_csv
from heli_common import cli_args as arg
from heli_common.defaults import ports
from heli_common.process import run_main
from heli_common.wire.mavlink.udp import TlogWriter, mavlink2
from heli_common.wire.mavlink.wire import SigningKeyError, f32_text, read_signing_key

PROG = "heli-ground"
HOME_MISMATCH_M = 1.0  # warn when a file's home is farther than this from the vehicle's


PORTS = ports()


class UsageError(Exception):
    """Bad input (file, arguments): exit status 2."""


def _common_options(before_the_command: bool) -> argparse.ArgumentParser:
    """The connection options, taken before the command or after it (``heli-ground --instance 1
    params get X`` and ``heli-ground params get X --instance 1``): after it they have no
    defaults of their own, so that they never undo what was given before."""
    common = argparse.ArgumentParser(add_help=False)
    arg.add_instance_args(common)
    common.add_argument("--gcs-port", type=arg.bind_port, default=None,
                        help=f"UDP port to listen on: where the vehicle sends (default {PORTS.gcs}; "
                             f"{PORTS.api} is the vehicle's second link)")
    common.add_argument("--signing-key", type=Path, default=None,
                        help="MAVLink 2 signing key file (32 bytes or 64 hex digits)")
    common.add_argument("--connect-timeout-s", type=arg.positive, default=30.0,
                        help="how long to wait for the vehicle's heartbeat")
    if not before_the_command:
        for action in common._actions:
            action.default = argparse.SUPPRESS
    return common


def build_parser() -> argparse.ArgumentParser:
    common = _common_options(before_the_command=False)
    p = argparse.ArgumentParser(prog=PROG, description=__doc__, parents=[_common_options(True)],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)

    up = sub.add_parser("upload", parents=[common], help="upload a mission or trajectory file")
    up.add_argument("file", type=Path, help=".waypoints, .plan, trajectory .toml or .csv")
    up.add_argument("--dt-s", type=arg.positive, default=None, help="TOML trajectory sampling step [s]")
    up.set_defaults(func=_upload)

    fly = sub.add_parser("fly", parents=[common],
                         help="upload, arm, start, follow to the end, land, disarm")
    fly.add_argument("file", type=Path)
    fly.add_argument("--dt-s", type=arg.positive, default=None, help="TOML trajectory sampling step [s]")
    fly.add_argument("--tlog", type=Path, default=None, help="also record the flight to this .tlog")
    fly.add_argument("--timeout-s", type=arg.positive, default=None,
                     help="give up following after this long (default: the mission's length + 120 s)")
    fly.add_argument("--quiet", action="store_true", help="no progress bar")
    fly.add_argument("--guided", action="store_true",
                     help="stream the trajectory (.toml/.csv) as SET_POSITION_TARGET_LOCAL_NED instead of "
                          "uploading it: ArduPilot in GUIDED, this bench's vehicle in OFFBOARD")
    fly.add_argument("--rate-hz", type=arg.positive, default=20.0,
                     help="--guided: setpoints per second of the vehicle's clock")
    fly.add_argument("--lift-m", type=float, default=None,
                     help="--guided: fly every setpoint this much higher (default: the lowest point "
                          "3 m above home)")
    fly.add_argument("--window-s", type=float, nargs=2, default=None, metavar=("FROM", "TO"),
                     help="--guided: the tracking window in trajectory time (default: [45, end], or all)")
    fly.add_argument("--pace-port", type=arg.port, default=None,
                     help="--guided: the plant's pacer port (heli-sitl up --firmware ardupilot: 9008+10N): "
                          "the simulation waits for this ground station (for --speedup > 1)")
    fly.add_argument("--track-csv", type=Path, default=None,
                     help="--guided: write the streamed target and the vehicle's estimate to this CSV")
    fly.set_defaults(func=_fly)

    lg = sub.add_parser("log", parents=[common],
                        help="record everything received to a .tlog (or convert one: --mcap/--csv FILE.tlog)")
    lg.add_argument("tlog", type=Path, nargs="?", default=None,
                    help="convert this .tlog (to --mcap and/or --csv) instead of recording")
    lg.add_argument("--out", type=Path, default=None, help="the .tlog to write (recording)")
    lg.add_argument("--csv", type=Path, default=None, help="then export run.csv columns to this file")
    lg.add_argument("--mcap", type=Path, default=None,
                    help="then write the flight as MCAP (Foxglove, PlotJuggler; docs/logs.md) to this file")
    lg.add_argument("--duration-s", type=arg.positive, default=None,
                    help="stop after this long (default: Ctrl-C)")
    lg.set_defaults(func=_log)

    pl = sub.add_parser("plot", help="the paper's Figs 5-8 from a .tlog")
    pl.add_argument("tlog", type=Path)
    pl.add_argument("--out", type=Path, required=True, help="output directory")
    pl.set_defaults(func=_plot)

    pa = sub.add_parser("params", help="vehicle parameters")
    psub = pa.add_subparsers(dest="action", required=True)
    g = psub.add_parser("get", parents=[common], help="print one parameter")
    g.add_argument("name")
    g.set_defaults(func=_param_get)
    s = psub.add_parser("set", parents=[common], help="set one parameter (the vehicle may refuse)")
    s.add_argument("name")
    s.add_argument("value", type=float)
    s.set_defaults(func=_param_set)
    d = psub.add_parser("dump", parents=[common], help="print every parameter (NAME VALUE)")
    d.add_argument("--out", type=Path, default=None, help="write to this file instead")
    d.set_defaults(func=_param_dump)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if argv is None:  # run as a program (not called from Python): SIGTERM ends it as Ctrl-C does,
        from heli_common.process import terminate_on_sigterm  # so a .tlog is closed, not cut

        terminate_on_sigterm()
    arg.resolve_instance(args, {"gcs_port": "gcs"})
    func: Callable[[argparse.Namespace], int] = args.func
    usage = (FileFormatError, TlogError, UsageError, McapMissingError)
    return run_main(PROG, lambda: func(args), usage=usage,
                    failure=(GroundError,), port_hint=" (another ground station listening? see --gcs-port)")


# ----------------------------------------------------------------------------- helpers


def _client(args: argparse.Namespace, tlog: TlogWriter | None = None) -> GroundClient:
    key = None
    if args.signing_key is not None:
        try:
            key = read_signing_key(args.signing_key)
        except SigningKeyError as exc:  # a missing or malformed key file is bad input
            raise UsageError(str(exc)) from exc
    return GroundClient(args.gcs_port, signing_key=key, tlog=tlog, target_system=args.sysid)


def _load(args: argparse.Namespace) -> MissionFile:
    mf = load_mission(args.file, args.dt_s)
    if not mf.items:
        raise UsageError(f"{args.file}: no mission items")
    return mf


def _check_home(gc: GroundClient, mf: MissionFile) -> None:
    """Warn (only) when the file was planned for another home: relative altitudes and local
    positions are about the vehicle's home, not the file's."""
    if mf.home is None:
        return
    from heli_common.geo import geo_to_ned_m

    try:
        home = gc.home()
    except GroundError:
        return
    n, e, d = geo_to_ned_m(home, mf.home.lat_deg, mf.home.lon_deg, mf.home.alt_amsl_m)
    if math.hypot(n, e) > HOME_MISMATCH_M or abs(d) > HOME_MISMATCH_M:
        print(f"{PROG}: warning: the file's home is {math.hypot(n, e):.1f} m / {-d:+.1f} m from the "
              f"vehicle's home ({home.lat_deg:.7f}, {home.lon_deg:.7f}, {home.alt_amsl_m:.1f} m)",
              file=sys.stderr)  # fmt: skip


def _describe(mf: MissionFile) -> str:
    if mf.is_trajectory:
        return f"timed trajectory, {len(mf.items) - 1} samples, {mf.duration_s or 0.0:.1f} s"
    return f"{len(mf.items)} mission items"


# ----------------------------------------------------------------------------- commands


def _upload(args: argparse.Namespace) -> int:
    mf = _load(args)
    with _client(args) as gc:
        gc.connect(args.connect_timeout_s)
        _check_home(gc, mf)
        gc.upload_mission(mf.items)
    print(f"uploaded {args.file} ({_describe(mf)})")
    return 0


def _fly(args: argparse.Namespace) -> int:
    if args.guided:
        return _fly_guided(args)
    mf = _load(args)
    tlog = TlogWriter(args.tlog) if args.tlog else None
    try:
        with _client(args, tlog) as gc:
            gc.connect(args.connect_timeout_s)
            _check_home(gc, mf)
            gc.upload_mission(mf.items)
            print(f"uploaded {args.file} ({_describe(mf)})", flush=True)
            # Mission mode first, then arm: the mission starts on the arming tick (as PX4
            # does), so the trajectory's t = 0 is the moment a held vehicle is released.
            # A vehicle that refuses mission mode while disarmed gets arm + MISSION_START.
            try:
                gc.set_mode(PX4_MAIN_AUTO, PX4_SUB_MISSION)
                gc.arm()
            except CommandRefusedError:
                gc.arm()
                try:
                    gc.start_mission()
                except GroundError:
                    with contextlib.suppress(GroundError):
                        gc.disarm()  # still on the ground: do not leave it armed
                    raise
            t0 = gc.vehicle_time_s()
            prog = _follow(gc, mf, args)
            n = len(mf.items)
            done = "" if mf.is_trajectory else f"; {len(prog.reached)} of {n} items reported reached"
            print(f"mission over after {prog.elapsed_s:.1f} s ({prog.reason}){done}", flush=True)
            if mf.items[-1].command in (mavlink2.MAV_CMD_NAV_LAND, mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH):
                # it ends on the ground: let it settle (EXTENDED_SYS_STATE comes at 1 Hz)
                with contextlib.suppress(GroundError):
                    gc.wait_landed(timeout_s=10.0)
            else:
                gc.recv_match(lambda m: m.get_type() == "EXTENDED_SYS_STATE" and gc.from_vehicle(m), 2.5)
            if gc.landed_state() != mavlink2.MAV_LANDED_STATE_ON_GROUND:
                gc.land()
                print("landing", flush=True)
                gc.wait_landed(timeout_s=180.0)
            _disarm_when_landed(gc)
            t1 = gc.vehicle_time_s()
            took = f" ({t1 - t0:.1f} s of vehicle time after the start)" if t0 is not None and t1 else ""
            print(f"landed and disarmed{took}")
    finally:
        if tlog is not None:
            tlog.close()
    return 0


def _fly_guided(args: argparse.Namespace) -> int:
    from ground.guided import GuidedFlight, GuidedOptions

    traj = load_trajectory(args.file)
    window = None if args.window_s is None else (float(args.window_s[0]), float(args.window_s[1]))
    if window is not None and not (0.0 <= window[0] < window[1]):
        raise UsageError(f"--window-s {window[0]:g} {window[1]:g}: expected 0 <= FROM < TO")
    opts = GuidedOptions(rate_hz=args.rate_hz, lift_m=args.lift_m, window_s=window, pace_port=args.pace_port)
    tlog = TlogWriter(args.tlog) if args.tlog else None
    try:
        with _client(args, tlog) as gc:
            gc.connect(args.connect_timeout_s)
            GuidedFlight(gc, traj, opts, track_csv=args.track_csv,
                         say=lambda line: print(line, flush=True)).run()  # fmt: skip
    finally:
        if tlog is not None:
            tlog.close()
    return 0


def _follow(gc: GroundClient, mf: MissionFile, args: argparse.Namespace) -> MissionProgress:
    from tqdm import tqdm

    timed = mf.is_trajectory
    total = float(mf.duration_s or 0.0) if timed else float(len(mf.items))
    if args.timeout_s is not None:
        timeout = float(args.timeout_s)
    elif timed:
        timeout = total + 120.0
    else:  # a waypoint mission's length is the vehicle's business: allow 30 s per item
        timeout = 120.0 + 30.0 * len(mf.items)
    quiet = True if args.quiet else None  # None: off where stderr is not a terminal (a log)
    with tqdm(total=total, unit="s" if timed else "item", disable=quiet, file=sys.stderr,
              bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} {unit} [{elapsed}<{remaining}]") as bar:

        def update(p: MissionProgress) -> None:
            n = min(total, round(p.elapsed_s) if timed else float(len(p.reached)))
            if n != bar.n:  # redraw on change only (a log file gets one line per redraw)
                bar.update(n - bar.n)

        prog = gc.follow_mission(len(mf.items), duration_s=mf.duration_s if timed else None,
                                 timeout_s=timeout, on_update=update)  # fmt: skip
        bar.update(total - bar.n)
    return prog


def _disarm_when_landed(gc: GroundClient, timeout_s: float = 10.0) -> None:
    """Disarm; the vehicle refuses until it is at rest on the ground, so retry a little."""
    deadline = time.monotonic() + timeout_s
    while True:
        gc.spin(0.3)
        if gc.armed() is False:
            return
        try:
            gc.disarm()
            return
        except GroundError:
            if time.monotonic() > deadline:
                raise


def _log(args: argparse.Namespace) -> int:
    if args.tlog is not None:  # convert a recorded log: no vehicle
        if args.out is not None or (args.csv is None and args.mcap is None):
            raise UsageError("log FILE.tlog converts it: give --mcap OUT.mcap and/or --csv OUT.csv")
        _export(args.tlog, args.csv, args.mcap, args.sysid)
        return 0
    if args.out is None:
        raise UsageError("log: give --out FILE.tlog to record (or a FILE.tlog to convert)")
    _record(args)
    _export(args.out, args.csv, args.mcap, args.sysid)
    return 0


def _export(tlog: Path, csv: Path | None, mcap: Path | None, sysid: int) -> None:
    if csv is not None:
        cols = tlog_columns(tlog)
        write_csv(cols, csv)
        print(f"wrote {csv} ({len(cols['t_s'])} rows)")
    if mcap is not None:
        out, n = tlog_to_mcap(tlog, mcap, system_id=sysid)
        print(f"wrote {out} ({n} rows)")


def _record(args: argparse.Namespace) -> None:
    with TlogWriter(args.out) as tlog, _client(args, tlog) as gc:
        end = None if args.duration_s is None else time.monotonic() + args.duration_s
        try:
            gc.connect(args.connect_timeout_s)
            until = "Ctrl-C to stop" if end is None else f"for {args.duration_s:g} s"
            print(f"recording every message from the vehicle into {args.out} ({until})", flush=True)
            while end is None or time.monotonic() < end:
                gc.spin(1.0 if end is None else max(0.0, min(1.0, end - time.monotonic())))
        except KeyboardInterrupt:
            pass  # the normal way to stop a recording without --duration-s
        n = gc.link.stats.rx_messages
    print(f"wrote {args.out} ({n} messages)")


def _plot(args: argparse.Namespace) -> int:
    from ground.plots import plot_figures

    cols = tlog_columns(args.tlog)
    if len(cols["t_s"]) < 2:
        raise UsageError(f"{args.tlog}: no position telemetry (LOCAL_POSITION_NED) from the vehicle")
    for f in plot_figures(cols, args.out, title=args.tlog.stem):
        print(f"wrote {f}")
    return 0


def _param_get(args: argparse.Namespace) -> int:
    with _client(args) as gc:
        gc.connect(args.connect_timeout_s)
        pv = gc.param_get(args.name)
    print(f"{pv.name} {f32_text(pv.value)}")
    return 0


def _param_set(args: argparse.Namespace) -> int:
    with _client(args) as gc:
        gc.connect(args.connect_timeout_s)
        res = gc.param_set(args.name, args.value)
    if not res.accepted:
        why = f": {res.reason}" if res.reason else ""
        raise GroundError(f"{args.name} = {args.value:g} refused{why} (still {f32_text(res.value.value)})")
    print(f"{res.value.name} {f32_text(res.value.value)}")
    return 0


def _param_dump(args: argparse.Namespace) -> int:
    with _client(args) as gc:
        gc.connect(args.connect_timeout_s)
        params = gc.param_list()
    # MAVProxy's "param save" layout (NAME VALUE), so "param load" reads it back
    text = "".join(f"{pv.name:<16} {f32_text(pv.value)}\n" for pv in params.values())
    if args.out is not None:
        args.out.write_text(text)
        print(f"wrote {args.out} ({len(params)} parameters)")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
