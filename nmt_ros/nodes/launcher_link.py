"""A launched node ends with its launcher.

``nmt launch`` passes its process id to every node it starts (:data:`LAUNCHER_PID_ENV`).
Such a node asks Linux for a signal when its parent dies (``prctl(PR_SET_PDEATHSIG)``), so a
launcher killed outright (SIGKILL, the OOM killer, a closed terminal) does not leave its
nodes running in the ROS domain: each gets SIGTERM and finishes as on a Ctrl-C (the
recorder closes its bag). Found by a fresh-clone CI run beside a busy loop (2026-12-07): a
test that gave up on a launch killed the launcher only, and its four nodes ran on for 50
minutes, their subscriptions changing what later tests waited for.

Linux sends the signal when the *thread* that started the node ends; ``run_graph`` starts
the nodes from the thread that calls it and waits for them there, so that thread outlives
them.

A node not started by ``nmt launch`` (``nmt run``, ``ros2 run``, a ROS 2 launch file) has
no such variable and is left as it is. Outside Linux the request is not available and
nothing is done.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal

LAUNCHER_PID_ENV = 'NMT_LAUNCHER_PID'
PR_SET_PDEATHSIG = 1   # <linux/prctl.h>


def launched_environment(env: dict[str, str], launcher_pid: int | None = None
                         ) -> dict[str, str]:
    """``env`` with this process (or ``launcher_pid``) named as the launcher of the node."""
    return {**env, LAUNCHER_PID_ENV: str(os.getpid() if launcher_pid is None
                                         else launcher_pid)}


def end_with_launcher(sig: int = signal.SIGTERM) -> str:
    """Have ``sig`` sent to this process when its launcher dies; what was done:
    ``'not launched'`` (no :data:`LAUNCHER_PID_ENV`), ``'linked'``, ``'unavailable'`` (no
    ``prctl``) or ``'launcher gone'`` (it died before the link was made: ``sig`` is sent
    now). Call it after the handler of ``sig`` is installed."""
    value = os.environ.get(LAUNCHER_PID_ENV, '')
    if not value:
        return 'not launched'
    try:
        launcher = int(value)
    except ValueError:
        return 'not launched'
    name = ctypes.util.find_library('c')
    try:
        libc = ctypes.CDLL(name, use_errno=True)
        prctl = libc.prctl
    except (OSError, AttributeError, TypeError):
        return 'unavailable'
    if prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
        return 'unavailable'
    # the launcher may have died before the request: then our parent is another process
    if os.getppid() != launcher:
        os.kill(os.getpid(), sig)
        return 'launcher gone'
    return 'linked'
