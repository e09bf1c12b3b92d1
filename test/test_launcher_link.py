"""A node started by ``nmt launch`` ends with its launcher (``nodes.launcher_link``): real
processes, the launcher killed with SIGKILL, the node's SIGTERM handler seen to run."""
from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap
import time

from process_groups import running
import pytest

from nmt_ros.nodes.launcher_link import LAUNCHER_PID_ENV, end_with_launcher

pytestmark = pytest.mark.skipif(not sys.platform.startswith('linux'),
                                reason='PR_SET_PDEATHSIG is Linux only')

# the node: a SIGTERM handler that writes a file, the link, then a long sleep
NODE = textwrap.dedent('''
    import os, signal, sys, time
    from nmt_ros.nodes.launcher_link import end_with_launcher
    out = sys.argv[1]
    def on_term(signum, frame):
        with open(out, 'a') as f:
            f.write('SIGTERM\\n')
        os._exit(0)
    signal.signal(signal.SIGTERM, on_term)
    with open(out, 'a') as f:
        f.write(end_with_launcher(signal.SIGTERM) + '\\n')
    time.sleep(120)
''')

# the launcher: starts the node with its own pid in the environment, prints the node's pid
LAUNCHER = textwrap.dedent('''
    import os, subprocess, sys, time
    from nmt_ros.nodes.launcher_link import launched_environment
    node = subprocess.Popen([sys.executable, '-c', sys.argv[1], sys.argv[2]],
                            env=launched_environment(dict(os.environ)))
    print(node.pid, flush=True)
    time.sleep(120)
''')


def wait_for_lines(path: Path, n: int, timeout_s: float = 60.0) -> list[str]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        lines = path.read_text().split() if path.exists() else []
        if len(lines) >= n:
            return lines
        time.sleep(0.05)
    return path.read_text().split() if path.exists() else []


def test_a_node_gets_sigterm_when_its_launcher_is_killed(tmp_path):
    out = tmp_path / 'node.txt'
    launcher = subprocess.Popen([sys.executable, '-c', LAUNCHER, NODE, str(out)],
                                stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        node_pid = int(launcher.stdout.readline())
        assert wait_for_lines(out, 1) == ['linked']
        assert running(node_pid)
        launcher.kill()                      # SIGKILL: the launcher cleans nothing up
        launcher.wait(timeout=30)
        assert wait_for_lines(out, 2) == ['linked', 'SIGTERM']
        deadline = time.monotonic() + 30
        while running(node_pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not running(node_pid)
    finally:
        try:
            os.killpg(launcher.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        launcher.wait()


def test_a_launcher_already_gone_sends_the_signal_at_once(tmp_path):
    out = tmp_path / 'node.txt'
    # the named launcher is not the parent (pid 1 never launches our nodes)
    node = subprocess.Popen([sys.executable, '-c', NODE, str(out)],
                            env={**os.environ, LAUNCHER_PID_ENV: '1'})
    try:
        assert node.wait(timeout=60) == 0
    finally:
        if node.poll() is None:
            node.kill()
    # the handler ran (and ended the node) inside the call, before it could return
    assert out.read_text().split() == ['SIGTERM']


def test_a_node_not_launched_is_left_alone(monkeypatch):
    monkeypatch.delenv(LAUNCHER_PID_ENV, raising=False)
    assert end_with_launcher() == 'not launched'
    monkeypatch.setenv(LAUNCHER_PID_ENV, 'not a pid')
    assert end_with_launcher() == 'not launched'
