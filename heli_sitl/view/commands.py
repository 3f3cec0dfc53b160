"""What the command line does with ``--view`` and ``heli-sitl view`` (heli_sitl/cli.py wires
these in; the launchers know nothing of the view).

* :func:`live_for_scenario`: a live view set up from a scenario (its pitch limits, its
  reference path drawn in advance), listening for the vehicle's telemetry.
* :func:`serve_until_interrupted`: keep a view up until Ctrl-C / SIGTERM.
* :func:`view_command`: ``heli-sitl view DIR|FILE`` (a replay) or ``heli-sitl view --listen
  PORT`` (a live view of whatever vehicle sends its MAVLink telemetry to that UDP port).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

import numpy as np

from heli_common.state import FloatArray
from heli_common.wire import servo_map
from heli_common.wire.mavlink.udp import Address
from heli_sitl.view.live import LiveView, open_live_view
from heli_sitl.view.recording import RecordingError, load_recording
from heli_sitl.view.replay import Replay
from heli_sitl.view.scene import SceneOptions

PATH_POINTS = 2000  # the reference path drawn from the scenario's trajectory


def scenario_limits_and_path(scenario: str, duration_s: float | None = None) -> tuple[FloatArray, FloatArray]:
    """The scenario's pitch limits (4, 2) and its reference path (N, 3), NWU."""
    from autopilot.scenario import Scenario

    sc = Scenario.load(scenario)
    t = np.linspace(0.0, duration_s or sc.run.duration_s, PATH_POINTS)
    return servo_map.limits_array(sc.airframe.limits.as_tuple()), sc.trajectory.sample(t)[:, 0:3]


def live_for_scenario(
    view_port: int, scenario: str, *, duration_s: float | None = None, forward_to: Address | None = None,
    feed_port: int = 0, title: str | None = None, draw_path: bool = True,
) -> LiveView:  # fmt: skip
    """A started live view of a vehicle of ``scenario`` (see the module docstring); ``draw_path``:
    the vehicle flies the scenario's trajectory (else the path is drawn as the targets come)."""
    limits, path = scenario_limits_and_path(scenario, duration_s)
    return open_live_view(view_port, limits_rad=limits, path_nwu_m=path if draw_path else None,
                          feed_port=feed_port, forward_to=forward_to,
                          title=title or f"live: {scenario}")  # fmt: skip


def announce(prog: str, url: str, what: str) -> None:
    print(f"{prog}: {what} at {url} (open it in a browser; loopback only)", flush=True)


def serve_until_interrupted(stop: threading.Event | None = None) -> None:
    """Block until Ctrl-C (or SIGTERM made KeyboardInterrupt), or ``stop`` is set."""
    ev = stop or threading.Event()
    try:
        while not ev.wait(0.5):
            pass
    except KeyboardInterrupt:
        # stopping: a second signal (the launcher's SIGTERM after our parent's death signal)
        # must not cut the view's own shutdown and its report short
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            signal.signal(signal.SIGINT, signal.SIG_IGN)


def report(prog: str, view: LiveView) -> None:
    """The push loop's figures, one line (frames pushed and their rate while frames came)."""
    s = view.stats()
    f = view.feed.stats()
    print(f"{prog}: view pushed {s.frames} frames in {s.first_to_last_s:.1f} s "
          f"({s.rate_hz:.1f} frames/s); "
          f"read {f.messages} MAVLink messages, {f.positions} positions"
          + (f", dropped {f.foreign} datagrams of other senders" if f.foreign else ""),
          flush=True)  # fmt: skip


def view_command(args: argparse.Namespace) -> int:
    """``heli-sitl view``: replay a recorded flight, or show a live one (``--listen``)."""
    from heli_common.process import terminate_on_sigterm

    terminate_on_sigterm()
    if args.listen is not None:
        limits = None
        path = None
        if args.scenario:
            limits, path = scenario_limits_and_path(args.scenario)
        live = open_live_view(args.port, limits_rad=limits, path_nwu_m=path, feed_port=args.listen,
                              title=f"live: UDP {args.listen}")  # fmt: skip
        announce("heli-sitl view", live.url,
                 f"live view of the vehicle sending to UDP 127.0.0.1:{args.listen}")
        try:
            serve_until_interrupted()
        finally:
            live.close()
            report("heli-sitl view", live)
        return 0
    if args.recording is None:
        print("heli-sitl view: give a run directory or file to replay, or --listen PORT", file=sys.stderr)
        return 2
    try:
        rec = load_recording(Path(args.recording))
    except RecordingError as exc:
        print(f"heli-sitl view: {exc}", file=sys.stderr)
        return 2
    limits = None
    if args.scenario:
        limits = scenario_limits_and_path(args.scenario)[0]
    opts = SceneOptions(title=f"replay: {rec.source}") if limits is None else SceneOptions(
        title=f"replay: {rec.source}", limits_rad=tuple((float(a), float(b)) for a, b in limits))  # fmt: skip
    replay = Replay(rec, args.port, options=opts, playing=not args.paused).start()
    announce("heli-sitl view", replay.url,
             f"replay of {rec.source} ({rec.duration_s:.1f} s, {len(rec.t_s)} rows)")
    try:
        serve_until_interrupted()
    finally:
        replay.close()
    return 0


def replay_after(prog: str, run_csv: Path, port: int) -> None:
    """``simulate --view``: the finished flight replayed until Ctrl-C (an in-process flight
    is over in a fraction of a second, before any browser could show it live)."""
    replay = Replay(load_recording(run_csv), port).start()
    announce(prog, replay.url, f"replay of the flight just flown ({run_csv}); Ctrl-C to stop")
    try:
        serve_until_interrupted()
    finally:
        replay.close()
