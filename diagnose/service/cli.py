"""The `stiction` command line: a thin shell around the library.

Each command lives in its own module under ``diagnose.service.commands`` with two functions,
``add_arguments(parser)`` and ``run(args) -> int``. Modules are imported only when their command
runs, so ``stiction identify`` never pays for torch. Domain errors print ``error: ...`` on stderr
and exit 1; usage errors exit 2; Ctrl-C exits 130; a reader that stops reading stdout
(``| head``) ends the command quietly with 141, as SIGPIPE ends a Unix tool; ``--traceback``
shows the Python traceback.
"""

from __future__ import annotations

import argparse
import atexit
import importlib
import os
import signal
import sys
import threading
from typing import NoReturn, Sequence

from ..errors import StictionError

# name -> (module, one-line help). Order is the order shown in --help.
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("demo", "run the nightly batch on the bundled sample logs and say where the reports are"),
    "identify": ("identify", "identify stiction (S, J, class) in one loop's record"),
    "explain": ("explain", "locate model/plant mismatch and name the missing physics"),
    "batch": ("batch", "diagnose many loops (files/folders) and write reports and a plant summary"),
    "monitor": ("monitor", "poll loops live over Modbus/TCP and diagnose each window"),
    "history": ("history", "show the S/J/class trend of a loop from the results database"),
    "simulate": ("simulate", "simulate a closed loop with a sticky valve and write it as CSV"),
    "reproduce": ("reproduce", "reproduce the seed paper's NARX-SP experiments (tables I-III, model mode)"),
    "bank": ("bank", "train or list the NARX-SP model bank"),
}


def _available(module: str) -> bool:
    return importlib.util.find_spec(f"diagnose.service.commands.{module}") is not None


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="stiction",
        description="Control-valve stiction diagnostics: identify S and J from routine plant data, "
                    "explain model mismatch, and run nightly over a plant.",
    )
    parser.add_argument("--traceback", action="store_true", help="show Python tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_) in COMMANDS.items():
        p = sub.add_parser(name, help=help_, description=help_)
        if name == command:
            importlib.import_module(f"diagnose.service.commands.{module}").add_arguments(p)
    return parser


def _stdout_gone() -> bool:
    """Whether stdout is a pipe whose reader has closed it (``| head`` read what it wanted), as
    opposed to some other connection breaking."""
    try:
        import select

        poll = select.poll()
        poll.register(sys.stdout.fileno(), select.POLLOUT)
        return any(ev & select.POLLERR for _, ev in poll.poll(0))
    except (AttributeError, OSError, ValueError):  # no poll, or stdout is not a file
        return False


def _quiet_exit() -> int:
    # what is still buffered would fail again when Python flushes stdout at exit
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (AttributeError, OSError, ValueError):
        pass
    return 128 + int(signal.SIGPIPE)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in argv if not a.startswith("-")), None)
    if command in COMMANDS and not _available(COMMANDS[command][0]):
        print(f"error: the {command!r} command is not available in this build", file=sys.stderr)
        return 2
    parser = build_parser(command if command in COMMANDS else None)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits 2 on usage errors, 0 on --help
        return int(exc.code or 0)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    module = importlib.import_module(f"diagnose.service.commands.{COMMANDS[args.command][0]}")
    try:
        rc = int(module.run(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not in Python's flush at exit
        return rc
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (StictionError, OSError) as exc:
        if isinstance(exc, BrokenPipeError) and _stdout_gone():
            return _quiet_exit()
        if args.traceback:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 1


def console() -> NoReturn:
    """The installed ``stiction`` program: `main`, then the end of the process.

    Once a command has returned, everything it wrote is closed or flushed; what is left is the
    interpreter freeing every object of numpy, pandas and the kernels one by one, which the user
    waits for (noticeably on a slow core) and nothing needs. So the process ends here
    without that teardown, after the exit handlers have run and stdout and stderr are flushed.
    Where another thread still runs (nothing of ours leaves one, but a plug-in might), the normal
    exit joins it instead.
    """
    rc = main()
    if threading.active_count() > 1:
        sys.exit(rc)
    atexit._run_exitfuncs()  # temporary folders, logging, child processes: as at a normal exit
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        rc = _quiet_exit()
    except (OSError, ValueError):
        rc = rc or 1
    try:
        sys.stderr.flush()
    except (OSError, ValueError):
        pass
    os._exit(rc)


if __name__ == "__main__":  # pragma: no cover
    console()
