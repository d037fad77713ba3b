"""Child processes that die with their parent.

A worker killed with SIGKILL cannot end its COLMAP processes, and nothing else would: they stay
blocked for ever on a result nobody reads, holding their memory (and keeping multiprocessing's
resource tracker alive). So every COLMAP child calls ``die_with_parent`` first.

On Linux this is ``prctl(PR_SET_PDEATHSIG, SIGKILL)``: the kernel kills the child when its parent
dies, even while COLMAP's C++ code holds the GIL or is stuck, which a watchdog thread in the
child could not promise. Its one trap: the signal fires when the parent *thread* that spawned the
child exits. ``sfm.run_sfm`` creates, uses and shuts down its pool in one call, so the
threads that spawn its processes (the caller's, or the pool's manager thread) outlive them.
Elsewhere a daemon thread polls ``os.getppid()``, which changes when the child is reparented.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent(parent_pid: int) -> None:
    """Kill this process when ``parent_pid`` (its parent, which spawned it) dies."""
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0:
            _unless_orphaned(parent_pid)  # the parent may have died before prctl took effect
            return
    threading.Thread(target=_watch, args=(parent_pid,), name="die-with-parent",
                     daemon=True).start()


def _unless_orphaned(parent_pid: int) -> None:
    if os.getppid() != parent_pid:
        os.kill(os.getpid(), signal.SIGKILL)


def _watch(parent_pid: int) -> None:
    stop = threading.Event()
    while not stop.wait(1.0):
        _unless_orphaned(parent_pid)
