"""``python -m benchmarks``: run every registered benchmark and print one aligned table.

Exit status 0 always (the table is a report; the ``ok`` column flags a missed target).
``python -m benchmarks plant`` runs only the groups whose title contains "plant".
``python -m benchmarks --table docs/performance.md`` (``make bench``) also writes the table
into that file, between its markers.
"""

from __future__ import annotations

import argparse
import datetime
import importlib
import math
import os
import platform
import re
import sys
import time
from pathlib import Path

from benchmarks import MODULES, REGISTRY, Row


def fmt_value(v: float) -> str:
    if not math.isfinite(v):
        return str(v)
    if v == 0.0:
        return "0"
    a = abs(v)
    if a >= 1e5 or a < 1e-3:
        return f"{v:.3e}"
    if a >= 100:
        return f"{v:,.0f}"
    return f"{v:.4g}"


def table(groups: list[tuple[str, list[Row]]]) -> str:
    header = ("group", "benchmark", "value", "unit", "target", "ok")
    lines: list[tuple[str, ...]] = []
    for title, rows in groups:
        for r in rows:
            ok = "" if r.ok is None else ("yes" if r.ok else "MISS")
            lines.append((title, r.name, fmt_value(r.value), r.unit, r.target, ok))
    widths = [max(len(h), *(len(row[i]) for row in lines)) for i, h in enumerate(header)]
    right = {2}  # numbers right-aligned

    def render(cells: tuple[str, ...]) -> str:
        out = [
            c.rjust(w) if i in right else c.ljust(w)
            for i, (c, w) in enumerate(zip(cells, widths, strict=True))
        ]
        return "| " + " | ".join(out) + " |"

    rules = [("-" * (w + 1) + ":") if i in right else "-" * (w + 2) for i, w in enumerate(widths)]
    sep = "|" + "|".join(rules) + "|"
    return "\n".join([render(header), sep, *(render(line) for line in lines)])


TABLE_BEGIN = "<!-- make bench: begin -->"
TABLE_END = "<!-- make bench: end -->"


def machine() -> str:
    """One line naming the machine the figures come from."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{platform.system()} {platform.machine()}, {os.cpu_count()} CPUs ({cpu}), "
            f"Python {platform.python_version()}")  # fmt: skip


def table_section(body: str) -> str:
    """The performance table as this run printed it, between the markers."""
    today = datetime.date.today().isoformat()
    return (f"{TABLE_BEGIN}\nAs `make bench` printed it on {today}, on {machine()}. Every floor\n"
            f"is measured in the same run as the figure divided by it.\n\n{body}\n{TABLE_END}")  # fmt: skip


def write_table(path: Path, body: str) -> None:
    """Replace the section between the markers of ``path`` (and nothing else) by this run's table."""
    text = path.read_text()
    pattern = re.compile(re.escape(TABLE_BEGIN) + ".*?" + re.escape(TABLE_END), re.DOTALL)
    if not pattern.search(text):
        raise ValueError(f"{path}: no {TABLE_BEGIN} ... {TABLE_END} section to replace")
    path.write_text(pattern.sub(lambda _: table_section(body), text, count=1))


def parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks",
        description="Run the benchmarks and print one table (exit status 0: the ok column flags "
                    "a missed target). Groups: " + ", ".join(t for t, _ in REGISTRY) + ".",
    )  # fmt: skip
    p.add_argument("groups", nargs="*", metavar="GROUP",
                   help="run only the groups whose title contains one of these words (default: all)")
    p.add_argument("--table", type=Path, metavar="FILE",
                   help="also put the table into FILE (make bench: docs/performance.md) between the "
                        f"markers '{TABLE_BEGIN}' and '{TABLE_END}' (every group must run)")
    return p.parse_args(argv)


def main(argv: list[str]) -> int:
    for mod in MODULES:
        importlib.import_module(mod)
    args = parse(argv)
    wanted = [a.lower() for a in args.groups]
    known = [t for t, _ in REGISTRY]
    unknown = [w for w in wanted if not any(w in t.lower() for t in known)]
    if unknown:
        print(f"python -m benchmarks: no group matches {', '.join(unknown)}; groups: {', '.join(known)}",
              file=sys.stderr)  # fmt: skip
        return 2
    if args.table is not None and wanted:
        print("python -m benchmarks: --table needs every group (a partial table would drop rows)",
              file=sys.stderr)  # fmt: skip
        return 2
    if args.table is not None and not args.table.is_file():
        print(f"python -m benchmarks: {args.table}: no such file", file=sys.stderr)
        return 2
    if args.table is not None and TABLE_BEGIN not in args.table.read_text():
        print(f"python -m benchmarks: {args.table} has no '{TABLE_BEGIN}' section", file=sys.stderr)
        return 2
    groups: list[tuple[str, list[Row]]] = []
    t0 = time.perf_counter()
    for title, fn in REGISTRY:
        if wanted and not any(w in title.lower() for w in wanted):
            continue
        t1 = time.perf_counter()
        try:
            groups.append((title, fn()))
        except Exception as exc:  # one broken group must not hide the others' figures
            groups.append((title, [Row(f"FAILED: {type(exc).__name__}: {exc}"[:90], math.nan, "")]))
        print(f"  {title}: {time.perf_counter() - t1:.1f} s", file=sys.stderr, flush=True)
    body = table(groups)
    print(body)
    print(f"\n(total {time.perf_counter() - t0:.1f} s, including numba load/compile; {machine()})")
    if args.table is not None:
        write_table(args.table, body)
        print(f"wrote the table into {args.table}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
