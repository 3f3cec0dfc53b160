"""docs/examples/: the quick-start notebook runs on a real Jupyter kernel, cell by cell, and
says what the README says it says."""

from __future__ import annotations

from pathlib import Path

import nbformat
from nbclient import NotebookClient

EXAMPLES = Path(__file__).resolve().parent.parent / "docs" / "examples"


def _text(cell: nbformat.NotebookNode) -> str:
    out = []
    for o in cell.get("outputs", []):
        if "text" in o:
            out.append(o["text"])
        out.append(o.get("data", {}).get("text/plain", ""))
    return "\n".join(out)


def test_the_quickstart_notebook_runs_and_shows_the_papers_figure_and_the_lqr(tmp_path: Path) -> None:
    nb = nbformat.read(EXAMPLES / "quickstart.ipynb", as_version=4)
    # the kernel starts where a user opens the notebook: docs/examples
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(EXAMPLES)}},
                   ).execute()  # fmt: skip
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert "(<ExitStatus.COMPLETED: 'completed'>, 0.0402)" in _text(code[0])
    assert "pos_err_m" in _text(code[2])
    assert any(o.get("output_type") == "display_data" and "image/png" in o.get("data", {})
               for o in code[3].outputs)  # the figure was drawn  # fmt: skip
    assert "LQR about hover completed RMS [45, 120] s 0.0294 m" in _text(code[4])
    assert "flights 20, failed (raised) 0" in _text(code[5])


def test_the_readme_counts_the_parameters_the_vehicle_serves() -> None:
    """`heli-sitl up` serves the table make_gcs builds (the TLC's gains, the PID's, the SIM_
    knobs, limits, failsafes, home): the README's count is that table's length."""
    import re

    from autopilot.params_table import ParamTable
    from autopilot.pid.gains import default_pid_gains
    from autopilot.scenario import Scenario

    sc = Scenario.load("paper")
    table = ParamTable(sc.gains, sc.airframe.limits, sc.run.rate_hz, pid_gains=default_pid_gains())
    readme = (EXAMPLES.parent.parent / "README.md").read_text()
    m = re.search(r"\*\*Parameters\*\* \((\d+) served by `heli-sitl up`", readme)
    assert m is not None and int(m.group(1)) == len(table) == 97


def test_the_readmes_python_snippets_run_as_written(tmp_path: Path) -> None:
    """Every ```python block of the README's "From Python" section, in order, in one fresh
    interpreter at the repository's root (what it saves goes to a temporary directory)."""
    import os
    import subprocess
    import sys

    root = EXAMPLES.parent.parent
    readme = (root / "README.md").read_text()
    section = readme.split("## From Python\n", 1)[1].split("\n## ", 1)[0]
    blocks = [b.split("```", 1)[0] for b in section.split("```python\n")[1:]]
    assert len(blocks) == 3
    code = "\n".join(blocks).replace('"out/', f'"{tmp_path}/')
    env = {**os.environ, "MPLBACKEND": "Agg"}
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=600,
                         env=env)  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    lines = out.stdout.splitlines()
    assert lines[0] == "0.0402" and lines[-1] == "LQR about hover 0.0294"
    assert (tmp_path / "fig8" / "flight.parquet").is_file()
