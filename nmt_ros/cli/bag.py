"""``nmt bag info|play|reindex``: the ``ros2 bag`` verbs we need, on our rosbag2 bags.

``info`` prints the ``ros2 bag info`` text (Jazzy ``format_bag_metadata.cpp``): a leading
blank line, labels padded to 19 columns, sizes in B or KiB/MiB/GiB/TiB (base 1024, one
decimal), durations and times as ``<sec>.<9-digit ns>``, dates ``%b %e %Y %H:%M:%S`` in local
time, topics sorted by name with continuation lines indented 19 spaces, service-event topics
counted under ``Service``. It reads ``metadata.yaml`` of a bag folder, or the summary of a
bare ``.mcap`` file.

``play`` publishes a bag at its recorded timing (see ``nmt_ros.nodes.bag_player``).
``reindex`` repairs a bag whose recording was interrupted (``nmt_ros.io.bags.reindex``).
"""
from __future__ import annotations

import argparse
import re
import sys
import time

from nmt_ros.io.bags import BagError, BagInfo, TopicInfo, bag_info, reindex

ACCEPTS_EXTRA_ARGS = True  # `nmt bag play BAG --ros-args ...` goes to rclpy.init
INDENT = 19
_SERVICE_TYPE = re.compile(r'^[^/]+/srv/.+_Event$')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    verbs = parser.add_subparsers(dest='bag_command', metavar='VERB', required=True)
    info = verbs.add_parser('info', help='print information about a bag',
                            description='print information about a bag (ros2 bag info format)')
    info.add_argument('bag_path', help='bag folder (with metadata.yaml) or .mcap file')
    info.add_argument('-t', '--topic-name', action='store_true',
                      help='only print the topic names')
    play = verbs.add_parser('play', help='publish a bag at its recorded timing',
                            description='publish a bag over ROS 2 at its recorded timing')
    play.add_argument('bag_path', help='bag folder (with metadata.yaml) or .mcap file')
    play.add_argument('-r', '--rate', type=float, default=1.0,
                      help='rate factor: 2 plays twice as fast (default 1)')
    play.add_argument('--topics', nargs='+', metavar='TOPIC',
                      help='only these topics (default: all)')
    play.add_argument('--clock', type=float, nargs='?', const=40.0, default=None,
                      metavar='HZ', help='publish /clock at HZ wall-clock rate (default 40)')
    play.add_argument('--wait-for-subscribers', type=int, default=0, metavar='N',
                      help='before playing, wait until every topic has N subscriptions')
    play.add_argument('--wait-timeout', type=float, default=10.0, metavar='S',
                      help='give up waiting for subscribers after S seconds (default 10)')
    play.add_argument('--delay', type=float, default=0.0, metavar='S',
                      help='sleep S seconds before the first message')
    rep = verbs.add_parser('reindex', help='repair an interrupted recording',
                           description='rebuild the MCAP summary and metadata.yaml of a bag')
    rep.add_argument('bag_path', help='bag folder or .mcap file')


# --------------------------------------------------------------------------- info format

def format_size(size: int) -> str:
    """Bytes as ``ros2 bag info`` prints them (``0 B``, ``15.1 KiB``)."""
    units = ('B', 'KiB', 'MiB', 'GiB', 'TiB')
    value, index = float(size), 0
    while value >= 1024 and index < len(units) - 1:
        value /= 1024
        index += 1
    return f'{value:.0f} {units[index]}' if index == 0 else f'{value:.1f} {units[index]}'


def format_seconds(ns: int) -> str:
    """``<sec>.<9-digit ns>``."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return f'{sec}.{nanosec:09d}'


def format_time_point(ns: int) -> str:
    """``Apr 24 2024 14:59:17.676000000 (1713995957.676000000)`` in local time."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    date = time.strftime('%b %e %Y %H:%M:%S', time.localtime(sec))
    return f'{date}.{nanosec:09d} ({format_seconds(ns)})'


def is_service_event_topic(topic: TopicInfo) -> bool:
    return topic.name.endswith('/_service_event') and bool(_SERVICE_TYPE.match(topic.type))


def format_bag_info(info: BagInfo) -> str:
    """The ``ros2 bag info`` text for a bag's metadata."""
    pad = ' ' * INDENT
    lines = ['']
    files = list(info.relative_file_paths)
    lines.append('Files:             ' + (files[0] if files else ''))
    lines.extend(pad + f for f in files[1:])
    lines.append('Bag size:          ' + format_size(info.bag_size))
    lines.append('Storage id:        ' + info.storage_id)
    lines.append('ROS Distro:        ' + (info.ros_distro or 'unknown'))
    lines.append('Duration:          ' + format_seconds(info.duration_ns) + 's')
    lines.append('Start:             ' + format_time_point(info.start_ns))
    lines.append('End:               ' + format_time_point(info.end_ns))
    lines.append('Messages:          ' + str(info.message_count))
    topics = sorted((t for t in info.topics if not is_service_event_topic(t)),
                    key=lambda t: t.name)
    services = sorted((t for t in info.topics if is_service_event_topic(t)),
                      key=lambda t: t.name)
    topic_lines = [f'Topic: {t.name} | Type: {t.type} | Count: {t.message_count} | '
                   f'Serialization Format: {t.serialization_format}' for t in topics]
    lines.append('Topic information: ' + (topic_lines[0] if topic_lines else ''))
    lines.extend(pad + line for line in topic_lines[1:])
    lines.append('Service:           ' + str(len(services)))
    service_lines = [
        f'Service: {t.name[:-len("/_service_event")]} | Type: {t.type[:-len("_Event")]} | '
        f'Event Count: {t.message_count} | Serialization Format: {t.serialization_format}'
        for t in services]
    lines.append('Service information: ' + (service_lines[0] if service_lines else ''))
    lines.extend(' ' * 21 + line for line in service_lines[1:])
    return '\n'.join(lines) + '\n'


# --------------------------------------------------------------------------- verbs

def _info(args: argparse.Namespace) -> int:
    info = bag_info(args.bag_path)
    if args.topic_name:
        names = sorted(t.name for t in info.topics if not is_service_event_topic(t))
        sys.stdout.write(''.join(name + '\n' for name in names))
    else:
        sys.stdout.write(format_bag_info(info))
    return 0


def _reindex(args: argparse.Namespace) -> int:
    info = reindex(args.bag_path)
    print(f'reindexed {args.bag_path}: {info.message_count} messages, '
          f'{format_seconds(info.duration_ns)} s')
    return 0


def _play(args: argparse.Namespace) -> int:
    from nmt_ros.io.bags import read_raw
    from nmt_ros.nodes.bag_player import BagPlayer, default_node_name
    from nmt_ros.nodes.runtime import cli_node

    info = bag_info(args.bag_path)
    topics = list(info.topics)
    if args.topics:
        unknown = sorted(set(args.topics) - {t.name for t in topics})
        if unknown:
            print(f'error: topics not in the bag: {unknown}', file=sys.stderr)
            return 2
        topics = [t for t in topics if t.name in set(args.topics)]
    with cli_node(args, default_node_name()) as node:
        player = BagPlayer(node, topics, publish_clock=args.clock is not None)
        try:
            if args.wait_for_subscribers > 0:
                player.wait_for_subscribers(args.wait_for_subscribers, args.wait_timeout)
            if args.delay > 0:
                time.sleep(args.delay)
            stats = player.play(read_raw(args.bag_path, [t.name for t in topics]),
                                rate=args.rate, clock_hz=args.clock)
            print(f'played {stats.messages} messages in {stats.wall_s:.3f} s '
                  f'(max lateness {stats.max_late_ns / 1e6:.3f} ms)', file=sys.stderr)
            return 0 if stats.all_acked else 1
        except TimeoutError as exc:
            print(f'error: {exc}', file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            return 130
        finally:
            player.destroy()


def run(args: argparse.Namespace) -> int:
    extra = list(getattr(args, 'extra', []))
    if extra and args.bag_command != 'play':
        print(f'error: unrecognized arguments: {" ".join(extra)}', file=sys.stderr)
        return 2
    verbs = {'info': _info, 'play': _play, 'reindex': _reindex}
    try:
        return verbs[args.bag_command](args)
    except (BagError, KeyError) as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 1
