"""Figures of the study (PNG, matplotlib's Agg backend: no display needed)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from nmt_ros.model.parameters import MUSCLES, SEGMENTS  # noqa: E402
from nmt_ros.study.trial import Observations, Truth  # noqa: E402

MUSCLE_LABELS = ('GMAX', 'ILPSO', 'HAMS', 'BFSH', 'RF', 'VAS', 'GAS', 'SOL', 'TA')
SEGMENT_LABELS = ('Foot', 'Shank', 'Thigh', 'HAT')


def _liftoff(ax: plt.Axes, t_lo: float) -> None:
    ax.axvline(t_lo, color='0.6', lw=0.8, ls=':')


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
    for a in axes.ravel():
        _liftoff(a, truth.liftoff_s)
        a.set_xlabel('time (s)')
    fig.suptitle(f'{title}; lift-off at {truth.liftoff_s * 1000:.1f} ms (dotted)')
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


__all__ = ['MUSCLE_LABELS', 'SEGMENTS', 'SEGMENT_LABELS', 'plot_reference_jump']
