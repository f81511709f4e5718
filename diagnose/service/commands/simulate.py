"""`stiction simulate`: write a simulated closed loop (with the true MV) as a wide CSV."""

from __future__ import annotations

import argparse
import math
import sys

from ...errors import DataError
from ...objective import MIN_SAMPLES
from ._args import number, whole_number

#: Largest S and J, % of valve span: the simulated loop runs at mid-span, and a wider band than
#: half the span drives OP into its limits (the loop then says nothing about stiction).
MAX_SJ_PCT = 50.0

#: Valve position (% of span) at which the simulated level (``--process integrating``) stands still,
#: against the valve's start at 50 %. At exactly 50 % the stuck valve already sits where the level
#: balances, and the load (added to PV, which a level does not accumulate) never pushes OP across
#: the band: the stem never moves. One % off balance is a level whose inflow the stuck valve does not
#: match, the way a real one never does: the level drifts, OP winds up, the valve slips, and the loop
#: settles into the stick-slip limit cycle of a sticky level loop.
INTEGRATING_BALANCE_PCT = 51.0


#: The longest simulation: the loop runs sample by sample in Python (about a minute per million),
#: and ten days at 1 s is more than any diagnosis here reads (`--max-samples` keeps 100 000).
MAX_SIM_SAMPLES = 1_000_000

#: identify refuses a shorter record, so a shorter simulation is a file nothing can diagnose
_min_samples = whole_number(MIN_SAMPLES, f"{MIN_SAMPLES} to {MAX_SIM_SAMPLES} samples (identify needs at least "
                                         f"{MIN_SAMPLES})")


def _samples(text: str) -> int:
    n = _min_samples(text)
    if n > MAX_SIM_SAMPLES:
        raise argparse.ArgumentTypeError(f"{text}: give {MIN_SAMPLES} to {MAX_SIM_SAMPLES} samples (the simulation "
                                         "runs sample by sample)")
    return n


def _nonzero(what: str, note: str):
    """A finite number other than 0: ``what`` names it, ``note`` says what its sign means."""
    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number; give {what} other than 0") from None
        if not math.isfinite(v) or v == 0:
            raise argparse.ArgumentTypeError(f"{text}: give {what} other than 0 ({note})")
        return v
    return parse


def _start(text: str) -> str:
    """``--start``: an ISO 8601 time (UTC unless it carries an offset) as ``...Z``."""
    from datetime import datetime, timezone

    try:
        t = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give an ISO 8601 time such as 2026-03-01T22:00:00Z "
                                         "(UTC unless it carries an offset)") from None
    t = t.replace(tzinfo=timezone.utc) if t.tzinfo is None else t.astimezone(timezone.utc)
    return t.isoformat().replace("+00:00", "Z")


# a zero process gain has no controller tuning (SIMC divides by it): a traceback, not a loop
_gain = _nonzero("a process gain", "negative: a reverse-acting process")
# a zero controller gain never moves OP, a non-finite one fills it with NaN: files identify refuses
_kc = _nonzero("a controller gain", "with the sign of the process gain")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--S", type=float, required=True, help="deadband + stickband, %% of valve span (0 to 50)")
    p.add_argument("--J", type=float, required=True, help="slip jump, %% of valve span (0 to 50)")
    p.add_argument("--process", choices=["foptd", "soptd", "integrating"], default="foptd",
                   help="process model (default foptd: first order plus dead time; integrating: a level "
                        f"balanced at {INTEGRATING_BALANCE_PCT:g} %% of valve span, the valve starting at 50 %%)")
    p.add_argument("--gain", type=_gain, default=None,
                   help="process gain, PV units per %% (integrating: per %% per second); default 1 (0.02)")
    p.add_argument("--tau-s", type=number(0.0, what="a time constant of 0 seconds or more (more than 0 "
                                                       "unless --process integrating)"),
                   default=20.0, help="process time constant (integrating: its input lag), seconds "
                                      "(default %(default)s)")
    p.add_argument("--delay-s", type=number(0.0, what="a dead time of 0 seconds or more"), default=3.0,
                   help="process dead time, seconds (default %(default)s)")
    p.add_argument("--ts-s", "--ts", dest="ts_s", type=number(0.0, above=True, what="a sample period of more "
                                                                                      "than 0 seconds"),
                   default=1.0, help="sample period, seconds (default %(default)s)")
    p.add_argument("--n", type=_samples, default=3000,
                   help=f"number of samples, {MIN_SAMPLES} or more (default %(default)s)")
    p.add_argument("--noise", type=number(0.0, what="a noise std of 0 or more PV units (0: no noise)"),
                   default=0.02, help="measurement noise std, PV units (default %(default)s)")
    p.add_argument("--load", type=number(0.0, what="a load step std of 0 or more PV units (0: no load)"),
                   default=0.01, help="random-walk load increment std, PV units (default %(default)s)")
    p.add_argument("--f0", type=int, choices=[-1, 1], default=1, help="valve's starting direction")
    p.add_argument("--kc", type=_kc, default=None, help="controller gain (default: SIMC tuning)")
    p.add_argument("--ti-s", type=number(0.0, above=True, what="an integral time of more than 0 seconds"),
                   default=None, help="integral time, seconds (default: SIMC)")
    p.add_argument("--seed", type=whole_number(0, "a whole number, 0 or more"), default=0, help="random seed")
    p.add_argument("--name", default="SIM", help="loop name (tag prefix of the columns)")
    p.add_argument("--start", type=_start, default=None, metavar="TIME",
                   help="time of the first sample, ISO 8601, UTC unless it carries an offset (default "
                        "2026-01-01T00:00:00Z; give each night's export its own to build a history)")
    p.add_argument("--out", required=True, help="output CSV file")


def _check_loop(rec, args: argparse.Namespace) -> None:
    """Refuse a simulation that overflowed."""
    import numpy as np

    from ...identification import MAX_MAGNITUDE

    for role in ("op", "pv", "mv"):
        x = getattr(rec, role)
        if not np.all(np.isfinite(x)) or float(np.max(np.abs(x))) > MAX_MAGNITUDE:
            given = ", ".join(f"{flag} {v:g}" for flag, v in (("--gain", args.gain), ("--noise", args.noise),
                                                               ("--load", args.load), ("--kc", args.kc),
                                                               ("--tau-s", args.tau_s)) if v is not None)
            raise DataError(f"the simulated {role.upper()} overflowed ({given}): give values of a plant's size")


def _warn_still_valve(rec, args: argparse.Namespace) -> None:
    """A valve that never moved leaves nothing to identify: say so (the file may still be wanted)."""
    import numpy as np

    if np.ptp(rec.mv) == 0:
        print(f"warning: the simulated valve never moved (OP travelled {np.ptp(rec.op):.3g} % of span against S = "
              f"{args.S:g} %): the record shows no stiction to identify; simulate more samples (--n), or check "
              "that --kc has the process gain's sign and --gain, --noise and --load a plant's size", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    from connectors.historian import write_wide
    from ...simulate import sticky_loop

    if args.S < 0 or args.J < 0:
        raise DataError("--S and --J must be >= 0 (% of valve span)")
    for flag, value in (("--S", args.S), ("--J", args.J)):
        if value > MAX_SJ_PCT:
            raise DataError(f"{flag} {value:g}: S and J are % of valve span; use at most {MAX_SJ_PCT:g} (the "
                            "simulated loop runs at mid-span, and a wider band drives OP into its limits)")
    if args.tau_s == 0 and args.process != "integrating":   # only a level's input lag may be 0
        raise DataError(f"--tau-s 0: a {args.process} process needs a time constant of more than 0 seconds")
    gain = args.gain if args.gain is not None else (0.02 if args.process == "integrating" else 1.0)
    rec = sticky_loop(args.S, args.J, n=args.n, ts_s=args.ts_s, gain=gain, tau_s=args.tau_s,
                      delay_s=args.delay_s, kind=args.process, noise_std=args.noise,
                      load_walk_std=args.load, f0=args.f0, seed=args.seed, name=args.name,
                      Kc=args.kc, Ti_s=args.ti_s,
                      u_balance_pct=INTEGRATING_BALANCE_PCT if args.process == "integrating" else None)
    _check_loop(rec, args)
    if args.start is not None:
        rec = rec.replace(start=args.start)
    try:
        write_wide(rec, args.out)
    except OverflowError:
        # the last time stamp lies past the year 9999 (a huge --ts-s or a late --start)
        raise DataError(f"--n {args.n} samples every {args.ts_s:g} s from {args.start or '2026-01-01'} end after the "
                        "year 9999; give a smaller --ts-s or --n, or an earlier --start") from None
    print(f"wrote {args.out}: {rec.n} samples at {rec.ts_s:g} s, S={args.S:g} %, J={args.J:g} %",
          file=sys.stderr)
    _warn_still_valve(rec, args)
    return 0
