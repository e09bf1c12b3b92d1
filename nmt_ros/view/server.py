"""The live view: a Foxglove WebSocket server (``foxglove-sdk``) fed with the graph's topics.

Every ROS topic is served as it travels in the graph: ``cdr`` message encoding with the
``ros2msg`` schema of its type (the full definition, ``nmt_ros.io.msgdefs``), so Foxglove and
Lichtblick decode, plot and inspect it like a ROS 2 bag. Beside them the scene topic
(``nmt_ros.view.scene.SCENE_TOPIC``, ``foxglove.SceneUpdate``, protobuf): the stick figure,
the muscles and the ground-force arrow (``nmt_ros.study.body_scene``).

The server binds to loopback unless told otherwise; the SDK buffers up to
``message_backlog_size`` messages per client and drops the oldest beyond (a slow viewer
loses frames, never the graph). ``ViewServer.publish`` never blocks on a client.
"""
from __future__ import annotations

from collections.abc import Iterable
import threading

import foxglove
from foxglove.channels import SceneUpdateChannel
from foxglove.websocket import Capability

from nmt_ros.io.msgdefs import full_definition, normalize_type_name
from nmt_ros.view import DEFAULT_HOST, DEFAULT_PORT
from nmt_ros.view.scene import SCENE_TOPIC, SceneBuilder


class _Listener:
    """Counts the subscriptions of every client (``foxglove.websocket.ServerListener``)."""

    def __init__(self) -> None:
        self.subscribed: dict[str, int] = {}
        self.changed = threading.Condition()

    def on_subscribe(self, _client: object, channel: object) -> None:
        with self.changed:
            self.subscribed[channel.topic] = self.subscribed.get(channel.topic, 0) + 1
            self.changed.notify_all()

    def on_unsubscribe(self, _client: object, channel: object) -> None:
        with self.changed:
            self.subscribed[channel.topic] = max(0, self.subscribed.get(channel.topic, 0) - 1)
            self.changed.notify_all()


class ViewServer:
    """A Foxglove WebSocket server serving ROS topics (CDR) and the body scene."""

    def __init__(self, *, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 scene: SceneBuilder | None = None, name: str = 'nmt_ros',
                 message_backlog_size: int = 4096) -> None:
        self.context = foxglove.Context()
        self.listener = _Listener()
        self.scene = scene if scene is not None else SceneBuilder()
        self.channels: dict[str, foxglove.Channel] = {}
        self.types: dict[str, str] = {}
        self.scene_channel = SceneUpdateChannel(SCENE_TOPIC, context=self.context)
        self.counts: dict[str, int] = {}
        self.server = foxglove.start_server(
            name=name, host=host, port=port, context=self.context,
            server_listener=self.listener, capabilities=[Capability.Time],
            message_backlog_size=message_backlog_size)

    @property
    def port(self) -> int:
        """The TCP port the server listens on (the chosen one, or the system's for 0)."""
        return int(self.server.port)

    def advertise(self, topic: str, msgtype: str) -> None:
        """Serve ``topic`` of ROS type ``msgtype`` (``pkg/msg/Type``); once per topic."""
        msgtype = normalize_type_name(msgtype)
        if topic in self.channels:
            if self.types[topic] != msgtype:
                raise ValueError(f'{topic} is served as {self.types[topic]}, not {msgtype}')
            return
        schema = foxglove.Schema(name=msgtype, encoding='ros2msg',
                                 data=full_definition(msgtype).encode('utf-8'))
        self.channels[topic] = foxglove.Channel(topic, schema=schema, message_encoding='cdr',
                                                context=self.context)
        self.types[topic] = msgtype

    def advertise_all(self, topics: Iterable[tuple[str, str]]) -> None:
        for topic, msgtype in topics:
            self.advertise(topic, msgtype)

    def publish(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Forward one CDR message of an advertised topic (and update the scene)."""
        self.channels[topic].log(data, log_time=int(log_time_ns))
        self.counts[topic] = self.counts.get(topic, 0) + 1
        update = self.scene.update(topic, data)
        if update is not None:
            self.scene_channel.log(update, log_time=int(log_time_ns))
            self.counts[SCENE_TOPIC] = self.counts.get(SCENE_TOPIC, 0) + 1

    def broadcast_time(self, time_ns: int) -> None:
        """Tell the clients the stream's current time (Foxglove's playback clock)."""
        self.server.broadcast_time(int(time_ns))

    def wait_for_subscription(self, topic: str, timeout_s: float) -> bool:
        """Block until a client subscribed to ``topic`` (True) or ``timeout_s`` passed."""
        with self.listener.changed:
            return self.listener.changed.wait_for(
                lambda: self.listener.subscribed.get(topic, 0) > 0, timeout=timeout_s)

    def stop(self) -> None:
        self.server.stop()
