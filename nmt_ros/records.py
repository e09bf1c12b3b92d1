"""The records that flow between the layers: a trial's data and what the estimators made of it.

The bottom of the house (beside ``model``): every layer may import these, and they import only
numpy and ``nmt_ros.model``. They are what passes between the study's steps (reference ->
observations -> trackers -> metrics), what the trackers return and what ``nmt_ros.io.trial_bag``
writes to and reads from bags.

Times are trial times in seconds (0 = onset of the jump); bags carry them as header stamps
offset by ``TRIAL_EPOCH_NS``. Arrays carry their axis order in the comments ([n, k]).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from nmt_ros.model.jumper import JumperModel

#: Header stamp of trial time 0 in the bags we write (2023-11-14T22:13:20Z): a fixed, nonzero
#: epoch so that ROS time is never 0 (ROS treats 0 as "unset" under sim time).
TRIAL_EPOCH_NS = 1_700_000_000 * 10**9


# --------------------------------------------------------------------------- a trial's data

@dataclass
class Truth:
    """The actual performance on a uniform grid (the force-plate rate)."""

    t: np.ndarray        # [n] s
    q: np.ndarray        # [n, 6] (rad, m)
    qd: np.ndarray       # [n, 6]
    qdd: np.ndarray      # [n, 6]
    a: np.ndarray        # [n, 9] activations
    u: np.ndarray        # [n, 9] excitations
    f: np.ndarray        # [n, 9] musculotendon forces (N)
    tau: np.ndarray      # [n, 3] joint torques by the muscles (N m) [ankle, knee, hip]
    s: np.ndarray        # [n, 3] ground wrench on the foot: Fx, Fy (N), moment about foot COM
    point_forces: np.ndarray  # [n, 2, 2] (heel, toe) x (Fx, Fy) (N)
    x0: np.ndarray       # [2] contact anchors (m)
    liftoff_s: float
    info: dict = field(default_factory=dict)

    @property
    def theta(self) -> np.ndarray:
        """Segment angles [n, 4] (foot, shank, thigh, HAT)."""
        return self.q[:, :4]

    def contact_mask(self) -> np.ndarray:
        """Samples of the ground-contact phase (t <= lift-off)."""
        return self.t <= self.liftoff_s

    def between(self, t0: float, t1: float) -> Truth:
        """The samples with t0 <= t <= t1 [s] (e.g. the part of a record that was replayed);
        lift-off, anchors and info unchanged."""
        keep = (self.t >= t0) & (self.t <= t1)
        return replace(self, **{f: getattr(self, f)[keep] for f in
                                ('t', 'q', 'qd', 'qdd', 'a', 'u', 'f', 'tau', 's',
                                 'point_forces')})


@dataclass
class Observations:
    """What a lab records: noisy, biased segment angles and ground wrench (unfiltered)."""

    t_angles: np.ndarray   # [n1] s (120 Hz)
    angles: np.ndarray     # [n1, 4] rad (foot, shank, thigh, HAT)
    t_wrench: np.ndarray   # [n2] s (1080 Hz)
    wrench: np.ndarray     # [n2, 3] Fx, Fy (N), moment about the foot COM (N m)
    frame_id: str = 'foot_com'
    info: dict = field(default_factory=dict)
    # Optional (lab recordings): the measured ankle centre, the model's (r1, r2), in the lab's
    # sagittal frame (x forward, y up; y = 0 the floor the force plates are in).
    t_ankle: np.ndarray | None = None   # [n3] s
    ankle: np.ndarray | None = None     # [n3, 2] m

    def before(self, t_end: float) -> Observations:
        """The observations up to ``t_end`` [s] (inclusive), on the same trial time."""
        def cut(t: np.ndarray | None, x: np.ndarray | None) -> tuple:
            if t is None:
                return None, None
            keep = np.asarray(t) <= t_end
            return np.asarray(t)[keep], np.asarray(x)[keep]
        ta, a = cut(self.t_angles, self.angles)
        tw, w = cut(self.t_wrench, self.wrench)
        tk, k = cut(self.t_ankle, self.ankle)
        return Observations(t_angles=ta, angles=a, t_wrench=tw, wrench=w,
                            frame_id=self.frame_id, info=dict(self.info), t_ankle=tk, ankle=k)

    def after(self, t_start: float) -> Observations:
        """The observations from ``t_start`` [s] on, on a trial time that starts there (the
        samples' times minus t_start); ``info['t_offset_s']`` accumulates the shift."""
        def cut(t: np.ndarray | None, x: np.ndarray | None) -> tuple:
            if t is None:
                return None, None
            keep = np.asarray(t) >= t_start - 1e-9
            return np.asarray(t)[keep] - t_start, np.asarray(x)[keep]
        ta, a = cut(self.t_angles, self.angles)
        tw, w = cut(self.t_wrench, self.wrench)
        tk, k = cut(self.t_ankle, self.ankle)
        info = {**self.info, 't_offset_s': float(self.info.get('t_offset_s', 0.0)) + t_start}
        return Observations(t_angles=ta, angles=a, t_wrench=tw, wrench=w,
                            frame_id=self.frame_id, info=info, t_ankle=tk, ankle=k)


def truth_from_simulation(model: JumperModel, t: np.ndarray, x: np.ndarray, u: np.ndarray,
                          x0: np.ndarray, liftoff_s: float, info: dict | None = None,
                          ) -> Truth:
    """Every truth signal from a sampled forward simulation (x = [q, qd, a] [n, 21], u [n, 9],
    contact anchors x0 [2] m, lift-off time s)."""
    q, qd, a = x[:, :6], x[:, 6:12], x[:, 12:]
    xdot, = model.batch(model.musculoskeletal_ode, x, u, x0)
    tau, f = model.batch(model.muscle_torques, q, qd, a)
    s, = model.batch(model.contact_outputs, q, qd, x0)
    pf, = model.batch(model.contact_forces, q, qd, x0)
    return Truth(t=np.asarray(t, dtype=float), q=q, qd=qd, qdd=xdot[:, 6:12], a=a, u=u, f=f,
                 tau=tau, s=s, point_forces=np.transpose(pf, (0, 2, 1)),
                 x0=np.asarray(x0, dtype=float), liftoff_s=float(liftoff_s),
                 info=dict(info or {}))


# --------------------------------------------------------------------------- estimates

@dataclass
class SKTResult:
    """Stage 1 on its output grid (the force-plate samples): the skeletal motion tracker's
    result, and the record optimal tracking returns too (then with ``muscles``)."""

    t: np.ndarray            # [n] s
    q: np.ndarray            # [n, 6]
    qd: np.ndarray           # [n, 6]
    qdd: np.ndarray          # [n, 6]
    tau: np.ndarray          # [n, 3] joint torques (N m): ankle, knee, hip
    s: np.ndarray            # [n, 3] synthesised ground wrench
    bias: np.ndarray         # [n] moment-bias estimate (N m)
    residual: np.ndarray     # [n, 7] normalised least-squares residual
    x0: np.ndarray
    status: str = 'ok'       # 'ok' | 'lost_control'
    events: list = field(default_factory=list)
    cpu_s: float = 0.0
    liftoff_s: float = float('nan')
    muscles: dict | None = None  # muscle-driven Stage 1 only: {'a', 'u', 'f'} [n, 9]

    @property
    def ok(self) -> bool:
        return self.status == 'ok'


@dataclass(frozen=True)
class MuscleEstimates:
    """Stage-2 estimates on its grid (a subset of the Stage-1 grid)."""

    t: np.ndarray    # [n] s
    f: np.ndarray    # [n, 9] musculotendon forces (N)
    a: np.ndarray    # [n, 9] activations (0..1)
    u: np.ndarray    # [n, 9] excitations (0..1), held over the next interval


@dataclass(frozen=True)
class TrialEstimates:
    """What one batch run estimated, as the estimates bag carries it: Stage 1, the IVD
    baseline's joint torques and, when Stage 2 ran, the muscles."""

    stage1: SKTResult
    ivd_t: np.ndarray       # [n] s
    ivd_tau: np.ndarray     # [n, 3] N m (ankle, knee, hip)
    muscles: MuscleEstimates | None = None

    def shifted(self, dt: float) -> TrialEstimates:
        """The same estimates with every time moved by ``dt`` [s] (e.g. back onto the
        recording's time after tracking from a later start)."""
        s1 = replace(self.stage1, t=self.stage1.t + dt, liftoff_s=self.stage1.liftoff_s + dt,
                     events=[{**e, 't': e['t'] + dt} if 't' in e else e
                             for e in self.stage1.events])
        m = self.muscles
        return TrialEstimates(stage1=s1, ivd_t=self.ivd_t + dt, ivd_tau=self.ivd_tau,
                              muscles=None if m is None else replace(m, t=m.t + dt))
