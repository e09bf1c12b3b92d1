"""rosbag2-compatible bags: a folder with ``metadata.yaml`` (v9) and ``<name>_0.mcap``
(``<name>_1.mcap``, ... when a recording is split by size or duration).

What is written (and why) follows rosbag2 Jazzy's MCAP storage plugin so that ``ros2 bag
info/play``, ``rosbags`` and the ``mcap`` tools read our bags:

- MCAP header profile ``ros2``; one schema per type, name ``pkg/msg/Type``, encoding
  ``ros2msg``, data = the full concatenated definition (``nmt_ros.io.msgdefs``).
- One channel per topic, message encoding ``cdr``, channel metadata
  ``offered_qos_profiles`` (v9 YAML string) and ``topic_type_hash`` (``RIHS01_...``).
- Messages: ``log_time`` = receive time, ``publish_time`` = send time, ``sequence`` 0. The
  payload is CDR exactly as rclpy serialises it (or as a raw subscription delivered it).
- A metadata record ``rosbag2`` with key ``serialized_metadata`` (YAML of the bag metadata,
  without the ``rosbag2_bagfile_information`` wrapper) at open and at close, plus the MCAP
  summary (Statistics, chunk/message indexes) that rosbag2 needs to open a file.
- ``metadata.yaml``: version 9, every field, ``ros_distro: jazzy``, written on close; it
  lists every file of a split bag (``relative_file_paths``, ``files``) in order.

Compression: chunks are compressed inside the MCAP (``compression='zstd'`` default, ``'lz4'``
or ``'none'``), which every MCAP reader handles transparently. This is the storage-level
compression of rosbag2's ``storage_preset_profile``; rosbag2's *file/message* compression
(``compression_mode``) is not used, so ``compression_format``/``compression_mode`` stay ``""``.

Crash safety: the writer closes a chunk and flushes it to the OS every ``flush_period_s``
(default 1 s of wall time), so a killed recorder loses at most that much. The unfinished file
has no summary and the folder no ``metadata.yaml``; :func:`reindex` (CLI: ``nmt bag reindex``,
like ``ros2 bag reindex``) salvages every complete chunk into a valid MCAP and writes
``metadata.yaml``. After :func:`close_bags_on_sigterm`, SIGTERM and SIGINT end a
``with BagWriter(...)`` block (the bag is closed cleanly), never in the middle of a write.
"""
from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
import functools
import io
import os
from pathlib import Path
import re
import signal
import struct
import threading
import time
from typing import Any, NamedTuple

from mcap import __version__ as mcap_version
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
import numpy as np
import yaml

from msg_adapters.cdr_arrays import decode_joint_states, decode_wrenches
from msg_adapters.cdr_padding import zero_padding
from msg_adapters.series import JointStateSeries, WrenchSeries

from . import msgdefs
from .qos import OBSERVATION_QOS, OfferedQos, as_qos_list, parse_qos_list, qos_list_to_yaml

METADATA_FILENAME = 'metadata.yaml'
METADATA_VERSION = 9
STORAGE_ID = 'mcap'
ROS_DISTRO = 'jazzy'
PROFILE = 'ros2'
LIBRARY = f'nmt_ros; mcap-python/{mcap_version}'
MCAP_MAGIC = b'\x89MCAP0\r\n'
_COMPRESSION = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                'none': CompressionType.NONE, '': CompressionType.NONE}


class BagError(RuntimeError):
    """A bag cannot be opened or written (missing, incomplete, wrong layout)."""


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag (``topics_with_message_count`` entry)."""

    name: str
    type: str
    serialization_format: str = 'cdr'
    offered_qos: tuple[OfferedQos, ...] = ()
    type_hash: str = ''
    message_count: int = 0


@dataclass(frozen=True)
class FileInfo:
    """One storage file of a bag (``files`` entry)."""

    path: str
    start_ns: int
    duration_ns: int
    message_count: int


@dataclass(frozen=True)
class BagInfo:
    """Bag metadata, as in ``metadata.yaml`` plus the on-disk size."""

    path: Path
    relative_file_paths: tuple[str, ...]
    files: tuple[FileInfo, ...]
    bag_size: int
    start_ns: int
    duration_ns: int
    message_count: int
    topics: tuple[TopicInfo, ...]
    storage_id: str = STORAGE_ID
    ros_distro: str = ROS_DISTRO
    custom_data: Mapping[str, str] = field(default_factory=dict)
    version: int = METADATA_VERSION
    compression_format: str = ''
    compression_mode: str = ''

    @property
    def end_ns(self) -> int:
        return self.start_ns + self.duration_ns

    def topic(self, name: str) -> TopicInfo:
        for t in self.topics:
            if t.name == name:
                return t
        raise KeyError(f'topic {name!r} not in bag {self.path} '
                       f'(topics: {[t.name for t in self.topics]})')


class RawMessage(NamedTuple):
    """A serialised message as stored (CDR bytes)."""

    topic: str
    msgtype: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes


class BagMessage(NamedTuple):
    """A deserialised message: ``topic, msgtype, log_time_ns, msg`` (an rclpy message)."""

    topic: str
    msgtype: str
    log_time_ns: int
    msg: Any


# --------------------------------------------------------------------------- metadata YAML

class _Rosbag2Dumper(yaml.SafeDumper):
    """Safe dumper writing ``~`` for null like yaml-cpp does for an empty custom_data map."""


_Rosbag2Dumper.add_representer(
    type(None), lambda dumper, _: dumper.represent_scalar('tag:yaml.org,2002:null', '~'))


def metadata_dict(info: BagInfo) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping (v9, rosbag2's field order)."""
    return {
        'version': METADATA_VERSION,
        'storage_identifier': info.storage_id,
        'duration': {'nanoseconds': int(info.duration_ns)},
        'starting_time': {'nanoseconds_since_epoch': int(info.start_ns)},
        'message_count': int(info.message_count),
        'topics_with_message_count': [
            {
                'topic_metadata': {
                    'name': t.name,
                    'type': t.type,
                    'serialization_format': t.serialization_format,
                    'offered_qos_profiles': [q.to_dict() for q in t.offered_qos],
                    'type_description_hash': t.type_hash,
                },
                'message_count': int(t.message_count),
            }
            for t in info.topics
        ],
        'compression_format': info.compression_format,
        'compression_mode': info.compression_mode,
        'relative_file_paths': list(info.relative_file_paths),
        'files': [
            {
                'path': f.path,
                'starting_time': {'nanoseconds_since_epoch': int(f.start_ns)},
                'duration': {'nanoseconds': int(f.duration_ns)},
                'message_count': int(f.message_count),
            }
            for f in info.files
        ],
        'custom_data': dict(info.custom_data) or None,
        'ros_distro': info.ros_distro,
    }


def _dump_yaml(data: Any) -> str:
    return yaml.dump(data, Dumper=_Rosbag2Dumper, sort_keys=False, default_flow_style=False,
                     allow_unicode=True, width=1 << 16)


def write_metadata_yaml(folder: str | os.PathLike, info: BagInfo) -> Path:
    """Write ``<folder>/metadata.yaml`` atomically (temporary file + rename)."""
    target = Path(folder) / METADATA_FILENAME
    tmp = target.with_name(METADATA_FILENAME + '.tmp')
    tmp.write_text(_dump_yaml({'rosbag2_bagfile_information': metadata_dict(info)}),
                   encoding='utf-8')
    os.replace(tmp, target)
    return target


def _directory_size(folder: Path) -> int:
    """Sum of the regular files directly in ``folder`` (what ``ros2 bag info`` reports)."""
    return sum(p.stat().st_size for p in folder.iterdir() if p.is_file())


def read_metadata_yaml(folder: str | os.PathLike) -> BagInfo:
    """Parse ``<folder>/metadata.yaml`` (versions 4..9).

    Fields that older versions lack (type hash, per-file list, ROS distro, custom data,
    compression) read as empty, as rosbag2's own reader reads them; anything else missing or
    malformed is a :class:`BagError`.
    """
    folder = Path(folder)
    path = folder / METADATA_FILENAME
    try:
        root = yaml.safe_load(path.read_text(encoding='utf-8'))
        meta = root['rosbag2_bagfile_information']
        topics = tuple(
            TopicInfo(
                name=t['topic_metadata']['name'],
                type=t['topic_metadata']['type'],
                serialization_format=t['topic_metadata']['serialization_format'],
                offered_qos=parse_qos_list(t['topic_metadata'].get('offered_qos_profiles')),
                type_hash=t['topic_metadata'].get('type_description_hash', '') or '',
                message_count=int(t['message_count']),
            )
            for t in meta['topics_with_message_count'] or []
        )
        files = tuple(
            FileInfo(path=f['path'],
                     start_ns=int(f['starting_time']['nanoseconds_since_epoch']),
                     duration_ns=int(f['duration']['nanoseconds']),
                     message_count=int(f['message_count']))
            for f in meta.get('files') or []
        )
        return BagInfo(
            path=folder,
            relative_file_paths=tuple(meta['relative_file_paths']),
            files=files,
            bag_size=_directory_size(folder),
            start_ns=int(meta['starting_time']['nanoseconds_since_epoch']),
            duration_ns=int(meta['duration']['nanoseconds']),
            message_count=int(meta['message_count']),
            topics=topics,
            storage_id=meta['storage_identifier'],
            ros_distro=meta.get('ros_distro') or '',
            custom_data={str(k): str(v) for k, v in (meta.get('custom_data') or {}).items()},
            version=int(meta['version']),
            compression_format=meta.get('compression_format') or '',
            compression_mode=meta.get('compression_mode') or '',
        )
    except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError) as exc:
        raise BagError(f'cannot parse {path}: {exc!r}') from None


# --------------------------------------------------------------------------- writing

class _Sections(threading.local):
    """Per thread: how deep in a BagWriter section it is, and a signal's exception deferred
    to the section's end (only the main thread, where Python runs signal handlers, defers)."""

    depth = 0
    pending: BaseException | None = None


_SECTIONS = _Sections()


def _uninterruptible(method: Any) -> Any:
    """A BagWriter method that a SIGTERM/SIGINT of :func:`close_bags_on_sigterm` does not cut
    in half: the signal's exception is raised when the outermost such method returns (an
    exception raised half-way through writing a chunk left a bag whose summary counted
    messages the file did not hold)."""
    @functools.wraps(method)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        state = _SECTIONS
        state.depth += 1
        try:
            return method(*args, **kwargs)
        finally:
            state.depth -= 1
            if state.depth == 0 and state.pending is not None:
                pending, state.pending = state.pending, None
                raise pending
    return wrapper


class BagWriter:
    """Write a rosbag2 bag folder incrementally, split into several files like rosbag2.

    >>> with BagWriter('out/run1') as bag:
    ...     bag.add_topic('/force_plate/wrench', 'geometry_msgs/msg/WrenchStamped')
    ...     bag.write('/force_plate/wrench', msg, log_time_ns=t_ns)

    ``topics_qos`` maps topic -> offered QoS (an :class:`OfferedQos`, a v9 dict, an rclpy
    ``QoSProfile`` or a list of these) used when the topic is added without one; topics with
    no QoS anywhere get :data:`~nmt_ros.io.qos.OBSERVATION_QOS` (reliable, keep_last 1000).
    ``write`` accepts rclpy messages (serialised with ``rclpy.serialization``) or CDR bytes;
    with a message object an unknown topic is added automatically. Not thread-safe: write
    from one thread (:class:`nmt_ros.io.background_writer.BackgroundBagWriter` gives a
    recorder a writer thread with a bounded queue).

    Splitting (rosbag2's ``--max-bag-size`` / ``--max-bag-duration``): before a message is
    written, the current file is finished and ``<name>_<i+1>.mcap`` begun if it already holds
    messages and either its size on disk reached ``max_bag_size`` bytes or the message's log
    time is more than ``max_bag_duration_s`` after the file's first message (0 = no limit).
    The size counts the chunks already written, so a file may exceed the limit by up to one
    chunk (``chunk_size``). Every file is a complete MCAP with all schemas and channels known
    when it began (and those added later) and its own ``rosbag2`` record; ``metadata.yaml``
    lists them all.
    """

    def __init__(self, path: str | os.PathLike, topics_qos: Mapping[str, Any] | None = None,
                 *, compression: str = 'zstd', chunk_size: int = 512 * 1024,
                 flush_period_s: float | None = 1.0, ros_distro: str = ROS_DISTRO,
                 custom_data: Mapping[str, str] | None = None, fsync: bool = False,
                 max_bag_size: int = 0, max_bag_duration_s: float = 0.0) -> None:
        self.path = Path(path)
        if compression not in _COMPRESSION:
            raise ValueError(f'compression must be one of zstd, lz4, none; got {compression!r}')
        if max_bag_size < 0 or max_bag_duration_s < 0:
            raise ValueError(f'max_bag_size ({max_bag_size} B) and max_bag_duration_s '
                             f'({max_bag_duration_s} s) must be >= 0 (0 = no splitting)')
        if self.path.exists() and (not self.path.is_dir() or any(self.path.iterdir())):
            raise FileExistsError(f'bag path {self.path} already exists and is not empty; '
                                  'refusing to overwrite')
        self.path.mkdir(parents=True, exist_ok=True)
        self._name = self.path.resolve().name
        self._compression = _COMPRESSION[compression]
        self._chunk_size = int(chunk_size)
        self._topics_qos = dict(topics_qos or {})
        self._ros_distro = ros_distro
        self._custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self._flush_period = flush_period_s
        self._fsync = fsync
        self.max_bag_size = int(max_bag_size)
        self._max_duration_ns = int(round(max_bag_duration_s * 1e9))
        self._schema_texts: dict[str, bytes] = {}
        self._topics: dict[str, TopicInfo] = {}
        self._counts: dict[str, int] = {}
        self._start: int | None = None
        self._end: int | None = None
        self._files: list[FileInfo] = []   # finished files
        self._closed = False
        self._info: BagInfo | None = None
        self._open_file(0)

    # -- files
    @property
    def file_name(self) -> str:
        """Name of the file being written (``<name>_<index>.mcap``)."""
        return self._file_name

    @property
    def mcap_path(self) -> Path:
        return self.path / self._file_name

    @property
    def file_names(self) -> tuple[str, ...]:
        """Every file of the bag so far, the current one last."""
        return tuple(f.path for f in self._files) + (self._file_name,)

    def _open_file(self, index: int) -> None:
        self._file_name = f'{self._name}_{index}.mcap'
        self._stream = open(self.path / self._file_name, 'xb')  # noqa: SIM115 (closed later)
        self._writer = Writer(self._stream, chunk_size=self._chunk_size,
                              compression=self._compression)
        self._writer.start(profile=PROFILE, library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        for topic in self._topics.values():
            self._register(topic)
        self._file_start: int | None = None
        self._file_end: int | None = None
        self._file_count = 0
        self._writer.add_metadata('rosbag2', {
            'serialized_metadata': _dump_yaml(metadata_dict(self._snapshot()))})
        self._next_flush = time.monotonic() + (self._flush_period or 0.0)
        self.flush()

    def _current_file_info(self) -> FileInfo:
        start = self._file_start or 0
        end = self._file_end if self._file_end is not None else start
        return FileInfo(self._file_name, start, end - start, self._file_count)

    def _finish_file(self) -> None:
        self._writer.add_metadata('rosbag2', {
            'serialized_metadata': _dump_yaml(metadata_dict(self._snapshot()))})
        self._writer.finish()
        self._stream.close()

    @_uninterruptible
    def split(self) -> None:
        """Finish the current file and continue in the next (``<name>_<i+1>.mcap``)."""
        self._check_open()
        self._finish_file()
        self._files.append(self._current_file_info())
        self._open_file(len(self._files))

    def _should_split(self, log_time_ns: int) -> bool:
        if self._file_count == 0:
            return False
        if self.max_bag_size and self._stream.tell() >= self.max_bag_size:
            return True
        return bool(self._max_duration_ns) and (
            log_time_ns - self._file_start > self._max_duration_ns)

    # -- topics
    def _register(self, topic: TopicInfo) -> None:
        """Schema (once per type) and channel of ``topic`` in the current file."""
        if topic.type not in self._schemas:
            self._schemas[topic.type] = self._writer.register_schema(
                name=topic.type, encoding='ros2msg', data=self._schema_texts[topic.type])
        self._channels[topic.name] = self._writer.register_channel(
            topic=topic.name, message_encoding='cdr', schema_id=self._schemas[topic.type],
            metadata={'offered_qos_profiles': qos_list_to_yaml(topic.offered_qos),
                      'topic_type_hash': topic.type_hash})

    @_uninterruptible
    def add_topic(self, topic: str, msgtype: str, qos: Any = None, *,
                  type_hash: str | None = None) -> None:
        """Declare a topic (type ``pkg/msg/Type``, offered QoS); idempotent for equal args."""
        self._check_open()
        msgtype = msgdefs.normalize_type_name(msgtype)
        if qos is None:
            qos = self._topics_qos.get(topic, OBSERVATION_QOS)
        offered = as_qos_list(qos)
        if topic in self._topics:
            if self._topics[topic].type != msgtype:
                raise ValueError(f'topic {topic} already added with type '
                                 f'{self._topics[topic].type}, not {msgtype}')
            return
        if msgtype not in self._schema_texts:
            self._schema_texts[msgtype] = msgdefs.full_definition(msgtype).encode('utf-8')
        thash = msgdefs.type_hash(msgtype) if type_hash is None else type_hash
        info = TopicInfo(name=topic, type=msgtype, offered_qos=offered, type_hash=thash)
        self._register(info)
        self._topics[topic] = info
        self._counts[topic] = 0

    @property
    def topics(self) -> tuple[TopicInfo, ...]:
        return tuple(replace(t, message_count=self._counts[t.name])
                     for t in self._topics.values())

    @property
    def message_count(self) -> int:
        """Messages written so far (all files)."""
        return sum(self._counts.values())

    # -- messages
    @_uninterruptible
    def write(self, topic: str, msg: Any, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Append one message (rclpy message or CDR ``bytes``) with its times in ns."""
        self._check_open()
        if topic not in self._channels:
            if isinstance(msg, bytes | bytearray | memoryview):
                raise KeyError(f'topic {topic} not added; call add_topic() before writing bytes')
            self.add_topic(topic, msgdefs.message_type_name(msg))
        if isinstance(msg, bytes | bytearray | memoryview):
            data = bytes(msg)
        else:
            from rclpy.serialization import serialize_message
            # rclpy leaves CDR padding as garbage: zeroed, the same data are the same file
            data = zero_padding(serialize_message(msg), msgdefs.message_type_name(msg))
        log_time_ns = int(log_time_ns)
        if self._should_split(log_time_ns):
            self.split()
        publish = log_time_ns if publish_time_ns is None else int(publish_time_ns)
        self._writer.add_message(channel_id=self._channels[topic], log_time=log_time_ns,
                                 data=data, publish_time=publish, sequence=0)
        self._counts[topic] += 1
        self._file_count += 1
        if self._file_start is None or log_time_ns < self._file_start:
            self._file_start = log_time_ns
        if self._file_end is None or log_time_ns > self._file_end:
            self._file_end = log_time_ns
        if self._start is None or log_time_ns < self._start:
            self._start = log_time_ns
        if self._end is None or log_time_ns > self._end:
            self._end = log_time_ns
        if self._flush_period is not None and time.monotonic() >= self._next_flush:
            self.flush()

    @_uninterruptible
    def flush(self) -> None:
        """Close the open chunk and hand everything written so far to the OS."""
        self._check_open()
        self._writer.flush()
        if self._fsync:
            os.fsync(self._stream.fileno())
        if self._flush_period is not None:
            self._next_flush = time.monotonic() + self._flush_period

    # -- closing
    def _snapshot(self) -> BagInfo:
        start = self._start or 0
        duration = (self._end - start) if self._end is not None else 0
        files = tuple(self._files) + (self._current_file_info(),)
        return BagInfo(
            path=self.path, relative_file_paths=tuple(f.path for f in files), files=files,
            bag_size=0, start_ns=start, duration_ns=duration, message_count=self.message_count,
            topics=self.topics, ros_distro=self._ros_distro, custom_data=self._custom_data)

    @_uninterruptible
    def close(self) -> BagInfo:
        """Finish the MCAP file (summary, statistics) and write ``metadata.yaml``; idempotent."""
        if self._closed:
            assert self._info is not None
            return self._info
        info = self._snapshot()
        self._finish_file()
        self._closed = True
        write_metadata_yaml(self.path, info)
        self._info = replace(info, bag_size=_directory_size(self.path))
        return self._info

    def _check_open(self) -> None:
        if self._closed:
            raise BagError(f'bag {self.path} is closed')

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def close_bags_on_sigterm() -> None:
    """Make SIGTERM raise ``SystemExit(143)`` (and SIGINT ``KeyboardInterrupt``) so
    ``with BagWriter(...)`` blocks and ``finally`` clauses run and the bag is finalised (call
    from the main thread of a recording process). A signal that arrives while the main thread
    is inside a BagWriter method takes effect when that method returns, so no chunk is left
    half written."""
    def _handler(signum: int, _frame: object) -> None:
        exc: BaseException = (KeyboardInterrupt() if signum == signal.SIGINT
                              else SystemExit(128 + signum))
        if _SECTIONS.depth:
            _SECTIONS.pending = exc
        else:
            raise exc

    signal.signal(signal.SIGTERM, _handler)
    signal.signal(signal.SIGINT, _handler)


# --------------------------------------------------------------------------- reading

def _file_sort_key(path: Path) -> tuple[int, str]:
    match = re.search(r'_(\d+)\.mcap$', path.name)
    return (int(match.group(1)) if match else 1 << 30, path.name)


def storage_files(path: str | os.PathLike) -> list[Path]:
    """The MCAP files of a bag folder (from metadata.yaml, else ``*.mcap``) or a bare file."""
    path = Path(path)
    if not path.exists():
        raise BagError(f'bag path {path} does not exist')
    if path.is_file():
        return [path]
    # Without metadata.yaml (an interrupted recording, which `reindex` repairs) the folder's
    # MCAP files are the bag, in rosbag2's split order (<name>_0.mcap, <name>_1.mcap, ...).
    if (path / METADATA_FILENAME).is_file():
        info = read_metadata_yaml(path)
        files = [path / Path(p).name for p in info.relative_file_paths]
        missing = [str(f) for f in files if not f.is_file()]
        if missing:
            raise BagError(f'bag {path}: files listed in metadata.yaml are missing: {missing}')
        return files
    files = sorted(path.glob('*.mcap'), key=_file_sort_key)
    if not files:
        raise BagError(f'no metadata.yaml and no .mcap file in {path}')
    return files


def _incomplete(path: Path, exc: BaseException) -> BagError:
    return BagError(
        f'{path} is not a complete MCAP file ({exc.__class__.__name__}: {exc}); if a recording '
        f'was interrupted, repair it with `nmt bag reindex {path.parent}` '
        '(nmt_ros.io.bags.reindex)')


@dataclass
class _FileSummary:
    path: Path
    size: int
    start_ns: int
    end_ns: int
    message_count: int
    topics: list[TopicInfo]
    ros_distro: str
    custom_data: dict[str, str]


def _read_file_summary(path: Path) -> _FileSummary:
    with open(path, 'rb') as stream:
        try:
            reader = make_reader(stream)
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                raise McapError('no summary/statistics section')
            records = [m for m in reader.iter_metadata() if m.name == 'rosbag2']
        except (McapError, struct.error, ValueError, EOFError) as exc:
            raise _incomplete(path, exc) from None
    stats = summary.statistics
    topics: dict[str, TopicInfo] = {}
    for cid, channel in summary.channels.items():
        schema = summary.schemas.get(channel.schema_id)
        count = int(stats.channel_message_counts.get(cid, 0))
        if channel.topic in topics:
            t = topics[channel.topic]
            topics[channel.topic] = replace(t, message_count=t.message_count + count)
            continue
        # Channel metadata is optional in MCAP (writers other than rosbag2 may leave it out):
        # no QoS and no type hash then. Present but unreadable is an error.
        meta = channel.metadata or {}
        try:
            offered = parse_qos_list(meta.get('offered_qos_profiles'))
        except (yaml.YAMLError, TypeError, ValueError, AttributeError) as exc:
            raise BagError(f'{path}: topic {channel.topic}: unreadable offered_qos_profiles '
                           f'in the channel metadata ({exc!r})') from None
        topics[channel.topic] = TopicInfo(
            name=channel.topic, type=schema.name if schema else '',
            serialization_format=channel.message_encoding, offered_qos=offered,
            type_hash=meta.get('topic_type_hash', ''), message_count=count)
    ros_distro, custom = '', {}
    if records:
        # rosbag2 writes the record with ``serialized_metadata`` (the bag metadata as YAML)
        # and ``ROS_DISTRO``; older rosbag2 versions wrote only the distro, so an absent or
        # empty ``serialized_metadata`` means "no custom data", a malformed one is an error.
        meta = records[-1].metadata
        try:
            parsed = yaml.safe_load(meta.get('serialized_metadata', '')) or {}
        except yaml.YAMLError as exc:
            raise BagError(f'{path}: unreadable serialized_metadata in the rosbag2 metadata '
                           f'record ({exc!r})') from None
        ros_distro = str(parsed.get('ros_distro') or meta.get('ROS_DISTRO', '') or '')
        custom = {str(k): str(v) for k, v in (parsed.get('custom_data') or {}).items()}
    start, end = int(stats.message_start_time), int(stats.message_end_time)
    if stats.message_count == 0:
        start = end = 0
    return _FileSummary(path=path, size=path.stat().st_size, start_ns=start, end_ns=end,
                        message_count=int(stats.message_count), topics=list(topics.values()),
                        ros_distro=ros_distro, custom_data=custom)


def _info_from_files(path: Path, files: Sequence[Path], relative: Sequence[str],
                     bag_size: int) -> BagInfo:
    summaries = [_read_file_summary(f) for f in files]
    topics: dict[str, TopicInfo] = {}
    for s in summaries:
        for t in s.topics:
            if t.name in topics:
                old = topics[t.name]
                topics[t.name] = replace(old, message_count=old.message_count + t.message_count)
            else:
                topics[t.name] = t
    nonempty = [s for s in summaries if s.message_count]
    start = min((s.start_ns for s in nonempty), default=0)
    end = max((s.end_ns for s in nonempty), default=0)
    return BagInfo(
        path=path, relative_file_paths=tuple(relative),
        files=tuple(FileInfo(r, s.start_ns, s.end_ns - s.start_ns, s.message_count)
                    for r, s in zip(relative, summaries)),
        bag_size=bag_size, start_ns=start, duration_ns=end - start,
        message_count=sum(s.message_count for s in summaries), topics=tuple(topics.values()),
        ros_distro=next((s.ros_distro for s in summaries if s.ros_distro), ''),
        custom_data=next((s.custom_data for s in summaries if s.custom_data), {}))


def bag_info(path: str | os.PathLike) -> BagInfo:
    """Metadata of a bag folder (from ``metadata.yaml``) or of a bare ``.mcap`` file (from its
    summary and ``rosbag2`` record), as ``ros2 bag info`` obtains it."""
    path = Path(path)
    if not path.exists():
        raise BagError(f'Bag path {path} does not exist.')
    if path.is_dir():
        if (path / METADATA_FILENAME).is_file():
            return read_metadata_yaml(path)
        raise BagError(f'Could not find metadata in bag directory {path} (interrupted '
                       f'recording? `nmt bag reindex {path}` rebuilds it)')
    return _info_from_files(path, [path], [str(path)], path.stat().st_size)


def read_raw(path: str | os.PathLike,
             topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
    """Serialised messages of a bag (folder or ``.mcap``) in log-time order per file."""
    wanted = None if topics is None else list(topics)
    for file in storage_files(path):
        with open(file, 'rb') as stream:
            reader = make_reader(stream)
            try:
                summary = reader.get_summary()
                if summary is None:
                    raise McapError('no summary section')
            except (McapError, struct.error, ValueError, EOFError) as exc:
                raise _incomplete(file, exc) from None
            for schema, channel, message in reader.iter_messages(
                    topics=wanted, log_time_order=True):
                yield RawMessage(channel.topic, schema.name if schema else '',
                                 message.log_time, message.publish_time, message.data)


def read_bag(path: str | os.PathLike,
             topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Messages of a bag as ``(topic, msgtype, log_time_ns, rclpy message)``."""
    from rclpy.serialization import deserialize_message
    for raw in read_raw(path, topics):
        msg = deserialize_message(raw.data, msgdefs.get_message_class(raw.msgtype))
        yield BagMessage(raw.topic, raw.msgtype, raw.log_time_ns, msg)


def read_arrays(path: str | os.PathLike, topic: str) -> JointStateSeries | WrenchSeries:
    """All messages of one JointState or WrenchStamped topic as stacked arrays.

    Decoding is vectorised over messages that share a layout (``msg_adapters.cdr_arrays``).
    """
    return read_topics_arrays(path, [topic])[topic]


def read_topics_arrays(path: str | os.PathLike, names: Sequence[str]
                       ) -> dict[str, JointStateSeries | WrenchSeries]:
    """:func:`read_arrays` of several topics in one pass over the bag (each chunk is read and
    decompressed once, whatever the number of topics)."""
    names = list(dict.fromkeys(names))
    blobs: dict[str, list[bytes]] = {n: [] for n in names}
    log_times: dict[str, list[int]] = {n: [] for n in names}
    types: dict[str, str] = {}
    for raw in read_raw(path, names):
        types[raw.topic] = raw.msgtype
        blobs[raw.topic].append(raw.data)
        log_times[raw.topic].append(raw.log_time_ns)
    missing = [n for n in names if n not in types]
    if missing:
        files = storage_files(path)
        known = {t.name: t.type for f in files for t in _read_file_summary(f).topics}
        for n in missing:
            if n not in known:
                raise KeyError(f'topic {n!r} not in bag {path} (topics: {sorted(known)})')
            types[n] = known[n]
    out: dict[str, JointStateSeries | WrenchSeries] = {}
    for n in names:
        log = np.asarray(log_times[n], dtype=np.int64)
        if types[n] == 'sensor_msgs/msg/JointState':
            out[n] = decode_joint_states(blobs[n], log)
        elif types[n] == 'geometry_msgs/msg/WrenchStamped':
            out[n] = decode_wrenches(blobs[n], log)
        else:
            raise ValueError(f'read_arrays supports sensor_msgs/msg/JointState and '
                             f'geometry_msgs/msg/WrenchStamped; {n} is {types[n]}')
    return out


# --------------------------------------------------------------------------- repair

def _is_complete_mcap(path: Path) -> bool:
    try:
        _read_file_summary(path)
        return True
    except BagError:
        return False


def _complete_prefix(data: bytes) -> int:
    """Length of the leading part of ``data`` made of whole top-level MCAP records."""
    if data[:8] != MCAP_MAGIC:
        raise BagError('not an MCAP file (bad magic)')
    pos = 8
    while pos + 9 <= len(data):
        opcode = data[pos]
        (length,) = struct.unpack_from('<Q', data, pos + 1)
        end = pos + 9 + length
        if opcode == 0 or end > len(data):
            break
        pos = end
        if opcode in (0x0F, 0x02):  # DataEnd, Footer: the data section is over
            break
    return pos


def _salvage(path: Path, compression: str) -> int:
    """Rewrite an interrupted MCAP from its complete records; returns messages kept."""
    data = path.read_bytes()
    prefix = data[:_complete_prefix(data)]
    tmp = path.with_name(path.name + '.reindex.tmp')
    kept = 0
    with open(tmp, 'wb') as out:
        writer = Writer(out, compression=_COMPRESSION[compression])
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        started = False
        last_rosbag2: dict[str, str] | None = None
        reader = StreamReader(io.BytesIO(prefix), validate_crcs=True)
        try:
            for record in reader.records:
                if isinstance(record, Header):
                    writer.start(profile=record.profile or PROFILE, library=record.library)
                    started = True
                elif isinstance(record, Schema) and record.id not in schema_ids:
                    schema_ids[record.id] = writer.register_schema(
                        record.name, record.encoding, record.data)
                elif isinstance(record, Channel) and record.id not in channel_ids:
                    channel_ids[record.id] = writer.register_channel(
                        record.topic, record.message_encoding,
                        schema_ids.get(record.schema_id, 0), dict(record.metadata))
                elif isinstance(record, Message) and record.channel_id in channel_ids:
                    writer.add_message(channel_ids[record.channel_id], record.log_time,
                                       record.data, record.publish_time, record.sequence)
                    kept += 1
                elif isinstance(record, Metadata):
                    if record.name == 'rosbag2':
                        last_rosbag2 = dict(record.metadata)
                    else:
                        writer.add_metadata(record.name, dict(record.metadata))
        except Exception:  # noqa: BLE001 - deliberate: see below
            # The salvage keeps every record read before the first damaged one and drops the
            # rest, as `ros2 bag reindex` does: which exception the reader raises depends on
            # the damage (CRC mismatch, a codec error inside a chunk, a short read), so all
            # of them end the loop. The loss is reported by the message count (kept).
            pass
        if not started:
            writer.start(profile=PROFILE, library=LIBRARY)
        if last_rosbag2 is not None:
            writer.add_metadata('rosbag2', last_rosbag2)
        writer.finish()
    os.replace(tmp, path)
    return kept


def reindex(path: str | os.PathLike, *, compression: str = 'zstd') -> BagInfo:
    """Repair a bag after an interrupted recording (like ``ros2 bag reindex``).

    Every MCAP file without a valid summary is rewritten from its complete chunks (messages
    in the unfinished last chunk are lost); then ``metadata.yaml`` is regenerated from the
    files. Works on a bag folder or a single ``.mcap``; complete bags are left as they are
    apart from a fresh ``metadata.yaml``. Returns the repaired bag's info.
    """
    path = Path(path)
    if not path.exists():
        raise BagError(f'bag path {path} does not exist')
    files = [path] if path.is_file() else sorted(path.glob('*.mcap'), key=_file_sort_key)
    if not files:
        raise BagError(f'no .mcap file in {path}')
    for file in files:
        if not _is_complete_mcap(file):
            _salvage(file, compression)
    if path.is_file():
        return _info_from_files(path, files, [str(path)], path.stat().st_size)
    info = _info_from_files(path, files, [f.name for f in files], 0)
    if not info.ros_distro:
        # The rosbag2 record (which names the distro) went with the damaged tail, and
        # metadata.yaml needs one: the distro this package records with (Jazzy).
        info = replace(info, ros_distro=ROS_DISTRO)
    write_metadata_yaml(path, info)
    return replace(info, bag_size=_directory_size(path))
