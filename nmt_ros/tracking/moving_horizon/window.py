"""The sliding window: spline control points, their data, Gauss-Newton steps, marginalisation.

The window holds the control points of segments [first, first + n_seg) of the knot grid
(control points first..first + n_seg + 2), the force plate's error parameters, the samples
that fall in those segments, and the arrival cost (``normal_equations.Prior``) that
summarises everything marginalised before.

Linearisations are kept per segment (its Gauss-Newton block H, g, cost and the point z it was
taken at, in arrays indexed by segment modulo a capacity). A step re-linearises only the
segments asked for (the newest, where data just arrived, and a few older ones in turn) and
uses the others' kept blocks as a quadratic model around their own points (first-order
consistent, exact for the linear parts); the step is kept only if it lowers that cost.
``drop_before`` marginalises the oldest segments into the prior, and the plate parameters
get the process noise of the time that passed. All arithmetic is in data time: the result is
a function of the samples alone.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from nmt_ros.model.skeleton import JOINT_MAP
from nmt_ros.tracking.moving_horizon.normal_equations import (
    NormalEquations,
    Prior,
    band_form,
    diffuse,
    diffuse_along,
    marginalize,
)
from nmt_ros.tracking.moving_horizon.residuals import LAYOUT, NB, NV, NX
from nmt_ros.tracking.moving_horizon.spline import KnotGrid, evaluate

#: Levenberg damping metric: 1 / (typical step)^2 per variable, a trust region in natural
#: units (0.01 rad, 1 mm, 0.05 of activation, 20 N, 2 N m; plate: 5 N, 1 N m, 1 mm of
#: centre of pressure).
_STEP = np.empty(NV)
_STEP[LAYOUT['q']] = [0.01] * 4 + [0.001] * 2
_STEP[LAYOUT['a']] = 0.05
_STEP[LAYOUT['s']] = [20.0, 20.0, 2.0]
_STEP_PLATE = np.array([5.0, 5.0, 1.0, 0.001])


@dataclass
class Samples:
    """Time-ordered samples of one stream inside the window: t [n] s, y [n, k]."""

    t: np.ndarray
    y: np.ndarray

    @classmethod
    def empty(cls, k: int) -> Samples:
        return cls(np.zeros(0), np.zeros((0, k)))

    def append(self, t: np.ndarray, y: np.ndarray) -> None:
        self.t = np.concatenate([self.t, t])
        self.y = np.concatenate([self.y, y.reshape(len(t), -1)])

    def drop_before(self, t: float) -> None:
        keep = self.t >= t - 1e-12
        self.t, self.y = self.t[keep], self.y[keep]


@dataclass
class Linearisation:
    """Gauss-Newton blocks of some segments: H [S, NB + NX]^2, g = -J'r [S, NB + NX], cost
    1/2 r'r [S], data rows [S, 4] (angle cost, angle rows, wrench cost, wrench rows) and the
    points z [S, NB + NX] they were taken at."""

    segments: np.ndarray
    H: np.ndarray
    g: np.ndarray
    cost: np.ndarray
    rows: np.ndarray
    z: np.ndarray


class SlidingWindow:
    """State of the estimator's window (see the module docstring)."""

    def __init__(self, grid: KnotGrid, first: int, C: np.ndarray, plate: np.ndarray,
                 kernel: object, plate_drift: np.ndarray, capacity: int) -> None:
        self.grid = grid
        self.first = first
        self.C = np.asarray(C, dtype=float).copy()
        self.plate = np.asarray(plate, dtype=float).copy()
        self.kernel = kernel
        self.plate_drift = np.asarray(plate_drift, dtype=float)   # variance per second [NX]
        self.angles = Samples.empty(4)
        self.wrench = Samples.empty(3)
        self.prior: Prior | None = None
        self.arrival_noise: np.ndarray | None = None   # variance per second [NV]
        # plate parameters' reversion time constants [s] (0: a random walk) [NX]
        self.plate_reversion_s = np.zeros(NX)
        # the joints' passive range [rad] (lower [3], upper [3] of ankle, knee, hip: the
        # ligament torques' limits) that extrapolated control points do not leave (None: any)
        self.joint_range: tuple[np.ndarray, np.ndarray] | None = None
        # new control points continue q at this fraction of the curve's end velocity
        # (``extend``)
        self.extrapolation_velocity = 1.0
        # kept linearisations, segment k at position k - base (contiguous for the window;
        # compacted when the buffer's end is reached)
        n = NB + NX
        self.cap = capacity
        size = 2 * capacity
        self.base = first
        self.lin_seg = np.full(size, -1, dtype=np.int64)
        self.lin_H = np.zeros((size, n, n))
        self.lin_band = np.zeros((size, NB, NB))     # upper band form of H[:NB, :NB]
        self.lin_g = np.zeros((size, n))
        self.lin_z = np.zeros((size, n))
        self.lin_cost = np.zeros(size)
        self.lin_rows = np.zeros((size, 4))
        # the last checked step's exact linearisation, kept: (C, plate, what it covers); a
        # step from there needs no re-linearisation of the same segments
        self._fresh: tuple[np.ndarray, np.ndarray, tuple] | None = None
        self._data_version = 0
        self._packed_of: tuple[tuple, tuple] | None = None    # ``_packed``
        # priors relaxed around landings (``prior_relaxation``): the vertical force [N] whose
        # upward crossing is a landing (inf: none), how far [s] around one a segment counts
        # as near it, and the SD multipliers there (wrench 2nd derivative, excitation rate)
        self.landing_load = np.inf
        self.landing_span_s = 0.0
        self.landing_relax = np.ones(2)
        self._landings = np.zeros(0)    # landing times [s] found so far
        # the excitations' rate prior tightened in still stance (``still_segments``): the
        # largest deviation [3] (N, N, N m) of a segment's mean plate reading from the others
        # within ``still_span_s`` (inf: off), and the SD multipliers there
        self.still_band = np.full(3, np.inf)
        self.still_span_s = 0.0
        self.still_relax = np.ones(2)
        self._landings_of: tuple | None = None   # the data they were found in
        # still_segments' answer for every segment of the data, and the data it is of
        self._still_of: tuple | None = None
        self._still_first = 0
        self._still_flags = np.zeros(0, bool)

    # ------------------------------------------------------------------ shape
    @property
    def n_seg(self) -> int:
        return self.C.shape[0] - 3

    @property
    def last(self) -> int:
        """Global index of the last segment."""
        return self.first + self.n_seg - 1

    @property
    def segments(self) -> np.ndarray:
        return np.arange(self.first, self.first + self.n_seg)

    @property
    def t_start(self) -> float:
        return float(self.grid.time(self.first))

    @property
    def t_end(self) -> float:
        return float(self.grid.time(self.first + self.n_seg))

    def points_of(self, segments: np.ndarray, C: np.ndarray, plate: np.ndarray) -> np.ndarray:
        """z [S, NB + NX] of ``segments`` (global): their four control points and the plate."""
        loc = np.asarray(segments) - self.first
        c = C.reshape(-1)[loc[:, None] * NV + np.arange(NB)[None, :]]
        return np.concatenate([c, np.broadcast_to(plate, (c.shape[0], NX))], axis=1)

    def extend(self, last_segment: int) -> None:
        """Append segments up to ``last_segment`` (global): new control points continue q at
        ``extrapolation_velocity`` x the curve's velocity at the window's end (C[-1] -
        C[-3]) / 2 per knot interval, and hold a and s.

        Not at the control polygon's last step C[-1] - C[-2] (the extrapolation until
        2026-12-04): the last control point is the window's least determined (one or two
        mocap samples fix it), and its step from the one before can zigzag while the curve
        itself is smooth. In flight, 0.1 s after a take-off, it had all four angles turning
        11 deg per knot (23 rad/s) where the curve turned at a few rad/s; the extrapolated
        points started that update's linearisation at a cost of 10^8, its Gauss-Newton step
        moved the foot 3 rad and the window lost control - the first failure at 24 of the
        40 re-initialisations of 16 realisations of bags/routine. And shrunk (0.75): the
        newest end's velocity is uncertain, overshooting it costs more than lagging it.
        Measured (python bench/bench_estimator_seeds.py --seeds 1,...,16, this machine,
        against the polygon's step): re-initialisations 2.50 -> 0.19 a minute (40 -> 3,
        13 of 16 realisations without one); with the curve's full velocity 1.25, at half of
        it 0.50 but the estimator's muscle forces 7.8 -> 8.6 % F0 (0.75: 7.8).

        Not at its last acceleration: the window's end is fixed by one or two mocap samples,
        so its curvature is the least certain part of the estimate, and quadratic
        extrapolation amplified it update after update (three new points per update: a foot
        angle went 0, -2, -4, -7 deg, then -11, -20, -30 deg, one Gauss-Newton step could not
        pull it back and the next linearisation, at a 10^10 cost, diverged - in quiet
        stance). Measured on the first 20 s of bags/routine (bench/bench_estimator.py): 12 ->
        10 restarts, refined torques 5.3 / 3.3 / 4.8 -> 3.2 / 2.1 / 4.0 % of peak, muscle
        forces 7.7 -> 6.2 % F0; on 20-60 s, 34 -> 17 restarts. Holding q (zero velocity)
        restarted least (3) but left an Eq. 1 residual the activations absorbed (muscle
        forces 12 % F0).

        Nor past a joint's passive range (``joint_range``, ``within_joint_range``): the
        ligament torques grow as exp(34 rad^-1) past the knee's extension limit, and at a
        take-off (the knee extending at ~10 rad/s) 25 ms of extrapolation put the newest
        control points 0.5-0.8 rad beyond it: passive torques of 10^6-10^12 N m in the
        newest segments' Eq. 1 rows, whose Gauss-Newton step then sent the foot's rate to
        2000 rad/s (a loss of control 67 ms after lift-off on 3 of 5 jumps of a seed)."""
        add = last_segment - self.last
        if add <= 0:
            return
        if self.n_seg + add >= self.cap:
            raise ValueError(f'the window would exceed its capacity of {self.cap} segments')
        if last_segment - self.base >= self.lin_seg.size:     # compact the kept blocks
            live = slice(self.first - self.base, self.last + 1 - self.base)
            n_live = self.n_seg
            for arr in (self.lin_seg, self.lin_H, self.lin_band, self.lin_g, self.lin_z,
                        self.lin_cost, self.lin_rows):
                arr[:n_live] = arr[live].copy()
            self.lin_seg[n_live:] = -1
            self.base = self.first
        self.C = continued_control_points(self.C, add, self.extrapolation_velocity,
                                          self.joint_range)

    def add_samples(self, angles: tuple[np.ndarray, np.ndarray],
                    wrench: tuple[np.ndarray, np.ndarray]) -> None:
        if len(angles[0]):
            self.angles.append(*angles)
        if len(wrench[0]):
            self.wrench.append(*wrench)
        self._data_version += 1

    # ------------------------------------------------------------------ linearise
    def landings(self) -> np.ndarray:
        """Times [s] where the plate's vertical force rises through ``landing_load``: the
        first sample above it, after at least 3 ms below and followed by at least 3 ms above
        (a one-sample spike is not a landing, except on a plate slower than 333 Hz, where
        3 ms is one sample). Landings found in earlier calls are kept for a second (the
        samples before the window are gone)."""
        seen = (self._data_version, self.wrench.t.size, self.first)
        if seen == self._landings_of:
            return self._landings
        self._landings_of = seen
        t, fy = self.wrench.t, self.wrench.y[:, 1]
        ok = np.isfinite(fy)
        t, fy = t[ok], fy[ok]
        if t.size > 2:
            k = max(1, int(np.ceil(0.003 / max(float(np.median(np.diff(t))), 1e-6))))
            up = (fy > self.landing_load).astype(np.int8)
            if up.size >= 2 * k:
                run = np.lib.stride_tricks.sliding_window_view(up, k)
                low, high = run.max(axis=1) == 0, run.min(axis=1) == 1     # [n - k + 1]
                i = np.arange(k, up.size - k + 1)
                new = t[i[high[i] & low[i - k]]]
                known = self._landings
                if known.size and new.size:
                    new = new[np.abs(new[:, None] - known[None, :]).min(axis=1) > 1e-9]
                self._landings = np.sort(np.concatenate([known, new]))
        self._landings = self._landings[self._landings >= self.t_start - 1.0]
        return self._landings

    def prior_relaxation(self, segments: np.ndarray) -> np.ndarray:
        """SD multipliers [S, 2] of the kernel's ``relax`` input per segment:
        ``landing_relax`` for segments within ``landing_span_s`` of a landing
        (``landings``), ones elsewhere."""
        segments = np.asarray(segments)
        out = np.ones((segments.size, 2))
        if np.isfinite(self.still_band).all() and not np.all(self.still_relax == 1):
            out[self.still_segments(segments)] = self.still_relax
        if not np.isfinite(self.landing_load) or np.all(self.landing_relax == 1):
            return out
        tl = self.landings()
        if tl.size:
            t0 = self.grid.time(segments) - self.landing_span_s
            t1 = self.grid.time(segments + 1) + self.landing_span_s
            pos = np.minimum(np.searchsorted(tl, t0), tl.size - 1)
            out[(tl[pos] >= t0) & (tl[pos] <= t1)] = self.landing_relax
        return out

    def still_segments(self, segments: np.ndarray) -> np.ndarray:
        """Which ``segments`` are in still stance (``still_of_segments``), worked out once
        for every segment of the data until the data change (an update evaluates the kernel
        several times; the test was 8 % of the estimator's time when repeated at each)."""
        segments = np.asarray(segments, dtype=np.int64)
        t = self.wrench.t
        key = (self._data_version, t.size, self.first)     # as ``landings``' data
        if key != self._still_of:
            finite = t[np.isfinite(self.wrench.y).all(axis=1)]
            if finite.size:
                seg = self.grid.locate(finite)[0]
                self._still_first = int(seg.min())
                self._still_flags = self.still_of_segments(
                    np.arange(self._still_first, int(seg.max()) + 1))
            else:
                self._still_first, self._still_flags = 0, np.zeros(0, bool)
            self._still_of = key
        at = segments - self._still_first
        inside = (at >= 0) & (at < self._still_flags.size)
        out = np.zeros(segments.size, bool)
        out[inside] = self._still_flags[at[inside]]
        return out

    def still_of_segments(self, segments: np.ndarray) -> np.ndarray:
        """Which ``segments`` are in still stance, from the plate alone: every segment
        within ``still_span_s`` of it (the data so far: at the window's open end, the past
        only) has plate samples, is loaded (mean vertical force above ``landing_load``) and
        has a mean reading within ``still_band`` of those segments' median. The plate reads
        the body's momentum change (the vertical and fore-aft forces its COM's acceleration,
        the moment its rotation about the ankle), so a still plate is a still body; a
        segment mean of ~9 samples at 1080 Hz has a third of the noise SD. A plate slower
        than the knot rate (the real drop jump's 100 Hz) leaves segments without samples:
        never still there. Compiled (``_still_blocks``)."""
        segments = np.asarray(segments, dtype=np.int64)
        t, y = self.wrench.t, self.wrench.y
        ok = np.isfinite(y).all(axis=1)
        t, y = t[ok], y[ok]
        still = np.zeros(segments.size, bool)
        if t.size == 0 or segments.size == 0:
            return still
        seg = self.grid.locate(t)[0]
        first, last = int(seg.min()), int(seg.max())
        reach = int(np.ceil(self.still_span_s / self.grid.dt - 1e-9))
        inside = (segments >= first) & (segments <= last)
        ok_block = _still_blocks(seg - first, last - first + 1, y, float(self.landing_load),
                                 reach, segments[inside] - first,
                                 np.asarray(self.still_band, dtype=float))
        still[np.flatnonzero(inside)] = ok_block
        return still

    def _pack(self, samples: Samples, segments: np.ndarray, capacity: int, k: int,
              ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """Samples of ``segments`` padded to ``capacity`` per segment: batches of (slot [S'],
        u [S', cap], y [S', cap k], mask [S', cap k]), the first covering every segment and
        further ones the samples beyond the capacity (rarely: a faster stream)."""
        S = segments.size
        lo = np.searchsorted(samples.t, self.grid.time(segments) - 1e-12)
        hi = np.searchsorted(samples.t, self.grid.time(segments + 1) - 1e-12)
        count = hi - lo
        batches = []
        offset = 0
        while offset == 0 or (count > offset).any():
            n = np.clip(count - offset, 0, capacity)
            slot = np.arange(S) if offset == 0 else np.nonzero(n)[0]
            col = np.arange(capacity)[None, :]
            take = col < n[slot][:, None]
            src = np.where(take, (lo[slot] + offset)[:, None] + col, 0)
            u = np.zeros((slot.size, capacity))
            y = np.zeros((slot.size, capacity, k))
            m = np.zeros((slot.size, capacity, k))
            if samples.t.size:
                t0 = self.grid.time(segments[slot])[:, None]
                u[take] = ((samples.t[src] - t0) / self.grid.dt)[take]
                vals = samples.y[src]
                ok = np.isfinite(vals) & take[:, :, None]
                y[ok] = vals[ok]
                m[ok] = 1.0
            batches.append((slot, u, y.reshape(slot.size, -1), m.reshape(slot.size, -1)))
            offset += capacity
        return batches

    def _packed(self, segments: np.ndarray) -> tuple[list, list]:
        """The samples of ``segments`` packed for the kernel (``_pack``: angles, wrench), kept
        for the next call on the same segments and data (the rescue's checked iterations
        evaluate the same segments several times an update)."""
        key = (self._data_version, self.first, segments.tobytes())
        if self._packed_of is None or self._packed_of[0] != key:
            kern = self.kernel
            self._packed_of = (key, (
                self._pack(self.angles, segments, kern.angle_capacity, 4),
                self._pack(self.wrench, segments, kern.wrench_capacity, 3)))
        return self._packed_of[1]

    def evaluate(self, segments: np.ndarray, C: np.ndarray, plate: np.ndarray,
                 dynamics_scale: float = 1.0) -> Linearisation:
        """Linearise the residuals of ``segments`` (global) at (C, plate) with the compiled
        kernel (``segment_kernel``): one batched call (more for samples over capacity)."""
        segments = np.asarray(segments, dtype=np.int64)
        kern = self.kernel
        S = segments.size
        ang, wr = self._packed(segments)
        z = self.points_of(segments, C, plate)
        relax = self.prior_relaxation(segments)
        n = NB + NX
        H, g = np.zeros((S, n, n)), np.zeros((S, n))
        cost, rows = np.zeros(S), np.zeros((S, 4))
        for call in range(max(len(ang), len(wr))):
            if call == 0:       # the first batches of both streams cover every segment
                slots = np.arange(S)
                parts = [*ang[0][1:], *wr[0][1:]]
            else:
                parts = []
                slots = np.unique(np.concatenate([b[call][0] for b in (ang, wr)
                                                  if call < len(b)]))
                for batches, cap, k in ((ang, kern.angle_capacity, 4),
                                        (wr, kern.wrench_capacity, 3)):
                    u = np.zeros((slots.size, cap))
                    y, m = np.zeros((slots.size, cap * k)), np.zeros((slots.size, cap * k))
                    if call < len(batches):
                        bs, bu, by, bm = batches[call]
                        where = np.searchsorted(slots, bs)
                        u[where], y[where], m[where] = bu, by, bm
                    parts += [u, y, m]
            ones = np.ones((slots.size, 1))
            out = kern(z[slots, :NB], z[slots, NB:], *parts, dynamics_scale * ones,
                       ones * (call == 0), relax[slots])
            at = slice(None) if call == 0 else slots     # a slice: no gather and scatter
            H[at] += out[0]
            g[at] += out[1]
            cost[at] += out[2][:, 0]
            rows[at] += np.column_stack([o[:, 0] for o in out[3:7]])
        return Linearisation(segments, H, g, cost, rows, z)

    def keep(self, lin: Linearisation) -> None:
        slot = _as_slice(lin.segments - self.base)
        self.lin_seg[slot] = lin.segments
        self.lin_H[slot] = lin.H
        self.lin_band[slot] = band_form(lin.H, NB)
        self.lin_g[slot] = lin.g
        self.lin_cost[slot] = lin.cost
        self.lin_rows[slot] = lin.rows
        self.lin_z[slot] = lin.z

    def relinearise(self, segments: np.ndarray, dynamics_scale: float = 1.0) -> None:
        self.keep(self.evaluate(segments, self.C, self.plate, dynamics_scale))

    def rows(self, segments: np.ndarray) -> np.ndarray:
        """Kept data rows [S, 4] of ``segments`` (see ``Linearisation``)."""
        return self.lin_rows[np.asarray(segments) - self.base]

    def _prior_at(self, C: np.ndarray, plate: np.ndarray,
                  ) -> tuple[float, np.ndarray, np.ndarray] | None:
        p = self.prior
        if p is None:
            return None
        k = p.first - self.first
        z = np.concatenate([C[k:k + p.n_ctrl].ravel(), plate])
        d = z - p.lin
        H, g = p.shifted(z)
        return 0.5 * float(d @ p.H @ d) - float(p.g @ d), H, g

    def _models(self, C: np.ndarray, plate: np.ndarray, count: int | None = None,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every window segment's kept model at (C, plate) (``count``: the oldest ``count``
        segments' only): (segments [S], H [S, ...], cost [S], -gradient [S, NB + NX])."""
        n = self.n_seg if count is None else min(count, self.n_seg)
        segs = np.arange(self.first, self.first + n)
        slot = slice(self.first - self.base, self.first + n - self.base)
        if (self.lin_seg[slot] != segs).any():
            missing = segs[self.lin_seg[slot] != segs]
            self.keep(self.evaluate(missing, self.C, self.plate))
        H = self.lin_H[slot]
        d = self.points_of(segs, C, plate) - self.lin_z[slot]
        Hd = np.einsum('sij,sj->si', H, d)
        g = self.lin_g[slot]
        cost = self.lin_cost[slot] - np.einsum('si,si->s', g, d) + 0.5 * np.einsum(
            'si,si->s', d, Hd)
        return segs, H, cost, g - Hd

    def model_cost(self, C: np.ndarray, plate: np.ndarray,
                   exact: Linearisation | None = None,
                   models: tuple[np.ndarray, ...] | None = None) -> float:
        """Cost of (C, plate): kept segment models (``models``: ``_models(C, plate)`` if
        already made), with ``exact`` ones replacing them (all of them: no model needed, the
        rescue's and the start's checked steps over the whole window)."""
        if (exact is not None and models is None
                and np.array_equal(exact.segments, self.segments)):
            cost = exact.cost
        else:
            _, _, cost, _ = models if models is not None else self._models(C, plate)
            if exact is not None:
                cost = cost.copy()
                cost[exact.segments - self.first] = exact.cost
        prior = self._prior_at(C, plate)
        return float(cost.sum()) + (prior[0] if prior is not None else 0.0)

    # ------------------------------------------------------------------ solve
    def normal_equations(self, models: tuple[np.ndarray, ...] | None = None,
                         ) -> NormalEquations:
        """The Gauss-Newton system at (C, plate) (``models``: ``_models(C, plate)`` if
        already made)."""
        ne = NormalEquations(self.C.shape[0], NV, NX)
        segs, H, _, g = models if models is not None else self._models(self.C, self.plate)
        band = self.lin_band[self.first - self.base:self.last + 1 - self.base]
        ne.add_segments(segs - self.first, H, g, band)
        prior = self._prior_at(self.C, self.plate)
        if prior is not None:
            ne.add_dense(self.prior.first - self.first, self.prior.n_ctrl, prior[1], prior[2])
        return ne

    def step_metric(self) -> np.ndarray:
        """Levenberg damping metric [n_ctrl NV + NX] (``_STEP``)."""
        return 1.0 / np.concatenate([np.tile(_STEP, self.C.shape[0]), _STEP_PLATE]) ** 2

    def step(self, segments: np.ndarray, damping: float, dynamics_scale: float = 1.0,
             check: bool = True) -> tuple[float, float]:
        """Re-linearise ``segments``, take one damped Gauss-Newton step on the whole window
        and (``check``) keep it only if it lowers the cost. Returns (cost before, after)."""
        segments = np.asarray(segments, dtype=np.int64)
        covers = (segments.tobytes(), float(dynamics_scale), self._data_version)
        fresh = self._fresh
        if not (fresh is not None and fresh[0] is self.C and fresh[1] is self.plate
                and fresh[2] == covers
                and (self.lin_seg[segments - self.base] == segments).all()):
            self.relinearise(segments, dynamics_scale)
        models = self._models(self.C, self.plate)
        before = self.model_cost(self.C, self.plate, models=models)
        ne = self.normal_equations(models)
        dz = ne.solve(damping * self.step_metric())
        C_new = self.C + dz[:-NX].reshape(self.C.shape)
        plate_new = self.plate + dz[-NX:]
        if not check:
            self.C, self.plate = C_new, plate_new
            return before, before - 0.5 * float(dz @ np.concatenate([ne.g, ne.gx]))
        exact = self.evaluate(segments, C_new, plate_new, dynamics_scale)
        after = self.model_cost(C_new, plate_new, exact)
        if np.isfinite(after) and after < before:
            self.C, self.plate = C_new, plate_new
            self.keep(exact)       # = what re-linearising these segments here would give
            self._fresh = (self.C, self.plate, covers)
        return before, after

    def solve(self, segments: np.ndarray, iterations: int, damping: float,
              dynamics_scale: float = 1.0, tol: float = 1e-3, min_damping: float = 1e-6,
              check: bool = True) -> float:
        """Levenberg-Marquardt iterations (damping halved after a step that lowers the
        cost, x4 after one that does not); returns the final damping."""
        for _ in range(iterations):
            try:
                before, after = self.step(segments, damping, dynamics_scale, check)
            except np.linalg.LinAlgError:       # not positive definite: damp more, retry
                damping = min(damping * 100.0, 1e6)
                before, after = self.step(segments, damping, dynamics_scale, check)
            if after < before:
                damping = max(damping / 2.0, min_damping)
                if before - after < tol * before:
                    break
            else:
                damping = min(damping * 4.0, 1e6)
        return damping

    # ------------------------------------------------------------------ marginalise
    def start_prior(self, sd_plate: np.ndarray) -> None:
        """A prior N(0, sd_plate^2) on the plate parameters (at a cold start)."""
        n = 3 * NV + NX
        H = np.zeros((n, n))
        H[3 * NV:, 3 * NV:] = np.diag(1.0 / np.asarray(sd_plate, dtype=float) ** 2)
        lin = np.concatenate([self.C[:3].ravel(), np.zeros(NX)])
        self.prior = Prior(first=self.first, n_ctrl=3, H=H, g=np.zeros(n), lin=lin)

    def drop_before(self, segment: int, translation_sd: float = 0.0) -> None:
        """Marginalise the segments before ``segment`` (global) into the arrival cost; the
        plate parameters then get the drift of the time that passed. ``translation_sd`` [m]
        (0: none): where the body is (a common horizontal and vertical shift of the arrival
        control points) is made that uncertain, for segments where nothing held it to the
        ground (the estimator's ``airborne_translation_diffusion_m_sqrt_s`` over their
        span)."""
        m = segment - self.first
        if m <= 0:
            return
        segs, Hs, _, gs = self._models(self.C, self.plate, m)
        n = (m + 3) * NV
        H = np.zeros((n + NX, n + NX))
        g = np.zeros(n + NX)
        for s in range(m):
            lo = s * NV
            H[lo:lo + NB, lo:lo + NB] += Hs[s, :NB, :NB]
            H[lo:lo + NB, n:] += Hs[s, :NB, NB:]
            H[n:, lo:lo + NB] += Hs[s, NB:, :NB]
            H[n:, n:] += Hs[s, NB:, NB:]
            g[lo:lo + NB] += gs[s, :NB]
            g[n:] += gs[s, NB:]
        prior = self._prior_at(self.C, self.plate)
        if prior is not None:
            k = (self.prior.first - self.first) * NV
            w = self.prior.n_ctrl * NV
            H[k:k + w, k:k + w] += prior[1][:w, :w]
            H[k:k + w, n:] += prior[1][:w, w:]
            H[n:, k:k + w] += prior[1][w:, :w]
            H[n:, n:] += prior[1][w:, w:]
            g[k:k + w] += prior[2][:w]
            g[n:] += prior[2][w:]
        Hp, gp = marginalize(H, g, m * NV)
        lin = np.concatenate([self.C[m:m + 3].ravel(), self.plate])
        reverting = self.plate_reversion_s > 0
        if reverting.any():       # Gauss-Markov plate parameters: their mean decays to zero
            Hp, gp, lin = revert_toward_zero(Hp, gp, lin, 3 * NV, np.exp(
                -m * self.grid.dt / np.where(reverting, self.plate_reversion_s, np.inf)))
        Hp, gp = diffuse(Hp, gp, 3 * NV + np.arange(NX), self.plate_drift * m * self.grid.dt)
        if self.arrival_noise is not None:   # the arrival state's own process noise
            Hp, gp = diffuse(Hp, gp, np.arange(3 * NV), np.tile(self.arrival_noise, 3)
                             * m * self.grid.dt)
        if translation_sd > 0:
            E = np.zeros((Hp.shape[0], 2))
            for k in range(3):
                E[k * NV + 4, 0] = E[k * NV + 5, 1] = 1.0
            Hp, gp = diffuse_along(Hp, gp, E, np.full(2, translation_sd ** 2))
        self.prior = Prior(first=segment, n_ctrl=3, H=Hp, g=gp, lin=lin)
        self.lin_seg[segs[:m] - self.base] = -1
        self.C = self.C[m:]
        self.first = segment
        self.angles.drop_before(self.t_start)
        self.wrench.drop_before(self.t_start)

    # ------------------------------------------------------------------ outputs
    def values(self, t: np.ndarray, orders: int = 3) -> np.ndarray:
        """Spline values [P, orders, NV] at instants inside the window."""
        return evaluate(self.C, self.first, self.grid, np.asarray(t, dtype=float), orders)


def continued_control_points(C: np.ndarray, add: int, fraction: float,
                             joint_range: tuple[np.ndarray, np.ndarray] | None = None,
                             ) -> np.ndarray:
    """C [n, NV] (n >= 3) with ``add`` control points appended (``SlidingWindow.extend``):
    q continues at ``fraction`` x the cubic B-spline's velocity at its end, (C[-1] - C[-3]) /
    2 per knot interval, within ``joint_range`` (``within_joint_range``); a and s held."""
    q = LAYOUT['q']
    v = fraction * (C[-1, q] - C[-3, q]) / 2
    out = np.concatenate([C, np.repeat(C[-1:], add, axis=0)])
    for k in range(C.shape[0], C.shape[0] + add):
        out[k, q] = out[k - 1, q] + v
        if joint_range is not None:
            out[k, q] = within_joint_range(out[k, q], out[k - 1, q], *joint_range)
    return out


def within_joint_range(q_new: np.ndarray, q_last: np.ndarray, lower: np.ndarray,
                       upper: np.ndarray) -> np.ndarray:
    """The extrapolated coordinates q_new [6] with each joint angle (ankle = foot - shank,
    knee = shank - thigh, hip = thigh - HAT, ``skeleton.JOINT_MAP``) kept within
    [lower, upper] [rad], or at q_last's angle where that is already outside: the foot angle
    and the translations as extrapolated, the other segments following the clamped joints."""
    th_new, th_last = JOINT_MAP @ q_new, JOINT_MAP @ q_last
    th = np.clip(th_new, np.minimum(lower, th_last), np.maximum(upper, th_last))
    if (th == th_new).all():
        return q_new
    out = q_new.copy()
    out[1:4] = q_new[0] - np.cumsum(th)      # JOINT_MAP inverted from the foot angle on
    return out


def revert_toward_zero(H: np.ndarray, g: np.ndarray, lin: np.ndarray, first: int,
                       phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The prior (H, g) linearised at ``lin`` (variables ``first`` + k of it for k < len(phi))
    after the deterministic part of a first-order Gauss-Markov process, p' = phi p (each
    parameter's mean decays toward zero by phi = exp(-dt / tau)): in p', H' = S H S and
    g' = S g with S = 1 / phi on those variables, linearised at phi lin. The process noise is
    added separately (``diffuse``). Returns (H', g', lin')."""
    scale = np.ones(H.shape[0])
    idx = first + np.arange(phi.size)
    scale[idx] = 1.0 / phi
    return H * scale[:, None] * scale[None, :], g * scale, lin / scale


def _as_slice(index: np.ndarray) -> slice | np.ndarray:
    """``index`` as a slice where it is a run of consecutive integers (a view, not a copy,
    when indexing), else itself."""
    if index.size and index[-1] - index[0] == index.size - 1 and (
            index.size < 3 or (np.diff(index) == 1).all()):
        return slice(int(index[0]), int(index[-1]) + 1)
    return index


def warm_up() -> None:
    """Load (or compile) the compiled loops of the window (``_still_blocks``, the spline's
    ``evaluate``) now, not in a stream's first window."""
    _still_blocks(np.zeros(2, dtype=np.int64), 1, np.ones((2, 3)), 0.0, 1,
                  np.zeros(1, dtype=np.int64), np.ones(3))
    evaluate(np.zeros((4, NV)), 0, KnotGrid(0.0, 0.01), np.zeros(1), 3)


@numba.njit(cache=True)
def _still_blocks(seg: np.ndarray, n: int, y: np.ndarray, landing_load: float, reach: int,
                  at: np.ndarray, band: np.ndarray) -> np.ndarray:
    """``SlidingWindow.still_of_segments``' test of the segments ``at`` (indices into the n
    segments of the data, whose samples y [P, 3] fall in segments ``seg`` [P], both relative
    to the data's first segment): each segment's mean reading (its samples summed in order,
    then divided by their count); a segment without samples or not loaded fails every block
    that holds it; a block [j - reach, j + reach] (cut to the data) of at least reach + 1
    segments passes where every mean is within ``band`` [3] of the block's median. Compiled
    (numba): as numpy it was 4 % of the estimator's time, in per-call overhead."""
    count = np.zeros(n, dtype=np.int64)
    sums = np.zeros((n, 3))
    for i in range(seg.size):
        count[seg[i]] += 1
        for k in range(3):
            sums[seg[i], k] += y[i, k]
    usable = np.zeros(n, dtype=np.bool_)
    means = np.zeros((n, 3))
    for j in range(n):
        if count[j] > 0:
            for k in range(3):
                means[j, k] = sums[j, k] / count[j]
            usable[j] = means[j, 1] > landing_load
    out = np.zeros(at.size, dtype=np.bool_)
    values = np.empty(2 * reach + 1)
    for b in range(at.size):
        lo, hi = max(at[b] - reach, 0), min(at[b] + reach, n - 1)
        m = hi - lo + 1
        if m < reach + 1:
            continue
        fine = True
        for j in range(lo, hi + 1):
            fine = fine and usable[j]
        if not fine:
            continue
        for k in range(3):
            for j in range(lo, hi + 1):
                values[j - lo] = means[j, k]
            ordered = np.sort(values[:m])
            med = 0.5 * (ordered[(m - 1) // 2] + ordered[m // 2])
            dev = 0.0
            for j in range(m):
                dev = max(dev, abs(values[j] - med))
            if not dev <= band[k]:
                fine = False
                break
        out[b] = fine
    return out
