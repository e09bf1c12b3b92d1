"""Launched graphs in a process group of their own, so that a test that gives up on one
(a timeout under load) kills its nodes too: killing only the launcher left its node
processes running in the test session's ROS domain, where their subscriptions changed the
counts later tests wait for (a fresh-clone CI beside a busy loop, 2026-12-07: the SIGINT
launch test timed out, then three tests of test_nodes.py and the view test failed)."""
from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
from typing import Any


def popen_group(cmd: list[str], **kwargs: Any) -> subprocess.Popen:
    """``subprocess.Popen`` in a new session (its process group: the launcher and its nodes)."""
    return subprocess.Popen(cmd, start_new_session=True, **kwargs)


def kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL to every process left in ``proc``'s group (the launcher may have ended and
    left its nodes), then reap ``proc``."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()


def _stat(pid: int | str) -> list[str] | None:
    """The fields of ``/proc/<pid>/stat`` after the command name (state first), or None."""
    try:
        return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except (OSError, IndexError):
        return None


def running(pid: int) -> bool:
    """The process exists and is not a zombie awaiting its reaper."""
    fields = _stat(pid)
    return fields is not None and fields[0] not in ('Z', 'X')


def children(pid: int) -> list[int]:
    """The running processes whose parent is ``pid``."""
    found = []
    for entry in Path('/proc').glob('[0-9]*'):
        fields = _stat(entry.name)
        if fields is not None and int(fields[1]) == pid and fields[0] not in ('Z', 'X'):
            found.append(int(entry.name))
    return found
