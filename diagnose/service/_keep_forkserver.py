"""Imported by the monitor's forkserver (its preload), nowhere else: the forkserver ignores SIGTERM.

systemd stops a service by sending SIGTERM to every process of its cgroup. The forkserver would die
of it, and with it, by the parent-death signal `diagnose.service.batch.die_with_parent` sets, the
diagnosis workers and the windows they are diagnosing, before the monitor could finish them. The
forkserver still exits with the monitor (its pipe from the monitor closes), and the workers it forks
inherit the ignored signal until their initializer sets their own handling.
"""

from __future__ import annotations

import signal

signal.signal(signal.SIGTERM, signal.SIG_IGN)
