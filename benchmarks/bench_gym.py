"""The Gymnasium environment's speed side by side with RotorPy's and with the cores' pace (issue 49).

Environment steps per second (vehicles x steps / wall) of ``HeliSitl/Track-v0`` through the
public Gymnasium API only (``gymnasium.make`` for one env, ``gymnasium.make_vec(...,
vectorization_mode="vector_entry_point")`` for N = 256 and 4096), zero actions, resets
included as they come; the vectorised env as it comes and again pinned to one core; against

* RotorPy 3.0.0's batched ``QuadrotorEnv`` for the same N (and N = 1), measured by
  ``rotorpy_probe.py`` in a venv of its own (:data:`ROTORPY_VENV`, created here on first use:
  the project's venv never sees torch), one torch thread, 100 Hz, ``cmd_motor_speeds``;
* the floor: the in-process paper flight's ticks per second of wall (``hs.simulate``, the
  compiled loop's own wall time, the fastest flight of :data:`SECONDS` of flights before the
  figures and as many after them) times the cores this process may run on.

Every figure is measured in this run, each within :data:`SECONDS` of wall (plus set-up): the
fastest of :data:`WINDOWS` windows, RotorPy's as ours.
``python -m benchmarks gym`` runs only this group.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np

from benchmarks import Row, above, bench

ENV_ID = "HeliSitl/Track-v0"
SECONDS = 3.0  # timed wall time of each measurement
WINDOWS = 3  # ... split into this many windows: the fastest counts (the machine is shared)
WARMUP_STEPS = 5  # untimed steps first: the compiled kernels load on the first calls
VEC_SIZES = (256, 4096)
ROTORPY_SIZES = (1, *VEC_SIZES)
ROOT = Path(__file__).resolve().parent.parent
ROTORPY_VENV = ROOT / "out" / "bench" / "venv-rotorpy"
PROBE = Path(__file__).resolve().parent / "rotorpy_probe.py"
# torch pinned in every pip call: an unpinned one would pull a multi-GB CUDA build. RotorPy's
# wheel declares none of torch, torchdiffeq, roma and stable-baselines3, which its learning
# module imports; pinned at the versions first measured with so the figures stay comparable.
ROTORPY_REQUIREMENTS = ("torch==2.13.0", "rotorpy==3.0.0", "torchdiffeq==0.2.5", "roma==1.8.0",
                        "stable-baselines3==2.9.2")  # fmt: skip
STAMP = ".heli-sitl-requirements"  # in the venv: what was installed, once it all installed
# RotorPy's own figures for this kind of machine (issue 49), one thread: N -> env-steps/s
ROTORPY_QUOTED = {1: 348.0, 256: 29_200.0}
ONE_ENV_TARGET_X = 100.0  # one env >= 100 x RotorPy's (issue 49)
VEC_TARGET_PCT = 80.0  # the vectorised env >= 80 % of the cores' pace (issue 49)


@dataclass(frozen=True)
class Rate:
    """A timed run: ``vehicles`` stepped ``steps`` times in ``wall_s`` seconds."""

    vehicles: int
    steps: int
    wall_s: float
    resets: int = -1  # vehicles reset within the window, where counted (RotorPy's)

    @property
    def env_steps_per_s(self) -> float:
        return self.vehicles * self.steps / self.wall_s


def best_window(step: Callable[[], object], vehicles: int, seconds: float) -> Rate:
    """``step()`` called for :data:`WINDOWS` consecutive windows of ``seconds / WINDOWS`` wall
    each; the fastest window (the others lost time to whatever else the machine ran)."""
    clock = time.perf_counter
    best = Rate(vehicles, 0, math.inf)
    for _ in range(WINDOWS):
        steps, t0 = 0, clock()
        while True:
            step()
            steps += 1
            wall = clock() - t0
            if wall >= seconds / WINDOWS:
                break
        if steps / wall > best.steps / best.wall_s:
            best = Rate(vehicles, steps, wall)
    return best


# --- ours: the public Gymnasium API only ---------------------------------------------------------


def one_env_rate(seconds: float, unwrapped: bool = False) -> Rate:
    """``gymnasium.make(ENV_ID)`` stepped with a zero action, reset when an episode ends;
    ``unwrapped``: its ``.unwrapped`` env, without the wrappers ``make`` adds (the order
    enforcer, the passive checker), to show what they cost."""
    import gymnasium

    import heli_sitl.gym  # noqa: F401  (registers the id)

    made = gymnasium.make(ENV_ID)
    env = made.unwrapped if unwrapped else made
    action = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    env.reset(seed=0)
    for _ in range(WARMUP_STEPS):
        env.step(action)
    env.reset(seed=1)

    def step() -> None:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()

    rate = best_window(step, 1, seconds)
    made.close()
    return rate


def vec_env_rate(num_envs: int, seconds: float) -> Rate:
    """``gymnasium.make_vec(ENV_ID, num_envs, "vector_entry_point")`` stepped with zero actions
    (it resets its own vehicles: Gymnasium 1.x autoreset)."""
    import gymnasium

    import heli_sitl.gym  # noqa: F401  (registers the id)

    envs = gymnasium.make_vec(ENV_ID, num_envs=num_envs, vectorization_mode="vector_entry_point")
    action = np.zeros(envs.action_space.shape, dtype=envs.action_space.dtype)
    envs.reset(seed=0)
    for _ in range(WARMUP_STEPS):
        envs.step(action)
    envs.reset(seed=1)
    rate = best_window(lambda: envs.step(action), num_envs, seconds)
    envs.close()
    return rate


def vec_env_rate_one_core(num_envs: int, seconds: float) -> Rate:
    """The same in a child process pinned to one CPU with one numba and one BLAS thread,
    whatever way the env parallelises (threads or processes inherit the pinning)."""
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
           "OPENBLAS_NUM_THREADS": "1"}  # fmt: skip
    cmd = [sys.executable, "-m", "benchmarks.bench_gym", "--one-core", str(num_envs), str(seconds)]
    done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    if done.returncode != 0:
        raise RuntimeError(_last_line(done.stderr))
    r = json.loads(done.stdout.strip().splitlines()[-1])
    return Rate(int(r["vehicles"]), int(r["steps"]), float(r["wall_s"]))


def _one_core_child(num_envs: int, seconds: float) -> None:
    """``python -m benchmarks.bench_gym --one-core N SECONDS``: pin, measure, print JSON."""
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    r = vec_env_rate(num_envs, seconds)
    print(json.dumps({"vehicles": r.vehicles, "steps": r.steps, "wall_s": r.wall_s}))


# --- the floor -------------------------------------------------------------------------------------


def flight_ticks_per_s(seconds: float) -> float:
    """Ticks per second of wall of the in-process paper flight (``hs.simulate()``, the
    compiled loop's own wall time): the fastest of the flights flown in ``seconds`` (at least
    3) after a first one that loads the kernels. A flight lasts some 40 ms: the fastest is one
    the rest of the machine left alone, so the floor leans high (the ratios to it low)."""
    import heli_sitl as hs

    hs.simulate()
    best, flights, t0 = 0.0, 0, time.perf_counter()
    while flights < 3 or time.perf_counter() - t0 < seconds:
        rec = hs.simulate().record
        assert rec is not None  # the paper flight does not fail
        best = max(best, (rec.t_s.size - 1) / rec.wall_s)
        flights += 1
    return best


def cores() -> int:
    return len(os.sched_getaffinity(0))


# --- RotorPy, in its own venv ----------------------------------------------------------------------


def _last_line(text: str) -> str:
    """What a failed child said: pip's first ERROR line, else its last line."""
    lines = [ln.strip() for ln in text.strip().splitlines() if ln.strip()]
    errors = [ln.removeprefix("ERROR: ") for ln in lines if ln.startswith("ERROR")]
    return errors[0] if errors else (lines or ["no output"])[-1]


def _run(cmd: list[str]) -> None:
    """One install step; RuntimeError saying why when it fails."""
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=1200)
    except subprocess.TimeoutExpired:
        raise RuntimeError(f"{' '.join(cmd[-2:])}: timed out") from None
    if done.returncode != 0:
        raise RuntimeError(f"install failed: {_last_line(done.stderr + done.stdout)}")


def rotorpy_python() -> Path:
    """The interpreter of RotorPy's venv, creating the venv and installing the pinned
    requirements when it is missing or holds other versions. Raises RuntimeError naming why
    it cannot (e.g. no package index reachable)."""
    py = ROTORPY_VENV / "bin" / "python"
    want = "\n".join(ROTORPY_REQUIREMENTS) + "\n"
    stamp = ROTORPY_VENV / STAMP
    if py.is_file() and stamp.is_file() and stamp.read_text() == want:
        return py
    shutil.rmtree(ROTORPY_VENV, ignore_errors=True)
    ROTORPY_VENV.parent.mkdir(parents=True, exist_ok=True)
    print(f"  creating {os.path.relpath(ROTORPY_VENV, ROOT)} for RotorPy (once)", file=sys.stderr, flush=True)
    pip = [str(py), "-m", "pip", "install", "--quiet", "--retries", "1", "--timeout", "30"]
    report = ROTORPY_VENV / "torch-choice.json"
    _run([sys.executable, "-m", "venv", str(ROTORPY_VENV)])
    # which torch plain pip would take, before taking it: only a CPU build (a "+cpu" wheel,
    # as this machine's pip finds one); PyPI's own is the CUDA build with GBs of dependencies
    _run([*pip, "--dry-run", "--no-deps", "--ignore-installed", "--report", str(report),
          ROTORPY_REQUIREMENTS[0]])  # fmt: skip
    chosen = json.loads(report.read_text())["install"][0]
    version = chosen["metadata"]["version"]
    if not version.endswith("+cpu"):
        where = urlsplit(chosen["download_info"]["url"]).netloc or "a local file"
        raise RuntimeError(f"pip offers torch {version} from {where}, not a CPU build: not installed")
    # torch alone first, then the rest with torch pinned again so that the resolver keeps it
    _run([*pip, ROTORPY_REQUIREMENTS[0]])
    _run([*pip, *ROTORPY_REQUIREMENTS])
    stamp.write_text(want)
    return py


def rotorpy_rates(seconds: float) -> dict[int, Rate]:
    """RotorPy's env-steps per second for :data:`ROTORPY_SIZES`, one thread, zero actions."""
    py = rotorpy_python()
    cmd = [str(py), str(PROBE), "--envs", *map(str, ROTORPY_SIZES), "--seconds", str(seconds),
           "--windows", str(WINDOWS)]
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
    done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        raise RuntimeError(f"probe failed: {_last_line(done.stderr)}")
    out = json.loads(done.stdout.strip().splitlines()[-1])
    return {int(r["num_envs"]): Rate(int(r["num_envs"]), int(r["steps"]), float(r["wall_s"]),
                                     int(r["resets"])) for r in out["runs"]}  # fmt: skip


# --- the table -------------------------------------------------------------------------------------


def _failed(what: str, exc: Exception) -> Row:
    why = str(exc) if isinstance(exc, RuntimeError) else f"{type(exc).__name__}: {exc}"
    return Row(f"{what}: not measured: {why}"[:120], math.nan, "")


@bench("Gymnasium env vs RotorPy")
def bench_gym() -> list[Row]:
    """Ours, RotorPy's and the floor, each measured here; a part that cannot run says why in
    its row and the others still run."""
    rows: list[Row] = []
    n_cores = cores()
    # the floor before the figures, and again after them (below): the faster of the two counts
    tick_rate = flight_ticks_per_s(SECONDS)

    rotorpy: dict[int, Rate] = {}
    try:
        rotorpy = rotorpy_rates(SECONDS)
    except Exception as exc:  # no index, no wheel, a broken probe: the rest still runs
        rows.append(_failed("RotorPy 3.0.0", exc))

    def vs_rotorpy(ours: float, n: int, target: float | None = None) -> list[Row]:
        if n not in rotorpy:
            return []
        x = ours / rotorpy[n].env_steps_per_s
        name = f"  / RotorPy's, N = {n}"
        return [Row(name, x, "x", *above(x, target))] if target is not None else [Row(name, x, "x")]

    measured: dict[int, float] = {}  # ours, N -> env-steps/s (N = 1: gymnasium.make)
    one_core: dict[int, float] = {}  # ours pinned to one core
    failed: list[Row] = []
    bare = math.nan  # the one env without make's wrappers
    try:
        measured[1] = one_env_rate(SECONDS).env_steps_per_s
        bare = one_env_rate(SECONDS, unwrapped=True).env_steps_per_s
    except Exception as exc:
        failed.append(_failed(f"ours, one env ({ENV_ID})", exc))
    for n in VEC_SIZES:
        try:
            measured[n] = vec_env_rate(n, SECONDS).env_steps_per_s
        except Exception as exc:
            failed.append(_failed(f"ours, vector env N = {n}", exc))
            continue
        try:
            one_core[n] = vec_env_rate_one_core(n, SECONDS).env_steps_per_s
        except Exception as exc:
            failed.append(_failed(f"ours, vector env N = {n} on one core", exc))
    tick_rate = max(tick_rate, flight_ticks_per_s(SECONDS))
    pace = tick_rate * n_cores
    rows.append(Row("floor: in-process paper flight (hs.simulate), ticks per s of wall, best of the run",
                    tick_rate, "steps/s"))  # fmt: skip
    rows.append(Row(f"floor: the cores' pace, x {n_cores} cores", pace, "steps/s"))
    for n, r in rotorpy.items():
        quoted = f"; issue 49 quotes {ROTORPY_QUOTED[n]:,.0f}" if n in ROTORPY_QUOTED else ""
        name = f"RotorPy 3.0.0 QuadrotorEnv N = {n}, 1 thread, 100 Hz, zero actions"
        rows.append(Row(f"{name} ({r.steps} steps, {r.resets} resets{quoted})", r.env_steps_per_s, "steps/s"))
    rows += failed

    def vs_quoted(ours: float, n: int) -> list[Row]:
        if n not in ROTORPY_QUOTED:
            return []
        return [Row(f"  / RotorPy's quoted {ROTORPY_QUOTED[n]:,.0f} (issue 49), N = {n}",
                    ours / ROTORPY_QUOTED[n], "x")]  # fmt: skip

    if 1 in measured:
        one = measured[1]
        rows.append(Row("ours, one env (gymnasium.make), zero action", one, "steps/s"))
        rows += vs_rotorpy(one, 1, ONE_ENV_TARGET_X)
        rows += vs_quoted(one, 1)
        rows.append(Row("  / one core's pace (the flight's tick rate)", 100 * one / tick_rate, "%"))
        rows.append(Row("  the same unwrapped (env.unwrapped: without make's wrappers)", bare, "steps/s"))
    for n in VEC_SIZES:
        if n not in measured:
            continue
        vec = measured[n]
        rows.append(Row(f"ours, vector env N = {n} (make_vec, vector_entry_point), as it comes",
                        vec, "steps/s"))  # fmt: skip
        pct = 100 * vec / pace
        rows.append(Row(f"  / the cores' pace ({n_cores} cores)", pct, "%", *above(pct, VEC_TARGET_PCT)))
        rows += vs_rotorpy(vec, n)
        rows += vs_quoted(vec, n)
        if n in one_core:
            single = one_core[n]
            rows.append(Row("  the same pinned to one core, one thread", single, "steps/s"))
            rows.append(Row("    / one core's pace (the flight's tick rate)", 100 * single / tick_rate, "%"))
            rows.append(Row("    as it comes / on one core", vec / single, "x"))

    return rows


if __name__ == "__main__":
    if sys.argv[1:2] == ["--one-core"]:
        _one_core_child(int(sys.argv[2]), float(sys.argv[3]))
    else:
        print("usage: python -m benchmarks.bench_gym --one-core N SECONDS", file=sys.stderr)
        raise SystemExit(2)
