"""`stiction monitor`: poll loops over Modbus/TCP and diagnose each window as it fills."""

from __future__ import annotations

import argparse
import signal
import sys

from ._args import number, whole_number


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", metavar="CONFIG.toml", help="Modbus poller configuration (devices, loops, registers)")
    p.add_argument("--duration", type=number(0.0, above=True, what="a positive number of seconds"), default=None,
                   help="stop after this many seconds (default: run until Ctrl-C)")
    p.add_argument("--out", default="stiction-monitor-out", help="folder for each window's JSON/Markdown "
                                                                 "(default ./stiction-monitor-out)")
    p.add_argument("--window", type=whole_number(1, "1 or more"), default=None, help="samples per diagnosed window (default: the config's)")
    p.add_argument("--db", default=None, help="history database (default $STICTION_HOME/history.sqlite "
                                              "or ~/.local/share/stiction/history.sqlite)")
    p.add_argument("--no-history", action="store_true", help="do not store results in the history database")
    p.add_argument("--metrics-port", type=_port, default=None, help="serve Prometheus metrics on this local port")
    p.add_argument("--workers", type=whole_number(1, "1 or more"), default=1,
                   help="diagnosis worker processes (default 1)")
    from .batch import add_explain_argument

    add_explain_argument(p, "off", "the default; it takes 3-40 s per window")
    p.add_argument("--figures", action="store_true", help="draw figures for every window's report")


def _port(text: str) -> int:
    port = whole_number(1, "a TCP port, 1-65535")(text)
    if port > 65535:
        raise argparse.ArgumentTypeError(f"{text}: give a TCP port, 1-65535")
    return port


def run(args: argparse.Namespace) -> int:
    from ...plain import duration
    from ..monitor import run_monitor
    from .batch import explain_mode

    stats = run_monitor(args.config, args.out, duration_s=args.duration, db=args.db, history=not args.no_history,
                        metrics_port=args.metrics_port, window_samples=args.window, workers=args.workers,
                        explain=explain_mode(args.explain), figures=args.figures)
    dropped = f", {stats.dropped} dropped at the stop" if stats.dropped else ""
    stopped = f", stopped by {signal.Signals(stats.signal).name}" if stats.signal is not None else ""
    # a device that never answered had no outage (it was never up): say so beside the outages
    never = (f", {len(stats.never_answered)} device(s) never answered ({', '.join(stats.never_answered)})"
             if stats.never_answered else "")
    print(f"{stats.diagnosed} windows diagnosed, {stats.failed} failed, {stats.skipped_short} too short{dropped}; "
          f"{stats.polls} polls ({stats.polls_failed} failed, {stats.polls_missed} missed) in {duration(stats.wall_s)}, "
          f"{stats.outages} outage(s){never}, {stats.reconnects} reconnection(s), "
          f"poller CPU {stats.poll_cpu_s:.1f} s{stopped}; results in {args.out}", file=sys.stdout)
    if stats.signal is not None:
        return 128 + stats.signal  # the shell's code for a signal: 130 for SIGINT, 143 for SIGTERM
    if stats.polls_good == 0:
        from ..monitor import nothing_read_error

        raise nothing_read_error(args.config, stats)
    return 0
