"""End of stream: how a producer says it is done and a consumer knows it has everything.

A producer announces ``state = finished`` on ``/nmt/status`` with the number of messages it
published per topic and the stamp of the first (:func:`end_of_stream_values`); a consumer
flushes once it has seen that many (:class:`EndOfStream`, kept per trial by
:class:`TrialBook`). Topics are independent DDS writers, so the announcement may overtake the
last data messages: counting, not ordering, decides. ROS-free.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping

#: DiagnosticStatus names end with these suffixes (``<node>: <part>``).
STREAM_PART = 'stream'
FINISHED = 'finished'
COUNT_PREFIX = 'count.'
FIRST_PREFIX = 'first_stamp.'


def end_of_stream_values(counts: Mapping[str, int],
                         first_stamps: Mapping[str, int] | None = None,
                         **extra: object) -> dict[str, object]:
    """Key/values announcing that the producer published ``counts[topic]`` messages, the
    first of them stamped ``first_stamps[topic]`` (which identifies the trial)."""
    values: dict[str, object] = {'state': FINISHED}
    values.update({COUNT_PREFIX + topic: int(n) for topic, n in counts.items()})
    values.update({FIRST_PREFIX + topic: int(n) for topic, n in (first_stamps or {}).items()})
    values.update(extra)
    return values


def parse_end_of_stream(values: Mapping[str, str],
                        ) -> dict[str, tuple[int, int | None]] | None:
    """topic -> (count, first stamp or None) from a status record's values (None if not an
    end-of-stream record)."""
    if values.get('state') != FINISHED:
        return None
    out = {}
    for key, value in values.items():
        if not key.startswith(COUNT_PREFIX):
            continue
        topic = key[len(COUNT_PREFIX):]
        try:
            first = values.get(FIRST_PREFIX + topic)
            out[topic] = (int(value), None if first is None else int(first))
        except (TypeError, ValueError):
            continue
    return out


class EndOfStream:
    """Has a consumer seen everything its producers announced (for the current trial)?

    An announcement names, per topic, how many messages were published and the stamp of the
    first one. Only announcements whose first stamp matches the first message the consumer
    received on that topic count, so a stale announcement (an earlier trial, delivered late
    or replayed from a transient-local history) never ends the current trial.
    """

    def __init__(self, topics: Iterable[str]) -> None:
        self.topics = tuple(topics)
        self.announced: dict[str, tuple[int, int | None, float]] = {}

    def reset(self) -> None:
        self.announced = {}

    def announce(self, counts: Mapping[str, tuple[int, int | None]], now: float) -> bool:
        """Record an announcement; True if it concerns one of our topics."""
        mine = {t: v for t, v in counts.items() if t in self.topics}
        for topic, (n, first) in mine.items():
            self.announced[topic] = (n, first, now)
        return bool(mine)

    def _valid(self, first_seen: Mapping[str, int]) -> dict[str, tuple[int, float]]:
        out = {}
        for topic, (n, first, at) in self.announced.items():
            if first is not None and topic in first_seen and first_seen[topic] != first:
                continue  # another trial
            if first is not None and topic not in first_seen:
                continue  # nothing of that trial received yet
            out[topic] = (n, at)
        return out

    def announced_at(self, first_seen: Mapping[str, int]) -> float | None:
        valid = self._valid(first_seen)
        return min((at for _, at in valid.values()), default=None)

    def complete(self, seen: Mapping[str, int], first_seen: Mapping[str, int]) -> bool:
        """Every validly announced topic seen in full (and at least one announced)."""
        valid = self._valid(first_seen)
        return bool(valid) and all(seen.get(t, 0) >= n for t, (n, _) in valid.items())

    def missing(self, seen: Mapping[str, int], first_seen: Mapping[str, int]) -> dict[str, int]:
        return {t: n - seen.get(t, 0) for t, (n, _) in self._valid(first_seen).items()
                if seen.get(t, 0) < n}


class TrialBook:
    """Per-trial book-keeping of a tracker for the end-of-stream protocol.

    Inputs seen (every message received, accepted or not, with the stamp of the first),
    outputs published (count and first stamp, for our own announcement) and the producers'
    announcements. ``verdict`` says when the trial is over: every announced message received,
    or ``timeout_s`` after a valid announcement with messages still missing.
    """

    def __init__(self, inputs: Iterable[str]) -> None:
        self.end = EndOfStream(inputs)
        self.trial = 0
        self.active = False
        self.seen: dict[str, int] = {}
        self.first_seen: dict[str, int] = {}
        self.published: dict[str, int] = {}
        self.first_published: dict[str, int] = {}

    def saw(self, topic: str, stamp_ns: int | None) -> None:
        """One message of ``topic`` received (``stamp_ns`` None: its stamp unreadable)."""
        self.seen[topic] = self.seen.get(topic, 0) + 1
        if stamp_ns is not None:
            self.first_seen.setdefault(topic, int(stamp_ns))

    def start(self) -> int:
        self.trial += 1
        self.active = True
        self.published = {}
        self.first_published = {}
        return self.trial

    def output(self, topic: str, first_stamp_ns: int, n: int) -> None:
        self.published[topic] = self.published.get(topic, 0) + int(n)
        self.first_published.setdefault(topic, int(first_stamp_ns))

    def announcement(self, values: Mapping[str, str], now: float) -> bool:
        counts = parse_end_of_stream(values)
        return bool(counts) and self.end.announce(counts, now)

    def verdict(self, now: float, timeout_s: float) -> str | None:
        """None (go on), or why the trial ends now."""
        if not self.active:
            return None
        if self.end.complete(self.seen, self.first_seen):
            return 'end of stream announced and every message received'
        at = self.end.announced_at(self.first_seen)
        if at is not None and now - at > timeout_s:
            missing = self.end.missing(self.seen, self.first_seen)
            return (f'end of stream announced but messages still missing after '
                    f'{timeout_s:g} s: {missing}')
        return None

    def finish(self, more_follows: bool = False) -> tuple[dict[str, int], dict[str, int]]:
        """End the trial: (published counts, first stamps) for the announcement.

        ``more_follows``: the trial ends inside one producer stream (a gap in the input) and
        the next starts at once; the inputs seen and the announcements received stay, so that
        the producers' end of stream (counted from their first message) still ends the last
        trial instead of an idle timeout."""
        out = (dict(self.published), dict(self.first_published))
        self.active = False
        if not more_follows:
            self.seen = {}
            self.first_seen = {}
            self.end.reset()
        return out
