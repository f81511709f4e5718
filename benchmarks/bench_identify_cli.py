"""Wall time of the whole ``stiction identify FILE --json`` command.

Interpreter start, imports, reading the file, the identification and the JSON output are all
included: this is the time a user waits. The data are a simulated sticky loop
(``stiction simulate --S 3 --J 1 --n N``) with the stem-position column dropped, so identify takes
the OP/PV (Hammerstein) path. Variants run in the same session, interleaved run by run, so that
machine load affects them alike:

* ``identify``: the command as installed (the widest vector variant of the kernels the CPU has);
* ``identify, baseline kernels``: the same with the kernels' x86-64 baseline variant (what a CPU
  without AVX2 runs; the numbers are the same);
* ``identify, bytecode cached``: with Python's own compile cache (``__pycache__/*.pyc``) allowed, as
  on a user's machine, where this session sets ``PYTHONDONTWRITEBYTECODE`` (some containers do);
* ``--baseline-src DIR`` (repeatable): the same command run from another source tree (e.g. an
  earlier commit checked out with ``git worktree add``), through ``PYTHONPATH``: before/after
  ratios, run by run, in one run. Every variant runs from a scratch directory.

Two floors are timed as well: ``python -c pass`` and ``python -c "import numpy"``.

Usage::

    python benchmarks/bench_identify_cli.py [--runs 7] [--n 10000] [--baseline-src DIR] [--md FILE]
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.machine import cpu_model  # noqa: E402


def _stiction_cmd() -> list[str]:
    exe = Path(sys.executable).with_name("stiction")
    if exe.exists():
        return [str(exe)]
    return [sys.executable, "-c", "import sys; from diagnose.service.cli import main; sys.exit(main())"]


def make_loop(directory: Path, n: int) -> Path:
    """Simulated sticky loop (S = 3 %, J = 1 %) with the stem position (``.POS``) column removed."""
    full = directory / "loop_full.csv"
    subprocess.run([*_stiction_cmd(), "simulate", "--S", "3", "--J", "1", "--n", str(n), "--out", str(full)],
                   check=True, capture_output=True)
    with open(full, newline="") as fh:
        rows = list(csv.reader(fh))
    keep = [i for i, name in enumerate(rows[0]) if not name.upper().endswith(".POS")]
    out = directory / "loop_op_pv.csv"
    with open(out, "w", newline="") as fh:
        csv.writer(fh).writerows([[r[i] for i in keep] for r in rows])
    return out


def _run(cmd: list[str], env: dict[str, str], cwd: str) -> tuple[float, float, bytes]:
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    # run outside any source tree: ``python -c`` puts the working directory first on sys.path, ahead
    # of PYTHONPATH, so from the repository root a baseline tree would silently run this one's code
    proc = subprocess.run(cmd, env=env, capture_output=True, cwd=cwd)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr.decode(errors='replace')}")
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return wall, cpu, proc.stdout


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7, help="timed runs per variant (default 7)")
    ap.add_argument("--n", type=int, default=10000, help="samples in the simulated loop (default 10000)")
    ap.add_argument("--baseline-src", metavar="DIR", action="append", default=[],
                    help="also time the command from this source tree (run through PYTHONPATH); repeatable")
    ap.add_argument("--md", metavar="FILE", help="also write the results as a Markdown fragment")
    args = ap.parse_args(argv)

    base_env = dict(os.environ)
    cached_env = dict(base_env)
    cached_env.pop("PYTHONDONTWRITEBYTECODE", None)
    # the installed program's entry point (`console`, which skips the interpreter's teardown), or
    # `main` in a tree that predates it: each tree as its users ran it
    entry = ("import diagnose.service.cli as c; f = getattr(c, 'console', None); "
             "f() if f else sys.exit(c.main())")
    main_code = f"import sys; {entry}"
    isa0_code = f"import sys, diagnose.kernels as k; k.set_isa(0); {entry}"
    with tempfile.TemporaryDirectory() as tmp:
        data = make_loop(Path(tmp), args.n)
        tail = ["identify", str(data), "--json"]
        variants = {"identify": ([*_stiction_cmd(), *tail], base_env),
                    "identify, baseline kernels": ([sys.executable, "-c", isa0_code, *tail], base_env),
                    "identify, bytecode cached": ([*_stiction_cmd(), *tail], cached_env)}
        for src in args.baseline_src:
            env = dict(base_env, PYTHONPATH=str(Path(src).resolve()))
            variants[f"identify from {src}"] = ([sys.executable, "-c", main_code, *tail], env)
        floors = {"python -c pass": [sys.executable, "-c", "pass"],
                  "python -c 'import numpy'": [sys.executable, "-c", "import numpy"]}
        # warm-up (writes caches), and the outputs of this tree's variants must agree. The warm-up
        # may write bytecode for every tree: with PYTHONDONTWRITEBYTECODE set, a baseline tree
        # would otherwise compile all its modules (and any packages beside it) on every timed run,
        # while this tree reads the bytecode its "bytecode cached" variant wrote
        outs = {}
        for name, (cmd, env) in variants.items():
            warm_env = dict(env)
            warm_env.pop("PYTHONDONTWRITEBYTECODE", None)
            outs[name] = _run(cmd, warm_env, tmp)[2]
        same = len({v for k, v in outs.items() if not k.startswith("identify from")}) == 1
        load0 = os.getloadavg()
        times: dict[str, list[tuple[float, float]]] = {k: [] for k in [*variants, *floors]}
        for _ in range(args.runs):
            for name, (cmd, env) in variants.items():
                times[name].append(_run(cmd, env, tmp)[:2])
            for name, c in floors.items():
                times[name].append(_run(c, base_env, tmp)[:2])
        load1 = os.getloadavg()

    lines = [f"`stiction identify FILE --json`, simulated loop S = 3 %, J = 1 %, n = {args.n} samples, "
             f"OP/PV only (stem position dropped); {args.runs} runs per variant, interleaved.",
             f"Machine: {os.cpu_count()} CPUs ({cpu_model()}), Python {platform.python_version()}; "
             f"load average {load0[0]:.2f} before, {load1[0]:.2f} after.",
             f"PYTHONDONTWRITEBYTECODE in this session: {os.environ.get('PYTHONDONTWRITEBYTECODE') or 'unset'}.",
             f"JSON outputs of this tree's variants identical: {'yes' if same else 'NO'}.",
             "",
             "| variant | wall min (s) | wall median (s) | wall max (s) | CPU median (s) |",
             "|---|---:|---:|---:|---:|"]
    for name, rows in times.items():
        wall = [w for w, _ in rows]
        cpu = [c for _, c in rows]
        label = name
        lines.append(f"| {label} | {min(wall):.3f} | {statistics.median(wall):.3f} | {max(wall):.3f} | "
                     f"{statistics.median(cpu):.3f} |")
    for src in args.baseline_src:
        # run by run: the variants of one round ran back to back, under the same load
        pairs = [a / b for (a, _), (b, _) in zip(times["identify"], times[f"identify from {src}"])]
        lines.append(f"\nThis tree against {src}, wall run by run: median {statistics.median(pairs):.3f}x "
                     f"(min {min(pairs):.3f}, max {max(pairs):.3f}).")
    text = "\n".join(lines) + "\n"
    sys.stdout.write(text)
    if args.md:
        path = Path(args.md)
        tmp_path = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp_path.write_text(text)
        os.replace(tmp_path, path)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
