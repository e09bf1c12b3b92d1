"""The live view (Foxglove WebSocket) and the rendered movie, checked from outside.

The client here is independent of our server code: the ``websockets`` library speaking the
Foxglove WebSocket protocol itself (JSON control messages, binary message data), the
``foxglove.sdk.v1`` subprotocol (the name foxglove-sdk >= 0.8 accepts for the same protocol
as ``foxglove.websocket.v1``). ROS messages are decoded with mcap_ros2's CDR decoder from
the ``ros2msg`` schema the server advertises, the scene with protobuf from the advertised
FileDescriptorSet; the values are compared with the bag read by mcap_ros2.
"""
from __future__ import annotations

import asyncio
import base64
import json
import os
from pathlib import Path
import socket
import struct
import subprocess
import sys
import time

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
import numpy as np
from process_groups import kill_group, popen_group
import pytest
import websockets

from nmt_ros.cli.launch import graph_parameters
from nmt_ros.io.bags import BagWriter, read_raw
from nmt_ros.model.parameters import MUSCLES, Q_NAMES
from nmt_ros.topics import (
    FORCE_PLATE_WRENCH,
    MUSCLE_FORCES,
    SKELETAL_GENERALIZED_COORDINATES,
    SKELETAL_GROUND_WRENCH,
    SKELETAL_JOINT_TORQUES,
    STATUS,
    TRUTH_GENERALIZED_COORDINATES,
    TRUTH_GROUND_WRENCH,
    TRUTH_MUSCLE_FORCES,
)
from nmt_ros.view.scene import MUSCLE_OFFSET_M, SCENE_TOPIC

REPO = Path(__file__).resolve().parents[1]
NMT = [sys.executable, '-m', 'nmt_ros.cli.main']
SUBPROTOCOL = 'foxglove.sdk.v1'
#: The routine's truth relabelled as estimates (a recording of the graph would carry these).
AS_ESTIMATES = {TRUTH_GENERALIZED_COORDINATES: SKELETAL_GENERALIZED_COORDINATES,
                TRUTH_MUSCLE_FORCES: MUSCLE_FORCES, TRUTH_GROUND_WRENCH: SKELETAL_GROUND_WRENCH,
                FORCE_PLATE_WRENCH: FORCE_PLATE_WRENCH}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


@pytest.fixture(scope='module')
def estimates_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """1.2 s of the shipped routine around a countermovement jump's take-off (16.6-17.8 s),
    its truth under the estimate topics' names, with the force plate."""
    bag = tmp_path_factory.mktemp('view') / 'estimates'
    start = 1_700_000_000_000_000_000 + 16_600_000_000
    end = start + 1_200_000_000
    types = {}
    with BagWriter(bag) as writer:
        for raw in read_raw(REPO / 'bags' / 'routine', list(AS_ESTIMATES)):
            if not start <= raw.log_time_ns <= end:
                continue
            topic = AS_ESTIMATES[raw.topic]
            if topic not in types:
                writer.add_topic(topic, raw.msgtype)
                types[topic] = raw.msgtype
            writer.write(topic, raw.data, raw.log_time_ns)
    return bag


def bag_messages(bag: Path, topic: str) -> list:
    """(stamp ns, decoded message) of a topic, read with mcap + mcap_ros2 (not our reader)."""
    out = []
    for file in sorted(bag.glob('*.mcap')):
        with open(file, 'rb') as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _s, _c, _m, msg in reader.iter_decoded_messages(topics=[topic]):
                out.append((msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec, msg))
    return out


class FoxgloveClient:
    """A minimal Foxglove WebSocket client: advertisements, subscriptions, message data."""

    def __init__(self, port: int, topics: list[str]) -> None:
        self.port = port
        self.topics = topics
        self.channels: dict[int, dict] = {}
        self.received: dict[str, list[tuple[int, bytes]]] = {t: [] for t in topics}
        self.connected_at: float | None = None

    async def run(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                ws = await websockets.connect(f'ws://127.0.0.1:{self.port}',
                                              subprotocols=[SUBPROTOCOL], max_size=None)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                await asyncio.sleep(0.1)
        self.connected_at = time.monotonic()
        by_subscription = {}
        async with ws:
            assert ws.subprotocol == SUBPROTOCOL
            try:
                while time.monotonic() < deadline:
                    frame = await asyncio.wait_for(ws.recv(), deadline - time.monotonic())
                    if isinstance(frame, str):
                        op = json.loads(frame)
                        if op['op'] == 'advertise':
                            for c in op['channels']:
                                self.channels[c['id']] = c
                            wanted = {c['topic']: c['id'] for c in self.channels.values()
                                      if c['topic'] in self.topics}
                            if len(wanted) == len(self.topics) and not by_subscription:
                                await asyncio.sleep(0.3)   # let the advertisements settle
                                subs = [{'id': i, 'channelId': wanted[t]}
                                        for i, t in enumerate(self.topics)]
                                by_subscription = {i: t for i, t in enumerate(self.topics)}
                                await ws.send(json.dumps({'op': 'subscribe',
                                                          'subscriptions': subs}))
                    elif frame[0] == 1:                    # message data
                        sub_id, log_time = struct.unpack_from('<IQ', frame, 1)
                        self.received[by_subscription[sub_id]].append((log_time, frame[13:]))
            except websockets.ConnectionClosed:
                return

    def channel(self, topic: str) -> dict:
        return next(c for c in self.channels.values() if c['topic'] == topic)

    def ros_decoder(self, topic: str):
        c = self.channel(topic)
        assert (c['encoding'], c['schemaEncoding']) == ('cdr', 'ros2msg')
        schema = Schema(id=1, name=c['schemaName'], encoding='ros2msg',
                        data=c['schema'].encode())
        return DecoderFactory().decoder_for('cdr', schema)

    def protobuf_class(self, topic: str) -> type:
        c = self.channel(topic)
        assert (c['encoding'], c['schemaEncoding']) == ('protobuf', 'protobuf')
        files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(c['schema']))
        pool = descriptor_pool.DescriptorPool()
        for f in files.file:
            pool.Add(f)
        return message_factory.GetMessageClass(pool.FindMessageTypeByName(c['schemaName']))


def run_client(port: int, topics: list[str], timeout_s: float) -> FoxgloveClient:
    client = FoxgloveClient(port, topics)
    asyncio.run(client.run(timeout_s))
    return client


def test_view_of_a_bag_serves_its_topics_and_the_scene(estimates_bag: Path) -> None:
    port = free_port()
    proc = popen_group(NMT + ['view', '--bag', str(estimates_bag), '--view-port', str(port),
                                   '--wait-for-client', '60'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=dict(os.environ))
    try:
        client = run_client(port, [MUSCLE_FORCES, SCENE_TOPIC], timeout_s=120)
        out, _ = proc.communicate(timeout=60)
    finally:
        kill_group(proc)
    assert proc.returncode == 0, out
    assert f'ws://127.0.0.1:{port}' in out

    # every muscle-force message, decoded, equals the recording's
    decode = client.ros_decoder(MUSCLE_FORCES)
    got = [decode(data) for _, data in client.received[MUSCLE_FORCES]]
    expected = bag_messages(estimates_bag, MUSCLE_FORCES)
    assert len(expected) == 145 and len(got) == len(expected)      # 1.2 s at 120 Hz, both ends
    for msg, (stamp, ref) in zip(got, expected):
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == stamp
        assert list(msg.name) == list(ref.name) == list(MUSCLES)
        assert list(msg.effort) == list(ref.effort)
        assert list(msg.position) == list(ref.position)
    # log times are the recording's
    assert [t for t, _ in client.received[MUSCLE_FORCES]] == [
        r.log_time_ns for r in read_raw(estimates_bag, [MUSCLE_FORCES])]

    # the scene: 30 per second of the coordinates' time, each from recorded values
    scene_cls = client.protobuf_class(SCENE_TOPIC)
    scenes = [scene_cls.FromString(data) for _, data in client.received[SCENE_TOPIC]]
    assert 35 <= len(scenes) <= 37
    coords = dict(bag_messages(estimates_bag, SKELETAL_GENERALIZED_COORDINATES))
    forces = dict(expected)
    from nmt_ros.model.jumper import default_model
    from nmt_ros.study.body_scene import BodyDescription

    body = BodyDescription()
    model = default_model()
    for i, scene in enumerate(scenes):
        (entity,) = scene.entities
        meta = {kv.key: kv.value for kv in entity.metadata}
        assert meta['source'] == 'estimates'
        q_msg = coords[int(meta['coordinates_stamp_ns'])]
        q = np.array([q_msg.position[list(q_msg.name).index(n)] for n in Q_NAMES])
        if 'forces_stamp_ns' not in meta:    # only before the stream's first forces
            assert i == 0
            continue
        f_stamp = int(meta['forces_stamp_ns'])
        # paced by the forces: the coordinates are the newest at or before them
        assert 0 <= f_stamp - int(meta['coordinates_stamp_ns']) < 1e9 / 120
        f = np.array(forces[f_stamp].effort)
        assert [float(meta[f'force_{m}_n']) for m in MUSCLES] == list(f)
        assert entity.timestamp.seconds * 10**9 + entity.timestamp.nanos == \
            int(meta['coordinates_stamp_ns'])
        # joints: the ankle is q's (r1, r2) itself; knee and hip the model's
        ankle, knee, hip = ([s.pose.position.x, s.pose.position.y, s.pose.position.z]
                            for s in entity.spheres[:3])
        np.testing.assert_allclose(ankle, [q[4], 0.0, q[5]], atol=1e-12)
        _, knee_m, hip_m, _, _, com_m = model.call(model.positions, q)
        np.testing.assert_allclose(knee, [knee_m[0], 0.0, knee_m[1]], atol=1e-12)
        np.testing.assert_allclose(hip, [hip_m[0], 0.0, hip_m[1]], atol=1e-12)
        com = entity.spheres[3].pose.position
        np.testing.assert_allclose([com.x, com.z], com_m, atol=1e-12)
        # muscles: the lines after the 4 bones and the ground line, along the paths
        pose = body.pose(q, f)
        muscles = entity.lines[5:]
        assert len(muscles) == len(MUSCLES)
        for line, m in zip(muscles, pose.muscles):
            pts = np.array([[p.x, p.y, p.z] for p in line.points])
            np.testing.assert_allclose(pts[:, [0, 2]], m.points, atol=1e-12)
            assert np.all(pts[:, 1] == -MUSCLE_OFFSET_M)
            assert line.thickness == pytest.approx(m.width_m)
    # the ground force is drawn while loaded (the take-off is in this window)
    assert any(len(s.entities[0].arrows) for s in scenes)
    assert any(not len(s.entities[0].arrows) for s in scenes)


def test_launch_view_serves_the_graph_from_before_the_replay(tmp_path: Path) -> None:
    """``nmt launch --view``: a client that connected before the replay receives every
    /nmt/muscle/forces message the recorder recorded, with the same values."""
    port = free_port()
    record = tmp_path / 'rec'
    proc = popen_group(NMT + ['launch', '--view', '--view-port', str(port), '--record',
                                   str(record), '--log-dir', str(tmp_path / 'logs')],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=dict(os.environ))
    try:
        client = run_client(port, [MUSCLE_FORCES, SKELETAL_JOINT_TORQUES], timeout_s=200)
        out, _ = proc.communicate(timeout=120)
    finally:
        kill_group(proc)
    assert proc.returncode == 0, out
    for topic in (MUSCLE_FORCES, SKELETAL_JOINT_TORQUES):
        decode = client.ros_decoder(topic)
        got = [decode(data) for _, data in client.received[topic]]
        recorded = bag_messages(record, topic)
        assert len(recorded) > 200 and len(got) == len(recorded), topic
        for msg, (stamp, ref) in zip(got, recorded):
            assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == stamp
            assert list(msg.effort) == list(ref.effort)


def test_graph_parameters_count_the_viewer() -> None:
    plain = graph_parameters({}, record='rec')
    viewed = graph_parameters({}, record='rec', view=True)
    assert 'viewer' not in plain
    assert plain['observation_publisher']['ros__parameters']['expected_subscribers'] == 2
    assert viewed['observation_publisher']['ros__parameters']['expected_subscribers'] == 3
    wait = viewed['skeletal_tracker']['ros__parameters']['wait_for']
    assert wait[0] == f'{SKELETAL_JOINT_TORQUES}=3' and all(w.endswith('=2') for w in wait[1:])
    assert all(w.endswith('=2') for w in viewed['muscle_tracker']['ros__parameters']['wait_for'])
    only_view = graph_parameters({}, view=True)
    assert only_view['observation_publisher']['ros__parameters']['expected_subscribers'] == 2
    assert 'recorder' not in only_view


def test_layout_names_our_topics() -> None:
    layout = json.loads((REPO / 'config' / 'foxglove_layout.json').read_text())
    panels = set()

    def walk(node: object) -> None:
        if isinstance(node, str):
            panels.add(node)
        else:
            walk(node['first'])
            walk(node['second'])

    walk(layout['layout'])
    assert panels == set(layout['configById'])
    assert layout['configById']['3D!scene']['topics'] == {SCENE_TOPIC: {'visible': True}}
    muscles = layout['configById']['Plot!muscles']['paths']
    assert [p['value'] for p in muscles] == [f'{MUSCLE_FORCES}.effort[{i}]' for i in range(9)]
    assert [p['label'] for p in muscles] == list(MUSCLES)
    torques = layout['configById']['Plot!torques']['paths']
    assert [p['label'] for p in torques] == ['ankle', 'knee', 'hip']
    assert all(p['value'].startswith(SKELETAL_JOINT_TORQUES + '.effort[') for p in torques)
    assert layout['configById']['DiagnosticSummary!status']['topicToRender'] == STATUS


def test_render_a_gif(estimates_bag: Path, tmp_path: Path) -> None:
    from PIL import Image

    out = tmp_path / 'movie.gif'
    done = subprocess.run(NMT + ['render', str(estimates_bag), '--out', str(out), '--start',
                                 '0.3', '--duration', '0.3', '--fps', '10', '--dpi', '40'],
                          capture_output=True, text=True, env=dict(os.environ))
    assert done.returncode == 0, done.stderr
    with Image.open(out) as im:
        assert im.n_frames == 4 and im.size == (320, 160)
    bad = subprocess.run(NMT + ['render', str(estimates_bag), '--out', str(tmp_path / 'x.avi')],
                         capture_output=True, text=True, env=dict(os.environ))
    assert bad.returncode == 2 and '.mp4 or .gif' in bad.stderr
    empty = subprocess.run(NMT + ['render', str(REPO / 'bags' / 'reference_jump'), '--out',
                                  str(tmp_path / 'y.gif'), '--source', 'estimates'],
                           capture_output=True, text=True, env=dict(os.environ))
    assert empty.returncode == 2 and SKELETAL_GENERALIZED_COORDINATES in empty.stderr
