"""heli-sitl demo: plant and autopilot as separate OS processes on loopback, flying a scenario.

Every process started here is stopped on success, error or Ctrl-C; a failure exits
non-zero with a one-line reason (busy port, a process died, timeout).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from heli_sitl.mavlink_link import LOOPBACK


class DemoError(RuntimeError):
    """One-line reason the demo failed."""


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((LOOPBACK, 0))
        return int(s.getsockname()[1])


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
    extra_plant_args: tuple[str, ...] = ()
    extra_autopilot_args: tuple[str, ...] = ()


def _cmd(module: str) -> list[str]:
    return [sys.executable, "-m", module]


def run_demo(opts: DemoOptions) -> dict[str, object]:
    opts.out.mkdir(parents=True, exist_ok=True)
    pp = opts.plant_port or free_udp_port()
    ap = opts.autopilot_port or free_udp_port()
    common = ["--mode", opts.mode, "--rate-hz", str(opts.rate_hz), "--scenario", opts.scenario]
    if opts.duration_s is not None:
        common += ["--duration-s", str(opts.duration_s)]
    plant_cmd = _cmd("heli_sitl.cli") + ["run", *common, "--port", str(pp),
                                         "--autopilot-port", str(ap), *opts.extra_plant_args]
    ap_cmd = _cmd("autopilot.cli") + [*common, "--port", str(ap), "--plant-port", str(pp),
                                      "--autostart", "--out", str(opts.out),
                                      *opts.extra_autopilot_args]  # fmt: skip
    procs: list[tuple[str, subprocess.Popen[bytes]]] = []
    env = dict(os.environ)
    try:
        for name, cmd in (("plant", plant_cmd), ("autopilot", ap_cmd)):
            procs.append((name, subprocess.Popen(cmd, stderr=subprocess.PIPE, env=env)))
        limit = opts.timeout_s or (600.0 if opts.mode == "lockstep" else 400.0)
        deadline = time.monotonic() + limit
        autopilot = procs[1][1]
        while autopilot.poll() is None:
            for name, p in procs:
                if p.poll() is not None and p.returncode != 0:
                    raise DemoError(f"{name} died: {_reason(p)}")
            if time.monotonic() > deadline:
                raise DemoError(f"timeout: the flight did not finish within {limit:.0f} s")
            time.sleep(0.05)
        if autopilot.returncode != 0:
            raise DemoError(f"autopilot failed: {_reason(autopilot)}")
    finally:
        for _, p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for _, p in procs:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    summary_path = opts.out / "summary.json"
    if not summary_path.is_file():
        raise DemoError("autopilot wrote no summary.json")
    summary: dict[str, object] = json.loads(summary_path.read_text())
    return summary


def _reason(p: subprocess.Popen[bytes]) -> str:
    err = p.stderr.read().decode(errors="replace").strip() if p.stderr else ""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    return lines[-1] if lines else f"exit code {p.returncode}"
