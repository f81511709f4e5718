import os
import threading
import time

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
    cores = os.cpu_count() or 1
    assert thread_count(None) == cores
    assert thread_count(None, cap=1) == 1 and thread_count(None, cap=64) == cores
    assert thread_map(lambda i: i, [], threads=4) == []


def test_workers_share_the_cores_and_get_at_least_one(monkeypatch):
    import os

    from diagnose.parallel import cores_per_worker

    monkeypatch.setattr(os, "cpu_count", lambda: 8)
    assert [cores_per_worker(w) for w in (0, 1, 2, 3, 8, 16)] == [8, 8, 4, 2, 1, 1]
    monkeypatch.setattr(os, "cpu_count", lambda: None)
    assert cores_per_worker(4) == 1
