"""Estimates scored against a synthetic truth phase by phase (long streams, routines).

A routine alternates quiet stance, movement on the plate, flight and landings; one RMS over
all of it hides where an estimator fails. The phases are defined on the truth alone:

* ``flight``: the true vertical ground force below ``air_force_n`` [N];
* ``landing``: the first ``landing_s`` [s] after each touchdown (impact and absorption);
* ``quiet``: on the plate, every segment rate below ``quiet_rate_rad_s`` [rad/s];
* ``moving``: on the plate otherwise (countermovement, push-off, recovery), landings excluded;
* ``all``: every instant.

Errors are RMS over the instants of a phase that have an estimate: joint torques in % of the
truth's peak |torque| of each joint over the whole record, musculotendon forces in % of F0.
``coverage`` is the fraction of truth instants that have an estimate.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from nmt_ros.model.jumper import JumperModel
from nmt_ros.records import Truth

PHASES = ('all', 'quiet', 'moving', 'flight', 'landing')


def truth_phases(truth: Truth, air_force_n: float = 1.0, landing_s: float = 0.15,
                 quiet_rate_rad_s: float = 0.05) -> dict[str, np.ndarray]:
    """Boolean masks over ``truth.t`` for each phase of :data:`PHASES`."""
    air = truth.s[:, 1] < air_force_n
    touchdowns = truth.t[1:][~air[1:] & air[:-1]]
    landing = np.zeros(truth.t.size, bool)
    for t_td in touchdowns:
        landing |= (truth.t >= t_td) & (truth.t < t_td + landing_s)
    still = np.abs(truth.qd[:, :4]).max(axis=1) < quiet_rate_rad_s
    return {'all': np.ones(truth.t.size, bool), 'quiet': ~air & still & ~landing,
            'moving': ~air & ~still & ~landing, 'flight': air, 'landing': landing & ~air}


def phase_scores(model: JumperModel, truth: Truth, t: np.ndarray, tau: np.ndarray | None,
                 f: np.ndarray | None = None, tol_s: float = 1e-6) -> dict[str, Any]:
    """Torque [% peak] and muscle-force [% F0] RMS errors per phase of estimates at instants
    ``t`` [s] (matched to truth instants within ``tol_s``; others are ignored), with the
    number of instants scored and the coverage of each phase (``tau`` or ``f`` None: not
    scored)."""
    t = np.asarray(t, dtype=float)
    k = np.clip(np.searchsorted(truth.t, t - tol_s), 0, truth.t.size - 1)
    ok = np.abs(truth.t[k] - t) <= tol_s
    k = k[ok]
    tau = None if tau is None else np.asarray(tau)[ok]
    f = None if f is None else np.asarray(f)[ok]
    peak = np.abs(truth.tau).max(axis=0)
    f0 = model.p.muscles.f0
    masks = truth_phases(truth)
    covered = np.zeros(truth.t.size, bool)
    covered[k] = True
    out: dict[str, Any] = {'torque_peak_nm': dict(zip(('ankle', 'knee', 'hip'),
                                                      peak.round(2).tolist()))}
    for name in PHASES:
        m = masks[name][k]
        row: dict[str, Any] = {'n': int(m.sum()),
                               'coverage': float(covered[masks[name]].mean())
                               if masks[name].any() else float('nan')}
        if m.any():
            if tau is not None:
                err = np.sqrt(((tau[m] - truth.tau[k[m]]) ** 2).mean(axis=0)) / peak * 100
                row['torque_rms_pct_peak'] = dict(zip(('ankle', 'knee', 'hip'),
                                                      err.round(3).tolist()))
            if f is not None:
                fe = np.sqrt(((f[m] - truth.f[k[m]]) ** 2).mean(axis=0)) / f0 * 100
                row['muscle_force_rms_pct_f0'] = {'mean': float(fe.mean().round(3)),
                                                  'max': float(fe.max().round(3))}
        out[name] = row
    return out


def format_phase_scores(scores: dict[str, Any]) -> str:
    """A small table of :func:`phase_scores`."""
    lines = [f'{"phase":8s} {"n":>7s} {"cover":>6s}  torque % peak (ankle knee hip)'
             '   muscle % F0 (mean max)']
    for name in PHASES:
        row = scores.get(name)
        if not row or not row['n']:
            continue
        tq = row.get('torque_rms_pct_peak', {j: float('nan') for j in ('ankle', 'knee',
                                                                       'hip')})
        line = (f'{name:8s} {row["n"]:7d} {row["coverage"]:6.3f}  {tq["ankle"]:6.2f} '
                f'{tq["knee"]:6.2f} {tq["hip"]:6.2f}')
        if 'muscle_force_rms_pct_f0' in row:
            mf = row['muscle_force_rms_pct_f0']
            line += f'            {mf["mean"]:6.2f} {mf["max"]:6.2f}'
        lines.append(line)
    return '\n'.join(lines)
