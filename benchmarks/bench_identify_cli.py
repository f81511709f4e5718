"""Wall time of the whole ``stiction identify FILE --json`` command, native kernels against numba.

Interpreter start, imports, reading the file, the identification and the JSON output are all
included: this is the time a user waits. The data are a simulated sticky loop
(``stiction simulate --S 3 --J 1 --n N``) with the stem-position column dropped, so identify takes
the OP/PV (Hammerstein) path. Both kernel paths run in the same session, interleaved run by run,
so that machine load affects them alike:

* ``native``: the C kernels (``STICTION_NATIVE=1``; the library is built on the warm-up run if the
  cache does not have it);
* ``numba``: the numba fallback (``STICTION_NATIVE=0``; numba's on-disk cache warmed by the warm-up
  run, i.e. no compilation is timed);
* ``native kernels, bytecode cached``: as ``native`` with Python's own compile cache (``__pycache__/*.pyc``)
  allowed, as on a user's machine: the other variants inherit this session's environment, and where
  that sets ``PYTHONDONTWRITEBYTECODE`` (some containers and CI images do) every run compiles the
  package's sources again. The warm-up run writes the cache.

Two floors are timed as well: ``python -c pass`` and ``python -c "import numpy"``.

Usage::

    python benchmarks/bench_identify_cli.py [--runs 7] [--n 10000] [--md docs/_bench_speed.md]
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


def _run(cmd: list[str], env: dict[str, str]) -> tuple[float, float, bytes]:
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr.decode(errors='replace')}")
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return wall, cpu, proc.stdout


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7, help="timed runs per variant (default 7)")
    ap.add_argument("--n", type=int, default=10000, help="samples in the simulated loop (default 10000)")
    ap.add_argument("--md", metavar="FILE", help="also write the results as a Markdown fragment")
    args = ap.parse_args(argv)

    base_env = dict(os.environ)
    base_env.pop("STICTION_NATIVE", None)
    variants = {"native kernels": dict(base_env, STICTION_NATIVE="1"),
                "numba kernels": dict(base_env, STICTION_NATIVE="0")}
    cached_env = dict(base_env, STICTION_NATIVE="1")
    cached_env.pop("PYTHONDONTWRITEBYTECODE", None)
    variants["native kernels, bytecode cached"] = cached_env
    floors = {"python -c pass": [sys.executable, "-c", "pass"],
              "python -c 'import numpy'": [sys.executable, "-c", "import numpy"]}
    with tempfile.TemporaryDirectory() as tmp:
        data = make_loop(Path(tmp), args.n)
        cmd = [*_stiction_cmd(), "identify", str(data), "--json"]
        # warm-up: builds the native library / loads numba's cache once, and checks both agree
        outs = {name: _run(cmd, env)[2] for name, env in variants.items()}
        same = len(set(outs.values())) == 1
        load0 = os.getloadavg()
        times: dict[str, list[tuple[float, float]]] = {k: [] for k in [*variants, *floors]}
        for _ in range(args.runs):
            for name, env in variants.items():
                times[name].append(_run(cmd, env)[:2])
            for name, c in floors.items():
                times[name].append(_run(c, base_env)[:2])
        load1 = os.getloadavg()

    lines = [f"`stiction identify FILE --json`, simulated loop S = 3 %, J = 1 %, n = {args.n} samples, "
             f"OP/PV only (stem position dropped); {args.runs} runs per variant, interleaved.",
             f"Machine: {os.cpu_count()} CPUs ({_cpu_model()}), Python {platform.python_version()}; "
             f"load average {load0[0]:.2f} before, {load1[0]:.2f} after.",
             f"PYTHONDONTWRITEBYTECODE in this session: {os.environ.get('PYTHONDONTWRITEBYTECODE') or 'unset'}.",
             f"JSON outputs of all variants identical: {'yes' if same else 'NO'}.",
             "",
             "| variant | wall min (s) | wall median (s) | wall max (s) | CPU median (s) |",
             "|---|---:|---:|---:|---:|"]
    for name, rows in times.items():
        wall = [w for w, _ in rows]
        cpu = [c for _, c in rows]
        label = f"identify, {name}" if name in variants else name
        lines.append(f"| {label} | {min(wall):.3f} | {statistics.median(wall):.3f} | {max(wall):.3f} | "
                     f"{statistics.median(cpu):.3f} |")
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
