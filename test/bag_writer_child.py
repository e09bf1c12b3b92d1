"""A bag writer in a child process, for the crash-safety tests (test_bags, test_ts_reader):
it writes a WrenchStamped on '/w' every 0.93 ms (force.x = its index), flushing every 20 ms,
and says 'ready' after 1500 messages; the test then signals it."""
from __future__ import annotations

from pathlib import Path
import subprocess
import sys

CHILD = r'''
import sys, time
from msg_adapters.wrench import to_wrench_stamped
from nmt_ros.io.bags import BagWriter, close_bags_on_sigterm
close_bags_on_sigterm()
with BagWriter(sys.argv[1], flush_period_s=0.02) as bag:
    bag.add_topic('/w', 'geometry_msgs/msg/WrenchStamped')
    i = 0
    while True:
        bag.write('/w', to_wrench_stamped(i * 925926, 'plate', [float(i), 0.0, 0.0]),
                  i * 925926)
        i += 1
        if i == 500:
            bag.flush()
        if i > 500:
            time.sleep(0.0005)
        if i == 1500:
            print('ready', flush=True)
'''


def run_child_until_ready(path: Path) -> subprocess.Popen:
    child = subprocess.Popen([sys.executable, '-c', CHILD, str(path)], stdout=subprocess.PIPE,
                             text=True)
    line = child.stdout.readline()
    assert line.strip() == 'ready', f'child failed before writing (rc={child.poll()})'
    return child
