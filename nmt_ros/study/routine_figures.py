"""The routine's figure (PNG, Agg): vertical ground force over the routine, the jump heights
targeted and achieved, and the quiet-stance sway (centre of pressure)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def plot_routine(t: np.ndarray, fy_bw: np.ndarray, cop_m: np.ndarray, cycles: list[dict],
                 stances: list[tuple[float, float]], path: str | Path,
                 obs_t: np.ndarray | None = None, obs_fy_bw: np.ndarray | None = None,
                 title: str = 'Routine') -> Path:
    """t [n] s, vertical force fy_bw [n] (BW), centre of pressure cop_m [n] (m, NaN in
    flight), cycles (``Cycle.as_dict()``), quiet-stance windows; optional observed force."""
    fig, axes = plt.subplots(3, 1, figsize=(13, 9), constrained_layout=True,
                             gridspec_kw={'height_ratios': [3, 2, 2]})
    ax = axes[0]
    if obs_t is not None:
        ax.plot(obs_t, obs_fy_bw, color='0.75', lw=0.4, label='observed')
    ax.plot(t, fy_bw, color='C0', lw=0.8, label='truth')
    for a, b in stances:
        ax.axvspan(a, b, color='C2', alpha=0.08, lw=0)
    for c in cycles:
        ax.annotate(c['kind'], (c['start_s'], ax.get_ylim()[1] if False else 0),
                    xytext=(0, -12), textcoords='offset points', fontsize=7, color='C3')
    ax.set(ylabel='vertical ground force (BW)', title=f'{title}: vertical ground force '
           '(green: quiet stance)')
    ax.legend(loc='upper right', fontsize=8)
    ax = axes[1]
    x = np.arange(len(cycles))
    tgt = [100 * c['target_height_m'] for c in cycles]
    ach = [100 * c['achieved_height_m'] for c in cycles]
    ax.bar(x - 0.2, tgt, 0.4, label='targeted', color='C1')
    ax.bar(x + 0.2, ach, 0.4, label='achieved (truth)', color='C0')
    ax.set_xticks(x, [f"{c['kind']}\n{c['start_s']:.1f} s" for c in cycles], fontsize=8)
    ax.set(ylabel='jump height (cm)', title='Jump heights (COM apex above standing)')
    ax.legend(fontsize=8)
    ax = axes[2]
    ax.plot(t, 1000 * (cop_m - np.nanmedian(cop_m)), color='C4', lw=0.6)
    for a, b in stances:
        ax.axvspan(a, b, color='C2', alpha=0.08, lw=0)
    ax.set(xlabel='time (s)', ylabel='centre of pressure (mm)',
           title='Centre of pressure (from its median; loaded samples)')
    lo, hi = np.nanpercentile(1000 * (cop_m - np.nanmedian(cop_m)), [0.5, 99.5])
    ax.set_ylim(lo - 10, hi + 10)
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
