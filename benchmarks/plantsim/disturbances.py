"""Noise of several colours, loads and setpoint moves, as arrays with one value per sample.

Every function takes the generator it draws from, so a record's signals follow from its seed.
Colours: `white`, `ar1` (first-order autoregressive), `random_walk` (optionally leaky), `pink`
(power falling as 1/f, shaped in the frequency domain). Deterministic loads: `steps`, `sine`,
`square` (an upstream on/off device, optionally with first-order edges), `sawtooth` (fill and
dump: slow ramp, fast return) and `daily` (a 24-hour cycle).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

__all__ = ["white", "ar1", "random_walk", "pink", "coloured", "steps", "sine", "square", "sawtooth",
           "daily", "first_order_filter", "COLOURS"]

COLOURS = ("white", "ar1", "random_walk", "pink")


def white(n: int, std: float, rng: np.random.Generator) -> np.ndarray:
    return rng.normal(0.0, std, n) if std > 0 else np.zeros(n)


def ar1(n: int, std: float, phi: float, rng: np.random.Generator) -> np.ndarray:
    """Stationary AR(1) ``x_k = phi x_{k-1} + e_k`` with standard deviation ``std``."""
    if std <= 0:
        return np.zeros(n)
    e = rng.normal(0.0, std * math.sqrt(1.0 - phi * phi), n)
    x0 = rng.normal(0.0, std)
    out, _ = signal.lfilter([1.0], [1.0, -phi], e, zi=[phi * x0])
    return out


def random_walk(n: int, step_std: float, rng: np.random.Generator, *, leak: float = 0.0) -> np.ndarray:
    """Random walk with increments of ``step_std``; ``0 < leak < 1`` pulls it back toward zero."""
    if step_std <= 0:
        return np.zeros(n)
    e = rng.normal(0.0, step_std, n)
    return signal.lfilter([1.0], [1.0, -(1.0 - leak)], e)


def pink(n: int, std: float, rng: np.random.Generator) -> np.ndarray:
    """1/f noise of standard deviation ``std`` (white noise shaped by ``1/sqrt(f)`` in amplitude)."""
    if std <= 0 or n < 2:
        return np.zeros(n)
    spec = rng.normal(size=n // 2 + 1) + 1j * rng.normal(size=n // 2 + 1)
    f = np.fft.rfftfreq(n)
    f[0] = f[1]
    spec /= np.sqrt(f)
    spec[0] = 0.0
    x = np.fft.irfft(spec, n)
    return x * (std / x.std())


def coloured(colour: str, n: int, std: float, rng: np.random.Generator, *, phi: float = 0.95,
             leak: float = 0.002) -> np.ndarray:
    """Noise of ``colour`` scaled to standard deviation ``std`` (a random walk's steps are
    scaled so its spread over the record is about ``std``)."""
    if colour == "white":
        return white(n, std, rng)
    if colour == "ar1":
        return ar1(n, std, phi, rng)
    if colour == "random_walk":
        w = random_walk(n, 1.0, rng, leak=leak)
        sd = float(np.std(w))
        return w * (std / sd) if sd > 0 else w
    if colour == "pink":
        return pink(n, std, rng)
    raise ValueError(f"unknown noise colour {colour!r}; use one of {', '.join(COLOURS)}")


def steps(n: int, at: list[int], sizes: list[float]) -> np.ndarray:
    out = np.zeros(n)
    for k, s in zip(at, sizes):
        out[int(k):] += s
    return out


def sine(n: int, ts_s: float, period_s: float, amp: float, phase: float = 0.0) -> np.ndarray:
    return amp * np.sin(2.0 * math.pi * np.arange(n) * ts_s / period_s + phase)


def first_order_filter(x: np.ndarray, tau_s: float, ts_s: float) -> np.ndarray:
    """Exact first-order lag of a sampled signal held between samples."""
    if tau_s <= 0:
        return np.asarray(x, dtype=float)
    a = math.exp(-ts_s / tau_s)
    out, _ = signal.lfilter([1.0 - a], [1.0, -a], x, zi=[a * x[0]])
    return out


def square(n: int, ts_s: float, period_s: float, amp: float, *, duty: float = 0.5, phase: float = 0.0,
           edge_tau_s: float = 0.0) -> np.ndarray:
    """On/off load between ``-amp`` and ``+amp``: on for ``duty`` of each period, edges lagged by ``edge_tau_s``."""
    t = np.arange(n) * ts_s / period_s + phase / (2.0 * math.pi)
    raw = np.where((t % 1.0) < duty, amp, -amp)
    return first_order_filter(raw, edge_tau_s, ts_s)


def sawtooth(n: int, ts_s: float, period_s: float, amp: float, *, rise: float = 0.85,
             phase: float = 0.0) -> np.ndarray:
    """Fill-and-dump load: rises for ``rise`` of the period and falls back in the rest (``-amp..amp``)."""
    t = (np.arange(n) * ts_s / period_s + phase / (2.0 * math.pi)) % 1.0
    up = t < rise
    out = np.where(up, -1.0 + 2.0 * t / rise, 1.0 - 2.0 * (t - rise) / (1.0 - rise))
    return amp * out


def daily(n: int, ts_s: float, amp: float, phase: float) -> np.ndarray:
    """A 24-hour cycle (ambient temperature, demand)."""
    return sine(n, ts_s, 86400.0, amp, phase)
