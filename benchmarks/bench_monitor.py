"""Monitor load: N loops polled every second from one process on loopback, windows diagnosed.

Starts `connectors.modbus_sim` (a real pymodbus TCP server in its own process) serving ``--loops``
simulated loops, then runs `diagnose.service.monitor.Monitor` (the `stiction monitor` engine) in
this process for ``--duration`` seconds: the poller on this process's event loop, window
diagnoses in ``--workers`` worker processes. Reports polls, failed and missed polls, windows
diagnosed, and the CPU time of the polling process (user+sys of this process, which also stores
the results in the history; wall time includes draining the last windows).

    python benchmarks/bench_monitor.py --loops 200 --duration 120 --window 60
    python benchmarks/bench_monitor.py --loops 200 --duration 60 --stride 10   # one request per loop
"""

from __future__ import annotations

import argparse
import asyncio
import io
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--loops", type=int, default=200)
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--period", type=float, default=1.0)
    ap.add_argument("--window", type=int, default=60, help="samples per diagnosed window")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--stride", type=int, default=8, help="registers per loop (> 8: one request per loop)")
    args = ap.parse_args()

    from connectors.modbus_sim import default_config_text, free_port
    from diagnose.service.monitor import Monitor

    port = free_port()
    root = Path(tempfile.mkdtemp(prefix="bench_monitor_"))
    cfg = root / "plant.toml"
    cfg.write_text(default_config_text(port, args.loops, period_s=args.period, window_samples=args.window,
                                       stride=args.stride))
    sim = subprocess.Popen([sys.executable, "-m", "connectors.modbus_sim", "--port", str(port), "--config",
                            str(cfg), "--ts", str(args.period)], stdout=subprocess.PIPE, text=True)
    try:
        line = sim.stdout.readline()
        if not line.startswith("READY"):
            raise SystemExit(f"simulator did not start: {line!r}")
        log = io.StringIO()
        mon = Monitor(str(cfg), root / "out", db=root / "h.sqlite", workers=args.workers, log=log)
        ru0 = resource.getrusage(resource.RUSAGE_SELF)
        t0 = time.monotonic()
        stats = asyncio.run(mon.run(args.duration))
        wall = time.monotonic() - t0
        ru1 = resource.getrusage(resource.RUSAGE_SELF)
    finally:
        sim.terminate()
        sim.wait()
    cpu_main = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    expected = args.loops * int(args.duration / args.period)
    load = os.getloadavg()
    print(f"### Monitor load ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())})\n")
    print(f"{args.loops} loops on one pymodbus server process (loopback), polled every {args.period:g} s from one "
          f"process for {args.duration:g} s; {'one read request per loop' if args.stride > 8 else 'contiguous blocks (up to 120 registers per request)'}; "
          f"window {args.window} samples, diagnosed in {args.workers} worker process(es). "
          f"Machine: {os.cpu_count()} CPUs, load average at the end {load[0]:.1f}.\n")
    print("| polls | expected | failed | missed | windows diagnosed | failed windows | polling process CPU | % of one core | wall s |")
    print("|---|---|---|---|---|---|---|---|---|")
    print(f"| {stats.polls} | {expected} | {stats.polls_failed} | {stats.polls_missed} | {stats.diagnosed} | "
          f"{stats.failed} | {cpu_main:.1f} s (poller alone {stats.poll_cpu_s:.1f} s) | "
          f"{100 * cpu_main / wall:.1f} % | {wall:.0f} |")
    if stats.errors:
        print("\nfirst errors: " + "; ".join(stats.errors[:3]))


if __name__ == "__main__":
    main()
