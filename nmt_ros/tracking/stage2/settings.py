"""Stage 2 settings: LQT weights (Appendix B), saturation handling, windows, internal step.

The one parameter file is ``nmt_ros/tracking/data/stage2.yaml`` (with the sources of its
values); ``load_stage2_settings`` reads it, keyword overrides replace fields.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml

SETTINGS_FILE = Path(__file__).resolve().parents[1] / 'data' / 'stage2.yaml'


@dataclass(frozen=True)
class Stage2Settings:
    """LQT weights (Appendix B), saturation handling and window options (``data/stage2.yaml``).

    P = k_p I3, Q = k_q I3, R = k_r diag(r_i / F0_i^2) with r keyed by muscle name; k_f
    (0: the paper) adds 1/2 int f' K_f f dt with K_f = k_f diag(1 / F0_i^2) to Eq. 11
    (``lqt.with_force_term``).
    window_length H [s]; window_stride [s] (None: one sample of the reference grid);
    max_step [s]: input intervals longer than this are split into substeps (``references``).
    saturation: 'plan' (default; the excitation bounds are part of the problem: a bounded-LQT
    plan fixes which muscles sit at u = 0 or 1 and when, and the LQT of Eqs. 12-14 runs on the
    free muscles, see ``nmt_ros.tracking.stage2``) or 'clip' (the paper: unconstrained LQT,
    Eq. 9 clipped to [0, 1]). saturation_margin: a planned activation step within this
    fraction of its reachable interval from an end counts as held at that bound; plan_tol,
    plan_max_iterations: interior-point tolerance and iteration cap of the bounded LQT.
    """

    k_q: float
    k_r: float
    k_p: float
    r: dict[str, float]
    window_length: float
    window_stride: float | None
    max_step: float
    source: str = ''
    saturation: str = 'plan'
    saturation_margin: float = 1e-3
    plan_tol: float = 1e-7
    plan_max_iterations: int = 60
    k_f: float = 0.0          # force term of Eq. 11 (beyond the paper): K_f = k_f diag(1/F0^2)

    def __post_init__(self) -> None:
        if self.saturation not in ('plan', 'clip'):
            raise ValueError(f"saturation must be 'plan' or 'clip', not {self.saturation!r}")

    def force_weight(self, f0: np.ndarray) -> np.ndarray | None:
        """K_f diagonal [m] (1/N^2 per s) for peak forces f0 [m] (N); None when k_f is 0."""
        if self.k_f == 0:
            return None
        if self.k_f < 0:
            raise ValueError(f'k_f must be >= 0, not {self.k_f}')
        return self.k_f / np.asarray(f0, dtype=float) ** 2

    def weights(self, names: tuple[str, ...], f0: np.ndarray,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Q [3, 3], R diagonal [m], P [3, 3]) for muscles ``names`` with peak forces f0 [m]."""
        missing = [n for n in names if n not in self.r]
        if missing:
            raise KeyError(f'Stage 2 settings have no R weight for {missing}')
        r = np.array([self.r[n] for n in names], dtype=float)
        return (self.k_q * np.eye(3), self.k_r * r / np.asarray(f0, dtype=float) ** 2,
                self.k_p * np.eye(3))


def load_stage2_settings(path: str | Path | None = None, **overrides: object) -> Stage2Settings:
    """Read ``data/stage2.yaml`` (or ``path``); keyword overrides replace fields."""
    path = Path(path) if path is not None else SETTINGS_FILE
    with open(path) as fh:
        d = yaml.safe_load(fh)
    stride = d.get('window_stride')
    optional = {}
    for key, kind in (('saturation', str), ('saturation_margin', float), ('plan_tol', float),
                      ('plan_max_iterations', int), ('k_f', float)):
        if d.get(key) is not None:
            optional[key] = kind(d[key])
    settings = Stage2Settings(
        k_q=float(d['k_q']), k_r=float(d['k_r']), k_p=float(d['k_p']),
        r={str(k): float(v) for k, v in d['r'].items()},
        window_length=float(d['window_length']),
        window_stride=None if stride is None else float(stride),
        max_step=float(d['max_step']),
        source=str(d.get('weights_source', '')).strip(), **optional)
    return replace(settings, **overrides) if overrides else settings
