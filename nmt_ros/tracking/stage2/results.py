"""Stage 2's records: the muscle state, the output of one applied plan, the saturation report
and the result on the input grid (``assemble`` stacks the step outputs into it)."""
from __future__ import annotations

from dataclasses import dataclass, field
import time

import numpy as np

from nmt_ros.tracking.stage2.lqt import lqt_control
from nmt_ros.tracking.stage2.plans import WindowPlan
from nmt_ros.tracking.stage2.references import Stage2Reference


@dataclass(frozen=True)
class MuscleState:
    """The muscle part of the tracker's state at global sample ``index``."""

    index: int
    t: float
    a: np.ndarray            # [m]
    f: np.ndarray            # [m] N


@dataclass(frozen=True)
class Stage2Step:
    """Outputs of ``forward_pass.apply_plan`` for the samples [start, start + k) of one plan."""

    start: int
    t: np.ndarray            # [k]
    a: np.ndarray            # [k, m] at t
    f: np.ndarray            # [k, m]
    eta: np.ndarray          # [k, m] Eq. 14 at t
    u: np.ndarray            # [k, m] applied (held over [t_i, t_i+1)), in [0, 1]
    u_demand: np.ndarray     # [k, m] Eq. 9 at t (unclipped)
    saturated: np.ndarray    # [k, m] bool: u at a bound (planned, or the target out of reach)
    shortfall: np.ndarray    # [k, m] N: |f* - f| at the interval's end (int |eta - fdot|)
    W: np.ndarray            # [k, m, m]
    g: np.ndarray            # [k, m]
    planned: np.ndarray | None = None  # [k, m] bool: held at a bound by the plan


@dataclass(frozen=True)
class SaturationReport:
    """Where the excitation sits at a bound (per muscle, over the internal intervals).

    'clip' mode: Eq. 9 asked for u outside [0, 1] and was clipped (the LQT did not foresee it).
    'plan' mode: mostly planned - the bounded LQT holds the muscle at u = 0 or 1 and the LQT
    of the free muscles accounts for it (``fraction_planned``); the rest (and the shortfall) is
    what the forward pass still had to clip.
    """

    names: tuple[str, ...]
    fraction: np.ndarray          # [m] fraction of intervals saturated
    fraction_low: np.ndarray      # [m] ... at u = 0 (force could not drop faster)
    fraction_high: np.ndarray     # [m] ... at u = 1 (force could not rise faster)
    shortfall_integral: np.ndarray  # [m] N: int |eta - fdot_realised| dt (unplanned only)
    shortfall_max: np.ndarray     # [m] N, largest one-interval shortfall
    fraction_planned: np.ndarray | None = None  # [m] ... held at a bound by the plan

    @property
    def any(self) -> bool:
        return bool(np.any(self.fraction > 0))

    def summary(self) -> dict[str, dict[str, float]]:
        planned = (self.fraction_planned if self.fraction_planned is not None
                   else np.zeros_like(self.fraction))
        return {n: {'fraction': float(self.fraction[i]),
                    'fraction_low': float(self.fraction_low[i]),
                    'fraction_high': float(self.fraction_high[i]),
                    'fraction_planned': float(planned[i]),
                    'shortfall_integral_N': float(self.shortfall_integral[i])}
                for i, n in enumerate(self.names)}


@dataclass(frozen=True)
class Stage2Result:
    """Stage 2 on a grid t [n]: forces, activations, excitations, tracking, bookkeeping."""

    mode: str
    names: tuple[str, ...]
    t: np.ndarray                 # [n] s
    f: np.ndarray                 # [n, m] musculotendon forces (N)
    a: np.ndarray                 # [n, m]
    u: np.ndarray                 # [n, m] applied excitations (zero-order hold)
    u_demand: np.ndarray          # [n, m] Eq. 9 (unclipped)
    eta: np.ndarray               # [n, m] Eq. 14 (N/s)
    tau_ref: np.ndarray           # [n, 3]
    tau_muscle: np.ndarray        # [n, 3] C f
    W: np.ndarray = field(repr=False)  # [n, m, m] the W each sample's control used
    g: np.ndarray = field(repr=False)  # [n, m]
    saturation: SaturationReport = field(repr=False, default=None)
    cpu_s: dict[str, float] = field(default_factory=dict)
    wall_s: dict[str, float] = field(default_factory=dict)
    window_length: float | None = None
    window_stride: float | None = None
    substeps: int = 1
    saturation_mode: str = 'clip'
    plan_iterations: tuple[int, ...] = ()   # interior-point iterations per plan ('plan' mode)
    plan_converged: bool = True             # every plan's interior point met its tolerance

    @property
    def tracking_error(self) -> np.ndarray:
        """tau_ref - C f [n, 3] (N m)."""
        return self.tau_ref - self.tau_muscle

    @property
    def rms_error(self) -> np.ndarray:
        """RMS torque-tracking error per joint [3] (N m)."""
        return np.sqrt(np.mean(self.tracking_error ** 2, axis=0))

    @property
    def rms_error_relative(self) -> np.ndarray:
        """RMS error per joint / the joint's peak |tau_ref| [3]."""
        return self.rms_error / np.max(np.abs(self.tau_ref), axis=0)

    @property
    def latency_s(self) -> float:
        """Delay between a reference sample and the force estimate that uses it."""
        if self.window_length is None:
            return float(self.t[-1] - self.t[0])
        return float(self.window_length + self.window_stride)


def assemble(ref: Stage2Reference, steps: list[Stage2Step], final: MuscleState,
             plans: list[WindowPlan], R: np.ndarray, names: tuple[str, ...], mode: str,
             saturation_mode: str, cpu: dict[str, float], wall: dict[str, float],
             window_length: float | None = None,
             window_stride: float | None = None) -> Stage2Result:
    """Stack step outputs (+ the final sample) into a ``Stage2Result`` on the input grid.

    Saturation statistics use every internal interval; the arrays are sampled at the
    input samples (every ``ref.substeps``-th internal row). R diagonal [m] of Eq. 11;
    window_length, window_stride [s] (windowed mode only).
    """
    last_plan = plans[-1]
    cat = {name: np.concatenate([getattr(s, name) for s in steps])
           for name in ('a', 'f', 'eta', 'u', 'u_demand', 'saturated', 'shortfall', 'W', 'g')}
    planned = np.concatenate([s.planned if s.planned is not None
                              else np.zeros_like(s.saturated) for s in steps])
    w_last, g_last = last_plan.W[-1], last_plan.g[-1]
    if last_plan.discrete is None:
        eta_last = lqt_control(w_last, g_last, final.f, R)
    else:                                   # no interval after the last sample
        eta_last = cat['eta'][-1]
    sub = slice(None, None, ref.substeps)
    a = np.vstack([cat['a'], final.a])[sub]
    f = np.vstack([cat['f'], final.f])[sub]
    eta = np.vstack([cat['eta'], eta_last])[sub]
    u = np.vstack([cat['u'], cat['u'][-1:]])[sub]
    u_dem = np.vstack([cat['u_demand'], cat['u_demand'][-1:]])[sub]
    W = np.concatenate([cat['W'], w_last[None]])[sub]
    g = np.vstack([cat['g'], g_last])[sub]
    sat, short, u_int = cat['saturated'], cat['shortfall'], cat['u']
    report = SaturationReport(
        names=names, fraction=sat.mean(axis=0),
        fraction_low=(sat & (u_int <= 0.0)).mean(axis=0),
        fraction_high=(sat & (u_int >= 1.0)).mean(axis=0),
        shortfall_integral=short.sum(axis=0), shortfall_max=short.max(axis=0),
        fraction_planned=planned.mean(axis=0))
    C = ref.C[sub]
    tau_m = np.einsum('npm,nm->np', C, f)
    return Stage2Result(mode=mode, names=names, t=ref.t[sub], f=f, a=a, u=u,
                        u_demand=u_dem, eta=eta, tau_ref=ref.tau_ref[sub], tau_muscle=tau_m,
                        W=W, g=g, saturation=report, cpu_s=cpu, wall_s=wall,
                        window_length=window_length, window_stride=window_stride,
                        substeps=ref.substeps, saturation_mode=saturation_mode,
                        plan_iterations=tuple(p.plan_iterations for p in plans),
                        plan_converged=all(p.plan_converged for p in plans))


class PartClock:
    """Accumulates CPU (process) and wall seconds per named part (``Stage2Result.cpu_s``,
    ``wall_s``): ``with clock('plan'): ...``."""

    def __init__(self, cpu: dict[str, float] | None = None,
                 wall: dict[str, float] | None = None) -> None:
        self.cpu = {} if cpu is None else cpu
        self.wall = {} if wall is None else wall

    def __call__(self, part: str) -> PartClock:
        self._part = part
        return self

    def __enter__(self) -> None:
        self._c0, self._w0 = time.process_time(), time.perf_counter()

    def __exit__(self, *exc: object) -> None:
        self.cpu[self._part] = self.cpu.get(self._part, 0.0) + time.process_time() - self._c0
        self.wall[self._part] = self.wall.get(self._part, 0.0) + time.perf_counter() - self._w0
