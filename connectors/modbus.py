"""Modbus/TCP poller: read loops' OP/PV/SP/MV registers live and hand windows on as records.

Configuration (TOML, `load_modbus_config`)::

    period_s = 1.0            # poll period
    timeout_s = 0.5           # per request
    window_samples = 600      # samples per window handed to on_window (optional)

    [devices.plc1]
    host = "127.0.0.1"
    port = 5020
    device_id = 1             # Modbus unit id (default for this device's loops)

    [loops.FIC101]
    device = "plc1"
    op = { address = 0, type = "float32", order = "ABCD" }            # holding register by default
    pv = { address = 2, type = "float32", order = "CDAB", table = "input" }
    sp = { address = 4, type = "int16", scale = 0.01 }                 # value = raw * scale + offset
    mv = { address = 6, type = "uint16", scale = 0.01, range = [0, 100] }

Types: ``float32`` (two registers; ``order`` ABCD, CDAB, BADC or DCBA), ``int32``/``uint32`` (two
registers, ``order`` ABCD or CDAB...), ``int16``, ``uint16``. ``scale``/``offset`` turn the raw
number into engineering units; ``range = [lo, hi]`` then scales OP/MV to % of span. A ``port``
outside 1..65535, two roles of one loop on the same registers (same table and unit id), or two
loops on overlapping registers read as another type, order or span, is a one-line error naming
the file, the loop and the key when the file is read (loops may share a register read the same
way: one PV for split-range valves).

`ModbusPoller` keeps one `pymodbus.client.AsyncModbusTcpClient` per device, shared by that
device's loops, and reads each device's registers in as few requests as possible (contiguous
blocks per table and unit id). Every device polls in its own task with timestamps taken at read
time; a device that is down or slow never delays another. Failed reads are recorded as NaN
samples (gaps), never as invented values; reconnection uses exponential backoff. Every
``window_samples`` samples a loop's window is cut at its gaps and each usable stretch is handed
to ``on_window`` as a `diagnose.record.LoopRecord` (``meta["source"] == "modbus"``, a ``gap``
finding when polls were lost).
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import struct
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping

import numpy as np

from diagnose.errors import ConnectorError, ModbusReadError
from diagnose.record import Finding, LoopRecord

from .tagmap import load_toml

ROLES = ("op", "pv", "sp", "mv")
TYPES = {"float32": 2, "int32": 2, "uint32": 2, "int16": 1, "uint16": 1}
ORDERS = ("ABCD", "CDAB", "BADC", "DCBA")
TABLES = ("holding", "input")
EXCEPTION_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
                   4: "server device failure", 6: "server device busy", 10: "gateway path unavailable",
                   11: "gateway target device failed to respond"}


# ------------------------------------------------------------------------------------------ decoding

def _bytes_from_registers(regs: list[int], order: str) -> bytes:
    raw = b"".join(struct.pack(">H", r & 0xFFFF) for r in regs)
    if len(raw) == 2:
        return raw[::-1] if order in ("BADC", "DCBA") else raw
    a, b, c, d = raw
    return bytes({"ABCD": (a, b, c, d), "CDAB": (c, d, a, b), "BADC": (b, a, d, c), "DCBA": (d, c, b, a)}[order])


def decode_registers(regs: list[int], dtype: str, order: str = "ABCD") -> float:
    """The number held in ``regs`` (16-bit register values as read) for ``dtype`` and byte order.

    ``order`` names where the bytes of the big-endian value A B C D sit in register 0 (high byte,
    low byte) and register 1: ABCD = big-endian, CDAB = word-swapped, BADC = byte-swapped,
    DCBA = little-endian.
    """
    data = _bytes_from_registers(list(regs), order)
    fmt = {"float32": ">f", "int32": ">i", "uint32": ">I", "int16": ">h", "uint16": ">H"}[dtype]
    return float(struct.unpack(fmt, data)[0])


def encode_value(value: float, dtype: str, order: str = "ABCD") -> list[int]:
    """Registers that `decode_registers` reads back as ``value`` (used by the simulator and tests)."""
    fmt = {"float32": ">f", "int32": ">i", "uint32": ">I", "int16": ">h", "uint16": ">H"}[dtype]
    v = float(value) if dtype == "float32" else int(round(value))
    raw = struct.pack(fmt, v)
    if len(raw) == 2:
        raw = raw[::-1] if order in ("BADC", "DCBA") else raw
    else:
        a, b, c, d = raw
        # the permutations are their own inverses except CDAB/DCBA... all four are involutions
        raw = bytes({"ABCD": (a, b, c, d), "CDAB": (c, d, a, b), "BADC": (b, a, d, c),
                     "DCBA": (d, c, b, a)}[order])
    return [int.from_bytes(raw[i:i + 2], "big") for i in range(0, len(raw), 2)]


# ------------------------------------------------------------------------------------------- config

@dataclass(frozen=True)
class RegisterMap:
    """Where one role of a loop lives and how to turn the registers into a number."""

    address: int
    type: str = "float32"
    order: str = "ABCD"
    table: str = "holding"
    scale: float = 1.0
    offset: float = 0.0
    range: tuple[float, float] | None = None
    device_id: int | None = None

    @property
    def count(self) -> int:
        return TYPES[self.type]

    def value(self, regs: list[int]) -> float:
        x = decode_registers(regs, self.type, self.order) * self.scale + self.offset
        if self.range is not None:
            lo, hi = self.range
            x = 100.0 * (x - lo) / (hi - lo)
        return x


    def raw(self, x: float) -> float:
        """The register number that `value` turns into ``x``."""
        if self.range is not None:
            lo, hi = self.range
            x = lo + x * (hi - lo) / 100.0
        return (x - self.offset) / self.scale


def _implausible(x: np.ndarray) -> np.ndarray:
    # what a 32-bit value read in the wrong word or byte order looks like: far beyond any process
    # value, or a denormal next to zero
    a = np.abs(x)
    return ~np.isfinite(x) | (a > 1e6) | ((a > 0) & (a < 1e-20))


def better_order(rm: RegisterMap, x: np.ndarray) -> tuple[str, float, float] | None:
    """For a 32-bit register map whose values look like a wrong byte order: (the order under which
    the same registers give plausible numbers, a value as read, the same value in that order), or
    None."""
    x = np.asarray(x, float)
    seen = x[~np.isnan(x)]
    if rm.count != 2 or seen.size == 0 or not _implausible(seen).mean() > 0.5:
        return None
    sample = seen[:: max(1, seen.size // 50)]
    for order in ORDERS:
        if order == rm.order:
            continue
        alt = replace(rm, order=order)
        try:
            y = np.array([alt.value(encode_value(rm.raw(v), rm.type, rm.order)) for v in sample])
        except (OverflowError, ValueError, struct.error):
            continue
        if not _implausible(y).any():
            return order, float(sample[0]), float(y[0])
    return None


def _order_findings(lc: "LoopConfig", v: Mapping[str, list[float]]) -> list[Finding]:
    """One error finding per order to set, naming the keys read in a wrong byte order."""
    by_order: dict[str, list[str]] = {}
    for role, rm in lc.registers.items():
        hit = better_order(rm, np.asarray(v[role], float))
        if hit is not None:
            order, was, now = hit
            by_order.setdefault(order, []).append(f"loops.{lc.name}.{role} ({rm.type} {rm.order}: {was:.3g}, "
                                                  f"{order}: {now:.4g})")
    return [Finding("register_order", f"{', '.join(keys)} look read in the wrong byte order: set order = "
                    f"\"{order}\" (or check the address)", "error", {"order": order})
            for order, keys in by_order.items()]


@dataclass(frozen=True)
class DeviceConfig:
    name: str
    host: str
    port: int = 502
    device_id: int = 1
    timeout_s: float | None = None


@dataclass(frozen=True)
class LoopConfig:
    name: str
    device: str
    registers: Mapping[str, RegisterMap]
    device_id: int | None = None


@dataclass(frozen=True)
class ModbusConfig:
    devices: Mapping[str, DeviceConfig]
    loops: Mapping[str, LoopConfig]
    period_s: float = 1.0
    timeout_s: float = 0.5
    window_samples: int = 600
    reconnect_min_s: float = 0.5
    reconnect_max_s: float = 5.0
    path: str | None = None


def _err(msg: str, path: str | None) -> ConnectorError:
    return ConnectorError(msg, path=path or "<modbus config>")


def parse_modbus_config(data: Mapping[str, Any], path: str | None = None) -> ModbusConfig:
    """A `ModbusConfig` from parsed TOML data (see the module docstring)."""
    try:
        return _parse_modbus_config(data, path)
    except (TypeError, ValueError, OverflowError, AttributeError, KeyError) as exc:
        # int(inf) is an OverflowError: a port or address of inf is a bad value like any other
        raise _err(f"bad value in the Modbus config ({type(exc).__name__}: {exc})", path) from None


def _parse_modbus_config(data: Mapping[str, Any], path: str | None) -> ModbusConfig:
    if not isinstance(data, Mapping):
        raise _err("the Modbus config must be a TOML table", path)
    devs_raw = data.get("devices")
    loops_raw = data.get("loops")
    if not isinstance(devs_raw, dict) or not devs_raw:
        raise _err("no [devices.<NAME>] tables", path)
    if not isinstance(loops_raw, dict) or not loops_raw:
        raise _err("no [loops.<NAME>] tables", path)
    timeout_s = float(data.get("timeout_s", 0.5))
    devices = {}
    for name, d in devs_raw.items():
        if not isinstance(d, dict) or "host" not in d:
            raise _err(f"devices.{name} needs a host", path)
        try:
            devices[name] = DeviceConfig(name, str(d["host"]), int(d.get("port", 502)), int(d.get("device_id", 1)),
                                         float(d["timeout_s"]) if "timeout_s" in d else None)
        except (TypeError, ValueError, OverflowError) as exc:
            raise _err(f"devices.{name}: {exc}", path) from None
        if not 1 <= devices[name].port <= 65535:
            raise _err(f"devices.{name}.port {devices[name].port} is outside 1..65535", path)
    loops = {}
    for name, spec in loops_raw.items():
        if not isinstance(spec, dict):
            raise _err(f"loops.{name} must be a table", path)
        dev = spec.get("device")
        if dev is None and len(devices) == 1:
            dev = next(iter(devices))
        if dev not in devices:
            raise _err(f"loops.{name}.device {dev!r} is not one of the devices ({', '.join(devices)})", path)
        regs = {}
        for role in ROLES:
            if role not in spec:
                continue
            r = spec[role]
            where = f"loops.{name}.{role}"
            if isinstance(r, int):
                r = {"address": r}
            if not isinstance(r, dict) or "address" not in r:
                raise _err(f"{where} needs an address", path)
            typ = str(r.get("type", "float32")).lower()
            order = str(r.get("order", "ABCD")).upper()
            table = str(r.get("table", "holding")).lower()
            if typ not in TYPES:
                raise _err(f"{where}.type {typ!r} is not one of {', '.join(TYPES)}", path)
            if order not in ORDERS:
                raise _err(f"{where}.order {order!r} is not one of {', '.join(ORDERS)}", path)
            if table not in TABLES:
                raise _err(f"{where}.table {table!r} is not one of {', '.join(TABLES)}", path)
            rng = r.get("range")
            if rng is not None:
                if not (isinstance(rng, list) and len(rng) == 2 and rng[0] != rng[1]):
                    raise _err(f"{where}.range must be [lo, hi]", path)
                rng = (float(rng[0]), float(rng[1]))
            addr = int(r["address"])
            if not 0 <= addr <= 65535:
                raise _err(f"{where}.address {addr} is outside 0..65535", path)
            regs[role] = RegisterMap(addr, typ, order, table, float(r.get("scale", 1.0)),
                                     float(r.get("offset", 0.0)), rng,
                                     int(r["device_id"]) if "device_id" in r else None)
        for need in ("op", "pv"):
            if need not in regs:
                raise _err(f"loops.{name} needs an {need} register", path)
        loop_id = int(spec["device_id"]) if "device_id" in spec else None
        _check_overlaps(name, regs, loop_id if loop_id is not None else devices[dev].device_id, path)
        loops[name] = LoopConfig(name, dev, regs, loop_id)
    _check_shared(devices, loops, path)
    period_s = float(data.get("period_s", 1.0))
    if not (math.isfinite(period_s) and period_s > 0):
        raise _err("period_s must be > 0", path)
    if not (math.isfinite(timeout_s) and timeout_s > 0):
        raise _err("timeout_s must be > 0", path)
    if int(data.get("window_samples", 600)) < 2:
        raise _err("window_samples must be at least 2", path)
    return ModbusConfig(devices, loops, period_s, timeout_s, int(data.get("window_samples", 600)),
                        float(data.get("reconnect_min_s", 0.5)), float(data.get("reconnect_max_s", 5.0)), path)


def _check_overlaps(loop: str, regs: Mapping[str, RegisterMap], device_id: int, path: str | None) -> None:
    """Two roles of one loop reading the same registers is a typo in the map; polled, it would give
    one signal twice (an OP equal to PV identifies nothing) or fail only at run time."""
    seen: list[tuple[str, RegisterMap]] = []
    for role, rm in regs.items():
        last = rm.address + rm.count - 1
        if last > 65535:
            raise _err(f"loops.{loop}.{role}.address {rm.address}: its {rm.count} registers run past 65535", path)
        for other, om in seen:
            if (om.table == rm.table and (om.device_id or device_id) == (rm.device_id or device_id)
                    and rm.address <= om.address + om.count - 1 and om.address <= last):
                raise _err(f"loops.{loop}.{role}.address {rm.address}: {rm.table} registers {rm.address}..{last} "
                           f"overlap loops.{loop}.{other} ({om.address}..{om.address + om.count - 1}); give each "
                           "role its own registers", path)
        seen.append((role, rm))


def _check_shared(devices: Mapping[str, DeviceConfig], loops: Mapping[str, LoopConfig], path: str | None) -> None:
    """Loops may share a signal (one PV register for two split-range valves) when they read it the
    same way; registers that only partly overlap, or are read as another type or order, are
    decoded two ways and one of them is a typo in the map."""
    by_unit: dict[tuple, list[tuple[int, int, str, RegisterMap]]] = {}
    for lc in loops.values():
        dev = devices[lc.device]
        for role, rm in lc.registers.items():
            uid = rm.device_id or lc.device_id or dev.device_id
            by_unit.setdefault((dev.host, dev.port, uid, rm.table), []).append(
                (rm.address, rm.address + rm.count - 1, f"loops.{lc.name}.{role}", rm))
    for (_, _, uid, table), regs in by_unit.items():
        regs.sort(key=lambda r: (r[0], r[1]))
        reach = None          # the register map reaching furthest so far
        for a, b, where, rm in regs:
            if reach is not None and a <= reach[1]:
                ra, rb, rwhere, rrm = reach
                same = (ra, rb, rrm.type, rrm.order) == (a, b, rm.type, rm.order)
                if not same:
                    raise _err(f"{where}.address {a}: {table} registers {a}..{b} ({rm.type} {rm.order}) overlap "
                               f"{rwhere} ({ra}..{rb}, {rrm.type} {rrm.order}) on device id {uid}; give each its "
                               "own registers, or the same address, type and order for a signal the loops share",
                               path)
            if reach is None or b > reach[1]:
                reach = (a, b, where, rm)


def load_modbus_config(path: str | os.PathLike) -> ModbusConfig:
    """Read a Modbus register-map TOML file."""
    path = os.fspath(path)
    return parse_modbus_config(load_toml(path, "Modbus config"), path)


# ------------------------------------------------------------------------------------------- poller

@dataclass
class _Block:
    table: str
    device_id: int
    address: int
    count: int
    members: list[tuple[str, str, RegisterMap]] = field(default_factory=list)  # (loop, role, map)


def plan_blocks(loops: list[LoopConfig], default_id: int, max_count: int = 120) -> list[_Block]:
    """Group a device's registers into contiguous read requests (per table and unit id).

    Only registers that touch or overlap are merged: reading across a hole could hit addresses the
    device does not have and fail the whole request.
    """
    items = []
    for lc in loops:
        for role, rm in lc.registers.items():
            uid = rm.device_id or lc.device_id or default_id
            items.append((rm.table, uid, rm.address, rm.count, lc.name, role, rm))
    items.sort(key=lambda it: (it[0], it[1], it[2]))
    blocks: list[_Block] = []
    for table, uid, addr, cnt, loop, role, rm in items:
        b = blocks[-1] if blocks else None
        if (b is not None and b.table == table and b.device_id == uid and addr <= b.address + b.count
                and addr + cnt - b.address <= max_count):
            b.count = max(b.count, addr + cnt - b.address)
        else:
            b = _Block(table, uid, addr, cnt)
            blocks.append(b)
        b.members.append((loop, role, rm))
    return blocks


@dataclass
class LoopStats:
    polls: int = 0
    good: int = 0
    missed: int = 0        # ticks skipped because the device task fell behind
    failed: int = 0        # polls whose read failed (timeout, connection, exception response)
    windows: int = 0
    last_error: str | None = None   # of the latest failed poll; None after a good one


class _Buffer:
    def __init__(self) -> None:
        self.t: list[float] = []
        self.v: dict[str, list[float]] = {r: [] for r in ROLES}


def _good(buf: _Buffer, i: int) -> bool:
    """Poll ``i`` of the buffer read both OP and PV."""
    return bool(np.isfinite(buf.v["op"][i]) and np.isfinite(buf.v["pv"][i]))


class ModbusPoller:
    """Poll every configured loop and hand windows of samples on as `LoopRecord`s.

    Parameters
    ----------
    config : ModbusConfig
    on_window : callable(LoopRecord), optional
        Called (from the event loop) with each usable stretch of a window; may be a
        coroutine function.
    window_samples : int, optional
        Samples per window (default ``config.window_samples``).
    on_sample : callable(loop_name, t_s, values: dict), optional
        Called for every poll of every loop (NaN values when the read failed).
    on_error : callable(loop_name, ModbusReadError), optional
        Called when a read fails with a configuration-type error (missing register, wrong id), and
        once per loop when its registers look read in the wrong byte order.
    min_samples : int
        Shortest stretch of a window that is handed on (default 20).
    """

    def __init__(self, config: ModbusConfig, *, on_window: Callable[[LoopRecord], Any] | None = None,
                 window_samples: int | None = None, on_sample: Callable[..., Any] | None = None,
                 on_error: Callable[[str, ModbusReadError], Any] | None = None, min_samples: int = 20) -> None:
        self.config = config
        self.on_window = on_window
        self.window_samples = int(window_samples or config.window_samples)
        self.on_sample = on_sample
        self.on_error = on_error
        self.min_samples = int(min_samples)
        self.stats: dict[str, LoopStats] = {name: LoopStats() for name in config.loops}
        self._buffers: dict[str, _Buffer] = {name: _Buffer() for name in config.loops}
        self._order_said: set[str] = set()
        self._clients: dict[str, Any] = {}
        self.callback_errors: list[tuple[str, str]] = []  # (loop, error) from on_window
        self.cpu_s = 0.0

    # ---------------------------------------------------------------- connections
    def _client(self, dev: DeviceConfig):
        from pymodbus.client import AsyncModbusTcpClient

        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
        c = self._clients.get(dev.name)
        if c is None:
            c = AsyncModbusTcpClient(dev.host, port=dev.port, timeout=dev.timeout_s or self.config.timeout_s,
                                     retries=0, reconnect_delay=0, reconnect_delay_max=0)
            self._clients[dev.name] = c
        return c

    async def _ensure(self, dev: DeviceConfig) -> bool:
        c = self._client(dev)
        if c.connected:
            return True
        try:
            return bool(await asyncio.wait_for(c.connect(), timeout=(dev.timeout_s or self.config.timeout_s) * 2))
        except (asyncio.TimeoutError, OSError, Exception):  # noqa: BLE001 - any failure = not connected
            return False

    def close(self) -> None:
        for c in self._clients.values():
            try:
                c.close()
            except Exception:  # noqa: BLE001
                pass
        self._clients.clear()

    # ---------------------------------------------------------------- reads
    async def _read_block(self, dev: DeviceConfig, b: _Block) -> list[int]:
        c = self._client(dev)
        fn = c.read_holding_registers if b.table == "holding" else c.read_input_registers
        where = f"{dev.name} ({dev.host}:{dev.port}, device id {b.device_id})"
        try:
            rr = await fn(b.address, count=b.count, device_id=b.device_id)
        except Exception as exc:  # pymodbus raises ModbusIOException/ConnectionException on timeouts
            name = type(exc).__name__
            raise ModbusReadError(f"no answer reading {b.table} registers {b.address}..{b.address + b.count - 1} "
                                  f"({name}); device down, or wrong device id?", path=where) from None
        if rr.isError():
            code = getattr(rr, "exception_code", None)
            what = EXCEPTION_NAMES.get(code, "error")
            if code in (2, 3):
                loops = sorted({m[0] for m in b.members})
                raise ModbusReadError(f"{b.table} registers {b.address}..{b.address + b.count - 1} do not exist "
                                      f"(Modbus exception {code}: {what}); check the register map of "
                                      f"{', '.join(loops)}", path=where)
            if code in (4, 10, 11):
                raise ModbusReadError(f"device id {b.device_id} does not answer (Modbus exception {code}: {what}); "
                                      "check device_id", path=where)
            raise ModbusReadError(f"Modbus exception {code}: {what}", path=where)
        regs = list(rr.registers)
        if len(regs) < b.count:
            raise ModbusReadError(f"short answer: {len(regs)} of {b.count} registers", path=where)
        return regs

    async def read_once(self) -> dict[str, dict[str, float]]:
        """Read every loop once, raising `ModbusReadError` on the first failure (a config check)."""
        out: dict[str, dict[str, float]] = {}
        for dname, dev in self.config.devices.items():
            loops = [lc for lc in self.config.loops.values() if lc.device == dname]
            if not loops:
                continue
            if not await self._ensure(dev):
                raise ModbusReadError("cannot connect", path=f"{dname} ({dev.host}:{dev.port})")
            for b in plan_blocks(loops, dev.device_id):
                regs = await self._read_block(dev, b)
                for loop, role, rm in b.members:
                    off = rm.address - b.address
                    out.setdefault(loop, {})[role] = rm.value(regs[off:off + rm.count])
        return out

    # ---------------------------------------------------------------- polling
    async def _poll_device(self, dname: str, dev: DeviceConfig, t_end: float | None) -> None:
        loops = [lc for lc in self.config.loops.values() if lc.device == dname]
        blocks = plan_blocks(loops, dev.device_id)
        period = self.config.period_s
        t0 = time.monotonic()
        wall0 = time.time() - t0
        k = 0
        backoff = self.config.reconnect_min_s
        next_connect = 0.0
        while True:
            now = time.monotonic()
            due = t0 + k * period
            if now > due + period:  # fell behind: the skipped ticks are missed polls (gaps)
                skip = int((now - due) // period)
                for _ in range(skip):
                    self._record_all(loops, wall0 + t0 + k * period, {}, missed=True)
                    k += 1
                due = t0 + k * period
            if t_end is not None and due >= t_end:
                return
            delay = due - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)
            values: dict[str, dict[str, float]] = {}
            connected = self._client(dev).connected
            if not connected and time.monotonic() >= next_connect:
                connected = await self._ensure(dev)
                if not connected:
                    next_connect = time.monotonic() + backoff
                    backoff = min(backoff * 2, self.config.reconnect_max_s)
                    for lc in loops:
                        self.stats[lc.name].last_error = f"cannot connect to {dev.host}:{dev.port}"
                else:
                    backoff = self.config.reconnect_min_s
            if connected:
                for b in list(blocks):
                    try:
                        regs = await self._read_block(dev, b)
                    except ModbusReadError as exc:
                        if "do not exist" in str(exc) and len(b.members) > 1:
                            # find the culprit next time: read this block's registers one by one
                            i = blocks.index(b)
                            blocks[i:i + 1] = [_Block(b.table, b.device_id, rm.address, rm.count, [m])
                                               for m in b.members for rm in (m[2],)]
                        for loop, _, _ in b.members:
                            self.stats[loop].last_error = str(exc)
                        if self.on_error is not None and "exception" in str(exc):
                            for loop in sorted({m[0] for m in b.members}):
                                self.on_error(loop, exc)
                        if not self._client(dev).connected:
                            next_connect = time.monotonic() + backoff
                            break
                        if "no answer" in str(exc):
                            break  # an unresponsive device: do not wait out every block's timeout
                        continue
                    t_read = time.time()
                    for loop, role, rm in b.members:
                        off = rm.address - b.address
                        try:
                            v = rm.value(regs[off:off + rm.count])
                        except (struct.error, ValueError):
                            v = math.nan
                        values.setdefault(loop, {})[role] = v
                        values[loop].setdefault("_t", t_read)
            self._record_all(loops, time.time(), values, missed=False)
            k += 1

    def _record_all(self, loops: list[LoopConfig], t_s: float, values: dict, *, missed: bool) -> None:
        for lc in loops:
            st = self.stats[lc.name]
            vals = values.get(lc.name, {})
            t = vals.get("_t", t_s)
            st.polls += 1
            ok = all(np.isfinite(vals.get(r, math.nan)) for r in ("op", "pv"))
            if missed:
                st.missed += 1
            elif ok:
                st.good += 1
                # an error is the current one until a good read: the monitor takes a poll that
                # comes back empty with an error for an outage, and a stale error made the ticks
                # missed just after a reconnection a second outage
                st.last_error = None
            else:
                st.failed += 1
            buf = self._buffers[lc.name]
            if ok and not missed and buf.t and not _good(buf, -1):
                # data are back after an outage: a new window starts here. The window is cut at
                # the outage anyway; on fixed boundaries the stretch after it would end at the
                # next one, too short to diagnose however long the data then run
                if any(_good(buf, i) for i in range(len(buf.t))):
                    self._emit(lc, buf)
                buf = self._buffers[lc.name] = _Buffer()
            buf.t.append(t)
            for r in ROLES:
                buf.v[r].append(vals.get(r, math.nan) if r in lc.registers else math.nan)
            if self.on_sample is not None:
                try:
                    self.on_sample(lc.name, t, {r: vals.get(r, math.nan) for r in lc.registers})
                except Exception as exc:  # noqa: BLE001
                    self._callback_failed(lc.name, exc)
            if len(buf.t) >= self.window_samples:
                self._emit(lc, buf)
                self._buffers[lc.name] = _Buffer()

    def _emit(self, lc: LoopConfig, buf: _Buffer) -> None:
        order = _order_findings(lc, buf.v)
        if order and self.on_error is not None and lc.name not in self._order_said:
            # said once per loop, from the whole window: garbage decodes to NaN now and then, which
            # cuts the window into pieces too short to carry the finding
            self._order_said.add(lc.name)
            for f in order:
                self.on_error(lc.name, ModbusReadError(f.message, path=self.config.path))
        for rec in window_records(lc, buf.t, buf.v, self.config.period_s, self.min_samples,
                                  source=self._source(lc), order=order):
            self.stats[lc.name].windows += 1
            if self.on_window is None:
                continue
            try:
                res = self.on_window(rec)
            except Exception as exc:  # noqa: BLE001 - a failing consumer must not stop polling
                self._callback_failed(lc.name, exc)
                continue
            if asyncio.iscoroutine(res):
                fut = asyncio.ensure_future(res)
                fut.add_done_callback(lambda f, name=lc.name: (not f.cancelled() and f.exception() is not None
                                                               and self._callback_failed(name, f.exception())))

    def _callback_failed(self, loop: str, exc: BaseException) -> None:
        self.callback_errors.append((loop, f"{type(exc).__name__}: {exc}"))
        self.stats[loop].last_error = f"on_window failed: {type(exc).__name__}: {exc}"

    def _source(self, lc: LoopConfig) -> str:
        dev = self.config.devices[lc.device]
        return f"modbus://{dev.host}:{dev.port}/{lc.device_id or dev.device_id}"

    def flush(self) -> None:
        """Hand on whatever the buffers hold now (at the end of a run)."""
        for name, lc in self.config.loops.items():
            buf = self._buffers[name]
            if buf.t:
                self._emit(lc, buf)
                self._buffers[name] = _Buffer()

    async def run(self, duration_s: float | None = None, *, flush: bool = True) -> dict[str, LoopStats]:
        """Poll until cancelled or for ``duration_s`` seconds; returns the per-loop statistics."""
        t_end = None if duration_s is None else time.monotonic() + float(duration_s)
        cpu0 = time.process_time()
        tasks = [asyncio.ensure_future(self._poll_device(n, d, t_end)) for n, d in self.config.devices.items()]
        try:
            await asyncio.gather(*tasks)
        finally:
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            self.cpu_s += time.process_time() - cpu0
            if flush:
                self.flush()
            self.close()
        return self.stats


#: How far outside 0..100 % of span a stem position read over Modbus may lie and still be one.
MV_SLACK_PCT = 50.0


def window_records(lc: LoopConfig, t: list[float], v: Mapping[str, list[float]], period_s: float,
                   min_samples: int, *, source: str | None = None,
                   order: list[Finding] | None = None) -> list[LoopRecord]:
    """Records from one window of polled samples: cut at every lost poll, none invented. ``order``:
    the window's `register_order` findings when the caller has them already."""
    from datetime import datetime, timezone

    from diagnose.quality import assess
    from .timebase import runs

    from .records import gross_outliers

    op = np.array(v["op"], dtype=float)       # copies: spikes are blanked below
    pv = np.array(v["pv"], dtype=float)
    n = op.size
    spikes: list[Finding] = []
    for role, x in (("op", op), ("pv", pv)):
        far = gross_outliers(x)
        if far.any():
            # a spike or a sentinel from the device is no measurement: like a lost poll, it cuts
            # the window rather than being replaced by an invented value
            spikes.append(Finding("outliers", f"{role.upper()} had {int(far.sum())} value(s) far outside its range "
                                  f"(the first {x[far][0]:.6g}): read as lost polls", "warning",
                                  {"role": role, "count": int(far.sum()), "first_value": float(x[far][0])}))
            x[far] = np.nan
    ok = np.isfinite(op) & np.isfinite(pv)
    segs = [(a, b) for a, b in runs(ok) if b - a >= min_samples]
    lost = int(np.count_nonzero(~ok))
    tt = np.asarray(t, float)
    out = []
    base: list[Finding] = list(_order_findings(lc, v) if order is None else order) + spikes
    if lost:
        gaps = runs(~ok)
        base.append(Finding("gap", f"{lost} of {n} polls failed or were missed ({len(gaps)} outage(s)); the "
                            "window is cut there, no values are invented", "warning",
                            {"lost": lost, "polls": n, "outages": [[int(a), int(b)] for a, b in gaps][:50],
                             "outage_s": [round(float(tt[min(b, n - 1)] - tt[a]), 3) for a, b in gaps][:50]}))
        if len(segs) > 1:
            base.append(Finding("segment", f"window split into {len(segs)} segments at the outages", "warning",
                                {"segments": len(segs)}))
    # SP and MV are optional: a lost poll or a spike in one of them leaves that signal out of the
    # segment (the loop is still judged from OP and PV) instead of cutting OP and PV short; a
    # spike kept would wreck the valve fit on the stem position
    extra = {}
    for r in ("sp", "mv"):
        if r in lc.registers:
            x = np.array(v[r], dtype=float)
            bad = gross_outliers(x)
            if r == "mv":
                # the stem position is read in % of span: half a span beyond it is no position (a
                # flat stem with one garbage register read is no outlier by the spread rule)
                with np.errstate(invalid="ignore"):
                    bad |= (x < -MV_SLACK_PCT) | (x > 100.0 + MV_SLACK_PCT)
            x[bad] = np.nan
            extra[r] = x
    for i, (a, b) in enumerate(segs):
        jitter = float(np.max(np.abs(np.diff(tt[a:b]) - period_s))) if b - a > 1 else 0.0
        roles = {}
        left_out = []
        for r, x in extra.items():
            bad = int(np.count_nonzero(~np.isfinite(x[a:b])))
            if bad:
                left_out.append(Finding(f"{r}_left_out", f"{r.upper()} had {bad} lost or far-out value(s) in this "
                                        f"segment: it is left out, and the loop is judged without it", "warning",
                                        {"role": r, "count": bad}))
            else:
                roles[r] = x[a:b]
        rec = LoopRecord(name=lc.name, ts_s=period_s, op=op[a:b], pv=pv[a:b], sp=roles.get("sp"), mv=roles.get("mv"),
                         start=datetime.fromtimestamp(tt[a], timezone.utc).isoformat().replace("+00:00", "Z"),
                         units={"op": "%", "mv": "%"}, source=source, findings=tuple(base + left_out),
                         meta={"format": "modbus", "segment": i, "n_segments": len(segs),
                               "t_first_s": float(tt[a]), "t_last_s": float(tt[b - 1]),
                               "jitter_s": round(jitter, 4), "quality_checked": True})
        out.append(rec.with_findings(*assess(rec)))
    return out
