"""Modbus/TCP poller against a real pymodbus server in another process (and pyModbusTCP as peer)."""

from __future__ import annotations

import asyncio
import math
import socket
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from connectors.modbus import (ModbusPoller, decode_registers, encode_value, load_modbus_config,
                               parse_modbus_config, plan_blocks)
from connectors.modbus_sim import default_config_text, free_port
from diagnose.errors import ConnectorError, ModbusReadError

ROOT = Path(__file__).resolve().parents[1]

MIXED = """
period_s = {period}
timeout_s = 0.3
window_samples = 1000
reconnect_min_s = 0.1
reconnect_max_s = 0.5

[devices.plc]
host = "127.0.0.1"
port = {port}
device_id = 1

[loops.F_ABCD]
op = {{ address = 0, type = "float32", order = "ABCD" }}
pv = {{ address = 2, type = "float32", order = "ABCD" }}
[loops.F_CDAB]
op = {{ address = 10, type = "float32", order = "CDAB" }}
pv = {{ address = 12, type = "float32", order = "CDAB", table = "input" }}
[loops.F_BADC]
op = {{ address = 20, type = "float32", order = "BADC" }}
pv = {{ address = 22, type = "float32", order = "BADC" }}
[loops.F_DCBA]
op = {{ address = 30, type = "float32", order = "DCBA" }}
pv = {{ address = 32, type = "float32", order = "DCBA" }}
[loops.I16]
op = {{ address = 40, type = "int16", scale = 0.01 }}
pv = {{ address = 41, type = "uint16", scale = 0.002, offset = 0.0 }}
sp = {{ address = 42, type = "int32", order = "CDAB", scale = 0.001 }}
mv = {{ address = 44, type = "uint16", range = [0, 10000] }}
"""


def start_server(args, timeout_s=30.0):
    p = subprocess.Popen([sys.executable, "-m", "connectors.modbus_sim", *args], cwd=ROOT,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    line = p.stdout.readline()
    if not line.startswith("READY"):
        p.kill()
        raise RuntimeError(f"simulator did not start: {line!r} {p.stderr.read()[-2000:]}")
    assert time.monotonic() - t0 < timeout_s
    return p, int(line.split()[1])


def stop(p):
    p.terminate()
    try:
        p.wait(5)
    except subprocess.TimeoutExpired:
        p.kill()


@pytest.fixture
def mixed_server(tmp_path):
    port = free_port()
    cfg_path = tmp_path / "map.toml"
    cfg_path.write_text(MIXED.format(port=port, period=0.1))
    p, _ = start_server(["--port", str(port), "--config", str(cfg_path), "--ts", "0.1", "--samples", "600"])
    yield load_modbus_config(cfg_path), port
    stop(p)


# -------------------------------------------------------------------------------------- decoding

@pytest.mark.parametrize("order, regs", [("ABCD", [0x3F80, 0x0000]), ("CDAB", [0x0000, 0x3F80]),
                                         ("BADC", [0x803F, 0x0000]), ("DCBA", [0x0000, 0x803F])])
def test_float32_orders_known_vectors(order, regs):
    assert decode_registers(regs, "float32", order) == 1.0
    assert encode_value(1.0, "float32", order) == regs


@pytest.mark.parametrize("dtype", ["float32", "int32", "uint32", "int16", "uint16"])
@pytest.mark.parametrize("order", ["ABCD", "CDAB", "BADC", "DCBA"])
def test_encode_decode_round_trip(dtype, order):
    vals = {"float32": [-123.25, 0.0, 3.5e5], "int32": [-70000, 5, 2 ** 31 - 1], "uint32": [0, 70000],
            "int16": [-32768, -1, 1234], "uint16": [0, 65535, 4321]}[dtype]
    for v in vals:
        assert decode_registers(encode_value(v, dtype, order), dtype, order) == v


def test_config_errors(tmp_path):
    with pytest.raises(ConnectorError, match="Modbus config file not found"):
        load_modbus_config(tmp_path / "none.toml")
    base = tomllib.loads(MIXED.format(port=1, period=1))
    base["loops"]["F_ABCD"]["op"]["order"] = "XYZW"
    with pytest.raises(ConnectorError, match=r"loops\.F_ABCD\.op\.order 'XYZW'"):
        parse_modbus_config(base)
    base = tomllib.loads(MIXED.format(port=1, period=1))
    del base["loops"]["I16"]["pv"]
    with pytest.raises(ConnectorError, match=r"loops\.I16 needs an pv register"):
        parse_modbus_config(base)


def test_blocks_group_contiguous_registers():
    cfg = parse_modbus_config(tomllib.loads(MIXED.format(port=1, period=1)))
    blocks = plan_blocks(list(cfg.loops.values()), 1)
    spans = sorted((b.table, b.address, b.count, len(b.members)) for b in blocks)
    assert spans == [("holding", 0, 4, 2), ("holding", 10, 2, 1), ("holding", 20, 4, 2),
                     ("holding", 30, 4, 2), ("holding", 40, 5, 4), ("input", 12, 2, 1)]


# ------------------------------------------------------------------------------ against a server

def test_all_orders_and_scaled_ints_live(mixed_server):
    cfg, _ = mixed_server
    poller = ModbusPoller(cfg)
    first = asyncio.run(poller.read_once())
    time.sleep(0.6)
    second = asyncio.run(ModbusPoller(cfg).read_once())
    for name, vals in first.items():
        for role, v in vals.items():
            assert math.isfinite(v) and -20 < v < 120, (name, role, v)  # a wrong order gives garbage
    # every float order decodes the same simulated loop family (OP near 50 %, PV near 50)
    for name in ("F_ABCD", "F_CDAB", "F_BADC", "F_DCBA"):
        assert 30 < first[name]["op"] < 70 and 45 < first[name]["pv"] < 55
    i16 = first["I16"]
    assert abs(i16["op"] * 100 - round(i16["op"] * 100)) < 1e-6      # int16 * 0.01
    assert abs(i16["sp"] - 50.0) < 0.01 and 0 <= i16["mv"] <= 100
    assert any(abs(first[n]["op"] - second[n]["op"]) > 1e-6 for n in first)  # values change live


def test_independent_peer_reads_the_same_registers(mixed_server):
    from pyModbusTCP.client import ModbusClient

    cfg, port = mixed_server
    peer = ModbusClient(host="127.0.0.1", port=port, unit_id=1, timeout=2.0, auto_open=True)
    for _ in range(5):
        ours = asyncio.run(ModbusPoller(cfg).read_once())
        regs = peer.read_holding_registers(0, 45)
        again = asyncio.run(ModbusPoller(cfg).read_once())
        assert regs is not None
        theirs = {o: decode_registers(regs[a:a + 2], "float32", o)
                  for o, a in (("ABCD", 0), ("CDAB", 10), ("BADC", 20), ("DCBA", 30))}
        if all(ours[f"F_{o}"]["op"] == pytest.approx(v) or again[f"F_{o}"]["op"] == pytest.approx(v)
               for o, v in theirs.items()):
            break
    else:
        pytest.fail(f"pyModbusTCP read {theirs}, we read {ours}")
    peer.close()


def test_wrong_device_id_and_missing_register(mixed_server):
    cfg, port = mixed_server
    text = MIXED.format(port=port, period=0.1).replace("device_id = 1", "device_id = 7")
    with pytest.raises(ModbusReadError, match="device id 7 does not answer"):
        asyncio.run(ModbusPoller(parse_modbus_config(tomllib.loads(text))).read_once())
    text = MIXED.format(port=port, period=0.1).replace("address = 40,", "address = 4000,")
    with pytest.raises(ModbusReadError, match=r"registers 4000\.\.4000 do not exist .*check the register map of I16"):
        asyncio.run(ModbusPoller(parse_modbus_config(tomllib.loads(text))).read_once())


def _run_through_a_restart(n_loops, period_s, window_samples, timeout_s, reconnect_s, run_s, down_at_s, down_for_s,
                           flush=True):
    """Poll simulated loops while their server goes away mid-run and comes back: (stats, windows)."""
    port = free_port()
    cfg = parse_modbus_config(tomllib.loads(default_config_text(port, n_loops, period_s=period_s,
                                                                window_samples=window_samples, timeout_s=timeout_s)))
    cfg = type(cfg)(**{**cfg.__dict__, "reconnect_min_s": reconnect_s[0], "reconnect_max_s": reconnect_s[1]})
    args = ["--port", str(port), "--loops", str(n_loops), "--ts", str(period_s), "--samples", "600"]
    p, _ = start_server(args)
    windows = []
    poller = ModbusPoller(cfg, on_window=windows.append, min_samples=5)

    async def scenario():
        task = asyncio.ensure_future(poller.run(run_s, flush=flush))
        await asyncio.sleep(down_at_s)
        stop(p)                                     # server goes away mid-run
        await asyncio.sleep(down_for_s)
        p2, _ = await asyncio.get_running_loop().run_in_executor(None, start_server, args)
        try:
            return await task, p2
        except BaseException:
            stop(p2)
            raise

    stats, p2 = asyncio.run(scenario())
    stop(p2)
    return stats, windows


def test_server_restart_gives_a_gap_and_recovery(tmp_path):
    stats, windows = _run_through_a_restart(2, 0.1, 1000, 0.3, (0.1, 0.4), 7.0, 2.0, 1.5)
    st = stats["SIM000"]
    assert st.failed > 5 and st.good > 30 and st.polls >= 60
    recs = [r for r in windows if r.name == "SIM000"]
    assert len(recs) >= 2                                          # before and after the outage
    gap = next(f for f in recs[0].findings if f.code == "gap")
    assert gap.data["lost"] >= 5
    assert all(np.all(np.isfinite(r.op)) for r in recs)           # nothing invented
    assert recs[-1].meta["t_first_s"] > recs[0].meta["t_last_s"]


def test_a_new_window_starts_when_the_data_come_back(tmp_path):
    # windows of 30 polls: the stretch after an outage runs to a full window of its own instead of
    # ending at the next fixed boundary (short of the half window the monitor diagnoses)
    _, windows = _run_through_a_restart(1, 0.05, 30, 0.2, (0.05, 0.2), 6.0, 1.2, 1.0, flush=False)
    cut = next(i for i, r in enumerate(windows) if any(f.code == "gap" for f in r.findings))
    after = windows[cut + 1:]
    assert after and after[0].meta["t_first_s"] > windows[cut].meta["t_last_s"]
    # the first window after the outage is whole: it starts at the first good poll
    assert after[0].n == 30 and not any(f.code == "gap" for f in after[0].findings)


def test_loops_sharing_a_pv_register_read_it_live(tmp_path):
    # split-range control: two valves, one flow transmitter; the same register read the same way
    port = free_port()
    text = (f"period_s = 0.1\ntimeout_s = 0.5\n[devices.plc]\nhost = '127.0.0.1'\nport = {port}\n"
            "[loops.FV101A]\nop = { address = 0, type = 'float32' }\npv = { address = 4, type = 'float32' }\n"
            "[loops.FV101B]\nop = { address = 2, type = 'float32' }\npv = { address = 4, type = 'float32' }\n")
    cfg_path = tmp_path / "split.toml"
    cfg_path.write_text(text)
    cfg = load_modbus_config(cfg_path)
    p, _ = start_server(["--port", str(port), "--config", str(cfg_path), "--ts", "0.1"])
    try:
        values = asyncio.run(ModbusPoller(cfg).read_once())
    finally:
        stop(p)
    assert values["FV101A"]["pv"] == values["FV101B"]["pv"] and math.isfinite(values["FV101A"]["pv"])
    assert values["FV101A"]["op"] != values["FV101B"]["op"]


def test_down_device_does_not_stall_the_others(mixed_server):
    cfg, port = mixed_server
    hole = socket.socket()                     # accepts TCP connections, never answers Modbus
    hole.bind(("127.0.0.1", 0))
    hole.listen(8)
    dead = free_port()                         # nothing listening at all
    text = MIXED.format(port=port, period=0.1).replace("]\nop =", ']\ndevice = "plc"\nop =')
    text += f"""
[devices.mute]
host = "127.0.0.1"
port = {hole.getsockname()[1]}
[devices.gone]
host = "127.0.0.1"
port = {dead}
[loops.MUTE]
device = "mute"
op = 0
pv = 2
[loops.GONE]
device = "gone"
op = 0
pv = 2
"""
    cfg2 = parse_modbus_config(tomllib.loads(text))

    def boom(rec):
        raise RuntimeError("consumer bug")

    poller = ModbusPoller(cfg2, on_window=boom, window_samples=5, min_samples=3)
    try:
        stats = asyncio.run(poller.run(2.0))
    finally:
        hole.close()
    assert poller.callback_errors and "consumer bug" in poller.callback_errors[0][1]  # polling went on
    assert stats["MUTE"].good == 0 and stats["GONE"].good == 0
    assert "no answer" in (stats["MUTE"].last_error or "")
    assert "cannot connect" in (stats["GONE"].last_error or "")
    for name in ("F_ABCD", "I16"):
        assert stats[name].good >= 17 and stats[name].missed == 0, stats[name]


def test_window_records_cut_at_lost_polls_without_inventing_values():
    from connectors.modbus import LoopConfig, RegisterMap, window_records

    lc = LoopConfig("L", "d", {"op": RegisterMap(0), "pv": RegisterMap(2), "sp": RegisterMap(4)})
    n = 100
    t = list(1000.0 + np.arange(n))
    op = list(50 + np.sin(np.arange(n) / 3))
    pv = list(np.cos(np.arange(n) / 3))
    for k in (40, 41, 42, 90):
        op[k] = math.nan
    sp = [1.0] * n
    recs = window_records(lc, t, {"op": op, "pv": pv, "sp": sp, "mv": [math.nan] * n}, 1.0, 20)
    assert [r.n for r in recs] == [40, 47]                       # 0-39, 43-89; 91-99 too short
    assert recs[1].meta["t_first_s"] == 1043.0 and recs[1].sp is not None and recs[1].mv is None
    gap = next(f for f in recs[0].findings if f.code == "gap")
    assert gap.data["lost"] == 4 and gap.data["outages"] == [[40, 43], [90, 91]]
    assert recs[0].start == "1970-01-01T00:16:40Z"
    # a spike from the device is no measurement: it cuts the window like a lost poll
    pv_spiky = np.cos(np.arange(n) / 3)
    pv_spiky[60] = 1e30
    recs = window_records(lc, t, {"op": list(50 + np.sin(np.arange(n) / 3)), "pv": pv_spiky, "sp": sp,
                                  "mv": [math.nan] * n}, 1.0, 20)
    assert [r.n for r in recs] == [60, 39] and pv_spiky[60] == 1e30      # the caller's data untouched
    spike = next(f for f in recs[0].findings if f.code == "outliers")
    assert spike.data == {"role": "pv", "count": 1, "first_value": 1e30} and spike.severity == "warning"


def test_a_spike_or_lost_poll_in_the_stem_position_leaves_it_out_of_its_stretch_only():
    from connectors.modbus import LoopConfig, RegisterMap, window_records

    lc = LoopConfig("L", "d", {"op": RegisterMap(0), "pv": RegisterMap(2), "sp": RegisterMap(4),
                               "mv": RegisterMap(6)})
    n = 100
    t = list(1000.0 + np.arange(n))
    op = 50 + np.sin(np.arange(n) / 3)
    op[50] = math.nan                                            # one lost poll: two stretches
    mv = 50 + np.sin(np.arange(n) / 3)
    mv[20] = 65535.0                                             # a sentinel in the first stretch
    sp = np.ones(n)
    sp[70] = math.nan                                            # SP lost once in the second
    recs = window_records(lc, t, {"op": list(op), "pv": list(np.cos(np.arange(n) / 3)), "sp": list(sp),
                                  "mv": mv}, 1.0, 20)
    assert [r.n for r in recs] == [50, 49] and mv[20] == 65535.0          # not cut at MV or SP
    first, second = recs
    assert first.mv is None and first.sp is not None
    assert second.mv is not None and np.all(second.mv < 52) and second.sp is None
    left = {f.code: f for f in first.findings}
    assert left["mv_left_out"].data == {"role": "mv", "count": 1} and left["mv_left_out"].severity == "warning"
    assert "sp_left_out" not in left
    codes = {f.code for f in second.findings}
    assert "sp_left_out" in codes and "mv_left_out" not in codes
    # a still stem (a stuck valve) with one garbage read: no spread to judge it by, but no position
    still = np.full(n, 42.0)
    still[70] = 655.35
    recs = window_records(lc, t, {"op": list(op), "pv": list(np.cos(np.arange(n) / 3)), "sp": list(np.ones(n)),
                                  "mv": still}, 1.0, 20)
    assert recs[0].mv is not None and np.all(recs[0].mv == 42.0) and recs[1].mv is None
    assert {f.code for f in recs[1].findings} >= {"mv_left_out"}


from hypothesis import example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_leaf = st.one_of(st.integers(-5, 70000), st.floats(allow_nan=True), st.text(max_size=5), st.booleans(),
                  st.lists(st.integers(-3, 3), max_size=3))
_role = st.one_of(_leaf, st.dictionaries(st.sampled_from(["address", "type", "order", "table", "scale", "offset",
                                                          "range", "device_id"]), _leaf, max_size=5))


@settings(max_examples=200, deadline=None, derandomize=True)
@example({"period_s": 0, "timeout_s": 0, "devices": {"a": {"host": 0, "port": math.inf}}, "loops": {"L1": {}}})
@example({"period_s": 1, "timeout_s": 1, "devices": {"a": {"host": "h"}},
          "loops": {"L1": {"device": "a", "op": {"address": -math.inf}, "pv": 2}}})
@given(st.fixed_dictionaries({
    "period_s": _leaf, "timeout_s": _leaf,
    "devices": st.dictionaries(st.sampled_from(["a", "b"]), st.dictionaries(
        st.sampled_from(["host", "port", "device_id", "timeout_s"]), _leaf, max_size=4), max_size=2),
    "loops": st.dictionaries(st.sampled_from(["L1", "L2"]), st.dictionaries(
        st.sampled_from(["device", "op", "pv", "sp", "device_id"]), _role, max_size=5), max_size=2)}))
def test_fuzz_modbus_config_only_connector_error(data):
    try:
        cfg = parse_modbus_config(data)
    except ConnectorError:
        return
    assert cfg.loops and cfg.devices and cfg.period_s > 0
