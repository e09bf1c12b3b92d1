"""``nmt view``: the live view (Foxglove WebSocket protocol) of a running graph or of a bag.

    nmt view [--view-host ADDR] [--view-port PORT]          # join the running graph
    nmt view --bag BAG [--rate R] [--start S] [--duration S] [--wait-for-client [S]]

Without ``--bag`` a ``viewer`` node joins the graph (every topic, as it flows) until Ctrl-C.
With ``--bag`` the bag is replayed into the server directly (no ROS graph), at its recorded
timing times ``--rate``; ``--wait-for-client`` holds the replay until a client subscribed to
the scene topic (at most S seconds, default 60). Open ``ws://ADDR:PORT`` in Foxglove or
Lichtblick ("Open connection" -> Foxglove WebSocket) and load ``config/foxglove_layout.json``.
"""
from __future__ import annotations

import argparse
import sys
import threading
import time

from nmt_ros.view import DEFAULT_HOST, DEFAULT_PORT

SCENE_SOURCES = ('auto', 'estimates', 'truth')
#: After a bag replay, the server stays up this long [s] so clients receive the last messages.
DRAIN_S = 0.5


def add_view_options(parser: argparse.ArgumentParser) -> None:
    """``--view-host``, ``--view-port`` (shared with ``nmt launch --view``)."""
    parser.add_argument('--view-host', default=DEFAULT_HOST, metavar='ADDR',
                        help=f'address the view server binds to (default {DEFAULT_HOST}, '
                             'loopback; 0.0.0.0 = every interface)')
    parser.add_argument('--view-port', '--port', dest='view_port', type=int,
                        default=DEFAULT_PORT, metavar='PORT',
                        help=f'TCP port of the view server (default {DEFAULT_PORT})')
    parser.add_argument('--scene-rate', type=float, default=30.0, metavar='HZ',
                        help='scenes per second of stream time (default 30)')
    parser.add_argument('--scene-source', choices=SCENE_SOURCES, default='auto',
                        help='draw the estimates, the truth, or estimates when present (auto)')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--bag', default=None, help='replay this bag into the view '
                        '(default: join the running graph)')
    parser.add_argument('--rate', type=float, default=1.0,
                        help='replay speed factor (0 = as fast as possible)')
    parser.add_argument('--start', type=float, default=0.0, metavar='S',
                        help='start this many seconds into the bag')
    parser.add_argument('--duration', type=float, default=None, metavar='S',
                        help='replay only this many seconds')
    parser.add_argument('--wait-for-client', type=float, nargs='?', const=60.0, default=None,
                        metavar='S', help='hold the replay until a client subscribed to the '
                                          'scene (at most S s, default 60)')
    add_view_options(parser)


def _run_bag(args: argparse.Namespace) -> int:
    from nmt_ros.model.subject import load_subject_model
    from nmt_ros.study.body_scene import BodyDescription
    from nmt_ros.view.bag_replay import bag_topics, replay_bag
    from nmt_ros.view.scene import SCENE_TOPIC, SceneBuilder
    from nmt_ros.view.server import ViewServer

    body = BodyDescription(load_subject_model(args.bag))     # the bag's subject, if it has one
    scene = SceneBuilder(body, rate_hz=args.scene_rate, source=args.scene_source)
    server = ViewServer(host=args.view_host, port=args.view_port, scene=scene)
    stop = threading.Event()
    try:
        server.advertise_all(bag_topics(args.bag))
        print(f'view: ws://{args.view_host}:{server.port} serving {args.bag}', flush=True)
        if args.wait_for_client is not None:
            if not server.wait_for_subscription(SCENE_TOPIC, args.wait_for_client):
                print(f'view: no client subscribed to {SCENE_TOPIC} within '
                      f'{args.wait_for_client:g} s; replaying anyway', flush=True)
        stats = replay_bag(server, args.bag, rate=args.rate, start_s=args.start,
                           duration_s=args.duration, stop=stop)
        print(f'view: sent {stats.messages} messages in {stats.wall_s:.1f} s '
              f'({server.counts.get(SCENE_TOPIC, 0)} scenes)', flush=True)
        time.sleep(DRAIN_S)   # the clients' queues empty before the server closes
        return 0
    except KeyboardInterrupt:
        stop.set()
        return 130
    finally:
        server.stop()


def run(args: argparse.Namespace) -> int:
    if args.bag is not None:
        try:
            return _run_bag(args)
        except (OSError, ValueError, RuntimeError) as exc:   # no bag, a port in use, ...
            print(f'error: {exc}', file=sys.stderr)
            return 2
    from nmt_ros.nodes.viewer import main as viewer_main

    return viewer_main(['nmt_view', '--ros-args',
                        '-p', f'host:={args.view_host}', '-p', f'port:={args.view_port}',
                        '-p', f'scene_rate_hz:={float(args.scene_rate)}',
                        '-p', f'scene_source:={args.scene_source}'])
