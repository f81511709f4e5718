"""Independent pieces of one computation on several threads.

The compiled kernels release the interpreter lock, so scoring different candidates, windows or
hypotheses on threads uses the machine's cores within one process. Every caller keeps its results
in the order of its items, so a result never depends on the number of threads.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, TypeVar

T = TypeVar("T")
R = TypeVar("R")


def usable_cores() -> int:
    """The cores this process may run on: its CPU affinity where the system reports one (a
    container's cpuset or ``taskset`` leaves fewer than the machine has, and threads beyond them only
    queue), else the machine's count."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def thread_count(threads: int | None, cap: int | None = None) -> int:
    """Threads to use: ``threads`` (at least 1), or the cores this process may use (`usable_cores`,
    at most ``cap``) when None. A caller that runs several computations in parallel itself passes
    1."""
    if threads is not None:
        return max(1, int(threads))
    n = usable_cores()
    return max(1, min(n, cap) if cap is not None else n)


def cores_per_worker(workers: int) -> int:
    """Threads each of ``workers`` processes on this machine may give its fits: the cores divided
    among them, at least one, so that workers x threads does not oversubscribe the machine."""
    return max(1, usable_cores() // max(1, int(workers)))


def thread_map(fn: Callable[[T], R], items: Iterable[T], threads: int | None = None) -> list[R]:
    """``[fn(i) for i in items]``, on up to ``threads`` threads (`thread_count`); in item order."""
    items = list(items)
    n = min(thread_count(threads), len(items))
    if n <= 1:
        return [fn(i) for i in items]
    with ThreadPoolExecutor(max_workers=n) as pool:
        return list(pool.map(fn, items))
