"""`stiction monitor` end to end against a live pymodbus server process serving simulated loops."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
import urllib.request
from datetime import datetime

import pytest

from connectors.modbus_sim import default_config_text, free_port
from diagnose.service.cli import main
from diagnose.service.history import History
from diagnose.service.monitor import window_id


def _start_sim(port: int) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-m", "connectors.modbus_sim", "--port", str(port), "--loops", "2",
                             "--ts", "0.04", "--samples", "3000"], stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    assert line.startswith("READY"), line
    return proc


def _stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def test_monitor_diagnoses_windows_survives_a_device_restart_and_serves_metrics(tmp_path, capsys):
    port, mport = free_port(), free_port()
    cfg = tmp_path / "plant.toml"
    cfg.write_text(default_config_text(port, 2, period_s=0.04, window_samples=150))
    sims = [_start_sim(port)]
    state: dict = {}

    def restart():
        _stop(sims[0])
        state["down_at"] = time.time()
        time.sleep(1.0)
        state["starting_at"] = time.time()
        sims.append(_start_sim(port))
        state["up_at"] = time.time()

    done = threading.Event()

    def scrape():
        # until both loops' diagnoses and the outage show up, or the monitor has ended (its last
        # answer is kept): on a loaded machine the windows are diagnosed late in the run
        while not done.is_set():
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{mport}/metrics", timeout=5) as r:
                    state["metrics"] = r.read().decode()
            except OSError:
                pass
            m = state.get("metrics", "")
            if 'stiction_s_pct{loop="SIM001"}' in m and "up_at" in state and _outage_counted(m):
                return
            time.sleep(0.3)

    timers = [threading.Timer(7.0, restart), threading.Timer(1.0, scrape)]
    for t in timers:
        t.start()
    try:
        rc = main(["monitor", str(cfg), "--duration", "19", "--out", str(tmp_path / "out"),
                   "--db", str(tmp_path / "h.sqlite"), "--metrics-port", str(mport)])
    finally:
        done.set()
        for t in timers:
            t.join()
        for p in sims:
            _stop(p)
    assert rc == 0
    out = capsys.readouterr()
    assert "windows diagnosed" in out.out and "failed" in out.out
    up = state["up_at"]
    # the outage and the reconnection are logged with their UTC times, in that order
    log = out.err.splitlines()
    down = [ln for ln in log if "device sim (" in ln and ": outage:" in ln]
    back = [ln for ln in log if "device sim (" in ln and "reconnected after" in ln]
    assert down and back and log.index(down[0]) < log.index(back[0]), out.err
    t_down = datetime.fromisoformat(down[0].split()[0].replace("Z", "+00:00")).timestamp()
    t_back = datetime.fromisoformat(back[0].split()[0].replace("Z", "+00:00")).timestamp()
    # (the log's times are whole seconds; the device may answer before its starter returns)
    assert state["down_at"] - 2.0 <= t_down <= state["up_at"] and state["starting_at"] - 1.0 <= t_back <= up + 5.0
    assert float(back[0].split("reconnected after ")[1].split()[0]) >= 0.5
    assert "1 outage(s), 1 reconnection(s)" in out.out
    for loop in ("SIM000", "SIM001"):
        files = sorted((tmp_path / "out" / loop).glob("2*.json"))
        assert len(files) >= 2, f"{loop}: {files}"
        results = [json.loads(f.read_text()) for f in files]
        starts = [datetime.fromisoformat(r["record"]["start"].replace("Z", "+00:00")).timestamp() for r in results]
        assert max(starts) > up - 0.5, "no window diagnosed after the device came back"
        assert (tmp_path / "out" / loop / "latest.md").read_text().startswith("# Stiction report")
        assert all(r["schema"] == "stiction.loop/2" and "S" in r and r["window"] for r in results)
    with History(tmp_path / "h.sqlite") as h:
        assert len(h.runs("SIM000")) >= 2 and len(h.runs("SIM001")) >= 2
    m = state["metrics"]
    assert 'stiction_s_pct{loop="SIM001"}' in m and 'stiction_polls_total{loop="SIM000"}' in m
    assert 'stiction_probability{loop="SIM001"}' in m
    assert _outage_counted(m)  # the outage was seen


def _outage_counted(metrics: str) -> bool:
    """Whether SIM000's failed or missed polls are above zero in a metrics page."""
    def value(name):
        lines = [ln for ln in metrics.splitlines() if ln.startswith(name + '{loop="SIM000"}')]
        return float(lines[0].split()[-1]) if lines else 0.0

    return value("stiction_polls_failed_total") + value("stiction_polls_missed_total") > 0


def test_window_ids_are_file_safe_and_ordered():
    from diagnose.simulate import sticky_loop

    rec = sticky_loop(1, 0, n=100, name="X").replace(start="2026-11-22T16:30:05.25Z")
    assert window_id(rec) == "20261122T163005Z"


def test_bad_config_is_a_one_line_error(tmp_path, capsys):
    cfg = tmp_path / "bad.toml"
    cfg.write_text("period_s = 1\n[loops.A]\ndevice = 'nope'\n")
    assert main(["monitor", str(cfg), "--duration", "1", "--out", str(tmp_path / "o"), "--no-history"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "Traceback" not in err


@pytest.mark.parametrize("edit, message", [
    (("port = ", "port = 70000\n#"), "devices.sim.port 70000 is outside 1..65535"),
    (("pv = { address = 2,", "pv = { address = 0, table = 'holding',"),
     "loops.SIM000.pv.address 0: holding registers 0..1 overlap loops.SIM000.op (0..1); give each role its own "
     "registers"),
    (("pv = { address = 2,", "pv = { address = 1, table = 'holding',"), "loops.SIM000.pv.address 1: holding"),
])
def test_a_port_out_of_range_or_roles_on_the_same_registers_are_config_errors(tmp_path, capsys, edit, message):
    cfg = tmp_path / "plant.toml"
    text = default_config_text(free_port(), 1, period_s=0.2, window_samples=150)
    old, new = edit
    assert old in text, text
    cfg.write_text(text.replace(old, new, 1))
    assert main(["monitor", str(cfg), "--duration", "5", "--out", str(tmp_path / "o"), "--no-history"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {cfg}: {message}") and len(err.strip().splitlines()) == 1, err


def test_registers_two_loops_read_two_ways_are_a_config_error(tmp_path, capsys):
    # a float32 of one loop on the upper register of another loop's float32: both decode garbage
    cfg = tmp_path / "plant.toml"
    text = default_config_text(free_port(), 2, period_s=0.2, window_samples=150)
    cfg.write_text(text.replace("op = { address = 8,", "op = { address = 7,", 1))
    assert main(["monitor", str(cfg), "--duration", "5", "--out", str(tmp_path / "o"), "--no-history"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {cfg}: loops.SIM001.op.address 7: holding registers 7..8 (float32 ABCD) overlap "
                          "loops.SIM000.mv (6..7, float32 ABCD) on device id 1; give each its own registers") \
        and len(err.strip().splitlines()) == 1, err


def _silent_device():
    """A TCP listener that accepts connections and never answers (a hung gateway)."""
    import socket

    srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    conns = []
    stop = threading.Event()

    def accept():
        srv.settimeout(0.2)
        while not stop.is_set():
            try:
                conns.append(srv.accept()[0])
            except OSError:
                pass

    th = threading.Thread(target=accept, daemon=True)
    th.start()

    def close():
        stop.set()
        th.join()
        for c in conns:
            c.close()
        srv.close()

    return srv.getsockname()[1], close


@pytest.mark.parametrize("kind", ["refused", "silent"])
def test_a_device_that_never_answers_is_named_and_the_exit_is_non_zero(tmp_path, capsys, kind):
    if kind == "refused":
        port, close = free_port(), (lambda: None)
    else:
        port, close = _silent_device()
    cfg = tmp_path / "plant.toml"
    cfg.write_text(default_config_text(port, 1, period_s=0.2, window_samples=150, timeout_s=0.3))
    try:
        rc = main(["monitor", str(cfg), "--duration", "2.5", "--out", str(tmp_path / "out"), "--no-history"])
    finally:
        close()
    out = capsys.readouterr()
    assert rc == 1
    err = out.err.splitlines()
    assert any("device sim (127.0.0.1:" in ln and "no answer" in ln for ln in err), out.err
    assert any("never answered" in ln for ln in err)
    # the closing line does not leave "0 outage(s)" alone for a device that was never up
    assert "0 outage(s), 1 device(s) never answered (sim)" in out.out
    last = err[-1]
    assert last.startswith("error: ") and str(cfg) in last and "nothing was read" in last
    assert "Traceback" not in out.err


def test_a_window_too_short_to_identify_is_refused_up_front(tmp_path, capsys):
    cfg = tmp_path / "plant.toml"
    cfg.write_text(default_config_text(free_port(), 1, period_s=0.2, window_samples=60))
    assert main(["monitor", str(cfg), "--duration", "5", "--out", str(tmp_path / "o"), "--no-history"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {cfg}: window_samples = 60 is too short") and "at least 100" in err
    assert len(err.splitlines()) == 1
    cfg.write_text(default_config_text(free_port(), 1, period_s=0.2, window_samples=600))
    assert main(["monitor", str(cfg), "--window", "40", "--duration", "5", "--out", str(tmp_path / "o"),
                 "--no-history"]) == 1
    assert capsys.readouterr().err.startswith("error: --window = 40 is too short")


def test_registers_read_in_the_wrong_word_order_name_the_order_to_set(tmp_path, capsys):
    # the simulator serves big-endian floats (ABCD); read word-swapped they are +-1e20-ish garbage,
    # which identify would only refuse as an OP outside 0..100 %
    port = free_port()
    cfg = tmp_path / "plant.toml"
    cfg.write_text(default_config_text(port, 1, period_s=0.04, window_samples=100, order="CDAB"))
    sim = _start_sim(port)
    try:
        main(["monitor", str(cfg), "--duration", "6", "--out", str(tmp_path / "o"), "--no-history"])
    finally:
        _stop(sim)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "wrong byte order" in ln]
    assert len(lines) == 1, err                                  # once, not once per window
    assert f" SIM000: {cfg}: loops.SIM000.op (float32 CDAB: " in lines[0]
    assert "loops.SIM000.pv (float32 CDAB: " in lines[0]
    assert lines[0].endswith('set order = "ABCD" (or check the address)')
    assert "0..100" not in err


def test_a_late_poll_is_not_an_outage_but_silence_or_an_error_is(tmp_path):
    import io

    from diagnose.service.monitor import OUTAGE_AFTER_S, Monitor

    cfg = tmp_path / "plant.toml"
    cfg.write_text(default_config_text(free_port(), 1, period_s=0.1, window_samples=150))
    log = io.StringIO()
    mon = Monitor(cfg, tmp_path / "out", history=False, log=log, workers=0)
    loop = next(iter(mon.config.loops))
    good, empty = {"op": 50.0, "pv": 1.0}, {"op": float("nan"), "pv": float("nan")}
    t = 1000.0
    mon._on_sample(loop, t, good)
    # a few empty polls shorter than OUTAGE_AFTER_S, no error: a late answer, nothing logged
    for k in range(1, 4):
        mon._on_sample(loop, t + 0.1 * k, empty)
    mon._on_sample(loop, t + 0.5, good)
    assert mon.stats.outages == 0 and mon.stats.reconnects == 0 and log.getvalue() == ""
    # silence that lasts: an outage from its first empty poll, and the reconnection after it
    t = 1010.0
    for k in range(int(OUTAGE_AFTER_S / 0.1) + 3):
        mon._on_sample(loop, t + 0.1 * k, empty)
    mon._on_sample(loop, t + 2.0, good)
    assert mon.stats.outages == 1 and mon.stats.reconnects == 1
    assert "outage" in log.getvalue() and "reconnected after 2.0 s" in log.getvalue()


def _polls(mport: int, loop: str) -> float:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{mport}/metrics", timeout=2) as r:
            text = r.read().decode()
    except OSError:
        return 0.0
    lines = [ln for ln in text.splitlines() if ln.startswith(f'stiction_polls_total{{loop="{loop}"}}')]
    return float(lines[0].split()[-1]) if lines else 0.0


@pytest.mark.parametrize("sig, code", [("SIGINT", 130), ("SIGTERM", 143)])
def test_a_signal_stops_the_monitor_cleanly(tmp_path, sig, code):
    import os
    import signal

    port, mport = free_port(), free_port()
    cfg = tmp_path / "plant.toml"
    # 400-sample windows (16 s): the run is stopped inside the first, each loop's partial window is
    # past the 200 samples diagnosed
    cfg.write_text(default_config_text(port, 2, period_s=0.04, window_samples=400))
    sim = _start_sim(port)
    # its own process group: the signal goes to the group, as Ctrl-C in a terminal and systemd's
    # stop (to the whole cgroup) reach the diagnosis workers too
    mon = subprocess.Popen([sys.executable, "-m", "diagnose.service.cli", "monitor", str(cfg), "--out",
                            str(tmp_path / "out"), "--db", str(tmp_path / "h.sqlite"), "--metrics-port", str(mport)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while _polls(mport, "SIM001") < 250 and time.monotonic() < deadline and mon.poll() is None:
            time.sleep(0.2)
        os.killpg(mon.pid, getattr(signal, sig))
        out, err = mon.communicate(timeout=90)
    finally:
        if mon.poll() is None:
            mon.kill()
            mon.communicate()
        _stop(sim)
    assert mon.returncode == code, err
    assert f"2 windows diagnosed, 0 failed, 0 too short;" in out and f"stopped by {sig}" in out, (out, err)
    for bad in ("CancelledError", "Traceback", "leaked", "not diagnosed"):
        assert bad not in err, err
    assert f"{sig}: stopping" in err
    for loop in ("SIM000", "SIM001"):
        files = sorted((tmp_path / "out" / loop).glob("2*.json"))
        assert len(files) == 1 and json.loads(files[0].read_text())["record"]["n"] >= 200, files
        assert not list((tmp_path / "out" / loop).glob("*.tmp*"))
    with History(tmp_path / "h.sqlite") as h:
        assert len(h.runs("SIM000")) == 1 and len(h.runs("SIM001")) == 1


def test_ticks_missed_just_after_a_reconnection_are_not_a_second_outage(tmp_path):
    import io

    from diagnose.service.monitor import Monitor

    cfg = tmp_path / "plant.toml"
    cfg.write_text(default_config_text(free_port(), 2, period_s=0.1, window_samples=150))
    log = io.StringIO()
    mon = Monitor(cfg, tmp_path / "out", history=False, log=log, workers=0)
    poller, loops = mon.poller, list(mon.config.loops.values())
    good = {lc.name: {"op": 50.0, "pv": 1.0} for lc in loops}
    t = 1000.0
    poller._record_all(loops, t, good, missed=False)
    for lc in loops:   # the device goes away: the poller's connection attempt fails
        poller.stats[lc.name].last_error = "cannot connect to 127.0.0.1:1"
    for k in range(1, 30):
        poller._record_all(loops, t + 0.1 * k, {}, missed=False)
    poller._record_all(loops, t + 3.0, good, missed=False)           # back
    # the reconnection took longer than a period: the poller records the ticks it skipped as missed
    poller._record_all(loops, t + 3.1, {}, missed=True)
    poller._record_all(loops, t + 3.2, {}, missed=True)
    poller._record_all(loops, t + 3.3, good, missed=False)
    text = log.getvalue()
    assert mon.stats.outages == 1 and mon.stats.reconnects == 1, text
    assert text.count("outage") == 1 and text.count("reconnected") == 1, text


@pytest.mark.parametrize("history", [False, True])
def test_each_window_line_says_how_many_of_the_loops_last_windows_showed_stiction(tmp_path, history):
    import io
    from concurrent.futures import Future
    from dataclasses import replace

    from diagnose.service.monitor import Monitor
    from diagnose.service.pipeline import diagnose
    from diagnose.simulate import sticky_loop

    cfg = tmp_path / "plant.toml"
    cfg.write_text(default_config_text(free_port(), 1, period_s=0.1, window_samples=150))
    log = io.StringIO()
    mon = Monitor(cfg, tmp_path / "out", history=history, db=tmp_path / "h.sqlite", log=log, workers=0)
    loop = dict(n=2000, gain=1.5, tau_s=20.0, delay_s=3.0, noise_std=0.02, load_walk_std=0.01, seed=1, name="SIM000")
    sticky = diagnose(sticky_loop(4.0, 1.5, **loop).replace(mv=None), explain=False, narx=False)
    healthy = diagnose(sticky_loop(0.0, 0.0, **loop).replace(mv=None), explain=False, narx=False)
    assert sticky.identification.stiction and not healthy.identification.stiction
    def window(d, i):   # each window its own stretch of the loop's data
        return replace(d, record=d.record.replace(start=f"2026-01-01T0{i}:00:00Z"), loop_id="SIM000",
                       window=f"w{i}", input_hash=f"window:w{i}")

    for i, d in enumerate((sticky, healthy, sticky)):
        fut: Future = Future()
        fut.set_result(window(d, i))
        mon._done("SIM000", fut)
    mon.close()
    lines = log.getvalue().splitlines()
    assert len(lines) == 3 and "[stiction" not in lines[0]      # one window says nothing of persistence
    assert lines[1].endswith("[stiction in 1 of the last 2 windows]")
    assert lines[2].endswith("[stiction in 2 of the last 3 windows]")
    if history:
        # a monitor started later counts on from the loop's windows in the history
        log = io.StringIO()
        mon = Monitor(cfg, tmp_path / "out", history=True, db=tmp_path / "h.sqlite", log=log, workers=0)
        fut = Future()
        fut.set_result(window(healthy, 3))
        mon._done("SIM000", fut)
        mon.close()
        assert log.getvalue().splitlines() == [f"SIM000 w3: {healthy.verdict_text} [stiction in 2 of the last 4 windows]"]


def test_a_history_that_fails_mid_run_is_said_and_the_monitor_goes_on(tmp_path):
    """A history database that fails while the monitor runs (damaged, gone, locked past the
    timeout) costs the window its row, said in one line; the window's files and line stand and the
    next windows are still diagnosed (before: an sqlite traceback from the event loop's callback)."""
    import io
    from concurrent.futures import Future
    from dataclasses import replace

    from diagnose.service.monitor import Monitor
    from diagnose.service.pipeline import diagnose
    from diagnose.simulate import sticky_loop

    cfg = tmp_path / "plant.toml"
    cfg.write_text(default_config_text(free_port(), 1, period_s=0.1, window_samples=150))
    log = io.StringIO()
    db = tmp_path / "h.sqlite"
    mon = Monitor(cfg, tmp_path / "out", history=True, db=db, log=log, workers=0)
    d = diagnose(sticky_loop(4.0, 1.5, n=1500, gain=1.5, tau_s=20.0, delay_s=3.0, noise_std=0.02,
                              load_walk_std=0.01, seed=1, name="SIM000").replace(mv=None), explain=False, narx=False)
    # the database is damaged after the monitor opened it: every write now fails
    for extra in ("-wal", "-shm"):
        (tmp_path / f"h.sqlite{extra}").unlink(missing_ok=True)
    db.write_bytes(b"not a database " * 300)
    for i in range(2):
        fut: Future = Future()
        fut.set_result(replace(d, loop_id="SIM000", window=f"w{i}", input_hash=f"window:w{i}"))
        mon._done("SIM000", fut)
        mon.history_writer.flush()
    mon.close()
    lines = log.getvalue().splitlines()
    assert len(lines) == 4, lines
    # the window's line first (it does not wait for the database), then its row's failure
    assert lines[0].startswith("SIM000 w0: ") and "[stiction" not in lines[0]
    assert lines[1].startswith(f"SIM000 w0: not stored in the history: {db}: not a usable history database")
    assert lines[2].startswith("SIM000 w1: ") and lines[2].endswith("[stiction in 2 of the last 2 windows]")
    assert lines[3].startswith(f"SIM000 w1: not stored in the history: {db}: ")
    assert mon.stats.diagnosed == 2 and len(mon.stats.errors) == 2


def test_an_output_folder_that_cannot_be_created_is_one_line(tmp_path, capsys):
    cfg = tmp_path / "plant.toml"
    cfg.write_text(default_config_text(free_port(), 1, period_s=0.1, window_samples=150))
    (tmp_path / "file").write_text("x")
    assert main(["monitor", str(cfg), "--out", str(tmp_path / "file" / "out"), "--no-history", "--duration", "1"]) == 1
    err = capsys.readouterr().err
    assert err == f"error: {tmp_path / 'file' / 'out'}: cannot create the output folder: Not a directory\n"


def test_a_history_locked_by_another_writer_does_not_stop_the_polling(tmp_path):
    """Another process's write lock on the history (a batch's transaction, a backup) holds back
    the rows only: windows keep being polled, diagnosed and said while it is held, and their rows
    land once it is released."""
    import asyncio
    import io
    import sqlite3

    from diagnose.service.monitor import Monitor

    port = free_port()
    cfg = tmp_path / "plant.toml"
    # 100-sample windows at 0.025 s: one every 2.5 s per loop
    cfg.write_text(default_config_text(port, 1, period_s=0.025, window_samples=100))
    db = tmp_path / "h.sqlite"
    sim = _start_sim(port)
    results: list[tuple[float, str]] = []
    log = io.StringIO()
    try:
        mon = Monitor(cfg, tmp_path / "out", db=db, log=log, workers=1,
                      on_result=lambda res: results.append((time.monotonic(), res.window)))
        locked, release = threading.Event(), threading.Event()
        held: dict = {}

        def hold_lock():
            conn = sqlite3.connect(db, timeout=5, isolation_level=None)
            conn.execute("BEGIN EXCLUSIVE")
            locked.set()
            release.wait(60)
            held["rows_before_release"] = conn.execute("SELECT COUNT(*) FROM runs").fetchone()[0]
            held["released_at"] = time.monotonic()
            conn.execute("COMMIT")
            conn.close()

        locker = threading.Thread(target=hold_lock)
        locker.start()
        assert locked.wait(10)

        def release_after_two_windows():
            # held until two windows were said, or 20 s (well inside SQLite's 30 s wait): the
            # writes wait, then land
            deadline = time.monotonic() + 20.0
            while len(results) < 2 and time.monotonic() < deadline:
                time.sleep(0.05)
            release.set()

        timer = threading.Thread(target=release_after_two_windows)
        timer.start()
        try:
            stats = asyncio.run(mon.run(13.0))
        finally:
            release.set()
            timer.join()
            locker.join()
    finally:
        _stop(sim)
    text = log.getvalue()
    while_locked = [w for t, w in results if t < held["released_at"]]
    # a row written on the event loop would hold the polling until the lock goes: no window said
    # while it is held, most of its 360 polls missed
    assert len(while_locked) >= 2, (results, held, text)
    assert held["rows_before_release"] == 0
    assert stats.polls_missed < 120, (stats, text)
    assert "not stored" not in text and stats.errors == [], text
    with sqlite3.connect(db) as conn:
        stored = {r[0] for r in conn.execute("SELECT input_hash FROM runs WHERE loop = 'SIM000'")}
    assert stats.diagnosed == len(results) >= 3
    assert stored == {f"window:{w}" for _, w in results}


def test_a_history_locked_when_the_monitor_starts_delays_neither_start_nor_polling(tmp_path):
    """A history another process holds locked as the monitor starts is busy, not broken: the
    monitor says so in one line, starts polling within its short wait (not SQLite's 30 s), and
    stores the windows once the lock is released."""
    import asyncio
    import io
    import sqlite3

    from diagnose.service.history import History
    from diagnose.service.monitor import STARTUP_DB_WAIT_S, Monitor

    port = free_port()
    cfg = tmp_path / "plant.toml"
    cfg.write_text(default_config_text(port, 1, period_s=0.025, window_samples=100))
    db = tmp_path / "h.sqlite"
    History(db).close()
    sim = _start_sim(port)
    results: list[str] = []
    log = io.StringIO()
    # another process's transaction, released by a timer thread
    conn = sqlite3.connect(db, timeout=5, isolation_level=None, check_same_thread=False)
    conn.execute("BEGIN EXCLUSIVE")
    release = threading.Timer(5.0, lambda: conn.execute("COMMIT"))
    try:
        t0 = time.monotonic()
        mon = Monitor(cfg, tmp_path / "out", db=db, log=log, workers=1,
                      on_result=lambda res: results.append(res.window))
        started_s = time.monotonic() - t0
        release.start()
        stats = asyncio.run(mon.run(8.0))
    finally:
        release.cancel()
        release.join()
        conn.close()
        _stop(sim)
    text = log.getvalue()
    assert STARTUP_DB_WAIT_S <= started_s < STARTUP_DB_WAIT_S + 5, started_s
    said = [ln for ln in text.splitlines() if "polling starts without" in ln]
    assert len(said) == 1 and str(db) in said[0] and "Traceback" not in text, text
    assert stats.diagnosed == len(results) >= 2 and stats.errors == [], (stats, text)
    with sqlite3.connect(db) as c:
        stored = {r[0] for r in c.execute("SELECT input_hash FROM runs WHERE loop = 'SIM000'")}
    assert stored == {f"window:{w}" for w in results}


def test_results_waiting_for_a_locked_history_are_bounded_and_stored_at_the_stop(tmp_path, monkeypatch):
    """While another writer holds the history, at most HISTORY_QUEUE results wait for it (one more
    is not stored, said in its line, and the window's line is not held up); closing the monitor
    stores those waiting once the lock is gone."""
    import io
    import sqlite3
    from concurrent.futures import Future
    from dataclasses import replace

    from diagnose.service import monitor as monitor_mod
    from diagnose.service.monitor import Monitor
    from diagnose.service.pipeline import diagnose
    from diagnose.simulate import sticky_loop

    monkeypatch.setattr(monitor_mod, "HISTORY_QUEUE", 2)
    cfg = tmp_path / "plant.toml"
    cfg.write_text(default_config_text(free_port(), 1, period_s=0.1, window_samples=150))
    db = tmp_path / "h.sqlite"
    log = io.StringIO()
    mon = Monitor(cfg, tmp_path / "out", db=db, log=log, workers=0)
    d = diagnose(sticky_loop(4.0, 1.5, n=1500, gain=1.5, tau_s=20.0, delay_s=3.0, noise_std=0.02,
                              load_walk_std=0.01, seed=1, name="SIM000").replace(mv=None), explain=False, narx=False)
    other = sqlite3.connect(db, timeout=5, isolation_level=None, check_same_thread=False)
    other.execute("BEGIN EXCLUSIVE")
    t0 = time.monotonic()
    for i in range(6):
        fut: Future = Future()
        fut.set_result(replace(d, loop_id="SIM000", window=f"w{i}", input_hash=f"window:w{i}"))
        mon._done("SIM000", fut)
    said_in = time.monotonic() - t0
    threading.Timer(2.0, lambda: (other.execute("COMMIT"), other.close())).start()
    mon.close()   # waits for the lock, then stores what waited
    text = log.getvalue()
    refused = [ln for ln in text.splitlines() if "not stored in the history: 2 results already wait" in ln]
    with sqlite3.connect(db) as conn:
        stored = {r[0] for r in conn.execute("SELECT input_hash FROM runs")}
    assert said_in < 1.0, said_in
    # the writer holds at most one batch (waiting on the lock) beside the 2 queued
    assert 1 <= len(refused) <= 4 and len(stored) + len(refused) == 6, text
    assert all(f"SIM000 w{i}: Stiction" in text for i in range(6)), text
    assert "waiting for the history database" in text


def _lock_for(db, seconds: float) -> tuple[threading.Thread, threading.Event]:
    """Another process's write lock (a batch's transaction, a backup) on ``db`` for ``seconds``."""
    import sqlite3

    locked = threading.Event()

    def hold():
        conn = sqlite3.connect(db, timeout=5, isolation_level=None)
        conn.execute("BEGIN EXCLUSIVE")
        locked.set()
        time.sleep(seconds)
        conn.execute("COMMIT")
        conn.close()

    t = threading.Thread(target=hold)
    t.start()
    assert locked.wait(10)
    return t, locked


def _windows(n: int) -> list:
    from dataclasses import replace

    from diagnose.service.pipeline import diagnose
    from diagnose.simulate import sticky_loop

    rec = sticky_loop(3.0, 1.0, n=600, noise_std=0.03, load_walk_std=0.02, seed=4, name="FIC 4")
    diag = diagnose(rec.replace(start="2026-02-01T00:00:00Z"), narx=False)
    return [replace(diag, input_hash=f"window:{i}") for i in range(n)]


def test_results_that_wait_out_a_long_lock_are_stored_when_it_goes(tmp_path):
    # a lock held longer than the writer's wait for it: the results are kept and tried again, not lost
    from diagnose.service.monitor import HistoryWriter

    db = tmp_path / "h.sqlite"
    History(db).close()
    said, failed = [], []
    writer = HistoryWriter(db, lambda d, why: failed.append(why), said.append, busy_timeout_s=0.3, retry_s=0.2)
    diags = _windows(5)
    locker, _ = _lock_for(db, 2.5)
    try:
        for d in diags[:3]:
            assert writer.put(d, "2026-02-02T00:00:00+00:00") is None
        time.sleep(1.0)                 # the first try has waited out its 0.3 s: they wait
        assert writer.waiting() == 3
        for d in diags[3:]:             # results that arrive meanwhile join them
            assert writer.put(d, "2026-02-02T00:00:00+00:00") is None
    finally:
        locker.join()
    writer.flush()
    writer.close()
    assert failed == []
    assert len(said) == 2 and "stayed locked by another process" in said[0] and "wait and are stored" in said[0]
    assert said[1].startswith("history: the") and "stored" in said[1]
    import sqlite3

    with sqlite3.connect(db) as conn:
        stored = sorted(r[0] for r in conn.execute("SELECT input_hash FROM runs WHERE loop = 'FIC_4'"))
    assert stored == [f"window:{i}" for i in range(5)]


def test_results_still_locked_out_at_the_stop_are_said_not_stored(tmp_path):
    from diagnose.service.monitor import HistoryWriter

    db = tmp_path / "h.sqlite"
    History(db).close()
    said, failed = [], []
    writer = HistoryWriter(db, lambda d, why: failed.append((d.input_hash, why)), said.append,
                           busy_timeout_s=0.2, retry_s=0.1)
    locker, _ = _lock_for(db, 2.0)
    try:
        for d in _windows(2):
            writer.put(d, "2026-02-02T00:00:00+00:00")
        time.sleep(0.6)
        writer.close()                  # the monitor stops while the lock is still held
        assert sorted(h for h, _ in failed) == ["window:0", "window:1"]
        assert all("stayed locked by another process" in why for _, why in failed)
        assert writer.waiting() == 0
    finally:
        locker.join()


def test_metrics_give_s_and_j_in_percent_of_span_for_an_op_logged_as_a_fraction():
    # the gauges are named and documented in % of span: a loop whose OP arrives as 0..1 (S and J
    # in fractions) must not publish S = 0.03 for a 3 % band
    from diagnose.quality import assess
    from diagnose.service.metrics import Metrics
    from diagnose.service.pipeline import diagnose
    from diagnose.simulate import sticky_loop

    rec = sticky_loop(3.0, 1.0, n=3000, noise_std=0.05, load_walk_std=0.02, seed=5, name="FV1").replace(mv=None)
    frac = rec.replace(op=rec.op / 100.0)
    frac = frac.with_findings(*assess(frac))
    d = diagnose(frac, narx=False)
    assert d.identification.op_units == "fraction of span" and d.identification.S_pct < 0.1
    m = Metrics(0)
    try:
        m.observe("FV1", d)
        S = m.registry.get_sample_value("stiction_s_pct", {"loop": "FV1"})
        J = m.registry.get_sample_value("stiction_j_pct", {"loop": "FV1"})
    finally:
        m.close()
    assert S == pytest.approx(100 * d.identification.S_pct) and S == pytest.approx(3.0, abs=0.3)
    assert J == pytest.approx(100 * d.identification.J_pct)


@pytest.mark.parametrize("argv, says", [
    (["--duration", "nan"], "--duration: nan: give a positive number of seconds"),
    (["--duration", "inf"], "--duration: inf: give a positive number"),
    (["--duration", "0"], "--duration: 0: give a positive number"),
    (["--metrics-port", "99999"], "--metrics-port: 99999: give a TCP port, 1-65535"),
    (["--workers", "0"], "--workers: 0: give 1 or more"),
])
def test_bad_monitor_options_are_usage_errors_before_anything_runs(tmp_path, capsys, argv, says):
    # NaN or infinity would run forever, a port past 65535 crashed in bind() with a traceback
    assert main(["monitor", str(tmp_path / "none.toml"), "--out", str(tmp_path / "o"), *argv]) == 2
    err = capsys.readouterr().err
    assert says in err and "Traceback" not in err and not (tmp_path / "o").exists()
