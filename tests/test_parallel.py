import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from diagnose.parallel import thread_count, thread_map


def test_results_come_back_in_item_order_whatever_finishes_first():
    seen = set()

    def slow_first(i):
        seen.add(threading.get_ident())
        time.sleep(0.05 if i == 0 else 0.0)      # the first item finishes last
        return i * i

    assert thread_map(slow_first, range(6), threads=3) == [0, 1, 4, 9, 16, 25]
    assert len(seen) > 1                          # it did run on several threads
    seen.clear()
    assert thread_map(slow_first, range(6), threads=1) == [0, 1, 4, 9, 16, 25]
    assert seen == {threading.get_ident()}        # one thread: the caller's own


def test_thread_count_honours_the_caller_and_the_cap():
    assert thread_count(1) == 1 and thread_count(0) == 1 and thread_count(5) == 5
    cores = len(os.sched_getaffinity(0))
    assert thread_count(None) == cores
    assert thread_count(None, cap=1) == 1 and thread_count(None, cap=64) == cores
    assert thread_map(lambda i: i, [], threads=4) == []


def test_workers_share_the_cores_and_get_at_least_one(monkeypatch):
    from diagnose import parallel

    monkeypatch.setattr(parallel, "usable_cores", lambda: 8)
    assert [parallel.cores_per_worker(w) for w in (0, 1, 2, 3, 8, 16)] == [8, 8, 4, 2, 1, 1]
    monkeypatch.setattr(parallel, "usable_cores", lambda: 1)
    assert parallel.cores_per_worker(4) == 1


def test_usable_cores_follow_the_process_affinity_not_the_machine():
    # a container's cpuset or taskset: the machine has more cores than the process may use
    code = ("import os; os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]}); "
            "from diagnose.parallel import usable_cores, thread_count, cores_per_worker; "
            "print(usable_cores(), thread_count(None), cores_per_worker(2))")
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=root).stdout.split()
    assert out == ["1", "1", "1"]


def test_usable_cores_fall_back_to_the_machine_count_without_affinity(monkeypatch):
    from diagnose import parallel

    monkeypatch.delattr(os, "sched_getaffinity")
    monkeypatch.setattr(os, "cpu_count", lambda: 6)
    assert parallel.usable_cores() == 6
    monkeypatch.setattr(os, "cpu_count", lambda: None)
    assert parallel.usable_cores() == 1
