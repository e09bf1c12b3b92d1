"""The whole body's vertical momentum balance in a recording: does the motion agree with the
measured forces, and what body mass do the forces imply?

Newton for the whole body, vertical: ``m (a_y + g) = F_y`` (the ground force is the only
external force besides gravity). The centre of mass (COM) comes from the kinematics: the planar
model's COM at the observed segment angles with its ankle at the measured ankle centre
(``/mocap/ankle_position``, written by ``nmt import-lab``). Three uses:

* **Unmeasured support** (a trial that begins on a box, a step, a chair, i.e. a support that
  is not on a force plate): while the body stands on it the plates read F_y = 0 but the COM
  does not fall (a_y ~ 0, not -g). The leading stretch where the COM's filtered vertical
  acceleration stays above -g/2 while the plates are unloaded is reported as unmeasured; the
  **step-off** is where it crosses -g/2 into the free fall that ends at the first touchdown
  (the COM and the force are filtered alike, ``cutoff_hz``, so the zero-phase filter smears
  the step-off symmetrically about the crossing). No mass is needed: F_y = 0 there.
* **Implied mass**, two documented estimates (:func:`implied_mass`):
  - *quiet stance*: the longest loaded window of at least ``quiet_min_s`` whose vertical force
    varies by less than ``quiet_max_cv`` (SD / mean): ``m = mean(F_y) / g`` (the COM's mean
    acceleration over a still window is ~0);
  - *impulse between flights*: a contact phase with free flight on both sides (after the
    step-off for the first one; an unloaded stretch is a flight only if the COM falls freely
    there, its parabola's acceleration within ``flight_acc_tolerance_g`` of -g): the COM's
    vertical velocity at touchdown (v_td) and at take-off (v_to) from parabolas of fixed
    curvature -g fitted to the COM over each flight, and the measured impulse
    ``J = int F_y dt`` over the contact: momentum ``m (v_to - v_td) = J - m g T`` gives
    ``m = J / (v_to - v_td + g T)``. Velocities come from whole flights, not from
    differentiating the positions twice, and the flight fits' residuals say how parabolic the
    measured COM is.
  Quiet stance is preferred when present (a direct weighing); both are reported.
  - *impulse over a supported stretch*, reported only (never the implied mass): over the
    longest loaded phase of at least ``supported_min_s`` (inside the filter's edges),
    ``m = J / (v_b - v_a + g T)`` with the COM's vertical velocities at its ends (the filtered
    COM's derivative). Right only if the plates carry the whole body throughout (a walk over
    the plates, a squat without a still moment: the unseen OpenCap walking2 gave 94.6 kg, the
    same subject's drop jumps 94.1-94.5); a chair or a foot beside the plates would make it
    low, and the planar COM's acceleration is too noisy against the force (0.3 g RMS with the
    right mass) to tell, so it only names a mass to give with ``--mass``.
* **Residual** ``a_y - (F_y / m - g)`` [m/s^2] after the step-off, with the mass the tracking
  uses: what the trackers will have to absorb.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nmt_ros.model.jumper import JumperModel
from nmt_ros.tracking.conditioning import SmoothSignal, cutoff_for_rate, sample_rate


@dataclass(frozen=True)
class BalanceSettings:
    """Thresholds of the momentum-balance checks (SI units)."""

    contact_threshold_n: float = 20.0   # a plate is loaded above this vertical force [N]
    min_phase_s: float = 0.05           # shorter loaded phases / unloaded gaps are noise [s]
    cutoff_hz: float = 10.0             # COM and force low-pass before comparing [Hz]
    min_flight_s: float = 0.08          # shortest unloaded stretch taken as a flight [s]
    flight_margin_s: float = 0.02       # flight samples this close to a contact are not fitted
    min_flight_samples: int = 5
    # an unloaded stretch is a flight when the COM's acceleration there (a free parabola) is
    # within this fraction of g of -g (the shipped drop jump's: -9.6 to -10.1 m/s^2;
    # Subject4's sit-to-stand, seated with its feet unloaded: -2.6 to +1.8, which taken for
    # flights implied 47 kg for a 62.6 kg subject)
    flight_acc_tolerance_g: float = 0.5
    quiet_min_s: float = 0.5            # quiet stance: window length [s]
    quiet_max_cv: float = 0.03          # ... and largest SD / mean of the vertical force
    support_fraction_g: float = 0.5     # unmeasured support: COM acceleration above -g x this
    supported_min_s: float = 1.0        # shortest loaded stretch weighed by its impulse [s]


@dataclass(frozen=True)
class MassEstimate:
    """A body mass implied by a recording's forces and motion."""

    mass_kg: float
    method: str                    # 'quiet stance' | 'impulse between flights' |
                                   # 'impulse over a supported stretch' (reported only)
    interval_s: tuple[float, float]
    detail: dict = field(default_factory=dict)


@dataclass
class MomentumBalance:
    """What the momentum balance of one recording says (module docstring)."""

    t: np.ndarray                  # [n] s, the kinematic samples
    com: np.ndarray                # [n, 2] m, the COM (lab sagittal frame)
    com_acc_y: np.ndarray          # [n] m/s^2, filtered
    force_y: np.ndarray            # [n] N, the vertical force filtered alike, at t
    contacts: list[tuple[float, float]]     # loaded phases [s] (threshold crossings)
    step_off_s: float | None       # end of the unmeasured support (None: none found)
    unmeasured_support_s: tuple[float, float] | None
    estimates: list[MassEstimate]
    gravity: float
    edge_s: float = 0.1            # the filter's edge: residuals this close to an end ignored

    @property
    def implied(self) -> MassEstimate | None:
        """The preferred estimate: quiet stance, else the impulse between flights."""
        for method in ('quiet stance', 'impulse between flights'):
            found = [e for e in self.estimates if e.method == method]
            if found:
                return found[0]
        return None

    def residual(self, mass_kg: float) -> np.ndarray:
        """a_y - (F_y / m - g) [n] (m/s^2) for body mass ``mass_kg``."""
        return self.com_acc_y - (self.force_y / mass_kg - self.gravity)

    def report(self, mass_kg: float | None = None) -> dict:
        """Figures for printing and for metadata (mass_kg: the mass the model uses)."""
        imp = self.implied
        out: dict = {
            'contacts_s': [[round(a, 4), round(b, 4)] for a, b in self.contacts],
            'step_off_s': None if self.step_off_s is None else round(self.step_off_s, 4),
            'unmeasured_support_s': (None if self.unmeasured_support_s is None else
                                     [round(v, 4) for v in self.unmeasured_support_s]),
            'implied_mass_kg': None if imp is None else round(imp.mass_kg, 2),
            'implied_mass_method': None if imp is None else imp.method,
            'estimates': [{'method': e.method, 'mass_kg': round(e.mass_kg, 2),
                           'interval_s': [round(v, 4) for v in e.interval_s],
                           **{k: (round(v, 4) if isinstance(v, float) else v)
                              for k, v in e.detail.items()}} for e in self.estimates],
        }
        if mass_kg is not None:
            # after the step-off, away from the recording's end (the filter's edge)
            after = ((self.t >= (self.step_off_s if self.step_off_s is not None
                                 else self.t[0] + self.edge_s))
                     & (self.t <= self.t[-1] - self.edge_s))
            r = self.residual(mass_kg)[after]
            out['model_mass_kg'] = round(float(mass_kg), 2)
            out['residual_rms_g_after_step_off'] = round(
                float(np.sqrt(np.mean(r ** 2)) / self.gravity), 3) if r.size else None
            if imp is not None:
                out['implied_vs_model_pct'] = round(100.0 * (imp.mass_kg / mass_kg - 1.0), 1)
        return out


def com_trajectory(model: JumperModel, t_angles: np.ndarray, angles: np.ndarray,
                   t_ankle: np.ndarray, ankle: np.ndarray) -> np.ndarray:
    """The planar model's COM [n, 2] (m) at the angle samples: segment angles [n, 4] (rad)
    and the ankle centre [m, 2] (m) resampled (linearly) onto t_angles [n] (s)."""
    t_angles = np.asarray(t_angles, dtype=float)
    ankle = np.asarray(ankle, dtype=float)
    r = np.column_stack([np.interp(t_angles, t_ankle, ankle[:, k]) for k in range(2)])
    q = np.hstack([np.asarray(angles, dtype=float), r])
    com, = model.batch(model.com, q)
    return np.asarray(com).reshape(-1, 2)


def loaded_phases(t: np.ndarray, fy: np.ndarray, threshold_n: float,
                  min_phase_s: float = 0.05) -> list[tuple[float, float]]:
    """Intervals [s] where the vertical force fy [n] (N) exceeds ``threshold_n``; ends at the
    (linearly interpolated) crossings, or at the first/last sample. Noise: loaded phases
    shorter than ``min_phase_s`` are dropped, then unloaded gaps shorter than it bridged."""
    t, fy = np.asarray(t, dtype=float), np.asarray(fy, dtype=float)
    above = fy > threshold_n
    if not above.any():
        return []
    edges = np.flatnonzero(np.diff(above.astype(int)))

    def crossing(i: int) -> float:          # between samples i and i + 1
        f0, f1 = fy[i] - threshold_n, fy[i + 1] - threshold_n
        return float(t[i] + (t[i + 1] - t[i]) * f0 / (f0 - f1))

    starts = ([float(t[0])] if above[0] else []) + [crossing(i) for i in edges if not above[i]]
    ends = [crossing(i) for i in edges if above[i]] + ([float(t[-1])] if above[-1] else [])
    merged: list[list[float]] = []
    for a, b in zip(starts, ends):
        if b - a < min_phase_s:
            continue                                   # a blip of noise
        if merged and a - merged[-1][1] < min_phase_s:
            merged[-1][1] = b                          # a dip of noise inside a contact
        else:
            merged.append([a, b])
    return [(a, b) for a, b in merged]


def fit_flight(t: np.ndarray, y: np.ndarray, gravity: float,
               ) -> tuple[np.ndarray, float] | None:
    """Least-squares parabola of curvature -g through (t, y) [m]: (c [2] with
    y(t) = c0 + c1 (t - t_mid) - g/2 (t - t_mid)^2, t_mid the samples' mean; RMS residual
    [m]); None with fewer than 3 samples."""
    t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
    if t.size < 3:
        return None
    tm = float(t.mean())
    rhs = y + 0.5 * gravity * (t - tm) ** 2
    a = np.column_stack([np.ones_like(t), t - tm])
    c, *_ = np.linalg.lstsq(a, rhs, rcond=None)
    res = a @ c - rhs
    return np.array([c[0], c[1], tm]), float(np.sqrt(np.mean(res ** 2)))


def flight_acceleration(t: np.ndarray, y: np.ndarray) -> float:
    """The vertical acceleration [m/s^2] of a least-squares parabola with free curvature
    through (t [s], y [m]) (-g in a free flight; ~0 for a body resting on a support)."""
    t = np.asarray(t, dtype=float)
    tm = t - t.mean()
    c = np.polyfit(tm, np.asarray(y, dtype=float), 2)
    return float(2.0 * c[0])


def _flight_velocity(fit: np.ndarray, t: float, gravity: float) -> float:
    return float(fit[1] - gravity * (t - fit[2]))


def _quiet_stance(t_w: np.ndarray, fy: np.ndarray, contacts: list[tuple[float, float]],
                  st: BalanceSettings, gravity: float) -> MassEstimate | None:
    """Longest window of >= quiet_min_s inside a contact with SD/mean of fy < quiet_max_cv."""
    best = None
    rate = sample_rate(t_w)
    n_win = int(np.ceil(st.quiet_min_s * rate))
    for a, b in contacts:
        idx = np.flatnonzero((t_w >= a) & (t_w <= b))
        if idx.size < n_win:
            continue
        f = fy[idx]
        csum = np.concatenate([[0.0], np.cumsum(f)])
        csq = np.concatenate([[0.0], np.cumsum(f ** 2)])
        mean = (csum[n_win:] - csum[:-n_win]) / n_win
        var = np.maximum((csq[n_win:] - csq[:-n_win]) / n_win - mean ** 2, 0.0)
        ok = (mean > 0) & (np.sqrt(var) < st.quiet_max_cv * np.abs(mean))
        if not ok.any():
            continue
        # grow the longest run of quiet windows into one interval
        runs = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(int), [0]])))
        lengths = runs[1::2] - runs[::2]
        k = int(np.argmax(lengths))
        i0, i1 = int(runs[2 * k]), int(runs[2 * k + 1] - 1 + n_win)
        sel = idx[i0:i1]
        est = MassEstimate(
            mass_kg=float(fy[sel].mean() / gravity), method='quiet stance',
            interval_s=(float(t_w[sel[0]]), float(t_w[sel[-1]])),
            detail={'mean_force_n': float(fy[sel].mean()),
                    'force_cv': float(fy[sel].std() / fy[sel].mean())})
        if best is None or np.diff(est.interval_s)[0] > np.diff(best.interval_s)[0]:
            best = est
    return best


def momentum_balance(model: JumperModel, t_angles: np.ndarray, angles: np.ndarray,
                     t_ankle: np.ndarray, ankle: np.ndarray, t_wrench: np.ndarray,
                     wrench: np.ndarray, settings: BalanceSettings = BalanceSettings(),
                     ) -> MomentumBalance:
    """The momentum balance of a recording (module docstring): segment angles [n, 4] (rad)
    at t_angles [n], the ankle centre [m, 2] (m) at t_ankle [m], the ground wrench [k, 3]
    (N, N, N m) at t_wrench [k] (all s)."""
    t_angles = np.asarray(t_angles, dtype=float)
    com = com_trajectory(model, t_angles, angles, t_ankle, ankle)
    return balance_from_com(t_angles, com, t_wrench, np.asarray(wrench)[:, 1],
                            model.p.gravity, settings)


def balance_from_com(t: np.ndarray, com: np.ndarray, t_wrench: np.ndarray, fy: np.ndarray,
                     gravity: float, settings: BalanceSettings = BalanceSettings(),
                     ) -> MomentumBalance:
    """:func:`momentum_balance` from a COM trajectory com [n, 2] (m) at t [n] (s) and the
    vertical ground force fy [k] (N) at t_wrench [k] (s)."""
    st = settings
    t, com = np.asarray(t, dtype=float), np.asarray(com, dtype=float)
    t_w, fy = np.asarray(t_wrench, dtype=float), np.asarray(fy, dtype=float)
    rate_k, rate_w = sample_rate(t), sample_rate(t_w)
    cut_k, _ = cutoff_for_rate(st.cutoff_hz, rate_k)
    cut_w, _ = cutoff_for_rate(min(st.cutoff_hz, float(cut_k)), rate_w)
    height = SmoothSignal(t, com[:, 1:2], rate_k, cut_k)
    acc = height(t, 2)[:, 0]
    force = SmoothSignal(t_w, fy[:, None], rate_w, cut_w)(np.clip(t, t_w[0], t_w[-1]))[:, 0]
    contacts = loaded_phases(t_w, fy, st.contact_threshold_n, st.min_phase_s)

    # Unmeasured support: the leading unloaded stretch in which the COM does not fall freely.
    step_off = support = None
    first_td = contacts[0][0] if contacts else float(t[-1])
    if contacts and contacts[0][0] <= t_w[0] + 1e-9:
        first_td = None                        # the recording starts loaded
    if first_td is not None:
        lead = t < first_td
        falling = acc < -st.support_fraction_g * gravity
        if lead.any() and not falling[lead][0]:
            # the free fall: the last run of 'falling' that starts inside the lead
            idx = np.flatnonzero(lead)
            starts = [i for i in idx[1:] if falling[i] and not falling[i - 1]]
            if starts:
                i = starts[-1]
                a0, a1 = acc[i - 1], acc[i]
                thr = -st.support_fraction_g * gravity
                step_off = float(t[i - 1] + (t[i] - t[i - 1]) * (a0 - thr) / (a0 - a1))
                support = (float(t[0]), step_off)

    # Implied mass.
    estimates = []
    quiet = _quiet_stance(t_w, fy, contacts, st, gravity)
    if quiet is not None:
        estimates.append(quiet)
    free_from = step_off if step_off is not None else float(t[0])
    for k, (td, to) in enumerate(contacts):
        before_start = contacts[k - 1][1] if k > 0 else free_from
        if k == 0 and first_td is None:
            continue
        after_end = contacts[k + 1][0] if k + 1 < len(contacts) else float(t[-1])
        if (td - before_start < st.min_flight_s) or (after_end - to < st.min_flight_s):
            continue
        m = st.flight_margin_s
        sel_b = (t > before_start + m) & (t < td - m)
        sel_a = (t > to + m) & (t < after_end - m)
        if sel_b.sum() < st.min_flight_samples or sel_a.sum() < st.min_flight_samples:
            continue
        # an unloaded stretch is a flight only if the COM falls freely there: a body resting
        # on a chair or a step while its feet unload the plates (a sit-to-stand) is not
        acc_b, acc_a = (flight_acceleration(t[sel], com[sel, 1]) for sel in (sel_b, sel_a))
        if max(abs(acc_b + gravity), abs(acc_a + gravity)) > st.flight_acc_tolerance_g * gravity:
            continue
        fit_b = fit_flight(t[sel_b], com[sel_b, 1], gravity)
        fit_a = fit_flight(t[sel_a], com[sel_a, 1], gravity)
        v_td = _flight_velocity(fit_b[0], td, gravity)
        v_to = _flight_velocity(fit_a[0], to, gravity)
        inside = (t_w >= td) & (t_w <= to)
        tt = np.concatenate([[td], t_w[inside], [to]])
        ff = np.concatenate([[st.contact_threshold_n], fy[inside], [st.contact_threshold_n]])
        impulse = float(np.trapezoid(ff, tt))
        denom = v_to - v_td + gravity * (to - td)
        if denom <= 0:
            continue
        estimates.append(MassEstimate(
            mass_kg=impulse / denom, method='impulse between flights', interval_s=(td, to),
            detail={'impulse_n_s': impulse, 'v_touchdown_m_s': v_td, 'v_takeoff_m_s': v_to,
                    'contact_s': to - td, 'flight_fit_rms_m': max(fit_b[1], fit_a[1]),
                    'flight_acc_m_s2': [acc_b, acc_a]}))
    edge = 1.0 / float(cut_k)
    supported = _supported_stretch(height, t_w, fy, contacts, edge, st, gravity)
    if supported is not None:
        estimates.append(supported)
    return MomentumBalance(t=t, com=com, com_acc_y=acc, force_y=force, contacts=contacts,
                           step_off_s=step_off, unmeasured_support_s=support,
                           estimates=estimates, gravity=gravity, edge_s=edge)


def _supported_stretch(height: SmoothSignal, t_w: np.ndarray, fy: np.ndarray,
                       contacts: list[tuple[float, float]], edge_s: float, st: BalanceSettings,
                       gravity: float) -> MassEstimate | None:
    """The mass the impulse over the longest loaded phase implies (module docstring; None if
    no phase is ``supported_min_s`` long inside the filter's edges ``edge_s`` [s]); ``height``
    is the COM's filtered height [m]."""
    t0, t1 = float(height.t[0]), float(height.t[-1])
    spans = [(max(a, t0) + edge_s, min(b, t1) - edge_s) for a, b in contacts]
    spans = [(a, b) for a, b in spans if b - a >= st.supported_min_s]
    if not spans:
        return None
    a, b = max(spans, key=lambda ab: ab[1] - ab[0])
    v = height(np.array([a, b]), 1)[:, 0]
    inside = (t_w > a) & (t_w < b)
    tt = np.concatenate([[a], t_w[inside], [b]])
    ff = np.concatenate([[np.interp(a, t_w, fy)], fy[inside], [np.interp(b, t_w, fy)]])
    impulse = float(np.trapezoid(ff, tt))
    denom = float(v[1] - v[0] + gravity * (b - a))
    if denom <= 0:
        return None
    return MassEstimate(mass_kg=impulse / denom, method='impulse over a supported stretch',
                        interval_s=(a, b), detail={'impulse_n_s': impulse,
                                                   'v_start_m_s': float(v[0]),
                                                   'v_end_m_s': float(v[1])})
