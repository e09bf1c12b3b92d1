"""Stage 2 streaming: feed samples as they arrive, get the outputs of every window whose
look-ahead is complete.

Window k (start t_k) is planned as soon as samples up to t_k + H are in; its output covers
[t_k, t_k + stride) on the internal grid. The state (``StreamState``) is explicit: the
reference rows still needed, the muscle state and the next window start. The batch windowed
mode runs the same plans and forward pass on the whole recording and equals ``push`` fed it in
chunks (tested).

The grid of a stream has the nominal step of ``start_stream`` (not one estimated from the
samples of each push), and ``samples_for_next_window`` says where the next window's data end:
a caller that pushes exactly up to there (``nmt_ros.tracking.streaming.Stage2Stream``) makes
the same computations in the same pieces however its input arrived, so its output is a
function of the input samples alone (bit for bit).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from nmt_ros.tracking.stage2.forward_pass import initial_state
from nmt_ros.tracking.stage2.plans import WindowPlanner
from nmt_ros.tracking.stage2.receding_horizon import run_windows
from nmt_ros.tracking.stage2.references import ReferenceBuilder, Stage2Reference, trim
from nmt_ros.tracking.stage2.results import MuscleState, Stage2Step


@dataclass(frozen=True)
class StreamState:
    """Explicit state of a streaming tracker: samples kept, muscles, next window start."""

    a0: np.ndarray
    substeps: int = 1
    reference: Stage2Reference | None = None
    muscle: MuscleState | None = None
    next_start: int = 0
    dt: float | None = None      # s, the nominal input step (None: from the samples)


def start_stream(references: ReferenceBuilder, a0: np.ndarray, dt: float) -> StreamState:
    """A fresh streaming state: initial activations a0 [m], input sample period dt [s]."""
    return StreamState(a0=np.asarray(a0, dtype=float), substeps=references.substeps_for(dt),
                       dt=float(dt))


def samples_for_next_window(stream: StreamState, length: int) -> int:
    """Input samples (counted from the stream's first) the reference must hold before the
    next window, ``length`` internal intervals from its start, can be planned."""
    return -(-(stream.next_start + length) // stream.substeps) + 1


def push(references: ReferenceBuilder, planner: WindowPlanner, stream: StreamState,
         t: np.ndarray, tau_ref: np.ndarray, theta: np.ndarray, theta_dot: np.ndarray,
         theta_ddot: np.ndarray, final: bool = False, window_length: float | None = None,
         window_stride: float | None = None) -> tuple[StreamState, list[Stage2Step]]:
    """Feed new input samples; returns the new state and the outputs now computable.

    t [k] s; tau_ref [k, 3] N m; theta, theta_dot, theta_ddot [k, 3] (rad, rad/s, rad/s^2).
    ``final``: no more samples (the last windows end at the last sample). Window length and
    stride in s (default: the settings').
    """
    ref = references.extend(stream.reference, t, tau_ref, theta, theta_dot, theta_ddot,
                            substeps=stream.substeps, dt=stream.dt)
    muscle = stream.muscle if stream.muscle is not None else initial_state(ref, stream.a0)
    steps: list[Stage2Step] = []
    next_start = stream.next_start
    if ref.n >= 2:
        length, stride = planner.window_samples(ref, window_length, window_stride)
        last_start = ref.end - (1 if final else length)
        starts = np.arange(stream.next_start, last_start + 1, stride)
        muscle, steps, _ = run_windows(planner, ref, muscle, starts, length, stride,
                                       final=final)
        if starts.size:
            next_start = int(starts[-1] + stride)
        ref = trim(ref, next_start)
    return replace(stream, reference=ref, muscle=muscle, next_start=next_start), steps
