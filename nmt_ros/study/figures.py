"""Figures of the study (PNG, matplotlib's Agg backend: no display needed)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from nmt_ros.model.parameters import MUSCLES, SEGMENTS  # noqa: E402
from nmt_ros.records import Observations, Truth  # noqa: E402

MUSCLE_LABELS = ('GMAX', 'ILPSO', 'HAMS', 'BFSH', 'RF', 'VAS', 'GAS', 'SOL', 'TA')
SEGMENT_LABELS = ('Foot', 'Shank', 'Thigh', 'HAT')


def _liftoff(ax: plt.Axes, t_lo: float) -> None:
    ax.axvline(t_lo, color='0.6', lw=0.8, ls=':')


def _finish(fig: plt.Figure, axes: np.ndarray, t_lo: float, path: str | Path) -> Path:
    """Mark lift-off and label time on every panel, save as PNG, close."""
    for a in np.ravel(axes):
        _liftoff(a, t_lo)
        a.set_xlabel('time (s)')
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_reference_jump(truth: Truth, obs: Observations | None, path: str | Path,
                        title: str = 'Reference jump (parameter optimisation)',
                        body_weight: float | None = None) -> Path:
    """Angles, ground forces and moment, excitations and activations vs time."""
    fig, axes = plt.subplots(2, 2, figsize=(12, 8), constrained_layout=True)
    ax = axes[0, 0]
    for j, label in enumerate(SEGMENT_LABELS):
        line, = ax.plot(truth.t, np.degrees(truth.q[:, j]), label=label)
        if obs is not None:
            ax.plot(obs.t_angles, np.degrees(obs.angles[:, j]), 'o', ms=3, mfc='none',
                    color=line.get_color())
    ax.set(ylabel='segment angle (deg)', title='Segment angles (lines: actual, o: observed)')
    ax.legend(loc='best', fontsize=8)
    ax = axes[0, 1]
    scale = body_weight or 1.0
    unit = 'BW' if body_weight else 'N'
    for k, label in ((0, 'fore-aft'), (1, 'vertical')):
        line, = ax.plot(truth.t, truth.s[:, k] / scale, label=f'{label} (actual)')
        if obs is not None:
            ax.plot(obs.t_wrench, obs.wrench[:, k] / scale, '.', ms=2, alpha=0.4,
                    color=line.get_color())
    ax.set(ylabel=f'ground force ({unit})', title='Ground forces (dots: observed)')
    ax2 = ax.twinx()
    ax2.plot(truth.t, truth.s[:, 2], 'k--', lw=1, label='moment (actual)')
    ax2.set_ylabel('ground moment about foot COM (N m)')
    ax.legend(loc='upper left', fontsize=8)
    ax2.legend(loc='upper right', fontsize=8)
    ax = axes[1, 0]
    for i in range(len(MUSCLE_LABELS)):
        base = 1.2 * (len(MUSCLES) - 1 - i)
        ax.fill_between(truth.t, base, base + truth.u[:, i], alpha=0.6)
        ax.axhline(base, color='0.8', lw=0.5)
    ax.set(yticks=1.2 * (len(MUSCLES) - 1 - np.arange(len(MUSCLES))) + 0.5,
           yticklabels=MUSCLE_LABELS, ylabel='excitation (0..1 per muscle)',
           title='Excitations (proximal-to-distal recruitment)')
    ax = axes[1, 1]
    for i, label in enumerate(MUSCLE_LABELS):
        ax.plot(truth.t, truth.a[:, i], label=label)
    ax.set(ylabel='activation', title='Activations')
    ax.legend(loc='best', fontsize=7, ncol=3)
    fig.suptitle(f'{title}; lift-off at {truth.liftoff_s * 1000:.1f} ms (dotted)')
    return _finish(fig, axes, truth.liftoff_s, path)


__all__ = ['MUSCLE_LABELS', 'SEGMENTS', 'SEGMENT_LABELS', 'plot_reference_jump']


JOINT_LABELS = ('Ankle', 'Knee', 'Hip')


def _angles_panel(ax: plt.Axes, truth: Truth, obs: Observations,
                  estimates: list[tuple[np.ndarray, np.ndarray, str]], title: str) -> None:
    """Segment angles: actual (thick), estimates (t, q, line style), raw observations (o)."""
    for j, label in enumerate(SEGMENT_LABELS):
        line, = ax.plot(truth.t, np.degrees(truth.q[:, j]), lw=2.2, alpha=0.5, label=label)
        for t, q, style in estimates:
            ax.plot(t, np.degrees(q[:, j]), style, lw=1, color=line.get_color())
        ax.plot(obs.t_angles, np.degrees(obs.angles[:, j]), 'o', ms=3, mfc='none',
                color=line.get_color())
    ax.set(title=title, ylabel='angle (deg)')
    ax.legend(fontsize=7)


def plot_fig3(truth: Truth, obs: Observations, run: object, path: str | Path,
              stage1_label: str = 'SKT') -> Path:
    """Paper Fig. 3: joint torques, angles, ground forces and moment: actual/Stage 1/IVD/
    observed (``stage1_label``: the Stage-1 method's name in the legends)."""
    skt, ivd = run.skt, run.ivd
    name = stage1_label
    fig, axes = plt.subplots(2, 2, figsize=(13, 8.5), constrained_layout=True)
    ax = axes[0, 0]
    for j, label in enumerate(JOINT_LABELS):
        line, = ax.plot(truth.t, truth.tau[:, j], lw=2.2, alpha=0.5, label=f'{label} actual')
        ax.plot(skt.t, skt.tau[:, j], '-', lw=1, color=line.get_color(), label=f'{label} {name}')
        ax.plot(ivd.t, ivd.tau[:, j], '--', lw=1, color=line.get_color(), label=f'{label} IVD')
    ax.set(title='(A) Joint torques (thick: actual, dashed: IVD)',
           ylabel='torque (N m)')
    ax.legend(fontsize=7, ncol=3)
    _angles_panel(axes[0, 1], truth, obs, [(skt.t, skt.q, '-'), (ivd.sim_t, ivd.sim_q, '--')],
                  '(B) Segment angles (thick: actual, thin: Stage 1, dashed: IVD sim.)')
    ax = axes[1, 0]
    for k, label in ((0, 'fore-aft'), (1, 'vertical')):
        line, = ax.plot(truth.t, truth.s[:, k], lw=2.2, alpha=0.5, label=f'{label} actual')
        ax.plot(skt.t, skt.s[:, k], '-', lw=1, color=line.get_color(), label=f'{label} {name}')
        ax.plot(ivd.sim_t, ivd.sim_s[:, k], '--', lw=1, color=line.get_color(),
                label=f'{label} IVD sim')
        ax.plot(obs.t_wrench, obs.wrench[:, k], '.', ms=1.5, alpha=0.3, color=line.get_color())
    ax.set(title='(C) Ground forces (dots: raw)', ylabel='force (N)')
    ax.legend(fontsize=7)
    ax = axes[1, 1]
    ax.plot(truth.t, truth.s[:, 2], 'k', lw=2.2, alpha=0.5, label='actual')
    ax.plot(skt.t, skt.s[:, 2], 'C3', lw=1, label=name)
    ax.plot(obs.t_wrench, obs.wrench[:, 2], '.', ms=1.5, alpha=0.3, color='0.4',
            label='raw (biased)')
    ax.plot(run.cond.wrench.t, run.cond.wrench.filtered[:, 2], 'C0', lw=0.8,
            label='filtered observation')
    ax.set(title='(D) Ground moment about the foot COM', ylabel='moment (N m)')
    ax.legend(fontsize=7)
    return _finish(fig, axes, truth.liftoff_s, path)


def plot_fig4(truth: Truth, run: object, path: str | Path, f0: np.ndarray) -> Path:
    """Paper Fig. 4: excitations and normalised muscle forces, NMT vs parameter optimisation."""
    s2 = run.stage2
    fig, axes = plt.subplots(3, 3, figsize=(12, 8), sharex=True, constrained_layout=True)
    for i, (ax, label) in enumerate(zip(axes.ravel(), MUSCLE_LABELS)):
        ax.plot(truth.t, truth.u[:, i], 'k', lw=1, label='PO excitation')
        ax.plot(truth.t, truth.f[:, i] / f0[i], 'k--', lw=1, label='PO force / F0')
        ax.plot(s2.t, s2.u[:, i], color='0.55', lw=2.2, alpha=0.8, label='NMT excitation')
        ax.plot(s2.t, s2.f[:, i] / f0[i], '--', color='0.55', lw=2.2, alpha=0.8,
                label='NMT force / F0')
        ax.set_title(label)
        ax.set_ylim(-0.05, 1.15)
    axes[0, 0].legend(fontsize=7)
    return _finish(fig, axes, truth.liftoff_s, path)


def plot_fig5(truth: Truth, obs: Observations, run: object, model: object,
              path: str | Path) -> Path:
    """Paper Fig. 5: NMT torques, and the NMT simulation's angles and ground forces."""
    s2, sim, skt = run.stage2, run.nmt_sim, run.skt
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6), constrained_layout=True)
    ax = axes[0]
    for j, label in enumerate(JOINT_LABELS):
        line, = ax.plot(truth.t, truth.tau[:, j], lw=2.2, alpha=0.5, label=f'{label} actual')
        ax.plot(s2.t, s2.tau_muscle[:, j], '-', lw=1, color=line.get_color(),
                label=f'{label} NMT')
        ax.plot(skt.t, skt.tau[:, j], ':', lw=1, color=line.get_color(), label=f'{label} Stage 1')
    ax.set(title='(A) Joint torques', ylabel='torque (N m)')
    ax.legend(fontsize=7, ncol=3)
    _angles_panel(axes[1], truth, obs, [(sim.t, sim.x, '-')],
                  '(B) Segment angles: actual (thick), NMT (thin), observed (o)')
    ax = axes[2]
    s_sim, = model.batch(model.contact_outputs, sim.x[:, :6], sim.x[:, 6:12], sim.x0)
    for k, label in ((0, 'fore-aft'), (1, 'vertical')):
        line, = ax.plot(truth.t, truth.s[:, k], lw=2.2, alpha=0.5, label=f'{label} actual')
        ax.plot(sim.t, s_sim[:, k], '-', lw=1, color=line.get_color(), label=f'{label} NMT')
    ax.set(title='(C) Ground forces', ylabel='force (N)')
    ax.legend(fontsize=7)
    return _finish(fig, axes, truth.liftoff_s, path)


def plot_lab_fit(obs: Observations, estimates: object, path: str | Path, body_weight: float,
                 f0: np.ndarray, id_table: object | None = None,
                 title: str = 'Lab recording: estimate vs measurement',
                 id_label: str = 'OpenSim ID') -> Path:
    """A tracked lab recording over the tracked span (``estimates``: ``TrialEstimates`` on
    the recording's time): measured vs estimated ground forces [BW] and segment angles [deg],
    the estimated joint torques [N m] (with OpenSim's inverse dynamics, ``id_table``, when
    given) and the muscle forces [F0] (Stage 2's, else the estimator's)."""
    s1 = estimates.stage1
    t0, t1 = float(s1.t[0]), float(s1.t[-1])
    fig, axes = plt.subplots(2, 2, figsize=(12, 8), constrained_layout=True)
    kw = (obs.t_wrench >= t0 - 1e-9) & (obs.t_wrench <= t1 + 1e-9)
    ax = axes[0, 0]
    for j, (label, color) in enumerate((('Fx', 'C0'), ('Fy', 'C3'))):
        ax.plot(obs.t_wrench[kw], obs.wrench[kw, j] / body_weight, color=color, lw=0.8,
                alpha=0.5, label=f'{label} measured')
        ax.plot(s1.t, s1.s[:, j] / body_weight, color=color, lw=1.5, label=f'{label} model')
    ax.set_ylabel('ground force (BW)')
    ax.legend(fontsize=8, ncol=2)
    ax = axes[0, 1]
    ka = (obs.t_angles >= t0 - 1e-9) & (obs.t_angles <= t1 + 1e-9)
    for j, label in enumerate(SEGMENT_LABELS):
        ax.plot(obs.t_angles[ka], np.degrees(obs.angles[ka, j]), '.', ms=2.5, color=f'C{j}')
        ax.plot(s1.t, np.degrees(s1.q[:, j]), color=f'C{j}', lw=1.3, label=label)
    ax.set_ylabel('segment angle (deg; dots: measured)')
    ax.legend(fontsize=8, ncol=2)
    ax = axes[1, 0]
    for j, label in enumerate(('ankle', 'knee', 'hip')):
        ax.plot(s1.t, s1.tau[:, j], color=f'C{j}', lw=1.5, label=f'{label} (estimate)')
        if id_table is not None:
            col = ('ankle_angle_moment', 'knee_angle_moment', 'hip_flexion_moment')[j]
            keep = (id_table.time >= t0 - 1e-9) & (id_table.time <= t1 + 1e-9)
            ax.plot(id_table.time[keep], id_table.column(col)[keep], color=f'C{j}', lw=0.8,
                    ls='--', label=f'{label} ({id_label})')
    ax.set_ylabel('joint torque (N m)')
    ax.legend(fontsize=8, ncol=2)
    ax = axes[1, 1]
    m = estimates.muscles
    if m is not None:
        t_m, f_m, src = m.t, m.f, 'Stage 2'
    else:
        t_m, f_m, src = s1.t, (s1.muscles or {}).get('f'), 'Stage 1'
    if f_m is not None:
        for i, label in enumerate(MUSCLE_LABELS):
            ax.plot(t_m, f_m[:, i] / f0[i], lw=1.1, label=label)
        ax.legend(fontsize=7, ncol=3)
    ax.set_ylabel(f'muscle force (F0, {src})')
    fig.suptitle(title)
    for a in np.ravel(axes):
        a.set_xlabel('time (s)')
        a.set_xlim(t0, t1)
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
