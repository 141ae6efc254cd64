"""Where the test suite's time goes: each test's CPU (its process and every process under it: the desks, `calib`
commands, chromium, the job workers) and wall time, and how busy the machine was meanwhile, by module.

    .venv/bin/python benchmarks/suite_cpu.py [--top 20] [--rows FILE] [-- PYTEST ARGS]

Runs the suite as scripts/test.sh does (two xdist workers, modules whole, one BLAS thread; PYTEST ARGS, e.g. a
few test files, instead of all of it), with a plugin (this file, loaded by pytest in each worker) that reads
/proc before and after each test. Printed: the run's wall time, the tests' CPU, the machine's busy and idle
core-seconds over the run; then the modules by CPU, with their wall time and the idle core-seconds while they
ran; then the tests the machine idled most in (waiting on simulated motion, on a graph, on a page). A test's idle
is counted by the worker that ran it, so two tests waiting at once both count the same idle second.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TICK = os.sysconf("SC_CLK_TCK")
OUT = "SUITE_CPU_OUT"  # the folder the plugin writes each worker's lines to


def _tree_cpu() -> float:
    """CPU s of this process, its reaped children and every live process under it."""
    children: dict[int, list[int]] = defaultdict(list)
    cpu: dict[int, float] = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            fields = Path(f"/proc/{name}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children[int(fields[1])].append(int(name))
        cpu[int(name)] = sum(int(f) for f in fields[11:15]) / TICK
    total, todo = 0.0, list(children[os.getpid()])
    while todo:
        pid = todo.pop()
        total += cpu.get(pid, 0.0)
        todo += children[pid]
    own, reaped = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + reaped.ru_utime + reaped.ru_stime + total


def _busy() -> float:
    """The machine's busy core-seconds since boot (all but idle and iowait)."""
    values = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return (sum(values) - values[3] - values[4]) / TICK


# --- the pytest plugin (loaded as `-p suite_cpu` in each worker) ---------------------------------------------------
_lines = None


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    global _lines
    if _lines is None:
        _lines = open(Path(os.environ[OUT]) / f"{os.getpid()}.jsonl", "a", encoding="utf-8")  # noqa: SIM115
    cpu, wall, busy = _tree_cpu(), time.perf_counter(), _busy()
    yield
    row = [item.nodeid, _tree_cpu() - cpu, time.perf_counter() - wall, _busy() - busy]
    _lines.write(json.dumps([*row, os.environ.get("PYTEST_XDIST_WORKER", "gw0"), time.time() - row[2]]) + "\n")
    _lines.flush()


# --- the script ------------------------------------------------------------------------------------------------------
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--top", type=int, default=20, help="modules and tests listed")
    ap.add_argument(
        "--rows",
        type=Path,
        help="also write each test's figures here (JSON: node id, CPU s, wall s, "
        "the machine's busy core-s, worker, start in s since the run's start)",
    )
    ap.add_argument("pytest_args", nargs="*", help="after --: pytest's arguments (default: the whole suite)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as out:
        env = {
            **os.environ,
            OUT: out,
            "PYTHONPATH": os.pathsep.join([str(ROOT / "benchmarks"), os.environ.get("PYTHONPATH", "")]),
            "PYTEST_DISABLE_PLUGIN_AUTOLOAD": "1",
            "OPENBLAS_NUM_THREADS": "1",
        }
        plugins = ["-p", "suite_cpu", "-p", "xdist.plugin", "-p", "_hypothesis_pytestplugin"]
        plugins += ["-p", "schemathesis.pytest.plugin", "-n", "2", "--dist", "loadfile", "--no-loadscope-reorder"]
        start, busy, epoch = time.perf_counter(), _busy(), time.time()
        done = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *plugins, *args.pytest_args],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
        )
        wall, busy = time.perf_counter() - start, _busy() - busy
        rows = [json.loads(line) for f in Path(out).glob("*.jsonl") for line in f.read_text().splitlines()]
    if args.rows:
        args.rows.write_text(json.dumps([[*r[:5], round(r[5] - epoch, 3)] for r in rows], indent=0), encoding="utf-8")
    summary = done.stdout.strip().splitlines()[-1] if done.stdout.strip() else done.stderr[-500:]
    print(f"{summary}\nthe run {wall:.1f} s; the tests' CPU {sum(r[1] for r in rows):.1f} s; the machine busy "
          f"{busy:.0f} core-s, idle {2 * wall - busy:.0f} core-s of its two cores")  # fmt: skip
    modules: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0, 0.0])
    for nodeid, cpu, test_wall, test_busy, *_ in rows:
        m = modules[nodeid.split("::")[0]]
        m[0], m[1], m[2] = m[0] + cpu, m[1] + test_wall, m[2] + max(0.0, 2 * test_wall - test_busy)
    print(f"\n{'CPU s':>7} {'wall s':>7} {'idle':>6}  module")
    for name, (cpu, test_wall, idle) in sorted(modules.items(), key=lambda kv: -kv[1][0])[: args.top]:
        print(f"{cpu:7.1f} {test_wall:7.1f} {idle:6.1f}  {name}")
    print(f"\n{'idle':>6} {'CPU s':>7} {'wall s':>7}  test")
    for nodeid, cpu, test_wall, test_busy, *_ in sorted(rows, key=lambda r: r[3] - 2 * r[2])[: args.top]:
        print(f"{2 * test_wall - test_busy:6.1f} {cpu:7.1f} {test_wall:7.1f}  {nodeid}")
    sys.exit(0 if done.returncode == 0 else done.returncode)


if __name__ == "__main__":
    main()
