"""viewer: the graph's topics and the body scene served to Foxglove / Lichtblick (live view).

The node starts the Foxglove WebSocket server (``nmt_ros.view.server``, on ``host``:``port``,
loopback by default), advertises the graph's topics (``topics``: the observations, the
estimates and ``/nmt/status``, with their types) and subscribes to them at once, RELIABLE like
the graph's data topics, so ``nmt launch --view`` can count it among the subscribers the
replay waits for: a viewer that connected to the server before the replay misses nothing.
Topics that appear later (found every ``scan_period_s``) are added with a QoS adapted to
their publishers, as the recorder does.

Receive path: like the recorder, the subscriptions are polled (``polled_subscriptions``):
every ``take_period_s`` one timer callback takes every waiting CDR message and forwards it
unchanged (log time = the middleware's receive time), in receive order, to the server, which
also makes the scene (``scene_rate_hz`` scenes per second of the coordinates' header time).
"""
from __future__ import annotations

from collections.abc import Sequence
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState

from nmt_ros.io.msgdefs import get_message_class, message_type_name
from nmt_ros.model.subject import load_subject_model
from nmt_ros.nodes.node_base import STATUS_QOS, NmtNode, data_qos
from nmt_ros.nodes.polled_subscriptions import PolledSubscriptions
from nmt_ros.nodes.recorder import adapted_qos, is_hidden
from nmt_ros.nodes.runtime import run_node
from nmt_ros.study.body_scene import BodyDescription
from nmt_ros.topics import (
    FORCE_PLATE_WRENCH,
    MOCAP_SEGMENT_ANGLES,
    MUSCLE_OUTPUTS,
    SKELETAL_GROUND_WRENCH,
    SKELETAL_OUTPUTS,
    STATUS,
)
from nmt_ros.view import DEFAULT_HOST, DEFAULT_PORT
from nmt_ros.view.scene import SceneBuilder
from nmt_ros.view.server import ViewServer

NODE_NAME = 'viewer'
#: The graph's topics and types, subscribed before any publisher exists.
GRAPH_TOPICS: dict[str, type] = {
    MOCAP_SEGMENT_ANGLES: JointState, FORCE_PLATE_WRENCH: WrenchStamped,
    **{t: (WrenchStamped if t == SKELETAL_GROUND_WRENCH else JointState)
       for t in SKELETAL_OUTPUTS},
    **{t: JointState for t in MUSCLE_OUTPUTS},
    STATUS: DiagnosticArray,
}


class ViewerNode(NmtNode):
    """Polled raw subscriptions forwarded to a Foxglove WebSocket server."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__(NODE_NAME, gated=False, **kwargs)
        p = self.param
        self.host = p('host', DEFAULT_HOST, 'address the WebSocket server binds to '
                      '(loopback by default; 0.0.0.0 = every interface)')
        self.port = p('port', DEFAULT_PORT, 'TCP port of the WebSocket server (0 = any free)',
                      low=0, high=65535)
        self.scene_rate_hz = p('scene_rate_hz', 30.0, 'scenes per second of stream time',
                               low=0.1, high=1000.0)
        self.scene_source = p('scene_source', 'auto', "scene from 'estimates', 'truth' or "
                              "'auto' (estimates once they flow)")
        self.topics = p('topics', [''], "topics subscribed at start ('' = the graph's: "
                        'observations, estimates, status)')
        self.scan_period_s = p('scan_period_s', 0.5, 'discovery of further topics [s]',
                               low=0.01, high=60.0)
        self.take_period_s = p('take_period_s', 0.01, 'take waiting messages this often [s]',
                               low=0.0005, high=1.0)
        self.drain_idle_s = p('drain_idle_s', 0.3, 'on shutdown, forward until no message came '
                              'for this long, then wait as long for the clients [s]', low=0.0,
                              high=60.0)
        self.subject_file = p('subject_file', '', "the subject's model for the scene "
                              "(BAG/subject.yaml; '' = the shipped jumper)")
        try:
            body = BodyDescription(load_subject_model(self.subject_file or None))
            scene = SceneBuilder(body, rate_hz=self.scene_rate_hz, source=self.scene_source)
            self.server = ViewServer(host=self.host, port=self.port, scene=scene)
        except (ValueError, RuntimeError, OSError) as exc:
            self.server = None
            self.fail_to_start(f'cannot start the view server on {self.host}:{self.port}: '
                               f'{exc}')
            return
        self.get_logger().info(f'Foxglove WebSocket server on ws://{self.host}:'
                               f'{self.server.port} (open it in Foxglove or Lichtblick)')
        self.status.settings = {'url': f'ws://{self.host}:{self.server.port}'}
        self.inputs = PolledSubscriptions(self)
        chosen = ({t: get_message_class(t_type) for t, t_type in
                   (entry.split('=', 1) for entry in self.topics)}
                  if self.topics else GRAPH_TOPICS)
        for topic, cls in chosen.items():
            self._add(topic, cls, STATUS_QOS if topic == STATUS else data_qos(self.qos_depth))
        self.status.state = 'serving'
        self.create_timer(self.scan_period_s, self.scan)
        self.create_timer(self.take_period_s, self.take)

    def _add(self, topic: str, cls: type, qos: object) -> None:
        self.server.advertise(topic, message_type_name(cls))
        self.inputs.add(topic, cls, qos, raw=True)
        self.status.extra['topics'] = len(self.inputs)

    def scan(self) -> None:
        """Serve topics that appeared since the last scan (not hidden ones)."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self.inputs or is_hidden(topic):
                continue
            infos = self.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            try:
                cls = get_message_class(types[0])
            except (ValueError, KeyError) as exc:
                self.status.event(1, f'cannot serve {topic} ({types[0]}): {exc}')
                continue
            self._add(topic, cls, adapted_qos([i.qos_profile for i in infos], self.qos_depth))

    def take(self) -> int:
        """Forward every waiting message to the server, in receive order."""
        taken = self.inputs.take_all()
        batch = []
        for topic, messages in taken.items():
            self.status.receive(topic, len(messages))
            batch.extend((info['received_timestamp'], topic, data) for data, info in messages)
        batch.sort(key=lambda m: m[0])
        for received, topic, data in batch:
            self.server.publish(topic, data, received)
        if batch:
            self.status.mark_active()
        return len(batch)

    def on_shutdown(self, interrupted: bool) -> None:
        """Forward what is still arriving (until ``drain_idle_s`` passed without a message),
        give the clients ``drain_idle_s`` to receive it, then close the server."""
        if self.server is None:
            return
        last = time.monotonic()
        while time.monotonic() - last < self.drain_idle_s:
            if self.take():
                last = time.monotonic()
            else:
                time.sleep(self.take_period_s)
        time.sleep(self.drain_idle_s)
        self.inputs.destroy()
        self.server.stop()
        self.server = None


def main(args: Sequence[str] | None = None) -> int:
    return run_node(ViewerNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
