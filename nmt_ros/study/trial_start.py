"""Where a recording's tracking starts, and the tracked model's state there.

The trackers start at trial time 0 of the observations they are given, from a static squat on
the force plate (the paper's start, ``skeletal_tracker.initial_state``). A lab recording may
begin elsewhere: on a box that is not on a plate (the shipped drop jump), where the plates read
nothing while the body stands, so no model can follow both the motion and the forces. Tracking
then starts later (:func:`plan_start`):

* ``start_s`` given: there;
* else, when the bag carries the measured ankle centre (``/mocap/ankle_position``) and the
  momentum balance finds an unmeasured support at the start
  (``nmt_ros.study.momentum_balance``): at its step-off;
* else at the first sample.

The start is moved to the first force-plate sample at or after it, so the tracker's output
grid (k / force-plate rate from the start) falls on the recording's samples and the estimates
are stamped like the observations. A start with the plates loaded (vertical force above
``contact_threshold_n``) is the static start. A start in flight takes the state from the
measurements (``skeletal_tracker.flight_state``): filtered angles and rates, and the ankle
centre and its rate (low-passed like the angles), shifted vertically so that the model's lowest
contact point is on the ground (y = 0) at the first touchdown (the measured ankle height and
the model's heel and toe geometry differ by millimetres to centimetres), with the contact
anchors where the model's heel and toe are at that touchdown.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nmt_ros.model.jumper import JumperModel
from nmt_ros.records import Observations
from nmt_ros.study.momentum_balance import BalanceSettings, loaded_phases, momentum_balance
from nmt_ros.tracking.conditioning import (
    ConditioningSettings,
    SmoothSignal,
    condition,
    cutoff_for_rate,
    sample_rate,
)
from nmt_ros.tracking.skeletal_tracker import SKTState, flight_state, reference_arrays


@dataclass
class TrialStart:
    """Where tracking starts (recording time, s), why, and the state when it is in flight."""

    t_s: float
    reason: str
    in_flight: bool = False
    state: SKTState | None = None       # None: the static start from the observations
    balance: dict | None = None         # the momentum balance's report, when it could run
    notes: list[str] = field(default_factory=list)


def _rotated(theta: float, points: np.ndarray) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.column_stack([c * points[:, 0] - s * points[:, 1],
                            s * points[:, 0] + c * points[:, 1]])


def plan_start(model: JumperModel, obs: Observations, start_s: float | None = None,
               conditioning: ConditioningSettings | None = None,
               balance: BalanceSettings | None = None,
               needs_state: bool = True) -> TrialStart:
    """The start of tracking on ``obs`` (module docstring); settings None: the defaults."""
    conditioning = conditioning if conditioning is not None else ConditioningSettings()
    balance = balance if balance is not None else BalanceSettings()
    t_w = np.asarray(obs.t_wrench, dtype=float)
    t0, t1 = float(max(obs.t_angles[0], t_w[0])), float(min(obs.t_angles[-1], t_w[-1]))
    report = None
    has_ankle = obs.ankle is not None and obs.t_ankle is not None and len(obs.t_ankle) > 5
    step_off = None
    if has_ankle:
        mb = momentum_balance(model, obs.t_angles, obs.angles, obs.t_ankle, obs.ankle, t_w,
                              obs.wrench, balance)
        report = mb.report(model.p.total_mass)
        step_off = mb.step_off_s
    if start_s is not None:
        if not t0 <= start_s < t1:
            raise ValueError(f'--start {start_s:g} s is outside the recording '
                             f'({t0:.3f}..{t1:.3f} s)')
        t_req, reason = float(start_s), f'given start {start_s:g} s'
    elif step_off is not None:
        t_req = step_off
        a, b = report['unmeasured_support_s']
        reason = (f'detected step-off at {b:.3f} s: {a:.3f}..{b:.3f} s the body stands on a '
                  'support that is not on a force plate (the COM does not fall while the '
                  'plates read no load)')
    else:
        t_req = t0
        reason = ('first sample' if has_ankle else
                  'first sample (no /mocap/ankle_position: the start could not be checked '
                  'against the forces)')
    i = int(np.searchsorted(t_w, t_req - 1e-9))
    if i >= t_w.size - 6:
        raise ValueError(f'start {t_req:.3f} s leaves fewer than 6 force-plate samples')
    t_s = float(t_w[i])
    start = TrialStart(t_s=t_s, reason=reason, balance=report)
    if t_s > t_req + 1e-9:
        start.notes.append(f'start moved from {t_req:.4f} s to the next force-plate sample, '
                           f'{t_s:.4f} s')
    phases = loaded_phases(t_w, obs.wrench[:, 1], balance.contact_threshold_n,
                           balance.min_phase_s)
    if any(a - 1e-9 <= t_s <= b + 1e-9 for a, b in phases):       # on the plates
        return start
    start.in_flight = True
    if not needs_state:     # an estimator that starts from the data alone (moving horizon)
        start.notes.append('the start is in flight; the moving-horizon estimator starts from '
                           'the data (no start state needed)')
        return start
    if not has_ankle:
        raise ValueError(
            f'tracking would start at {t_s:.3f} s with no load on the force plates (in flight '
            'or on an unmeasured support), and the bag has no measured ankle position '
            '(/mocap/ankle_position) to place the model in the air: import the recording '
            'with nmt import-lab, or give --start at an instant on the plates')
    start.state, note = _flight_state(model, obs, t_s, conditioning, balance)
    start.notes.append(note)
    return start


def _flight_state(model: JumperModel, obs: Observations, t_s: float,
                  conditioning: ConditioningSettings, balance: BalanceSettings,
                  ) -> tuple[SKTState, str]:
    """State at ``t_s`` [s] (in flight) of ``obs``, filtered over the whole recording (no
    filter edge at the start), and what was done."""
    cond = condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench, conditioning)
    rate = sample_rate(obs.t_ankle)
    cut, _ = cutoff_for_rate(float(np.min(conditioning.angle_cutoff_hz)), rate,
                             conditioning.max_cutoff_fraction)
    ankle = SmoothSignal(obs.t_ankle, obs.ankle, rate, cut, conditioning.order)
    ref0 = reference_arrays(cond, np.array([t_s]))[0]
    points = np.asarray(model.p.contact.points, dtype=float)      # heel, toe [2, 2] (foot)
    phases = [p for p in loaded_phases(obs.t_wrench, obs.wrench[:, 1],
                                       balance.contact_threshold_n, balance.min_phase_s)
              if p[0] > t_s]
    t_td = phases[0][0] if phases else float(obs.t_ankle[-1])
    th1 = float(cond.angles(np.array([t_td]))[0, 0])
    r_td = ankle(np.array([t_td]))[0]
    pts = r_td + _rotated(th1, points)                           # heel, toe at touchdown
    dy = -float(pts[:, 1].min())
    r0 = ankle(np.array([t_s]))[0] + np.array([0.0, dy])
    rd0 = ankle(np.array([t_s]), 1)[0]
    state = flight_state(ref0, r0, rd0, pts[:, 0])
    what = ('touchdown' if phases else 'the end of the recording (no touchdown)')
    note = (f'start in flight: ankle {r0[1]:.3f} m above the ground, moving '
            f'({rd0[0]:+.2f}, {rd0[1]:+.2f}) m/s; measured ankle heights shifted by '
            f'{dy:+.4f} m so that the model\'s lowest contact point is on the ground at '
            f'{what}, {t_td:.3f} s')
    return state, note
