"""A live Modbus/TCP server serving simulated sticky loops (pymodbus's own TCP server).

Run it as a separate process::

    python -m connectors.modbus_sim --port 5020 --loops 4            # 4 loops, float32 ABCD
    python -m connectors.modbus_sim --port 0 --config map.toml        # registers from a poller map

It prints one line ``READY <port>`` on stdout when it serves (``--port 0`` picks a free loopback
port), then updates every loop's registers every ``--ts`` seconds from a precomputed closed-loop
simulation (`diagnose.simulate.sticky_loop`, valve S/J varying by loop), so values change live.

Default register layout (``default_config_text``): loop ``i`` (``SIM000``, ``SIM001``...) uses 8
holding registers from ``8*i``: OP, PV, SP, MV as float32 in the chosen ``--order``. With
``--config`` every loop of the poller's TOML is served at its own addresses, types, orders and
scaling (only the device(s) whose ``port`` matches are served; their ``device_id`` is the
server's unit id). From Python: `build_values`, `default_config_text`, `serve`.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import math
import socket
import sys
import time
from typing import Any

import numpy as np

from .modbus import ModbusConfig, encode_value, parse_modbus_config


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free on ``host`` a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def default_config_text(port: int | list[int], n_loops: int, *, order: str = "ABCD", host: str = "127.0.0.1",
                        device_id: int = 1, period_s: float = 1.0, window_samples: int = 600,
                        timeout_s: float = 0.5, stride: int = 8) -> str:
    """Poller TOML matching the simulator's default layout.

    ``port`` may be a list: one device per port, ``n_loops`` loops on each (named
    ``SIM<device><loop>``). ``stride`` > 8 leaves holes between loops so that every loop needs
    its own read request (a harder load).
    """
    ports = [port] if isinstance(port, int) else list(port)
    lines = [f"period_s = {period_s}", f"timeout_s = {timeout_s}", f"window_samples = {window_samples}",
             "reconnect_min_s = 0.2", "reconnect_max_s = 1.0", ""]
    for d, p in enumerate(ports):
        lines += [f"[devices.sim{d if len(ports) > 1 else ''}]", f'host = "{host}"', f"port = {p}",
                  f"device_id = {device_id}", ""]
    for d in range(len(ports)):
        dev = f"sim{d if len(ports) > 1 else ''}"
        for i in range(n_loops):
            base = stride * i
            lines.append(f"[loops.SIM{d:02d}{i:03d}]" if len(ports) > 1 else f"[loops.SIM{i:03d}]")
            lines.append(f'device = "{dev}"')
            for k, role in enumerate(("op", "pv", "sp", "mv")):
                lines.append(f'{role} = {{ address = {base + 2 * k}, type = "float32", order = "{order}" }}')
            lines.append("")
    return "\n".join(lines)


def build_values(n_loops: int, n_samples: int = 1800, *, seed: int = 0, ts_s: float = 1.0) -> list[dict[str, np.ndarray]]:
    """Simulated loop signals (OP %, PV, SP, MV %) to play back; a few distinct loops, reused."""
    from diagnose.simulate import sticky_loop

    bank = []
    for j in range(min(n_loops, 6)):
        S = [0.0, 1.0, 2.0, 3.0, 4.0, 6.0][j]
        rec = sticky_loop(S, S / 2, n=n_samples, ts_s=ts_s, noise_std=0.05, load_walk_std=0.05,
                          seed=seed + j, warmup=200)
        bank.append({"op": rec.op, "pv": rec.pv, "sp": rec.sp, "mv": rec.mv})
    out = []
    for i in range(n_loops):
        b = bank[i % len(bank)]
        shift = (37 * i) % n_samples
        out.append({r: np.roll(v, -shift) for r, v in b.items()})
    return out


def _raw_for(value: float, rm) -> float:
    """Engineering value -> the number stored in the registers (inverse of RegisterMap.value)."""
    x = value
    if rm.range is not None:
        lo, hi = rm.range
        x = lo + x / 100.0 * (hi - lo)
    return (x - rm.offset) / rm.scale


def _register_image(config: ModbusConfig, port: int | None) -> dict[int, list[tuple[str, str, Any]]]:
    """device id -> [(loop, role, RegisterMap)] for the devices this server plays."""
    out: dict[int, list[tuple[str, str, Any]]] = {}
    for lc in config.loops.values():
        dev = config.devices[lc.device]
        if port is not None and dev.port != port:
            continue
        for role, rm in lc.registers.items():
            uid = rm.device_id or lc.device_id or dev.device_id
            out.setdefault(uid, []).append((lc.name, role, rm))
    return out


async def serve(config: ModbusConfig, *, port: int, host: str = "127.0.0.1", ts_s: float = 1.0,
                seed: int = 0, n_samples: int = 1800, ready: Any = None, duration_s: float | None = None,
                only_port: bool = True) -> None:
    """Serve the config's loops live until cancelled (or ``duration_s``)."""
    from pymodbus.server import ModbusTcpServer
    from pymodbus.simulator import DataType, SimData, SimDevice

    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    image = _register_image(config, port if only_port else None)
    if not image:
        raise SystemExit(f"no loop in the config uses port {port}")
    names = sorted({loop for regs in image.values() for loop, _, _ in regs})
    sims = dict(zip(names, build_values(len(names), n_samples, seed=seed)))  # one sample per update
    devices = []
    for uid, regs in image.items():
        top = max(rm.address + rm.count for _, _, rm in regs)
        devices.append(SimDevice(id=uid, simdata=[SimData(0, count=top, values=0, datatype=DataType.REGISTERS)]))
    server = ModbusTcpServer(devices if len(devices) > 1 else devices[0], address=(host, port))
    await server.serve_forever(background=True)
    t0 = time.monotonic()
    k = 0
    try:
        while True:
            for uid, regs in image.items():
                for loop, role, rm in regs:
                    series = sims[loop].get(role)
                    if series is None:
                        continue
                    v = float(series[k % series.size])
                    raw = _raw_for(v, rm)
                    if rm.type != "float32":
                        lo, hi = {"int16": (-32768, 32767), "uint16": (0, 65535),
                                  "int32": (-2 ** 31, 2 ** 31 - 1), "uint32": (0, 2 ** 32 - 1)}[rm.type]
                        raw = min(max(round(raw), lo), hi) if math.isfinite(raw) else 0
                    await server.async_setValues(uid, 16, rm.address, encode_value(raw, rm.type, rm.order))
            if k == 0 and ready is not None:
                ready()
            k += 1
            if duration_s is not None and time.monotonic() - t0 >= duration_s:
                break
            await asyncio.sleep(max(0.0, t0 + k * ts_s - time.monotonic()))
    finally:
        await server.shutdown()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m connectors.modbus_sim",
                                description="Serve simulated sticky loops over Modbus/TCP (pymodbus server).")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default loopback)")
    p.add_argument("--port", type=int, default=5020, help="TCP port; 0 picks a free one (printed)")
    p.add_argument("--loops", type=int, default=4, help="number of loops in the default layout")
    p.add_argument("--order", default="ABCD", choices=["ABCD", "CDAB", "BADC", "DCBA"],
                   help="float32 byte order of the default layout")
    p.add_argument("--device-id", type=int, default=1, help="unit id of the default layout")
    p.add_argument("--config", help="poller TOML: serve its loops at their own registers instead")
    p.add_argument("--ts", type=float, default=1.0, help="seconds between value updates")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--samples", type=int, default=1800, help="length of the simulated record played in a loop")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    args = p.parse_args(argv)
    port = free_port(args.host) if args.port == 0 else args.port
    if args.config:
        import tomllib

        with open(args.config, "rb") as fh:
            data = tomllib.load(fh)
        config = parse_modbus_config(data, args.config)
        # serve the config's devices that listen on this port (or all, when --port differs)
        only = any(d.port == port for d in config.devices.values())
    else:
        import tomllib

        config = parse_modbus_config(tomllib.loads(default_config_text(port, args.loops, order=args.order,
                                                                       device_id=args.device_id)))
        only = True

    def ready() -> None:
        print(f"READY {port}", flush=True)

    try:
        asyncio.run(serve(config, port=port, host=args.host, ts_s=args.ts, seed=args.seed, ready=ready,
                          duration_s=args.duration, only_port=only, n_samples=args.samples))
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
