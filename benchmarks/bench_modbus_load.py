"""Load check of the Modbus/TCP poller: many loops polled at 1 s from one process (loopback only).

Starts simulator processes (``python -m connectors.modbus_sim``, one per device/port) and polls
their loops with one `connectors.modbus.ModbusPoller` in this process for a bounded time, first a
small baseline (20 loops) then the full load (200 loops), in the same run. Reports this process's
CPU use (process time / wall time, i.e. share of one core), polls, missed polls (ticks a device
task could not start in time), failed polls, windows handed on and the worst timestamp jitter.

    python benchmarks/bench_modbus_load.py --loops 200 --devices 4 --duration 60 \
        [--stride 10] [--out /tmp/modbus_load.md]

``--out`` replaces the whole file with the table: docs/_bench_connectors.md holds more than this
table, so write elsewhere and merge the figures into it by hand.

``--stride 10`` leaves register holes between loops so that every loop costs its own request
(200 requests per second); the default packs loops into ~120-register block reads.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from connectors.modbus import ModbusPoller, parse_modbus_config  # noqa: E402
from connectors.modbus_sim import default_config_text, free_port  # noqa: E402


def start_sims(cfg_path: Path, ports: list[int]) -> list[subprocess.Popen]:
    procs = []
    for p in ports:
        procs.append(subprocess.Popen([sys.executable, "-m", "connectors.modbus_sim", "--port", str(p),
                                       "--config", str(cfg_path), "--ts", "1.0", "--samples", "900"],
                                      cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    for proc in procs:
        line = proc.stdout.readline()
        if not line.startswith("READY"):
            raise SystemExit(f"simulator failed: {line!r} {proc.stderr.read()[-1000:]}")
    return procs


def run_case(n_loops: int, n_devices: int, duration_s: float, period_s: float, stride: int,
             window: int) -> dict:
    per_dev = max(1, n_loops // n_devices)
    ports = [free_port() for _ in range(n_devices)]
    text = default_config_text(ports, per_dev, period_s=period_s, window_samples=window, stride=stride,
                               timeout_s=0.5)
    with tempfile.TemporaryDirectory() as tmp:
        cfg_path = Path(tmp) / "load.toml"
        cfg_path.write_text(text)
        procs = start_sims(cfg_path, ports)
        try:
            cfg = parse_modbus_config(tomllib.loads(text))
            windows = []
            poller = ModbusPoller(cfg, on_window=windows.append)
            wall0, cpu0 = time.perf_counter(), time.process_time()
            stats = asyncio.run(poller.run(duration_s, flush=False))
            wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        finally:
            for p in procs:
                p.terminate()
            for p in procs:
                p.wait(5)
    polls = sum(s.polls for s in stats.values())
    jit = max((r.meta.get("jitter_s", 0.0) for r in windows), default=float("nan"))
    return {"loops": len(stats), "devices": n_devices, "duration_s": round(wall, 1),
            "cpu_pct_of_core": round(100 * cpu / wall, 1), "polls": polls,
            "expected_polls": int(len(stats) * duration_s / period_s),
            "missed": sum(s.missed for s in stats.values()), "failed": sum(s.failed for s in stats.values()),
            "windows": len(windows), "max_jitter_s": round(jit, 3)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loops", type=int, default=200)
    ap.add_argument("--devices", type=int, default=4)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--period", type=float, default=1.0)
    ap.add_argument("--stride", type=int, default=8, help="registers per loop (8 = packed, 10 = holes)")
    ap.add_argument("--window", type=int, default=30, help="samples per window handed on")
    ap.add_argument("--baseline-loops", type=int, default=20)
    ap.add_argument("--out", help="also write the table (markdown) to this file, replacing it "
                                    "(not docs/_bench_connectors.md: merge into it by hand)")
    args = ap.parse_args(argv)
    rows = []
    for n in (args.baseline_loops, args.loops):
        r = run_case(n, min(args.devices, n), args.duration, args.period, args.stride, args.window)
        r["stride"] = args.stride
        rows.append(r)
        print(r, flush=True)
    head = ["loops", "devices", "stride", "duration_s", "cpu_pct_of_core", "polls", "expected_polls", "missed",
            "failed", "windows", "max_jitter_s"]
    table = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    table += ["| " + " | ".join(str(r[h]) for h in head) + " |" for r in rows]
    md = "\n".join(table)
    print(md)
    if args.out:
        from connectors.historian import atomic_write

        cpu = os.cpu_count()
        atomic_write(args.out, f"<!-- bench_modbus_load.py {' '.join(argv or sys.argv[1:])}; "
                                    f"{cpu} CPUs -->\n{md}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
