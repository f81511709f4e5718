"""Live monitoring: poll loops over Modbus/TCP and diagnose each window as it fills.

`connectors.modbus.ModbusPoller` polls every loop on the event loop of this process and hands each
full window on as a `LoopRecord`. The window is diagnosed in a separate worker process (so the
polling never waits for a diagnosis), which writes ``OUT/LOOP/WINDOW.json`` and ``WINDOW.md`` (and
``latest.json``/``latest.md``), atomically. This process updates the optional Prometheus metrics
and hands each result to a thread that stores it in the history database (`HistoryWriter`: the
polling never waits for the database either). A device that restarts is reconnected by the poller
(its lost polls become gaps, never invented values); each outage and each reconnection is logged
with its UTC time and the outage's length, and a device that never answers is named at the end. A
window that cannot be diagnosed is logged and monitoring goes on. The window length is checked
before polling starts: a window too short to identify stiction is a one-line error naming the
configuration file and key.
"""

from __future__ import annotations

import asyncio
import json
import os
import queue
import signal
import sys
import threading
import time
from collections import deque
from concurrent.futures import Future
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, TextIO

from ..errors import DataError, StictionError
from ..parallel import cores_per_worker
from ..plain import duration
from .history import PERSIST_RUNS, history_loop, sticky_runs, verdict_of

if TYPE_CHECKING:
    from ..record import LoopRecord
    from .pipeline import Diagnosis

#: Shortest window (samples) the monitor accepts. The fit is scored on what is left after the
#: model's start-up samples, and shorter windows leave too few to identify; windows under 250
#: samples identify with a short-record warning.
MIN_WINDOW_SAMPLES = 100


#: Seconds of polls without data (and without an error) after which a device counts as out.
OUTAGE_AFTER_S = 1.0

#: Results that may wait for the history database (locked by another writer, a slow disk); one
#: more is not stored, said in its line, rather than held in memory without end.
HISTORY_QUEUE = 256
#: Seconds between the writer's tries to store results that waited out a lock (each try itself
#: waits up to the history's busy timeout for the lock).
HISTORY_RETRY_S = 5.0
#: How long the monitor's start waits for a history database another process holds locked before
#: it polls without the loops' earlier runs (the writer's thread then waits for the lock, as SQLite does).
STARTUP_DB_WAIT_S = 2.0


def _utc(t_s: float) -> str:
    from datetime import datetime, timezone

    return datetime.fromtimestamp(t_s, timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z")


@dataclass
class DeviceState:
    """What the monitor knows of one device's link: whether it answers, since when."""

    name: str
    where: str
    up: bool | None = None      # None: no poll yet
    since_s: float = 0.0        # wall time of the last change
    ever_read: bool = False
    outages: int = 0
    last_error: str | None = None
    missing_since_s: float | None = None   # first of the current run of polls without data


@dataclass
class MonitorStats:
    windows: int = 0
    diagnosed: int = 0
    failed: int = 0
    skipped_short: int = 0
    dropped: int = 0            # windows whose diagnosis had not begun when the monitor stopped
    errors: list[str] = field(default_factory=list)
    polls: int = 0
    polls_failed: int = 0
    polls_missed: int = 0
    polls_good: int = 0
    poll_cpu_s: float = 0.0
    wall_s: float = 0.0
    outages: int = 0
    reconnects: int = 0
    never_answered: list[str] = field(default_factory=list)
    signal: int | None = None   # the SIGINT or SIGTERM that stopped the run, None when it ran its course


def window_id(record: Any) -> str:
    """A file-safe name for a window from its first sample's UTC time (``20261122T163000Z``)."""
    start = str(record.start or "")
    digits = "".join(ch for ch in start[:19] if ch.isdigit())
    if len(digits) >= 14:
        return f"{digits[:8]}T{digits[8:14]}Z" + (f"_s{record.meta.get('segment')}"
                                                    if (record.meta.get("n_segments") or 1) > 1 else "")
    return f"w{int(time.time() * 1000)}"


def diagnose_window(record: LoopRecord, out_dir: str, explain: bool | str = False,
                    figures: bool = False, threads: int | None = None) -> Diagnosis:
    """Diagnose one window and write its JSON and Markdown (runs in a worker process; ``threads``:
    the worker's share of the cores, see `diagnose.service.pipeline.diagnose`)."""
    from connectors.historian import atomic_write

    from .batch import worker_setup, safe_name
    from .pipeline import diagnose
    from .report import loop_blocks, to_markdown

    worker_setup()
    loop = safe_name(record.name)
    wid = window_id(record)
    diag = replace(diagnose(record, explain=explain, threads=threads), loop_id=loop, window=wid,
                   input_hash=f"window:{wid}")
    d = Path(out_dir) / loop
    names: list[str] = []
    if figures:
        from . import figures as figs

        pngs = figs.loop_figures(diag)
        for name, png in pngs.items():
            atomic_write(d / f"{wid}_{name}.png", png)
        names = list(pngs)
    md = to_markdown(loop_blocks(diag, names), figure_path=f"{wid}_{{name}}.png")
    text = json.dumps(diag.to_dict(), indent=1, allow_nan=False)
    atomic_write(d / f"{wid}.md", md)
    atomic_write(d / f"{wid}.json", text)
    atomic_write(d / "latest.md", md)
    atomic_write(d / "latest.json", text)
    return diag


def _monitor_worker_init(parent_pid: int | None = None) -> None:
    """Diagnosis workers yield the CPU to the polling process (which must never miss a tick) and
    die with it."""
    from .batch import worker_setup

    worker_setup(parent_pid)   # a pool worker ignores Ctrl-C, which reaches the whole process group
    # systemd signals the whole cgroup: the monitor decides what becomes of a window in flight, so a
    # worker must not die under it
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        os.nice(10)
    except OSError:  # pragma: no cover - not permitted
        pass


#: Longest wait for the workers' warm-up before polling starts anyway (seconds).
WARM_UP_WAIT_S = 60.0


def _warm_up() -> bool:
    """Import the diagnosis stack in a fresh worker before the first window arrives."""
    from .batch import worker_setup

    worker_setup()
    from . import pipeline, report  # noqa: F401
    from .. import identification  # noqa: F401

    return True


class HistoryWriter:
    """Stores the monitor's results in the history database on a thread of its own.

    SQLite waits up to 30 s for a database another process holds locked (a batch's transaction, a
    backup); on the polling thread that wait would miss polls. Results queue here (at most
    `HISTORY_QUEUE`) and the thread stores what has gathered in one transaction, so a lock costs one
    wait for all of them, not one per window. A lock held longer than the wait (`HistoryBusy`) keeps
    the results: they are tried again every `HISTORY_RETRY_S` with what has gathered since, said
    once through ``say`` while they wait and once when they are stored; at most `HISTORY_QUEUE`
    wait, and beyond that the oldest are given up. A result that cannot be stored (a damaged
    database, or still locked when the monitor stops) costs its row only, said in one line through
    ``failed(diag, reason)``. The database is opened by the thread at its first result (an sqlite
    connection belongs to its thread) and again after a failed open.
    """

    def __init__(self, path: str | os.PathLike | None, failed: Callable[[Any, str], None],
                 say: Callable[[str], None] | None = None, *, busy_timeout_s: float | None = None,
                 retry_s: float = HISTORY_RETRY_S) -> None:
        self.path = path
        self.failed = failed
        self.say = say or (lambda msg: None)
        self.busy_timeout_s = busy_timeout_s
        self.retry_s = retry_s
        self._q: queue.Queue = queue.Queue(HISTORY_QUEUE)
        self._thread = threading.Thread(target=self._run, name="stiction-history", daemon=True)
        self._thread.start()

    def put(self, diag: Any, run_at: str) -> str | None:
        """Queue a result without waiting; the reason it will not be stored when the queue is full."""
        try:
            self._q.put_nowait((diag, run_at))
        except queue.Full:
            return (f"{HISTORY_QUEUE} results already wait for the history database {self.path} "
                    "(locked by another writer?)")
        return None

    def waiting(self) -> int:
        """Results queued or being stored."""
        return self._q.unfinished_tasks

    def flush(self) -> None:
        """Return when every result queued so far is stored (or said not to be)."""
        self._q.join()

    def close(self) -> None:
        """Store what is queued, then stop the thread."""
        if self._thread.is_alive():
            self._q.put(None)   # waits while the queue is full: the thread is emptying it
            self._thread.join()

    def _run(self) -> None:
        from .history import History, HistoryBusy, row_from_diagnosis

        hist: Any = None
        stop = False
        waiting: list = []      # results kept through a lock, oldest first; their task_done waits too
        while not stop:
            try:
                items = [self._q.get(timeout=self.retry_s if waiting else None)]
            except queue.Empty:
                items = []
            while True:
                try:
                    items.append(self._q.get_nowait())
                except queue.Empty:
                    break
            stop = any(it is None for it in items)
            batch = waiting + [it for it in items if it is not None]
            done = [None] * (len(items) - len(batch) + len(waiting))   # the stop mark's task_done
            try:
                if batch:
                    if hist is None:
                        hist = (History(self.path) if self.busy_timeout_s is None
                                else History(self.path, busy_timeout_s=self.busy_timeout_s))
                    hist.add_rows([row_from_diagnosis(d, run_at=t) for d, t in batch])
                    if waiting:
                        self.say(f"history: the {len(waiting)} result(s) that waited for the lock are stored")
                done += batch
                waiting = []
            except HistoryBusy as exc:
                # locked, not broken: keep them for the next try (or give them up at the stop)
                if stop:
                    self._give_up(batch, str(exc))
                    done += batch
                    waiting = []
                else:
                    if not waiting:
                        self.say(f"{exc}: {len(batch)} result(s) wait and are stored when it is released")
                    over = max(0, len(batch) - HISTORY_QUEUE)
                    self._give_up(batch[:over], f"more than {HISTORY_QUEUE} results waited for the lock")
                    done += batch[:over]
                    waiting = batch[over:]
                    if hist is not None:
                        hist.close()
                        hist = None
            except Exception as exc:  # the database, not the monitor, is in trouble: its rows are lost
                why = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
                if not isinstance(exc, StictionError):
                    why = f"{type(exc).__name__}: {why}"
                self._give_up(batch, why)
                done += batch
                waiting = []
            finally:
                for _ in done:
                    self._q.task_done()
        if hist is not None:
            hist.close()

    def _give_up(self, results: list, why: str) -> None:
        for d, _ in results:
            self.failed(d, why)


class Monitor:
    """Poll, diagnose windows off the event loop, store and publish the results.

    Parameters
    ----------
    config : ModbusConfig or path
        The poller configuration (`connectors.modbus.load_modbus_config`).
    out_dir : path
        Where each window's JSON/Markdown goes (``OUT/LOOP/``).
    db : path, optional
        History database (`diagnose.service.history.default_db_path()` when None); ``history=False``
        leaves it alone. It is opened (and its loops' last runs read) here; the results are stored
        by a `HistoryWriter`.
    metrics_port : int, optional
        Serve Prometheus metrics on this local port.
    window_samples : int, optional
        Samples per diagnosed window (default: the configuration's).
    workers : int
        Diagnosis worker processes (0: diagnose in a thread of this process).
    min_fraction : float
        A window shorter than this fraction of ``window_samples`` (a cut or final partial window) is
        not diagnosed.
    log : text stream
        One line per window (default stderr).
    """

    def __init__(self, config: Any, out_dir: str | os.PathLike, *, db: str | os.PathLike | None = None,
                 history: bool = True, metrics_port: int | None = None, window_samples: int | None = None,
                 workers: int = 1, explain: bool | str = False, figures: bool = False,
                 min_fraction: float = 0.5, log: TextIO | None = None,
                 on_result: Callable[[Diagnosis], Any] | None = None) -> None:
        from connectors.modbus import ModbusPoller, load_modbus_config

        # each window's Diagnosis comes back pickled: its types are imported now, not by the first
        # result while the poller runs
        from . import pipeline  # noqa: F401

        self.config = config if not isinstance(config, (str, os.PathLike)) else load_modbus_config(config)
        self.out_dir = Path(out_dir)
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DataError(f"{self.out_dir}: cannot create the output folder: {exc.strerror or exc}") from None
        self.explain = explain
        self.figures = figures
        self.log = log if log is not None else sys.stderr
        self.on_result = on_result
        self.window_samples = int(window_samples or self.config.window_samples)
        if self.window_samples < MIN_WINDOW_SAMPLES:
            where = ("--window" if window_samples else
                     f"{self.config.path or 'the Modbus configuration'}: window_samples")
            raise DataError(f"{where} = {self.window_samples} is too short to identify stiction; use at "
                            f"least {MIN_WINDOW_SAMPLES} samples (250 or more give firm S and J)")
        self.min_samples = max(int(min_fraction * self.window_samples), MIN_WINDOW_SAMPLES)
        self.stats = MonitorStats()
        self.devices = {name: DeviceState(name, f"{d.host}:{d.port}") for name, d in self.config.devices.items()}
        self.poller = ModbusPoller(self.config, on_window=self._on_window, window_samples=self.window_samples,
                                   on_sample=self._on_sample, on_error=self._on_read_error)
        self._said: set[tuple[str, str]] = set()
        self._say_lock = threading.Lock()
        # each loop's last verdicts, for the persistence said beside each window: its runs in the
        # history database when the monitor starts, then this run's windows (kept here, as the
        # history's writes are not waited for)
        self._recent: dict[str, deque] = {}
        self.history_writer: HistoryWriter | None = None
        if history:
            from .history import History, HistoryBusy, default_db_path

            self.db_path = Path(db) if db is not None else default_db_path()
            try:
                # a bad --db is a one-line error before polling starts
                with History(self.db_path, busy_timeout_s=STARTUP_DB_WAIT_S) as hist:
                    self._seed_recent(hist)
            except HistoryBusy as exc:
                # locked, not broken: polling starts now, and the writer's thread waits for the lock
                self._say(f"{exc}: polling starts without the loops' earlier runs, and this run's results "
                          "are stored when the lock is released")
            self.history_writer = HistoryWriter(self.db_path, self._not_stored, self._say)
        self.metrics = None
        if metrics_port is not None:
            from .metrics import Metrics

            self.metrics = Metrics(metrics_port, poll_stats=lambda: self.poller.stats)
        self.workers = workers
        self._pool: Any = None
        self._pending: set[Any] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._poll_task: asyncio.Future | None = None
        self._warm: list = []      # the workers' warm-up, awaited before the first poll

    def _seed_recent(self, hist: Any) -> None:
        for name in self.config.loops:
            loop = history_loop(name)
            try:
                runs = hist.runs(loop, limit=PERSIST_RUNS)
            except StictionError as exc:  # a damaged page: this run's windows still count
                self._say(f"{loop}: earlier runs not read from the history: {exc}")
                runs = []
            self._recent[loop] = deque(runs, maxlen=PERSIST_RUNS)

    def _say(self, msg: str) -> None:
        # one write per line, under a lock: the poller's callbacks, the diagnoses and the history's
        # thread all log here
        with self._say_lock:
            self.log.write(msg + "\n")
            self.log.flush()

    def _not_stored(self, res: Any, why: str) -> None:
        msg = f"{res.loop_id or res.identification.loop} {res.window}: not stored in the history: {why}"
        self.stats.errors.append(msg)
        self._say(msg)

    # ------------------------------------------------------------------------------ links
    def _on_sample(self, loop: str, t_s: float, values: dict) -> None:
        """Follow each device's link from its loops' polls; log outages and reconnections."""
        import math

        dev = self.devices.get(self.config.loops[loop].device)
        if dev is None:
            return
        def finite(v: Any) -> bool:
            try:
                return math.isfinite(float(v))
            except (TypeError, ValueError):
                return False

        ok = finite(values.get("op")) and finite(values.get("pv"))
        if ok:
            dev.missing_since_s = None
            if dev.up is False:
                self.stats.reconnects += 1
                what = "reconnected" if dev.ever_read else "first answer"
                self._say(f"{_utc(t_s)} device {dev.name} ({dev.where}): {what} after {t_s - dev.since_s:.1f} s "
                          "without data")
            if dev.up is not True:
                dev.up, dev.since_s = True, t_s
            dev.ever_read = True
            return
        err = self.poller.stats[loop].last_error if loop in self.poller.stats else None
        if dev.missing_since_s is None:
            dev.missing_since_s = t_s
        # A poll that came back empty without an error is a late answer (a busy poller or link), not
        # yet an outage: it becomes one when the device errs or stays silent for OUTAGE_AFTER_S.
        if dev.up is True and err is None and t_s - dev.missing_since_s < OUTAGE_AFTER_S:
            return
        if dev.up is not False:
            if dev.up is True:
                self.stats.outages += 1
                dev.outages += 1
            dev.up, dev.since_s = False, dev.missing_since_s
            self._say(f"{_utc(t_s)} device {dev.name} ({dev.where}): "
                      f"{'outage' if dev.ever_read else 'no answer'}: {err or 'no data'}; retrying")
        dev.last_error = err or dev.last_error

    # ------------------------------------------------------------------------------ windows
    def _submit(self, record: Any) -> Any:
        self._ensure_pool()
        # the workers' fits run on threads too: each worker gets its share of the cores
        return self._pool.submit(diagnose_window, record, str(self.out_dir), self.explain, self.figures,
                                 cores_per_worker(self.workers))

    def _ensure_pool(self) -> None:
        if self._pool is None:
            if self.workers > 0:
                import multiprocessing as mp
                from concurrent.futures import ProcessPoolExecutor

                ctx = mp.get_context("forkserver")
                ctx.set_forkserver_preload(["__main__", f"{__package__}._keep_forkserver"])
                self._pool = ProcessPoolExecutor(self.workers, mp_context=ctx,
                                                 initializer=_monitor_worker_init, initargs=(os.getpid(),))
                self._warm = [self._pool.submit(_warm_up) for _ in range(self.workers)]
            else:
                from concurrent.futures import ThreadPoolExecutor

                self._pool = ThreadPoolExecutor(1)

    def _on_read_error(self, loop: str, exc: Exception) -> None:
        # a configuration-type read error (missing register, wrong id, wrong byte order) comes
        # back with every poll: each is logged once per loop
        if (loop, str(exc)) not in self._said:
            self._said.add((loop, str(exc)))
            self._say(f"{_utc(time.time())} {loop}: {exc}")

    def _on_window(self, record: Any) -> None:
        self.stats.windows += 1
        if any(f.code == "register_order" for f in record.findings):
            # garbage from a wrong byte order (said once by `_on_read_error`) would only fail as an
            # OP outside 0..100 %
            self.stats.failed += 1
            return
        if record.n < self.min_samples:
            self.stats.skipped_short += 1
            return
        try:
            fut = self._submit(record)
        except Exception as exc:  # a broken pool: this window is lost, polling goes on
            self._failed(record.name, exc)
            return
        self._pending.add(fut)
        loop = self._loop
        fut.add_done_callback(lambda f: loop.call_soon_threadsafe(self._done, record.name, f)
                              if loop is not None and not loop.is_closed() else self._done(record.name, f))

    def _done(self, name: str, fut: Future) -> None:
        self._pending.discard(fut)
        if fut.cancelled():
            self.stats.dropped += 1
            self._say(f"{name}: window not diagnosed: the monitor stopped before its diagnosis began")
            return
        try:
            res = fut.result()
        except Exception as exc:
            self._failed(name, exc)
            return
        self.stats.diagnosed += 1
        loop = res.loop_id or name
        recent = self._recent.setdefault(history_loop(res.identification.loop), deque(maxlen=PERSIST_RUNS))
        recent.append(verdict_of(res.identification))
        if self.history_writer is not None:
            from .history import utc_now

            why = self.history_writer.put(res, utc_now())
            if why is not None:
                self._not_stored(res, why)
        held = sticky_runs(list(recent))
        if self.metrics is not None:
            self.metrics.observe(loop, res, held)
        said = "" if held is None else f" [stiction in {held[0]} of the last {held[1]} windows]"
        self._say(f"{loop} {res.window}: {res.verdict_text}{said}")
        if self.on_result is not None:
            self.on_result(res)

    def _failed(self, name: str, exc: Exception) -> None:
        self.stats.failed += 1
        msg = f"{name}: window not diagnosed: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
        self.stats.errors.append(msg)
        self._say(msg)
        if self.metrics is not None:
            self.metrics.failed(name)

    # ------------------------------------------------------------------------------ running
    def _on_signal(self, signum: int) -> None:
        """First SIGINT/SIGTERM: stop polling and end as a ``--duration`` run ends (the partial
        windows long enough are diagnosed). A second: drop the windows whose diagnosis has not begun."""
        name = signal.Signals(signum).name
        if self.stats.signal is None:
            self.stats.signal = signum
            self._say(f"{_utc(time.time())} {name}: stopping; the partial windows of {self.min_samples} samples or "
                      f"more are diagnosed first ({name} again drops those not yet begun)")
            if self._poll_task is not None:
                self._poll_task.cancel()
            return
        self._say(f"{_utc(time.time())} {name} again: dropping the windows not yet begun")
        for fut in list(self._pending):
            fut.cancel()

    def _catch_signals(self) -> list[int]:
        caught = []
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                self._loop.add_signal_handler(sig, self._on_signal, sig)  # type: ignore[union-attr]
            except (NotImplementedError, RuntimeError, ValueError):  # not the main thread, or Windows
                continue
            caught.append(sig)
        return caught

    async def run(self, duration_s: float | None = None, *, drain_s: float = 120.0) -> MonitorStats:
        """Poll for ``duration_s`` seconds (forever when None) or until SIGINT or SIGTERM, then
        finish pending diagnoses (``stats.signal`` says which signal stopped the run)."""
        self._loop = asyncio.get_running_loop()
        t0 = time.monotonic()
        caught = self._catch_signals()
        try:
            # the workers are started and warmed up before the first poll: starting them blocks
            # this thread until the fork server has imported the diagnosis stack (seconds on a busy
            # machine), and polls missed meanwhile would cut the first window and read as an outage
            self._ensure_pool()
            deadline = time.monotonic() + WARM_UP_WAIT_S
            while (not all(f.done() for f in self._warm) and self.stats.signal is None
                   and time.monotonic() < deadline):
                await asyncio.sleep(0.05)
            t0 = time.monotonic()                  # the run's time is its polling time
            self._poll_task = asyncio.ensure_future(self.poller.run(duration_s))
            if self.stats.signal is not None:      # stopped while the workers started
                self._poll_task.cancel()
            try:
                await self._poll_task
            except asyncio.CancelledError:
                if self.stats.signal is None:  # cancelled by the caller, not stopped by a signal
                    raise
            deadline = time.monotonic() + drain_s
            while self._pending and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
        finally:
            for sig in caught:
                self._loop.remove_signal_handler(sig)
            self.stats.wall_s = time.monotonic() - t0
            for st in self.poller.stats.values():
                self.stats.polls += st.polls
                self.stats.polls_failed += st.failed
                self.stats.polls_missed += st.missed
                self.stats.polls_good += st.good
            self.stats.poll_cpu_s = self.poller.cpu_s
            for dev in self.devices.values():
                if not dev.ever_read:
                    self.stats.never_answered.append(dev.name)
                    self._say(f"device {dev.name} ({dev.where}) never answered in {duration(self.stats.wall_s)}: "
                              f"{dev.last_error or 'no data'}")
                elif dev.up is False:
                    self._say(f"device {dev.name} ({dev.where}) still down at the end, since {_utc(dev.since_s)}")
            self.close()
        return self.stats

    def close(self) -> None:
        """Stop the workers, then store the results still queued for the history before returning."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        if self.history_writer is not None:
            # a stop that waits for a locked database says why it waits
            deadline = time.monotonic() + 1.0
            while self.history_writer.waiting() and time.monotonic() < deadline:
                time.sleep(0.02)
            waiting = self.history_writer.waiting()
            if waiting:
                self._say(f"{_utc(time.time())} waiting for the history database {self.db_path} to store "
                          f"{waiting} result(s)")
            self.history_writer.close()
            self.history_writer = None
        if self.metrics is not None:
            self.metrics.close()
            self.metrics = None


def run_monitor(config: Any, out_dir: str | os.PathLike, *, duration_s: float | None = None,
                **kw: Any) -> MonitorStats:
    """Run a `Monitor` to completion (SIGINT or SIGTERM stops it cleanly, see `Monitor.run`)."""
    mon = Monitor(config, out_dir, **kw)
    try:
        return asyncio.run(mon.run(duration_s))
    except StictionError:
        mon.close()
        raise


def nothing_read_error(config: Any, stats: MonitorStats) -> StictionError:
    """The one-line error of a run in which no device ever answered."""
    path = getattr(config, "path", None) or str(config)
    return StictionError(f"{path}: nothing was read in {duration(stats.wall_s)}: device(s) "
                         f"{', '.join(stats.never_answered) or '?'} never answered ({stats.polls_failed} failed, "
                         f"{stats.polls_missed} missed polls); check host, port and device_id, and that the "
                         "device is on")
