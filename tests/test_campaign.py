"""Campaigns (heli-sitl campaign): files checked before anything flies, samplers that draw
the declared distributions, the same rows from the same file whatever the cluster, a real
Dask scheduler and workers on loopback, resuming after a SIGKILL, a worker killed mid-way,
the figures drawn on the cluster byte for byte as here, a figure that fails costing nothing else.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from ports import new_port
from scipy import stats

from heli_common.config import ConfigError
from heli_common.threads import SINGLE_THREAD_ENV
from heli_sitl.studies.campaigns import engine, report
from heli_sitl.studies.campaigns.run import prepare, run_campaign
from heli_sitl.studies.campaigns.sampling import flight_count, sample_table
from heli_sitl.studies.campaigns.spec import parse

ROOT = Path(__file__).resolve().parent.parent

# 12 short flights in a world with turbulence and noisy sensors: every random stream on
SMALL = """
name = "small"
scenario = "paper"
world = "gps-typical"
samples = 12
sampler = "lhs"
seed = 3
duration_s = 12.0

[[vary]]
key = "plant.mismatch.mass"
dist = "uniform"
low = 0.9
high = 1.1

[[vary]]
key = "world.wind.speed_m_s"
dist = "uniform"
low = 0.0
high = 4.0

[[vary]]
key = "servo.tau_s"
dist = "truncnormal"
mean = 0.01
sd = 0.01
low = 0.0
high = 0.03
"""


def small_file(tmp_path: Path, text: str = SMALL, world: str = "") -> Path:
    f = tmp_path / "small.toml"
    body = text
    if world:
        body = body.replace('world = "gps-typical"', f'world = "{world}"')
    f.write_text(body)
    # the wind acts only with air loads on: a world file with the sensors and the air
    w = tmp_path / "air-and-gps.toml"
    w.write_text(
        (ROOT / "configs/world/gps-typical.toml")
        .read_text()
        .replace('name = "gps-typical"', 'name = "air-and-gps"')
        + "\n[air]\nfuselage = true\nrotor_inflow = true\n"
        "\n[turbulence]\nw20_m_s = 3.0\n"
    )
    f.write_text(f.read_text().replace('world = "gps-typical"', f'world = "{w}"'))
    return f


def rows(out: Path) -> list[dict[str, object]]:
    """The rows, without the one column that differs from run to run (each flight's wall
    time); NaN as None, so that equal rows compare equal."""
    out_rows = []
    for r in pq.read_table(out / engine.RESULTS).to_pylist():
        r.pop("wall_s")
        out_rows.append({k: None if isinstance(v, float) and v != v else v for k, v in r.items()})
    return out_rows


BAD = [
    ('nme = "x"\n', "unknown key 'nme' (did you mean 'name'?)"),
    (
        'sampler = "halton"\n[[vary]]\nkey = "plant.mismatch.mass"\nlow = 0.9\nhigh = 1.1\n',
        "sampler: expected one of",
    ),
    ('samples = 0\n[[vary]]\nkey = "plant.mismatch.mass"\nlow = 0.9\nhigh = 1.1\n', "samples"),
    ('[[vary]]\nkey = "world.wnd.speed_m_s"\nlow = 0.0\nhigh = 1.0\n', "world.wnd.speed_m_s"),
    (
        '[[vary]]\nkey = "plant.mismatch.mass"\nlow = 1.1\nhigh = 0.9\n',
        "(plant.mismatch.mass): low (1.1) must be below high",
    ),
    (
        '[[vary]]\nkey = "plant.mismatch.mass"\ndist = "normal"\nmean = 1.0\nsd = 0.0\n',
        "(plant.mismatch.mass).sd",
    ),
    ('[[vary]]\nkey = "plant.mismatch.mass"\ndist = "gamma"\n', "(plant.mismatch.mass).dist"),
    ('[[vary]]\nkey = "plant.mismatch.mass"\nlow = 0.9\nhigh = 1.1\nstep = 2\n', "unknown key 'step'"),
    (
        '[[vary]]\nkey = "plant.mismatch.mass"\ndist = "grid"\nlow = 0.9\nhigh = 1.1\nn = 3\n',
        'a grid needs sampler = "grid"',
    ),
    ('[[vary]]\nkey = "world.wind.speed_m_s"\nlow = 0.0\nhigh = 500.0\n', "world.wind.speed_m_s"),
    ('[[vary]]\nkey = "servo.tau_s[7]"\nlow = 0.0\nhigh = 0.1\n', "index 7 out of range"),
    ('[[vary]]\nkey = "world.wind"\nlow = 0.0\nhigh = 1.0\n', "a table, not a number"),
    ('[[vary]]\nkey = "speed"\nlow = 0.0\nhigh = 1.0\n', "speed: unknown setting"),
    (
        '[[vary]]\nkey = "plant.mismatch.mass"\nlow = 0.9\nhigh = 1.1\n'
        '[[vary]]\nkey = "world.mismatch.mass"\nlow = 0.9\nhigh = 1.1\n',
        "name the same setting",
    ),
    (
        'metrics = ["rms"]\n[[vary]]\nkey = "plant.mismatch.mass"\nlow = 0.9\nhigh = 1.1\n',
        "unknown key 'rms'",
    ),
    (
        '[[vary]]\nkey = "plant.mismatch.mass"\ndist = "truncnormal"\nmean = 2.0\nsd = 0.1\n'
        "low = 0.9\nhigh = 1.1\n",
        "the mean must lie within",
    ),
    ('world = "nowhere"\n[[vary]]\nkey = "plant.mismatch.mass"\nlow = 0.9\nhigh = 1.1\n', "nowhere"),
    ('controller = "lqr"\n[[vary]]\nkey = "plant.mismatch.mass"\nlow = 0.9\nhigh = 1.1\n', "controller"),
    ('feedforward = "x"\n[[vary]]\nkey = "plant.mismatch.mass"\nlow = 0.9\nhigh = 1.1\n', "feedforward"),
    ('controller = "pid"\n[[vary]]\nkey = "pid.rate.kq"\nlow = 1.0\nhigh = 2.0\n', "pid.rate.kq"),
    ('controller = "pid"\n[[vary]]\nkey = "pid.rate.kp"\nlow = 1.0\nhigh = 900.0\n', "pid.rate.kp"),
]


@pytest.mark.parametrize(("text", "expected"), BAD)
def test_bad_campaign_files_are_refused_before_flying_naming_the_key(
    tmp_path: Path, text: str, expected: str
) -> None:
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as err:
        prepare(f)
    msg = str(err.value)
    assert expected in msg and "\n" not in msg, msg


def test_the_controller_is_a_campaign_key_and_its_gains_can_vary(tmp_path: Path) -> None:
    """``controller = "pid"`` (or ``--controller pid``) flies the PID baseline: a row is the
    metrics of that very flight; ``pid.*`` varies its gains; the same samples either way."""
    import dataclasses

    from autopilot.pid.gains import default_pid_gains
    from autopilot.scenario import Scenario
    from heli_sitl.engine.closed_loop import SimOptions, simulate
    from heli_sitl.studies.campaigns.flight import fly, metrics

    f = tmp_path / "c.toml"
    f.write_text('samples = 2\nseed = 4\nduration_s = 20.0\n[[vary]]\nkey = "pid.rate.kp"\n'
                 "low = 4.0\nhigh = 8.0\n")  # fmt: skip
    with pytest.raises(ConfigError, match=r"pid.rate.kp: varies the PID.s gains, but the campaign flies the TLC"):  # noqa: E501
        prepare(f)  # the TLC would ignore pid.*: flights that differ in name only
    spec_p, base_p, table_p = prepare(f, controller="pid")
    assert spec_p.controller == "pid" and base_p.controller == "pid"
    kp = float(table_p[0, 0])
    assert 4.0 <= kp <= 8.0
    row_p = fly(spec_p, base_p, 0, spec_p.keys, [kp])
    assert not row_p["failed"]
    pid = base_p.pid_gains or default_pid_gains()
    gains = dataclasses.replace(pid, rate=dataclasses.replace(pid.rate, kp=(kp, kp, kp)))
    rec = simulate(Scenario.load("paper"), SimOptions(duration_s=20.0, controller="pid", pid_gains=gains))
    direct = metrics(rec, spec_p)
    assert row_p["rms_0_m"] == direct["rms_0_m"] and row_p["pitch_travel_rad"] == direct["pitch_travel_rad"]
    # the same samples for either controller: a TLC campaign of the same draws
    g = tmp_path / "t.toml"
    head = "samples = 2\nseed = 4\nduration_s = 20.0\n[[vary]]\n"
    g.write_text(head + 'key = "initial.yaw_error_rad"\nlow = 0.0\nhigh = 0.5\n')
    spec_t, base_t, table_t = prepare(g)
    spec_q, base_q, table_q = prepare(g, controller="pid")
    np.testing.assert_array_equal(table_t, table_q)
    row_t = fly(spec_t, base_t, 0, spec_t.keys, table_t[0].tolist())
    row_q = fly(spec_q, base_q, 0, spec_q.keys, table_q[0].tolist())
    assert not row_t["failed"] and row_t["rms_0_m"] != row_q["rms_0_m"]  # another controller, another flight
    h = tmp_path / "h.toml"
    h.write_text(head + 'key = "gains.loop4.omega_rad_s"\nlow = 8.0\nhigh = 12.0\n')
    with pytest.raises(ConfigError, match=r"gains.loop4.omega_rad_s: varies the TLC's gains, but .* the PID"):
        prepare(h, controller="pid")


def test_the_plant_is_a_campaign_key(tmp_path: Path) -> None:
    """``plant = "gavrilets"`` flies every sample on the rotor plant: a row is that flight's
    metrics; a plant that does not load is refused before anything flies."""
    from heli_common.vehicle.plant_model import PlantModel
    from heli_sitl.engine.closed_loop import SimOptions, simulate
    from heli_sitl.studies.campaigns.flight import fly, metrics
    from heli_sitl.studies.campaigns.settings import apply

    body = ('samples = 2\nseed = 4\nduration_s = 10.0\n[[vary]]\nkey = "initial.yaw_error_rad"\n'
            "low = 0.0\nhigh = 0.5\n")
    f, g = tmp_path / "gav.toml", tmp_path / "paper.toml"
    f.write_text('plant = "gavrilets"\n' + body)
    g.write_text(body)
    spec, base, table = prepare(f)
    assert spec.plant == "gavrilets" and base.plant.kind == "gavrilets"
    values = table[0].tolist()
    row = fly(spec, base, 0, spec.keys, values)
    assert not row["failed"]
    spec_p, base_p, _ = prepare(g)
    assert base_p.plant.kind == "paper"
    assert row["rms_0_m"] != fly(spec_p, base_p, 0, spec_p.keys, values)["rms_0_m"]  # another plant
    settings = {**dict(zip(spec.keys, values, strict=True)), "world.seed": float(row["seed"])}
    flight = apply(base, settings)
    rec = simulate(flight.scenario, SimOptions(world=flight.world, duration_s=10.0,
                                               plant=PlantModel.load("gavrilets")))  # fmt: skip
    assert metrics(rec, spec)["rms_0_m"] == row["rms_0_m"]  # the row is that very flight
    f.write_text('plant = "nowhere.toml"\n' + body)
    with pytest.raises(ConfigError, match=r"nowhere\.toml"):
        prepare(f)


def test_shipped_campaigns_are_valid_and_sized_as_documented() -> None:
    sizes = {
        "robustness": 1000,
        "region_of_attraction": 10 * 5 * 3,
        "margins": 13 * 11,
        "sensitivity": 128 * 14,
        "linkage-sweep": 10 * 10,
    }
    for name, n in sizes.items():
        spec, _, table = prepare(name)
        assert table.shape == (n, len(spec.vary)) == (flight_count(spec), len(spec.vary))


def test_samplers_draw_the_declared_marginals() -> None:
    vary = [
        {"key": "world.wind.speed_m_s", "dist": "uniform", "low": 1.0, "high": 3.0},
        {"key": "world.wind.from_deg", "dist": "normal", "mean": 90.0, "sd": 20.0},
        {"key": "servo.tau_s", "dist": "truncnormal", "mean": 0.02, "sd": 0.02, "low": 0.0, "high": 0.05},
        {"key": "servo.delay_s", "dist": "choice", "values": [0.0, 0.01, 0.02]},
    ]
    dists = [
        stats.uniform(1.0, 2.0),
        stats.norm(90.0, 20.0),
        stats.truncnorm((0.0 - 0.02) / 0.02, (0.05 - 0.02) / 0.02, loc=0.02, scale=0.02),
    ]
    for sampler in ("random", "lhs", "sobol"):
        spec = parse({"samples": 2000, "sampler": sampler, "seed": 7, "vary": vary}, "t")
        t = sample_table(spec)
        assert t.shape == (2000, 4)
        for j, d in enumerate(dists):
            p = stats.kstest(t[:, j], d.cdf).pvalue
            assert p > 0.01, (sampler, vary[j]["key"], p)
        freq = np.array([np.mean(t[:, 3] == v) for v in (0.0, 0.01, 0.02)])
        np.testing.assert_allclose(freq, 1 / 3, atol=0.04)
        again = sample_table(spec)
        np.testing.assert_array_equal(t, again)  # the seed fixes the samples
    grid = parse(
        {
            "sampler": "grid",
            "vary": [
                {"key": "servo.delay_s", "dist": "grid", "low": 0, "high": 0.02, "n": 3},
                {"key": "servo.tau_s", "dist": "choice", "values": [0.0, 0.05]},
            ],
        },
        "t",
    )
    np.testing.assert_allclose(
        sample_table(grid), [[0, 0], [0, 0.05], [0.01, 0], [0.01, 0.05], [0.02, 0], [0.02, 0.05]]
    )
    sal = parse({"sampler": "saltelli", "samples": 16, "vary": vary[:3]}, "t")
    assert sample_table(sal).shape == (16 * 5, 3) and flight_count(sal) == 80


@pytest.mark.slow
@pytest.mark.processes
def test_same_file_same_rows_on_one_and_two_workers(tmp_path: Path) -> None:
    f = small_file(tmp_path)
    bare = run_campaign(f, tmp_path / "a", workers=1, quiet=True, figures=False)
    assert bare["figures"] == [] and not list((tmp_path / "a").glob("*.png"))
    s = run_campaign(f, tmp_path / "b", workers=2, quiet=True)
    a, b = rows(tmp_path / "a"), rows(tmp_path / "b")
    assert [r["sample_id"] for r in a] == list(range(12))
    assert a == b  # every value, metric and seed
    assert not any(r["failed"] for r in a)
    assert len({r["seed"] for r in a}) == 12  # one random stream per flight
    assert s["counts"]["flights"] == 12
    assert (tmp_path / "b" / "campaign.json").is_file() and (tmp_path / "b" / "hist.png").is_file()
    # the same command again: everything is there, nothing flies
    again = run_campaign(f, tmp_path / "b", workers=2, quiet=True)
    assert again["run"]["flown_now"] == 0 and rows(tmp_path / "b") == b
    # the campaign flown without figures, run again: no flight, and now its figures
    drawn = run_campaign(f, tmp_path / "a", workers=1, quiet=True)
    assert drawn["run"]["flown_now"] == 0 and drawn["figures"] == s["figures"] != []
    assert (tmp_path / "a" / "hist.png").read_bytes() == (tmp_path / "b" / "hist.png").read_bytes()


def test_tasks_are_guided_big_first_single_flights_last() -> None:
    spec, _, _ = prepare("robustness", 10)
    for n, workers in ((1000, 2), (200, 2), (200, 1), (7, 4), (1, 2)):
        todo = list(range(3, 3 + n))
        tasks = engine.batches(spec, todo, workers)
        assert [i for t in tasks for i in t] == todo  # each sample once, in order
        sizes = [len(t) for t in tasks]
        assert sizes == sorted(sizes, reverse=True) and max(sizes) <= engine.MAX_BATCH
        assert sizes[-1] == 1  # the tail: single flights
    assert [len(t) for t in engine.batches(spec, list(range(1000)), 2)][:13] == [50] * 13
    # a fixed batch in the file wins
    fixed = dataclasses.replace(spec, batch=7)
    assert [len(t) for t in engine.batches(fixed, list(range(20)), 2)] == [7, 7, 6]


def test_a_flight_in_a_worker_does_not_fault_its_arrays_in_page_by_page() -> None:
    """The embedded cluster's malloc settings (engine.CLUSTER_CONFIG): under Dask's own
    (MALLOC_TRIM_THRESHOLD_=65536) a campaign flight in a worker took ~2000 minor page
    faults (its arrays' memory handed back to the OS and faulted in again, flight after
    flight) and its Python part ran at half speed; now ~1, as in a plain loop."""
    spec, base, table = prepare("robustness", 4)

    def faults_per_flight() -> tuple[float, str | None, str | None]:
        import resource

        from heli_sitl.studies.campaigns.flight import fly

        fly(spec, base, 0, spec.keys, table[0].tolist())  # the first one may grow the heap
        f0 = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
        for i in range(1, 4):
            fly(spec, base, i, spec.keys, table[i].tolist())
        f1 = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
        return (f1 - f0) / 3, os.environ.get("MALLOC_TRIM_THRESHOLD_"), os.environ.get("MALLOC_ARENA_MAX")

    with engine.cluster(1, None) as client:
        faults, trim, arenas = client.submit(faults_per_flight, pure=False).result()  # in the task thread
    assert faults < 100, f"{faults:.0f} page faults a flight"
    assert trim is None and arenas == "1"


def _spawn(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    return subprocess.Popen(args, stdout=log.open("wb"), stderr=subprocess.STDOUT, start_new_session=True)


def _stop(p: subprocess.Popen[bytes]) -> None:
    if p.poll() is None:
        os.killpg(p.pid, signal.SIGTERM)
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(10)


def _wait_for_parts(out: Path, n: int, proc: subprocess.Popen[bytes] | None, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if len(list((out / engine.PARTS).glob("part-*.parquet"))) >= n:
            return
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"campaign ended early ({proc.returncode})")
        time.sleep(0.05)
    raise AssertionError(f"fewer than {n} parts within {timeout_s} s")


@pytest.mark.slow
@pytest.mark.processes
def test_a_real_scheduler_with_two_workers_and_one_killed_mid_way(tmp_path: Path) -> None:
    """``dask scheduler`` and two ``dask worker`` processes on loopback: the campaign gives
    the embedded run's rows; then one worker is SIGKILLed during a second campaign, which
    still completes, every sample once."""
    f = small_file(tmp_path)
    run_campaign(f, tmp_path / "embedded", workers=2, quiet=True, figures=False)  # (rows compared)
    port = new_port()  # a free TCP port too, on loopback, in practice
    dask = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    sched = _spawn(
        [*dask, "--host", "127.0.0.1", "--port", str(port), "--dashboard-address", ":0"],
        tmp_path / "scheduler.log",
    )
    addr = f"tcp://127.0.0.1:{port}"
    worker_cmd = [sys.executable, "-m", "distributed.cli.dask_worker", addr, "--nthreads", "1",
                  "--nworkers", "1", "--no-nanny", "--host", "127.0.0.1", "--dashboard-address", ":0"]
    env = {**os.environ, **SINGLE_THREAD_ENV}
    workers = [
        subprocess.Popen(
            worker_cmd,
            stdout=(tmp_path / f"w{i}.log").open("wb"),
            stderr=subprocess.STDOUT,
            start_new_session=True,
            env=env,
        )
        for i in range(2)
    ]
    try:
        from dask.distributed import Client

        with Client(addr, timeout="60s") as c:  # both workers in before the campaign starts
            c.wait_for_workers(2, timeout=120)
        s = run_campaign(f, tmp_path / "cluster", scheduler=addr, quiet=True, figures=False)
        assert s["run"]["workers"] == 2
        assert rows(tmp_path / "cluster") == rows(tmp_path / "embedded")
        # a bigger campaign in one-flight tasks; kill a worker once the first results are in
        big = tmp_path / "big.toml"
        big.write_text(
            f.read_text()
            .replace("samples = 12", "samples = 30")
            .replace('name = "small"', 'name = "big"\nbatch = 1')
        )
        out = tmp_path / "big"
        cmd = [
            sys.executable,
            "-m",
            "heli_sitl.cli",
            "campaign",
            str(big),
            "--out",
            str(out),
            "--scheduler",
            addr,
            "--quiet",
            "--no-figures",
        ]
        camp = _spawn(cmd, tmp_path / "big.log")
        _wait_for_parts(out, 3, camp, 240)
        workers[0].kill()
        assert camp.wait(300) == 0, (tmp_path / "big.log").read_text()[-2000:]
        ids = [r["sample_id"] for r in rows(out)]
        assert ids == list(range(30)) and not any(r["failed"] for r in rows(out))
    finally:
        for w in workers:
            _stop(w)
        _stop(sched)


@pytest.mark.slow
@pytest.mark.processes
def test_a_killed_campaign_resumes_without_losing_or_repeating_a_flight(tmp_path: Path) -> None:
    f = small_file(tmp_path)
    f.write_text(
        f.read_text()
        .replace("samples = 12", "samples = 40")
        .replace('name = "small"', 'name = "resume"\nbatch = 2')
    )
    out = tmp_path / "out"
    cmd = [
        sys.executable,
        "-m",
        "heli_sitl.cli",
        "campaign",
        str(f),
        "--out",
        str(out),
        "--workers",
        "2",
        "--quiet",
        "--no-figures",
    ]
    camp = _spawn(cmd, tmp_path / "first.log")
    _wait_for_parts(out, 3, camp, 240)
    os.killpg(camp.pid, signal.SIGKILL)  # the campaign and its cluster, at once
    camp.wait(30)
    before = engine.done_ids(out)
    assert 0 < len(before) < 40
    done = subprocess.run(cmd, capture_output=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    ids = [r["sample_id"] for r in rows(out)]
    assert ids == list(range(40))  # each exactly once
    # the rows flown before the kill are the ones kept
    first = {r["sample_id"]: r for r in rows(out) if r["sample_id"] in before}
    assert len(first) == len(before)


@pytest.mark.slow
@pytest.mark.processes
def test_via_processes_flies_the_in_process_rows_again_over_mavlink(tmp_path: Path) -> None:
    """--via processes: a sample's scenario, gains, world and estimator written as files and
    flown by plant and autopilot processes in lockstep give the in-process row's RMS."""
    from heli_sitl.studies.campaigns.via_processes import compare

    f = small_file(tmp_path)
    f.write_text(f.read_text().replace("samples = 12", "samples = 2"))
    run_campaign(f, tmp_path / "out", workers=1, quiet=True, figures=False)
    res = compare(f, tmp_path / "out", limit=2, quiet=True)
    assert [r["sample_id"] for r in res] == [0, 1]
    for r in res:
        assert r["abs_diff_m"]["rms_0_m"] < 1e-3 and r["abs_diff_m"]["rms_10_m"] < 1e-3, r
    assert (tmp_path / "out" / "via_processes.json").is_file()


def _figures_from_the_cluster(
    monkeypatch: pytest.MonkeyPatch, lose: str = ""
) -> dict[str, bytes | Exception]:
    """What ``engine.render_figures`` hands back from the cluster's workers, by figure (filled
    as the campaign runs); ``lose``: that figure's task reported failed, as a lost worker's
    would be."""
    got: dict[str, bytes | Exception] = {}
    real = engine.render_figures

    def spy(*args: Any, **kwargs: Any) -> Iterator[tuple[report.Sheet, bytes | Exception]]:
        for sheet, png in real(*args, **kwargs):
            got[sheet.name] = png
            yield sheet, RuntimeError("worker lost") if sheet.name == lose else png

    monkeypatch.setattr(engine, "render_figures", spy)
    return got


def _count_figures_drawn_here(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """One entry per figure drawn in this process (the workers' own module is not patched)."""
    calls: list[int] = []
    real = report._png

    def counted(*args: Any, **kwargs: Any) -> bytes:
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(report, "_png", counted)
    return calls


def _few_flights(tmp_path: Path, n: int) -> Path:
    f = small_file(tmp_path)
    f.write_text(f.read_text().replace("samples = 12", f"samples = {n}"))
    return f


@pytest.mark.slow
@pytest.mark.processes
def test_the_figures_drawn_on_the_cluster_are_the_ones_drawn_here(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each figure is a task on the campaign's cluster, its PNG bytes sent back and written
    here: byte for byte the figure drawn here, as a re-run with every flight done draws it
    (no cluster then); campaign.json lists them in the same order either way."""
    f = _few_flights(tmp_path, 4)
    from_cluster = _figures_from_the_cluster(monkeypatch)
    drawn_here = _count_figures_drawn_here(monkeypatch)
    out = tmp_path / "out"
    s = run_campaign(f, out, workers=2, quiet=True)
    spec, _, _ = prepare(f)
    plan = report.sheets(spec)
    names = [sh.name for sh in plan]
    assert names[0] == "hist.png" and len(names) == 1 + len(spec.keys)
    assert s["figures"] == names and "figure_errors" not in s
    assert sorted(from_cluster) == sorted(names) and not drawn_here  # every one by a worker
    results = pq.read_table(out / engine.RESULTS)
    drawn = {sh.name: (out / sh.name).read_bytes() for sh in plan}
    for sheet in plan:
        here = report.render(spec, results, sheet)
        assert from_cluster[sheet.name] == drawn[sheet.name] == here, sheet.name
    # the same command again: nothing to fly, no cluster, the same figures drawn here
    from_cluster.clear()
    drawn_here.clear()
    again = run_campaign(f, out, workers=2, quiet=True)
    assert again["run"]["flown_now"] == 0 and not from_cluster and len(drawn_here) == len(plan)
    assert again["figures"] == names
    assert {sh.name: (out / sh.name).read_bytes() for sh in plan} == drawn


@pytest.mark.slow
@pytest.mark.processes
def test_a_figure_whose_task_fails_costs_neither_the_results_nor_campaign_json(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A figure that raises on its worker (and here too) is left out and reported in
    campaign.json; a figure whose task is lost is drawn here instead; the rows and
    campaign.json are written either way."""
    real_sheets = report.sheets
    broken = report.Sheet("vs_nowhere.png", "vs", key="nowhere")  # no such column, anywhere
    monkeypatch.setattr(report, "sheets", lambda spec: [*real_sheets(spec), broken])
    from_cluster = _figures_from_the_cluster(monkeypatch, lose="hist.png")
    f = _few_flights(tmp_path, 2)
    out = tmp_path / "out"
    s = run_campaign(f, out, workers=2, quiet=True)
    assert isinstance(from_cluster["vs_nowhere.png"], KeyError)  # raised on the worker
    assert [r["sample_id"] for r in rows(out)] == [0, 1]
    spec, _, _ = prepare(f)
    names = [sh.name for sh in real_sheets(spec)]
    saved = json.loads((out / "campaign.json").read_text())
    assert saved["counts"]["flights"] == 2
    assert saved["figures"] == s["figures"] == names  # the lost one drawn here, the broken one left out
    errors = saved["figure_errors"]
    assert list(errors) == ["vs_nowhere.png"] and "nowhere" in errors["vs_nowhere.png"]
    assert not (out / "vs_nowhere.png").exists()
    results = pq.read_table(out / engine.RESULTS)
    assert (out / "hist.png").read_bytes() == report.render(spec, results, report.Sheet("hist.png", "hist"))


def test_campaign_plots_survive_a_metric_with_no_finite_bins(tmp_path: Path) -> None:
    """A lost flight's error near 1e17 m beside others a few metres off it leaves no finite
    histogram bins (matplotlib raises): the figure states the range and the run goes on."""
    import pyarrow as pa

    from heli_sitl.studies.campaigns.report import plots
    from heli_sitl.studies.campaigns.spec import CampaignSpec

    spec = CampaignSpec(name="huge", metrics=("rms_10_m",))
    v = [8.2e16] * 139 + [8.2e16 + 16.0]
    t = pa.table({"sample_id": list(range(140)), "rms_10_m": v, "failed": [False] * 140,
                  "diverged": [True] * 140, "converged": [False] * 140})  # fmt: skip
    files = plots(spec, t, tmp_path)
    assert (tmp_path / "hist.png") in files and (tmp_path / "hist.png").stat().st_size > 5_000


def test_a_campaign_with_failed_flights_exits_non_zero(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A flight that raised is the bench's fault: the command says so and exits 3 (a flight
    that did not converge is the controller's result and exits 0)."""
    import heli_sitl.studies.campaigns.run as run
    from heli_sitl.cli import main

    def fake(failed: int) -> object:
        return lambda *a, **k: {"counts": {"flights": 10, "failed": failed, "diverged": 4}}

    monkeypatch.setattr(run, "run_campaign", fake(0))
    assert main(["campaign", "robustness", "--out", str(tmp_path)]) == 0
    monkeypatch.setattr(run, "run_campaign", fake(2))
    assert main(["campaign", "robustness", "--out", str(tmp_path)]) == 3
    assert "2 of 10 flights failed" in capsys.readouterr().err


def test_a_directory_flown_with_other_gains_is_another_campaign(tmp_path: Path) -> None:
    """The same campaign file over a gain file whose values changed: its rows would be stale,
    so the directory refuses it (a resumed comparison once reported a PID's old gains' rows
    beside its new trajectories); the same files again resume."""
    from heli_sitl.studies.campaigns.run import _claim, _identity

    spec, base, table = prepare("robustness-rotor")
    again = prepare("robustness-rotor")
    same = _identity(again[0], again[2], again[1])
    assert _identity(spec, table, base) == same
    pid = dataclasses.replace(base.scenario.gains, name="edited")
    edited = dataclasses.replace(base, scenario=dataclasses.replace(base.scenario, gains=pid))
    other = _identity(spec, table, edited)
    assert other["hash"] != same["hash"]
    _claim(tmp_path, same)
    _claim(tmp_path, same)  # a re-run of the same campaign: resumes
    with pytest.raises(ConfigError, match="holds the results of another campaign"):
        _claim(tmp_path, other)
