"""Time series of the two observation message types as stacked numpy arrays.

These containers are what ``nmt_ros.io.bags.read_arrays`` returns and what the batch helpers
of ``msg_adapters`` produce and consume. Stamps are integer nanoseconds (``header.stamp``);
``log_time_ns`` is the bag's receive time when the series was read from a bag.

JointState arrays that a message leaves empty are NaN-filled here, so every field is always
``[n, k]``: NaN means "not provided" (see ``msg_adapters.joint_state``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class JointStateSeries:
    """``n`` JointState samples of the same ``k`` named joints."""

    stamp_ns: np.ndarray          # [n] int64, header stamps
    names: tuple[str, ...]        # [k]
    position: np.ndarray          # [n, k] float64 (NaN where not provided)
    velocity: np.ndarray          # [n, k]
    effort: np.ndarray            # [n, k]
    frame_id: str = ''
    log_time_ns: np.ndarray | None = None  # [n] int64, bag log (receive) time

    def __len__(self) -> int:
        return int(self.stamp_ns.shape[0])

    @property
    def t(self) -> np.ndarray:
        """Header stamps in seconds (float64)."""
        return self.stamp_ns * 1e-9

    def column(self, name: str, field: str = 'position') -> np.ndarray:
        """One joint's samples ``[n]`` of ``field`` ('position', 'velocity' or 'effort')."""
        try:
            j = self.names.index(name)
        except ValueError:
            raise KeyError(f'no joint {name!r} in {list(self.names)}') from None
        return getattr(self, field)[:, j]


@dataclass(frozen=True)
class WrenchSeries:
    """``n`` WrenchStamped samples of one frame."""

    stamp_ns: np.ndarray          # [n] int64
    frame_id: str
    force: np.ndarray             # [n, 3] float64 (x, y, z) [N]
    torque: np.ndarray            # [n, 3] float64 (x, y, z) [N m]
    log_time_ns: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.stamp_ns.shape[0])

    @property
    def t(self) -> np.ndarray:
        """Header stamps in seconds (float64)."""
        return self.stamp_ns * 1e-9


@dataclass(frozen=True)
class CheckedBlock:
    """``n`` messages of one topic read at once (a live node's batch), each checked as one
    message alone would be: what it carried, or why it is refused.

    ``values`` holds the columns the reader asked for (NaN rows where refused); ``errors[i]``
    is None for an accepted message, else the reason (the ``ValueError`` text the
    single-message adapter gives); ``stamped[i]`` says whether the header stamp could be
    read at all (False only for a message too short to hold one: ``stamp_ns`` is 0 there).
    """

    stamp_ns: np.ndarray               # [n] int64 header stamps
    values: np.ndarray                 # [n, k] float64
    errors: tuple[str | None, ...]     # [n]
    stamped: np.ndarray                # [n] bool

    def __len__(self) -> int:
        return int(self.stamp_ns.shape[0])
