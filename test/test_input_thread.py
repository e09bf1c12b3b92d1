"""``InputThread``: a node busy with one batch for longer than its subscription's history
holds loses nothing (the thread keeps taking); without it the middleware's KEEP_LAST history
drops the oldest messages (the fault found with ``nmt demo`` beside a busy loop)."""
from __future__ import annotations

import time

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import Int64

from nmt_ros.nodes.input_thread import InputThread
from nmt_ros.nodes.node_base import data_qos
from nmt_ros.nodes.polled_subscriptions import PolledSubscriptions

N = 1000         # messages, published at ~800 Hz while the reader's owner is busy
DEPTH = 200      # the reader's history: 0.25 s of the stream


def _run(ros_context, threaded: bool) -> list[int]:
    pub_node = Node('input_thread_pub', context=ros_context)
    owner = Node('input_thread_owner', context=ros_context)
    publisher = pub_node.create_publisher(Int64, '/input_thread_test', data_qos(2 * N))
    polled = PolledSubscriptions(owner)
    polled.add('/input_thread_test', Int64, data_qos(DEPTH), raw=False)
    reader = InputThread(polled, 0.005) if threaded else polled
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(pub_node)
    try:
        deadline = time.monotonic() + 10.0
        while publisher.get_subscription_count() < 1 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert publisher.get_subscription_count() == 1, 'no match within 10 s'
        for i in range(N):                  # the owner is "busy" (takes nothing) meanwhile
            publisher.publish(Int64(data=i))
            time.sleep(1 / 800)
        time.sleep(0.5)
        got: list[int] = []
        for _ in range(20):                 # what reaches the owner's next takes
            for msgs in reader.take_all().values():
                got += [m.data for m, _info in msgs]
            time.sleep(0.02)
        return got
    finally:
        reader.destroy()
        executor.shutdown()
        pub_node.destroy_node()
        owner.destroy_node()


def test_a_busy_owner_loses_nothing_with_the_input_thread(ros_context) -> None:
    got = _run(ros_context, threaded=True)
    assert got == list(range(N))


def test_without_it_the_history_drops_the_oldest(ros_context) -> None:
    """The control: the same stream taken only after the owner's busy spell."""
    got = _run(ros_context, threaded=False)
    if len(got) == N:
        pytest.fail('the middleware kept every message: the test no longer shows the fault')
    assert got == list(range(N - len(got), N))     # the newest DEPTH survive, in order
