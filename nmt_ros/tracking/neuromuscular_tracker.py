"""Stage 2 of NMT: neuromuscular tracking (METHOD.md section 4, Eqs. 8-14).

Given the Stage-1 joint torques tau_ref[n, 3] (ankle, knee, hip; OpenSim generalized forces of
ankle_angle, knee_angle, hip_flexion) and the tracked joint kinematics theta, theta_dot,
theta_ddot [n, 3] on a uniform grid t[n], find the 9 musculotendon forces f[n, 9], activations
a[n, 9] and excitations u[n, 9] in [0, 1]:

* Eq. 10: fdot = eta, tau = C(theta) f; the LQT of Eq. 11 gives eta = R^-1 (g - W f) (Eq. 14)
  with W, g from the backward Riccati/adjoint sweep (``riccati``; Eqs. 12-13).
* Eq. 9: the model's force F(a, l_MT, v_MT) (DeGroote, rigid tendon) depends directly on a and
  adot = drift(a) + gain(a) u, so fdot = dF/da (drift + gain u) + dF/dl ldot + dF/dv vdot:
  u = (eta - dF/da drift - dF/dl ldot_MT - dF/dv vdot_MT) / (dF/da gain)   (``eq9_excitation``)
  with ldot_MT = v_MT and vdot_MT = d/dt (dl/dtheta theta_dot) from theta_ddot.

Saturation (``settings.saturation``; DEPARTS FROM THE PAPER in the default 'plan'):

* 'clip' - the paper. On each interval [t_i, t_i+1] the LQT closed loop fdot = R^-1 (g - W f)
  is solved exactly from the ACTUAL force f_i (W frozen at the interval mean, g linear), giving
  the force f*_i+1 the LQT asks for. F is affine in a (F = a dF/da + F(0, l, v)), so f*_i+1
  fixes the activation a*_i+1, and the excitation held over the interval is the one for which
  the model's own activation ODE (solved exactly: linear in a for constant u) lands on a*_i+1 -
  Eq. 9 integrated over the interval (the instantaneous Eq. 9 value is returned as
  ``u_demand``). If it lies outside [0, 1], u is clipped, the muscles produce less than asked
  (the shortfall is recorded, ``SaturationReport``), and the feedback picks up from the actual
  force. The LQT does not know the bounds: on a maximum-height jump (prime movers at u = 1 for
  much of the push-off) it loads the cheap muscles (HAMS r = 0.1, RF 0.3) beyond what they can
  give and redistributes too late - measured on the reference jump's true torques: torque RMS
  4.5 / 13.8 / 11.7 % of peak (ankle / knee / hip), NMT jump 8 % low.
* 'plan' - the LQT of Eq. 11 WITH the excitation bounds 0 <= u <= 1 (a constrained LQT), in
  two steps per plan. (1) ``riccati.solve_bounded_lqt``: Eq. 11 discretised on the internal
  grid (trapezoid tracking, interval-rate effort, the same Q, R, P) with the activations as
  unknowns and every activation step between the exact steps at u = 0 and u = 1 - a convex QP,
  solved by a primal-dual interior point whose Newton steps are discrete LQTs factorised by the
  Riccati (banded Cholesky) recursion; ~15 iterations, ~10 ms for the 0.25 s jump. Its active
  set says which muscles sit at a bound over which intervals. (2) the LQT of that active set,
  ``riccati.discrete_lqt``: Eqs. 12-14 in discrete form (Riccati, adjoint, feedback law) for
  the free muscles, the saturated ones entering as known inputs that follow their own
  activation dynamics at u = 0 / 1 (their C f moves into the reference, their effort weight
  into the state cost). ``apply`` then holds the saturated muscles at their bound and moves the
  free ones by the feedback law (activation step -> excitation as above; a target out of reach
  is still clipped and reported as unplanned). Why this and not simpler variants (prototypes
  measured on the reference jump during development, not kept): taking the saturated muscles
  out of the continuous LQT (time-varying R: effort weight x1e4 over their saturated
  intervals, their forces of the previous pass as a known input) and iterating the saturation
  pattern from pass to pass (a primal-dual active-set iteration; a muscle released when the
  costate asks for less than its bound) does not converge - the pattern cycles and the cost
  oscillates (best pass 0.8 / 3.3 / 2.0 %, cost 2x the constrained optimum); and even on the
  right active set the continuous exact-step LQT is 1-2 % F0 off the discrete optimum at 1 ms
  steps (its frozen per-interval coefficients err O(h^2) with a large constant in the
  co-contraction directions: 1.6 % F0 even without bounds, against 0.02 % for the discrete
  form), which made windowed and full horizon differ by 3.4 % F0. The discrete LQT on
  the QP's active set reproduces the QP to 1e-4 % F0; without active bounds it is the discrete
  counterpart of Eqs. 12-14. Result on the reference jump's true torques: 0.4 / 1.4 / 1.1 %,
  forces within 6.3 % F0 of the truth (RF; the rest <= 3.4 %), NMT jump 1 % low, 0.05 s CPU.

Two modes share the recipe (``plan_window`` / ``run_windows`` -> ``WindowPlan``; ``apply``
advances a ``MuscleState``): full horizon (the paper: one plan over [0, tf]) and receding
windows of length H (a plan per window start t_k with P = 0 at t_k + H, applied over
[t_k, t_k + stride); in 'plan' mode each window's bounded LQT starts from the activations the
previous window left, so windows are planned one after the other). ``push`` is the streaming
entry point; the batch windowed mode runs the same plans and ``apply`` on the whole recording,
and equals ``push`` fed it in chunks (tested). Latency of the windowed estimate: H plus a
stride. With the bounds in the problem the windows agree with the full horizon much sooner
(saturation pins most of the solution): 0.05 % F0 at H = 100 ms on the reference jump.

Internal grid: input intervals longer than ``max_step`` (1 ms) are split into substeps
(kinematics by quintic Hermite from theta, theta_dot, theta_ddot; tau_ref linear, causal);
with W, g frozen per interval the stiff modes (>= 400 1/s) would otherwise lag the change of
C(theta) by O(step) (about 10 % torque error at 120 Hz without substeps); 'plan' runs on the
same internal grid. Results are returned
on the input grid; saturation statistics count every internal interval.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
import time

import casadi as ca
import numpy as np
import yaml

from nmt_ros.model.jumper import JumperModel, default_model
from nmt_ros.model.squat import rest_activations_for_posture
from nmt_ros.tracking import riccati

SETTINGS_FILE = Path(__file__).resolve().parent / 'data' / 'stage2.yaml'

#: Activation margin (activation units) beyond which a target counts as unreachable.
_SAT_TOL = 1e-9
_ROW_FIELDS = ('t', 'tau_ref', 'theta', 'theta_dot', 'theta_ddot', 'C', 'v_mt', 'vdot_mt',
               'phi', 'psi', 'dfdl_0', 'dfdl_1', 'dfdv_0', 'dfdv_1')


# ---------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class Stage2Settings:
    """LQT weights (Appendix B), saturation handling and window options (``data/stage2.yaml``).

    P = k_p I3, Q = k_q I3, R = k_r diag(r_i / F0_i^2) with r keyed by muscle name.
    window_length H [s]; window_stride [s] (None: one sample of the reference grid);
    max_step [s]: input intervals longer than this are split into substeps (``reference``).
    saturation: 'plan' (default; the excitation bounds are part of the problem: a bounded-LQT
    plan fixes which muscles sit at u = 0 or 1 and when, and the LQT of Eqs. 12-14 runs on the
    free muscles, see the module docstring) or 'clip' (the paper: unconstrained LQT, Eq. 9
    clipped to [0, 1]). saturation_margin: a planned activation step within this fraction of
    its reachable interval from an end counts as held at that bound; plan_tol,
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

    def __post_init__(self) -> None:
        if self.saturation not in ('plan', 'clip'):
            raise ValueError(f"saturation must be 'plan' or 'clip', not {self.saturation!r}")

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
                      ('plan_max_iterations', int)):
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


# ---------------------------------------------------------------------------- Eq. 9
def eq9_excitation(eta: np.ndarray, dF_da: np.ndarray, dF_dl: np.ndarray, dF_dv: np.ndarray,
                   drift: np.ndarray, gain: np.ndarray, l_mt_dot: np.ndarray,
                   v_mt_dot: np.ndarray) -> np.ndarray:
    """Eq. 9 (elementwise, unclipped): u = (eta - F_a drift - F_l ldot - F_v vdot)/(F_a gain)."""
    return (eta - dF_da * drift - dF_dl * l_mt_dot - dF_dv * v_mt_dot) / (dF_da * gain)


@dataclass(frozen=True)
class ActivationLaw:
    """adot = (d0 + d1 a) + (g0 + g1 a) u, read off the model's ``activation_affine``."""

    d0: np.ndarray
    d1: np.ndarray
    g0: np.ndarray
    g1: np.ndarray

    @classmethod
    def from_model(cls, model: JumperModel) -> ActivationLaw:
        n = len(model.p.muscles.names)
        at = [model.call(model.activation_affine, np.full(n, x)) for x in (0.0, 0.5, 1.0)]
        (d_0, g_0), (d_h, g_h), (d_1, g_1) = at
        if not (np.allclose(d_h, 0.5 * (d_0 + d_1)) and np.allclose(g_h, 0.5 * (g_0 + g_1))):
            raise ValueError('activation drift and gain must be affine in a')
        return cls(d0=d_0, d1=d_1 - d_0, g0=g_0, g1=g_1 - g_0)

    def affine(self, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(drift, gain) at activation a."""
        return self.d0 + self.d1 * a, self.g0 + self.g1 * a

    def step(self, a0: np.ndarray, u: np.ndarray, h: float, derivative: bool = True,
             ) -> tuple[np.ndarray, np.ndarray | None]:
        """Exact a(h) for constant u, and d a(h) / d u (None unless ``derivative``)."""
        kappa = -(self.d1 + self.g1 * u)              # > 0 for u in [0, 1]
        c0 = self.d0 + self.g0 * u
        a_inf = c0 / kappa
        decay = np.exp(-kappa * h)
        a1 = a_inf + (a0 - a_inf) * decay
        if not derivative:
            return a1, None
        da_inf = (self.g0 * kappa + c0 * self.g1) / kappa ** 2
        return a1, da_inf * (1 - decay) + (a0 - a_inf) * h * self.g1 * decay

    def step_affine(self, u: float, h: float) -> tuple[np.ndarray, np.ndarray]:
        """(slope, offset) [m] of the exact step for a constant u: a(h) = slope a0 + offset."""
        kappa = -(self.d1 + self.g1 * u)
        decay = np.exp(-kappa * h)
        return decay, (self.d0 + self.g0 * u) / kappa * (1 - decay)

    def solve_step(self, a0: np.ndarray, a_target: np.ndarray, h: float,
                   max_iterations: int = 8, tol: float = 1e-13,
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Constant u in [0, 1] whose exact step from a0 reaches a_target (saturated if not).

        Returns (u, a(h), saturated). Bracketed Newton, vectorised (2-3 iterations for
        h <= 10 ms).
        """
        ends, _ = self.step(a0, np.stack([np.zeros_like(a0), np.ones_like(a0)]), h,
                            derivative=False)
        a_lo, a_hi = ends
        low = a_target < a_lo - _SAT_TOL
        high = a_target > a_hi + _SAT_TOL
        target = np.clip(a_target, a_lo, a_hi)
        lo, hi = np.zeros_like(a0), np.ones_like(a0)
        u = np.clip((target - a_lo) / np.maximum(a_hi - a_lo, 1e-300), 0.0, 1.0)
        for _ in range(max_iterations):
            val, der = self.step(a0, u, h)
            res = val - target
            if np.max(np.abs(res)) < tol:
                break
            hi = np.where(res > 0, u, hi)
            lo = np.where(res <= 0, u, lo)
            newton = u - res / np.where(der > 0, der, 1.0)
            u = np.where((newton >= lo) & (newton <= hi), newton, 0.5 * (lo + hi))
        u = np.where(low, 0.0, np.where(high, 1.0, u))
        a1, _ = self.step(a0, u, h, derivative=False)
        return u, a1, low | high


# ---------------------------------------------------------------------------- reference
@dataclass(frozen=True)
class Stage2Reference:
    """Reference samples and everything precomputed from them (no muscle state).

    Rows are the samples of the (possibly refined) internal grid: every input interval is
    split into ``substeps`` (kinematics by quintic Hermite interpolation of theta, theta_dot,
    theta_ddot; tau_ref linear), so input sample j is row j * substeps. Global (internal)
    index of row 0 = ``offset``. Muscle quantities are [n, m]; the force is affine
    in the activation, F = a phi + psi, and so are its partials (``*_0`` at a = 0, ``*_1`` at
    a = 1). ``grid`` holds the LQT data (scaled C'QC, C'Q tau_ref, exact-step coefficients).
    """

    offset: int
    substeps: int            # fine intervals per interval of the input grid
    t: np.ndarray            # [n] s
    tau_ref: np.ndarray      # [n, 3] N m
    theta: np.ndarray        # [n, 3] rad
    theta_dot: np.ndarray    # [n, 3] rad/s
    theta_ddot: np.ndarray   # [n, 3] rad/s^2
    C: np.ndarray            # [n, 3, m] m
    v_mt: np.ndarray         # [n, m] m/s (= ldot_MT)
    vdot_mt: np.ndarray      # [n, m] m/s^2
    phi: np.ndarray          # [n, m] dF/da (N)
    psi: np.ndarray          # [n, m] F(a = 0) (N)
    dfdl_0: np.ndarray
    dfdl_1: np.ndarray
    dfdv_0: np.ndarray
    dfdv_1: np.ndarray
    grid: riccati.LqtGrid

    @property
    def n(self) -> int:
        return self.t.shape[0]

    @property
    def end(self) -> int:
        """Global index of the last sample."""
        return self.offset + self.n - 1

    def rows(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Per-sample arrays for global indices [start, stop)."""
        s = slice(start - self.offset, stop - self.offset)
        return {k: getattr(self, k)[s] for k in _ROW_FIELDS}


@dataclass(frozen=True)
class WindowPlan:
    """What the live tracker needs to advance the muscles over intervals [start, start + k].

    W, g of Eqs. 12-13 (scaled: Wt = R^-1/2 W R^-1/2, gt = R^-1/2 g) at the k + 1 samples,
    and the reference rows. ``horizon_end`` = global index of the sample where this plan's
    backward sweep started (P = 0 there).

    'clip' plans (the paper's LQT): ``closed_loop`` holds the exact closed-loop step data of
    the k intervals. Saturation-aware plans ('plan'): ``discrete`` holds the discrete LQT in
    activation coordinates over the plan's active set - per interval the feedback K [k, m, m],
    k [k, m] (a free muscle's activation step is v = k - K a), and the step a_i+1 = E a_i +
    B v + c (E [k, m], c [k, m], free [k, m]: B = diag(free)); ``pattern`` [k, m] is +1 / -1
    where the muscle is held at u = 1 / 0, 0 where free. W, g are then the discrete ones,
    converted to force units with dF/da.
    """

    start: int
    horizon_end: int
    h: float
    wt: np.ndarray           # [k+1, m, m]
    gt: np.ndarray           # [k+1, m]
    r_sqrt: np.ndarray       # [m, m]
    r_inv_sqrt: np.ndarray   # [m, m]
    closed_loop: dict[str, np.ndarray]
    rows: dict[str, np.ndarray]
    discrete: dict[str, np.ndarray] | None = None
    pattern: np.ndarray | None = None   # [k, m] int8
    plan_iterations: int = 0            # interior-point iterations of the bounded LQT
    plan_cost: float = float('nan')     # its cost (discretised Eq. 11) over the horizon
    plan_converged: bool = True         # the interior point met its tolerance

    @property
    def k(self) -> int:
        return self.wt.shape[0] - 1

    @property
    def W(self) -> np.ndarray:
        """W [k+1, m, m] (physical units)."""
        return self.r_sqrt @ self.wt @ self.r_sqrt

    @property
    def g(self) -> np.ndarray:
        """g [k+1, m] (physical units)."""
        return self.gt @ self.r_sqrt.T


@dataclass(frozen=True)
class MuscleState:
    """The muscle part of the tracker's state at global sample ``index``."""

    index: int
    t: float
    a: np.ndarray            # [m]
    f: np.ndarray            # [m] N


@dataclass(frozen=True)
class Stage2Step:
    """Outputs of ``apply`` for the samples [start, start + k) of one plan."""

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
class StreamState:
    """Explicit state of a streaming tracker: samples kept, muscles, next window start."""

    a0: np.ndarray
    substeps: int = 1
    reference: Stage2Reference | None = None
    muscle: MuscleState | None = None
    next_start: int = 0


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


# ---------------------------------------------------------------------------- the recipe
class NeuromuscularTracker:
    """Stage 2 recipe (stateless; the state lives in ``MuscleState`` / ``StreamState``)."""

    def __init__(self, model: JumperModel | None = None,
                 settings: Stage2Settings | None = None) -> None:
        self.model = model if model is not None else default_model()
        if not self.model.has_muscles:
            raise ValueError('the model has no muscle paths')
        self.settings = settings if settings is not None else load_stage2_settings()
        mp = self.model.p.muscles
        self.names = tuple(mp.names)
        self.f0 = np.asarray(mp.f0, dtype=float)
        self.Q, self.R, self.P = self.settings.weights(self.names, self.f0)
        self.activation = ActivationLaw.from_model(self.model)
        th = ca.SX.sym('theta', 3)
        thd = ca.SX.sym('theta_dot', 3)
        thdd = ca.SX.sym('theta_ddot', 3)
        v = self.model.musculotendon_velocities(th, thd)
        vdot = ca.jacobian(v, th) @ thd + ca.jacobian(v, thd) @ thdd
        self._kinematics = ca.Function(
            'stage2_kinematics', [th, thd, thdd],
            [self.model.musculotendon_lengths(th), v, vdot, self.model.moment_arm_matrix(th)],
            ['theta', 'theta_dot', 'theta_ddot'], ['l_mt', 'v_mt', 'vdot_mt', 'C'])

    # ------------------------------------------------------------------ reference
    def substeps_for(self, h: float) -> int:
        """Fine intervals per input interval h so that none exceeds ``settings.max_step``."""
        return max(1, int(np.ceil(h / self.settings.max_step - 1e-9)))

    def reference(self, t: np.ndarray, tau_ref: np.ndarray, theta: np.ndarray,
                  theta_dot: np.ndarray, theta_ddot: np.ndarray, offset: int = 0,
                  substeps: int | None = None) -> Stage2Reference:
        """Precompute C(theta), the muscle kinematics/partials and the LQT grid (vectorised).

        t [n] uniform (s); tau_ref, theta, theta_dot, theta_ddot [n, 3]. ``substeps`` (default
        from ``settings.max_step``) refines the grid (see ``Stage2Reference``).
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        n = t.size
        arrays = [np.asarray(x, dtype=float).reshape(n, 3)
                  for x in (tau_ref, theta, theta_dot, theta_ddot)]
        if substeps is None:
            substeps = self.substeps_for((t[-1] - t[0]) / (n - 1)) if n >= 2 else 1
        if substeps > 1 and n >= 2:
            t, *arrays = refine_samples(t, *arrays, substeps=substeps)
            n = t.size
        tau_ref, theta, theta_dot, theta_ddot = arrays
        m = self.model
        l_mt, v_mt, vdot_mt, C = m.batch(self._kinematics, theta, theta_dot, theta_ddot)
        nm = len(self.names)
        psi, phi, dl0, dv0 = m.batch(m.muscle_force_partials, np.zeros((n, nm)), l_mt, v_mt)
        _, _, dl1, dv1 = m.batch(m.muscle_force_partials, np.ones((n, nm)), l_mt, v_mt)
        C = C.reshape(n, 3, nm)
        grid = riccati.prepare_grid(t, C, tau_ref, self.Q, self.R, self.P) if n >= 2 else None
        return Stage2Reference(offset=offset, substeps=substeps, t=t, tau_ref=tau_ref,
                               theta=theta, theta_dot=theta_dot, theta_ddot=theta_ddot, C=C,
                               v_mt=v_mt, vdot_mt=vdot_mt, phi=phi, psi=psi, dfdl_0=dl0,
                               dfdl_1=dl1, dfdv_0=dv0, dfdv_1=dv1, grid=grid)

    def extend(self, ref: Stage2Reference | None, t: np.ndarray, tau_ref: np.ndarray,
               theta: np.ndarray, theta_dot: np.ndarray, theta_ddot: np.ndarray,
               substeps: int | None = None) -> Stage2Reference:
        """Append input samples, computing only the new rows and intervals.

        The first call (``ref`` None) fixes ``substeps`` (default: from the step of the first
        two samples, or 1 if only one sample has arrived and ``substeps`` is not given).
        """
        if ref is not None and np.atleast_1d(t).size == 0:
            return ref   # nothing new (e.g. a final push without samples)
        if ref is None:
            if substeps is None and np.atleast_1d(t).size < 2:
                substeps = 1
            return self.reference(t, tau_ref, theta, theta_dot, theta_ddot,
                                  substeps=substeps)
        last = ref.rows(ref.end, ref.end + 1)
        joined = [np.concatenate([last[k], np.atleast_2d(x) if k != 't' else np.atleast_1d(x)])
                  for k, x in (('t', t), ('tau_ref', tau_ref), ('theta', theta),
                               ('theta_dot', theta_dot), ('theta_ddot', theta_ddot))]
        new = self.reference(*joined, offset=ref.end, substeps=ref.substeps)
        grid = new.grid if ref.grid is None else riccati.concat_grids(ref.grid, new.grid)
        merged = {k: np.concatenate([getattr(ref, k), getattr(new, k)[1:]])
                  for k in _ROW_FIELDS}
        return Stage2Reference(offset=ref.offset, substeps=ref.substeps, grid=grid, **merged)

    @staticmethod
    def trim(ref: Stage2Reference, keep_from: int) -> Stage2Reference:
        """Drop rows before global index ``keep_from`` (the last row is always kept)."""
        k = max(0, min(keep_from - ref.offset, ref.n - 1))
        rows = {name: arr[k:] for name, arr in ref.rows(ref.offset, ref.end + 1).items()}
        grid = None if ref.grid is None or k == ref.n - 1 else riccati.tail_grid(ref.grid, k)
        return Stage2Reference(offset=ref.offset + k, substeps=ref.substeps, grid=grid, **rows)

    # ------------------------------------------------------------------ plans
    @property
    def constrained(self) -> bool:
        """True for the saturation-aware LQT (``settings.saturation == 'plan'``)."""
        return self.settings.saturation == 'plan'

    def _plans(self, ref: Stage2Reference, starts: np.ndarray, length: int, stride: int,
               ) -> list[WindowPlan]:
        """Unconstrained plans ('clip' mode): one batched sweep for all window starts."""
        local = np.asarray(starts, dtype=int) - ref.offset
        wt, gt = riccati.backward_sweep(ref.grid, local, length, min(stride, length) + 1)
        ends = np.minimum(local + length, ref.n - 1)
        ks = np.minimum(stride, ends - local)
        cl = riccati.closed_loop_coefficients(wt, ref.grid.h)
        plans = []
        for j, (s, k) in enumerate(zip(local, ks)):
            plans.append(WindowPlan(
                start=int(s + ref.offset), horizon_end=int(ends[j] + ref.offset), h=ref.grid.h,
                wt=wt[j, :k + 1], gt=gt[j, :k + 1], r_sqrt=ref.grid.r_sqrt,
                r_inv_sqrt=ref.grid.r_inv_sqrt,
                closed_loop={name: arr[j, :k] for name, arr in cl.items()},
                rows=ref.rows(int(s + ref.offset), int(s + k + 1 + ref.offset))))
        return plans

    def activation_bounds(self, h: float) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        """Reachable activations after a step h: (slope, offset) at u = 0 and at u = 1."""
        return self.activation.step_affine(0.0, h), self.activation.step_affine(1.0, h)

    def bounded_plan(self, ref: Stage2Reference, a0: np.ndarray, start: int,
                     stop: int) -> riccati.BoundedLqtSolution:
        """The bounded LQT (Eq. 11 with 0 <= u <= 1) on global samples [start, stop] from a0.

        Discrete Eq. 11 on the internal grid, activations as unknowns, each step between the
        exact activation steps at u = 0 and u = 1 (``riccati.solve_bounded_lqt``).
        """
        r = ref.rows(start, stop + 1)
        s = slice(start - ref.offset, stop + 1 - ref.offset)
        lo, hi = self.activation_bounds(ref.grid.h)
        st = self.settings
        return riccati.solve_bounded_lqt(ref.grid.h, r['C'], r['tau_ref'], self.Q, self.R,
                                         ref.phi[s], ref.psi[s], a0, lo, hi, P=self.P,
                                         tol=st.plan_tol,
                                         max_iterations=st.plan_max_iterations)

    def plan_window(self, ref: Stage2Reference, state: MuscleState, length: int,
                    stride: int) -> WindowPlan:
        """The plan of the window starting at the muscle state (its horizon: ``length``
        intervals or up to the last sample; applied over ``stride`` intervals).

        'clip' mode: the paper's LQT on the window. 'plan' mode, the saturation-aware LQT:
        (1) the bounded LQT (``bounded_plan``) from the current activations decides which
        muscles sit at u = 0 / 1 over which intervals (its active set); (2) the discrete LQT
        (``riccati.discrete_lqt``: Riccati, adjoint and feedback law of the same discretised
        Eq. 11) over that active set - the held muscles' forces enter as known inputs of
        their own activation dynamics, only the free muscles are optimised; (3) ``apply``
        holds the saturated muscles at their bound and moves the free ones by the feedback law
        (activation step -> excitation, Eq. 9 over the interval).
        """
        start = state.index
        stop = min(start + length, ref.end)
        if start < ref.offset or stop <= start:
            raise ValueError('window outside the kept reference')
        if not self.constrained:
            return self._plans(ref, np.array([start]), length, stride)[0]
        qp = self.bounded_plan(ref, state.a, start, stop)
        pos = qp.position()
        margin = self.settings.saturation_margin
        pattern = np.where(pos >= 1 - margin, 1, np.where(pos <= margin, -1, 0)).astype(np.int8)
        h = ref.grid.h
        E, c = self.held_steps(pattern, h)
        free = pattern == 0
        rows = ref.rows(start, stop + 1)
        sl = slice(start - ref.offset, stop + 1 - ref.offset)
        phi, psi = ref.phi[sl], ref.psi[sl]
        dl = riccati.discrete_lqt(h, rows['C'], rows['tau_ref'], self.Q, self.R, phi, psi,
                                  E, free, c, P=self.P)
        k = min(stride, stop - start)
        # W, g in force units (f = phi a + psi) for the output
        ph = np.maximum(np.abs(phi[:k + 1]), 1e-9 * self.f0) * np.where(phi[:k + 1] < 0, -1, 1)
        W = dl.S[:k + 1] / (ph[:, :, None] * ph[:, None, :])
        g = (dl.s[:k + 1] + np.einsum('kij,kj->ki', dl.S[:k + 1], psi[:k + 1] / ph)) / ph
        r_is = ref.grid.r_inv_sqrt
        return WindowPlan(start=start, horizon_end=stop, h=h, wt=r_is @ W @ r_is,
                          gt=g @ r_is.T, r_sqrt=ref.grid.r_sqrt, r_inv_sqrt=r_is,
                          closed_loop={}, rows={name: arr[:k + 1] for name, arr in rows.items()},
                          discrete={'K': dl.K[:k], 'k': dl.k[:k], 'E': E[:k], 'c': c[:k],
                                    'free': free[:k]},
                          pattern=pattern[:k], plan_iterations=qp.iterations,
                          plan_cost=qp.cost, plan_converged=qp.converged)

    def held_steps(self, pattern: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
        """Activation step a_i+1 = E a_i + c of each interval for muscles held at a bound
        (pattern +1: u = 1, -1: u = 0; E = 1, c = 0 where free)."""
        (s0, o0), (s1, o1) = self.activation_bounds(h)
        E = np.where(pattern > 0, s1, np.where(pattern < 0, s0, 1.0))
        c = np.where(pattern > 0, o1, np.where(pattern < 0, o0, 0.0))
        return E, c

    def plan_full(self, ref: Stage2Reference, state: MuscleState | None = None) -> WindowPlan:
        """The paper's full horizon: Eqs. 12-13 over all of ``ref`` (P at its last sample).

        'plan' mode needs the muscle state at the first sample (the bounded plan starts there).
        """
        if not self.constrained:
            return self._plans(ref, np.array([ref.offset]), ref.n - 1, ref.n - 1)[0]
        if state is None:
            raise ValueError("saturation='plan' needs the initial muscle state")
        return self.plan_window(ref, state, ref.n - 1, ref.n - 1)

    def window_samples(self, ref: Stage2Reference, window_length: float | None = None,
                       window_stride: float | None = None) -> tuple[int, int]:
        """(window length, stride) in intervals of the reference's (internal) grid."""
        h = ref.grid.h
        length_s = self.settings.window_length if window_length is None else window_length
        stride_s = self.settings.window_stride if window_stride is None else window_stride
        length = max(1, int(round(length_s / h)))
        stride = ref.substeps if stride_s is None else max(1, int(round(stride_s / h)))
        if stride > length:
            raise ValueError(f'window stride ({stride} samples) exceeds its length ({length})')
        return length, stride

    def plan_windows(self, ref: Stage2Reference, starts: np.ndarray, length: int, stride: int,
                     final: bool = False) -> list[WindowPlan]:
        """Receding-horizon plans for global window starts, batched ('clip' mode only: a
        saturation-aware plan depends on the muscle state at its start, see ``plan_window``).

        Each window needs the reference up to start + length; with ``final`` (end of the
        recording) windows may end at the last sample instead.
        """
        if self.constrained:
            raise ValueError("saturation='plan': plan each window from its state "
                             '(plan_window)')
        starts = np.atleast_1d(np.asarray(starts, dtype=int))
        if starts.size == 0:
            return []
        if starts.min() < ref.offset:
            raise ValueError('window starts before the kept reference')
        if not final and starts.max() + length > ref.end:
            raise ValueError('window needs reference samples not received yet')
        return self._plans(ref, starts, length, stride)

    def run_windows(self, ref: Stage2Reference, muscle: MuscleState, starts: np.ndarray,
                    length: int, stride: int, final: bool = False,
                    clock: _Clock | None = None,
                    ) -> tuple[MuscleState, list[Stage2Step], list[WindowPlan]]:
        """Plan and apply the windows starting at ``starts`` in turn (batch and streaming).

        'clip' plans do not depend on the state and are swept together; 'plan' plans are made
        one after the other from the state the previous window left.
        """
        starts = np.atleast_1d(np.asarray(starts, dtype=int))
        clock = clock if clock is not None else _Clock({}, {})
        steps: list[Stage2Step] = []
        plans: list[WindowPlan] = []
        if starts.size == 0:
            return muscle, steps, plans
        if not final and starts.max() + length > ref.end:
            raise ValueError('window needs reference samples not received yet')
        if not self.constrained:
            with clock('riccati'):
                plans = self.plan_windows(ref, starts, length, stride, final=final)
            with clock('forward'):
                for plan in plans:
                    muscle, step = self.apply(plan, muscle)
                    steps.append(step)
            return muscle, steps, plans
        for start in starts:
            if muscle.index != start:
                raise ValueError(f'muscle state at sample {muscle.index}, window at {start}')
            with clock('plan'):
                plan = self.plan_window(ref, muscle, length, stride)
            with clock('forward'):
                muscle, step = self.apply(plan, muscle)
            plans.append(plan)
            steps.append(step)
        return muscle, steps, plans

    # ------------------------------------------------------------------ state
    def initial_state(self, ref: Stage2Reference, a0: np.ndarray) -> MuscleState:
        """Muscle state at the first reference sample from activations a0 [m]."""
        a0 = np.clip(np.asarray(a0, dtype=float), 0.0, 1.0)
        return MuscleState(index=ref.offset, t=float(ref.t[0]), a=a0,
                           f=a0 * ref.phi[0] + ref.psi[0])

    def apply(self, plan: WindowPlan, state: MuscleState) -> tuple[MuscleState, Stage2Step]:
        """Advance the muscles over the plan's intervals (Eq. 14 -> Eq. 9 -> Eq. 8, exact).

        Each interval's LQT target (the force, hence activation, the feedback law asks for at
        the interval's end, from the actual state at its start) fixes the excitation held
        over the interval: the one whose exact activation step lands there (Eq. 9 integrated
        over the interval), clipped to [0, 1] if out of reach ('clip' plans: the paper's
        saturation; 'plan' plans: only what the plan did not foresee). Muscles a 'plan' plan
        holds at a bound get that bound.
        """
        if state.index != plan.start:
            raise ValueError(f'state at sample {state.index}, plan starts at {plan.start}')
        k, h, rows = plan.k, plan.h, plan.rows
        m = state.a.size
        a_out = np.empty((k + 1, m))
        f_out = np.empty((k + 1, m))
        u_out = np.empty((k, m))
        short = np.empty((k, m))
        saturated = np.zeros((k, m), dtype=bool)
        target = np.empty((k, m))
        phi, psi = rows['phi'], rows['psi']
        phi_safe = np.maximum(phi, 1e-9 * self.f0)
        a, f = state.a, state.f
        a_out[0], f_out[0] = a, f
        if plan.discrete is None:
            cl = plan.closed_loop
            r_s, r_is = plan.r_sqrt, plan.r_inv_sqrt
            # the LQT's target force of every interval's end, from the actual force at start
            gh = np.einsum('kji,kj->ki', cl['u'], plan.gt[:-1])
            gh1 = np.einsum('kji,kj->ki', cl['u'], plan.gt[1:])
            forcing = cl['hphi1'] * gh + cl['hphi2'] * (gh1 - gh)
            for i in range(k):
                ft = r_s @ f
                y1 = cl['decay'][i] * (ft @ cl['u'][i]) + forcing[i]
                target[i] = r_is @ (cl['u'][i] @ y1)
                a_star = (target[i] - psi[i + 1]) / phi_safe[i + 1]
                u_out[i], a, saturated[i] = self.activation.solve_step(a, a_star, h)
                f = a * phi[i + 1] + psi[i + 1]
                a_out[i + 1], f_out[i + 1] = a, f
            held = np.zeros((k, m), dtype=bool)
            ft = f_out[:k] @ r_s.T
            eta = (plan.gt[:k] - np.einsum('kij,kj->ki', plan.wt[:k], ft)) @ r_is.T
        else:
            dz = plan.discrete
            held = ~dz['free']
            u_bound = (plan.pattern > 0).astype(float)
            for i in range(k):
                v = dz['k'][i] - dz['K'][i] @ a
                a_star = np.where(held[i], dz['E'][i] * a + dz['c'][i], a + v)
                target[i] = a_star * phi[i + 1] + psi[i + 1]
                u, a_new, sat = self.activation.solve_step(a, a_star, h)
                if held[i].any():
                    u = np.where(held[i], u_bound[i], u)
                    a_new, _ = self.activation.step(a, u, h, derivative=False)
                    sat = sat & ~held[i]
                u_out[i], saturated[i], a = u, sat, a_new
                f = a * phi[i + 1] + psi[i + 1]
                a_out[i + 1], f_out[i + 1] = a, f
            # the discrete Eq. 14: the force rate asked for over each interval
            eta = (target - f_out[:k]) / h
        short[:] = np.where(held, 0.0, np.abs(target - f_out[1:]))
        saturated |= held
        a_k = a_out[:k]
        drift, gain = self.activation.affine(a_k)
        dfdl = rows['dfdl_0'][:k] + a_k * (rows['dfdl_1'][:k] - rows['dfdl_0'][:k])
        dfdv = rows['dfdv_0'][:k] + a_k * (rows['dfdv_1'][:k] - rows['dfdv_0'][:k])
        u_demand = eq9_excitation(eta, phi_safe[:k], dfdl, dfdv, drift, gain, rows['v_mt'][:k],
                                  rows['vdot_mt'][:k])
        new_state = MuscleState(index=plan.start + k, t=float(rows['t'][k]), a=a, f=f)
        return new_state, Stage2Step(start=plan.start, t=rows['t'][:k], a=a_k, f=f_out[:k],
                                     eta=eta, u=u_out, u_demand=u_demand, saturated=saturated,
                                     shortfall=short, W=plan.W[:k], g=plan.g[:k], planned=held)

    # ------------------------------------------------------------------ streaming
    def start_stream(self, a0: np.ndarray, dt: float) -> StreamState:
        """A fresh streaming state: initial activations a0 [m], input sample period dt [s].

        (``nmt_ros.model.squat.rest_activations`` gives a0 from the first torque sample.)
        """
        return StreamState(a0=np.asarray(a0, dtype=float), substeps=self.substeps_for(dt))

    def push(self, stream: StreamState, t: np.ndarray, tau_ref: np.ndarray,
             theta: np.ndarray, theta_dot: np.ndarray, theta_ddot: np.ndarray,
             final: bool = False, window_length: float | None = None,
             window_stride: float | None = None) -> tuple[StreamState, list[Stage2Step]]:
        """Feed new input samples; returns the new state and the outputs now computable.

        Window k (start t_k) is planned as soon as samples up to t_k + H are in; its output
        covers [t_k, t_k + stride) on the internal grid (``substeps`` rows per input
        interval). ``final``: no more samples (the last windows end at the last sample).
        """
        ref = self.extend(stream.reference, t, tau_ref, theta, theta_dot, theta_ddot,
                          substeps=stream.substeps)
        muscle = stream.muscle if stream.muscle is not None else self.initial_state(
            ref, stream.a0)
        steps: list[Stage2Step] = []
        next_start = stream.next_start
        if ref.n >= 2:
            length, stride = self.window_samples(ref, window_length, window_stride)
            last_start = ref.end - (1 if final else length)
            starts = np.arange(stream.next_start, last_start + 1, stride)
            muscle, steps, _ = self.run_windows(ref, muscle, starts, length, stride,
                                                final=final)
            if starts.size:
                next_start = int(starts[-1] + stride)
            ref = self.trim(ref, next_start)
        return replace(stream, reference=ref, muscle=muscle, next_start=next_start), steps

    # ------------------------------------------------------------------ batch
    def track_motion(self, t: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                     tau: np.ndarray, x0: np.ndarray, t_stop: float, mode: str = 'full',
                     window_length: float | None = None) -> Stage2Result:
        """Stage 2 on a Stage-1 motion: generalised coordinates q, qd, qdd [n, 6] and joint
        torques tau [n, 3] at times t [s], up to ``t_stop`` [s], from the activations that hold
        its first posture at rest on springs anchored at ``x0``."""
        keep = np.asarray(t) <= t_stop
        m = self.model
        theta = [m.batch(m.joint_angles, x[keep])[0] for x in (q, qd, qdd)]
        a0 = rest_activations_for_posture(m, q[0], x0)
        return self.track(t[keep], tau[keep], *theta, a0, mode=mode,
                          window_length=window_length)

    def track(self, t: np.ndarray, tau_ref: np.ndarray, theta: np.ndarray,
              theta_dot: np.ndarray, theta_ddot: np.ndarray, a0: np.ndarray,
              mode: str = 'full', window_length: float | None = None,
              window_stride: float | None = None) -> Stage2Result:
        """Stage 2 on a whole recording: mode 'full' (the paper) or 'windowed'.

        The windowed mode is ``push`` fed the whole recording (same plans, same ``apply``);
        its CPU time is split between the plans ('plan': bounded LQT + Eqs. 12-13 per window
        in 'plan' mode; 'riccati': the batched sweeps in 'clip' mode) and ``apply``
        ('forward').
        """
        cpu = {'prepare': 0.0, 'plan': 0.0, 'riccati': 0.0, 'forward': 0.0}
        wall = dict(cpu)
        clock = _Clock(cpu, wall)
        with clock('prepare'):
            ref = self.reference(t, tau_ref, theta, theta_dot, theta_ddot)
        muscle = self.initial_state(ref, a0)
        if mode == 'full':
            length = stride = ref.n - 1
        elif mode == 'windowed':
            length, stride = self.window_samples(ref, window_length, window_stride)
        else:
            raise ValueError(f"mode must be 'full' or 'windowed', not {mode!r}")
        muscle, steps, plans = self.run_windows(ref, muscle, np.arange(0, ref.n - 1, stride),
                                                length, stride, final=True, clock=clock)
        h = ref.grid.h
        windowed = mode == 'windowed'
        return self.assemble(ref, steps, muscle, plans, mode, cpu, wall,
                             length * h if windowed else None,
                             stride * h if windowed else None)

    def assemble(self, ref: Stage2Reference, steps: list[Stage2Step], final: MuscleState,
                 plans: list[WindowPlan] | WindowPlan, mode: str, cpu: dict[str, float],
                 wall: dict[str, float], window_length: float | None = None,
                 window_stride: float | None = None) -> Stage2Result:
        """Stack step outputs (+ the final sample) into a ``Stage2Result`` on the input grid.

        Saturation statistics use every internal interval; the arrays are sampled at the
        input samples (every ``ref.substeps``-th internal row).
        """
        plans = [plans] if isinstance(plans, WindowPlan) else list(plans)
        last_plan = plans[-1]
        cat = {name: np.concatenate([getattr(s, name) for s in steps])
               for name in ('a', 'f', 'eta', 'u', 'u_demand', 'saturated', 'shortfall', 'W',
                            'g')}
        planned = np.concatenate([s.planned if s.planned is not None
                                  else np.zeros_like(s.saturated) for s in steps])
        w_last, g_last = last_plan.W[-1], last_plan.g[-1]
        if last_plan.discrete is None:
            eta_last = riccati.lqt_control(w_last, g_last, final.f, self.R)
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
            names=self.names, fraction=sat.mean(axis=0),
            fraction_low=(sat & (u_int <= 0.0)).mean(axis=0),
            fraction_high=(sat & (u_int >= 1.0)).mean(axis=0),
            shortfall_integral=short.sum(axis=0), shortfall_max=short.max(axis=0),
            fraction_planned=planned.mean(axis=0))
        C = ref.C[sub]
        tau_m = np.einsum('npm,nm->np', C, f)
        return Stage2Result(mode=mode, names=self.names, t=ref.t[sub], f=f, a=a, u=u,
                            u_demand=u_dem, eta=eta, tau_ref=ref.tau_ref[sub], tau_muscle=tau_m,
                            W=W, g=g, saturation=report, cpu_s=cpu, wall_s=wall,
                            window_length=window_length, window_stride=window_stride,
                            substeps=ref.substeps, saturation_mode=self.settings.saturation,
                            plan_iterations=tuple(p.plan_iterations for p in plans),
                            plan_converged=all(p.plan_converged for p in plans))


class _Clock:
    """Accumulates CPU (process) and wall seconds per named part."""

    def __init__(self, cpu: dict[str, float], wall: dict[str, float]) -> None:
        self.cpu, self.wall = cpu, wall

    def __call__(self, part: str) -> _Clock:
        self._part = part
        return self

    def __enter__(self) -> None:
        self._c0, self._w0 = time.process_time(), time.perf_counter()

    def __exit__(self, *exc: object) -> None:
        self.cpu[self._part] = self.cpu.get(self._part, 0.0) + time.process_time() - self._c0
        self.wall[self._part] = self.wall.get(self._part, 0.0) + time.perf_counter() - self._w0


# ---------------------------------------------------------------------------- refinement
#: Quintic Hermite basis on s in [0, 1], rows: y0, h y0', h^2 y0'', y1, h y1', h^2 y1'';
#: columns: coefficients of s^0..s^5.
_QUINTIC = np.array([
    [1, 0, 0, -10, 15, -6],
    [0, 1, 0, -6, 8, -3],
    [0, 0, 0.5, -1.5, 1.5, -0.5],
    [0, 0, 0, 10, -15, 6],
    [0, 0, 0, -4, 7, -3],
    [0, 0, 0, 0.5, -1, 0.5],
])


def refine_samples(t: np.ndarray, tau_ref: np.ndarray, theta: np.ndarray,
                   theta_dot: np.ndarray, theta_ddot: np.ndarray, substeps: int,
                   ) -> tuple[np.ndarray, ...]:
    """Split each interval into ``substeps``: theta by quintic Hermite (C2, consistent
    theta_dot, theta_ddot), tau_ref linearly (causal: uses only the interval's end samples).

    Returns (t, tau_ref, theta, theta_dot, theta_ddot) with (n - 1) * substeps + 1 rows.
    """
    n = t.size
    h = (t[-1] - t[0]) / (n - 1)
    s = np.arange(substeps) / substeps                             # [N]
    powers = s[:, None] ** np.arange(6)                            # [N, 6]
    d1 = np.zeros_like(powers)
    d1[:, 1:] = powers[:, :-1] * np.arange(1, 6)
    d2 = np.zeros_like(powers)
    d2[:, 2:] = powers[:, :-2] * (np.arange(2, 6) * np.arange(1, 5))
    nodes = np.stack([theta[:-1], h * theta_dot[:-1], h * h * theta_ddot[:-1], theta[1:],
                      h * theta_dot[1:], h * h * theta_ddot[1:]], axis=1)   # [n-1, 6, 3]
    coef = np.einsum('bc,ibj->icj', _QUINTIC, nodes)               # [n-1, 6 powers, 3]

    def at(basis: np.ndarray, scale: float, last: np.ndarray) -> np.ndarray:
        inner = np.einsum('sc,icj->isj', basis, coef).reshape(-1, 3) * scale
        return np.vstack([inner, last[-1:]])

    tf = np.concatenate([(t[:-1, None] + h * s).ravel(), t[-1:]])
    tau = np.vstack([(tau_ref[:-1, None] + s[:, None] * (tau_ref[1:] - tau_ref[:-1])[:, None])
                     .reshape(-1, tau_ref.shape[1]), tau_ref[-1:]])
    return (tf, tau, at(powers, 1.0, theta), at(d1, 1 / h, theta_dot),
            at(d2, 1 / h ** 2, theta_ddot))


# ---------------------------------------------------------------------------- synthetic truth
@dataclass(frozen=True)
class SyntheticReference:
    """A squat-jump-like motion with known muscle forces: tau_ref = C(theta) f_true."""

    t: np.ndarray
    theta: np.ndarray
    theta_dot: np.ndarray
    theta_ddot: np.ndarray
    tau_ref: np.ndarray
    u_true: np.ndarray
    a_true: np.ndarray
    f_true: np.ndarray


def synthetic_reference(model: JumperModel | None = None, dt: float = 1e-3,
                        duration: float = 0.25,
                        start_deg: tuple[float, float, float] = (25.0, -70.0, 80.0),
                        end_deg: tuple[float, float, float] = (-30.0, 0.0, 0.0),
                        ) -> SyntheticReference:
    """Known-truth Stage-2 input (tests, benchmarks).

    Joint angles (ankle, knee, hip) move from a squat to extension with a minimum-jerk profile;
    smooth excitations (extensors on proximal-to-distal, flexors low) drive the model's
    activation ODE (fine RK4); f_true = F(a_true, l_MT, v_MT), tau_ref = C f_true.
    """
    model = model if model is not None else default_model()
    t = np.arange(0.0, duration + 0.5 * dt, dt)
    s = t / duration
    pos = 10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5
    vel = (30 * s ** 2 - 60 * s ** 3 + 30 * s ** 4) / duration
    acc = (60 * s - 180 * s ** 2 + 120 * s ** 3) / duration ** 2
    span = np.radians(np.subtract(end_deg, start_deg))
    theta = np.radians(start_deg) + pos[:, None] * span
    theta_dot = vel[:, None] * span
    theta_ddot = acc[:, None] * span
    # excitations: base level + smooth rise at a muscle-specific onset
    #               gmax  ilpso hams  bfsh  rf    vas   gas   sol   ta
    base = np.array([0.08, 0.03, 0.08, 0.03, 0.05, 0.10, 0.08, 0.10, 0.03])
    peak = np.array([0.60, 0.06, 0.45, 0.06, 0.25, 0.65, 0.50, 0.60, 0.06])
    onset = np.array([0.00, 0.10, 0.01, 0.10, 0.05, 0.03, 0.09, 0.08, 0.10]) * duration / 0.25
    rise = 0.04 * duration / 0.25

    def excitation(time: float | np.ndarray) -> np.ndarray:
        x = np.clip((np.asarray(time)[..., None] - onset) / rise, 0.0, 1.0)
        return base + (peak - base) * x * x * (3 - 2 * x)

    law = ActivationLaw.from_model(model)
    u_true = excitation(t)

    def adot(a: np.ndarray, time: float) -> np.ndarray:
        drift, gain = law.affine(a)
        return drift + gain * excitation(time)

    a = np.empty_like(u_true)
    a[0] = -(law.d0 + law.g0 * base) / (law.d1 + law.g1 * base)   # steady state of u(0)
    sub = 10
    hh = dt / sub
    for i in range(t.size - 1):
        x = a[i]
        for j in range(sub):
            tt = t[i] + j * hh
            k1 = adot(x, tt)
            k2 = adot(x + 0.5 * hh * k1, tt + 0.5 * hh)
            k3 = adot(x + 0.5 * hh * k2, tt + 0.5 * hh)
            k4 = adot(x + hh * k3, tt + hh)
            x = x + hh / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        a[i + 1] = x
    l_mt, = model.batch(model.musculotendon_lengths, theta)
    v_mt, = model.batch(model.musculotendon_velocities, theta, theta_dot)
    f_true, = model.batch(model.muscle_force, a, l_mt, v_mt)
    C, = model.batch(model.moment_arm_matrix, theta)
    tau_ref = np.einsum('npm,nm->np', C.reshape(t.size, 3, 9), f_true)
    return SyntheticReference(t=t, theta=theta, theta_dot=theta_dot, theta_ddot=theta_ddot,
                              tau_ref=tau_ref, u_true=u_true, a_true=a, f_true=f_true)
