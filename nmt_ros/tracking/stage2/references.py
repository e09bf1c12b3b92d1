"""The Stage-2 reference: torque and kinematics samples on the internal grid, and everything
precomputed from them (moment arms, musculotendon kinematics, force partials, the LQT grid).

Internal grid: input intervals longer than ``max_step`` (1 ms) are split into substeps
(kinematics by quintic Hermite from theta, theta_dot, theta_ddot; tau_ref linear, causal);
with W, g frozen per interval the stiff modes (>= 400 1/s) would otherwise lag the change of
C(theta) by O(step) (about 10 % torque error at 120 Hz without substeps). A streaming
reference grows by ``ReferenceBuilder.extend`` (only the new rows and intervals are computed)
and sheds what no window needs any more by ``trim``.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from nmt_ros.model.compiled import compiled
from nmt_ros.model.jumper import JumperModel
from nmt_ros.tracking.stage2 import lqt

ROW_FIELDS = ('t', 'tau_ref', 'theta', 'theta_dot', 'theta_ddot', 'C', 'v_mt', 'vdot_mt',
              'phi', 'psi', 'dfdl_0', 'dfdl_1', 'dfdv_0', 'dfdv_1')


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
    dfdl_0: np.ndarray       # [n, m] dF/dl_MT at a = 0 (N/m)
    dfdl_1: np.ndarray       # [n, m] ... at a = 1
    dfdv_0: np.ndarray       # [n, m] dF/dv_MT at a = 0 (N s/m)
    dfdv_1: np.ndarray       # [n, m] ... at a = 1
    grid: lqt.LqtGrid | None  # None while fewer than 2 samples

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
        return {k: getattr(self, k)[s] for k in ROW_FIELDS}


class ReferenceBuilder:
    """Builds and extends ``Stage2Reference``s for one model and one set of LQT weights."""

    def __init__(self, model: JumperModel, Q: np.ndarray, R: np.ndarray, P: np.ndarray,
                 max_step: float, sweeps: bool = True,
                 k_force: np.ndarray | None = None) -> None:
        """Q [3, 3], R diagonal [m], P [3, 3] of Eq. 11; max_step [s] of the internal grid;
        ``sweeps``: prepare the grid's sweep data (``lqt.prepare_grid``; 'clip' mode);
        k_force: the force term's K_f diagonal [m] (``lqt.with_force_term``; None: none)."""
        self.sweeps = sweeps
        self.k_force = k_force
        self.model = model
        self.Q, self.R, self.P = Q, R, P
        self.max_step = max_step
        self.n_muscles = len(model.p.muscles.names)
        th = ca.SX.sym('theta', 3)
        thd = ca.SX.sym('theta_dot', 3)
        thdd = ca.SX.sym('theta_ddot', 3)
        l_mt = model.musculotendon_lengths(th)
        v = model.musculotendon_velocities(th, thd)
        vdot = ca.jacobian(v, th) @ thd + ca.jacobian(v, thd) @ thdd
        nm = self.n_muscles
        psi, phi, dl0, dv0 = model.muscle_force_partials(ca.DM.zeros(nm), l_mt, v)
        _, _, dl1, dv1 = model.muscle_force_partials(ca.DM.ones(nm), l_mt, v)
        # Everything a reference row needs in one function, compiled to C (model.compiled):
        # in CasADi's virtual machine these rows cost ~170 us per sample (~0.2 s per second
        # of a 1080 Hz stream), compiled a few us; the VM is the fallback without a compiler.
        self._rows = compiled(ca.Function(
            'stage2_reference_rows', [th, thd, thdd],
            [v, vdot, model.moment_arm_matrix(th), psi, phi, dl0, dv0, dl1, dv1],
            ['theta', 'theta_dot', 'theta_ddot'],
            ['v_mt', 'vdot_mt', 'C', 'psi', 'phi', 'dfdl_0', 'dfdv_0', 'dfdl_1', 'dfdv_1']))

    def substeps_for(self, h: float) -> int:
        """Fine intervals per input interval h [s] so that none exceeds ``max_step``."""
        return max(1, int(np.ceil(h / self.max_step - 1e-9)))

    def build(self, t: np.ndarray, tau_ref: np.ndarray, theta: np.ndarray,
              theta_dot: np.ndarray, theta_ddot: np.ndarray, offset: int = 0,
              substeps: int | None = None, dt: float | None = None) -> Stage2Reference:
        """Precompute C(theta), the muscle kinematics/partials and the LQT grid (vectorised).

        t [n] uniform (s); tau_ref [n, 3] (N m), theta, theta_dot, theta_ddot [n, 3] (rad,
        rad/s, rad/s^2). ``substeps`` (default from ``max_step``) refines the grid (see
        ``Stage2Reference``). dt [s]: the nominal input step (default: the mean step of t; a
        stream passes 1 / rate so that its grid does not depend on how it was cut).
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        n = t.size
        arrays = [np.asarray(x, dtype=float).reshape(n, 3)
                  for x in (tau_ref, theta, theta_dot, theta_ddot)]
        if substeps is None:
            step = dt if dt is not None else (t[-1] - t[0]) / (n - 1) if n >= 2 else None
            substeps = self.substeps_for(step) if step is not None else 1
        if substeps > 1 and n >= 2:
            t, *arrays = refine_samples(t, *arrays, substeps=substeps, dt=dt)
            n = t.size
        tau_ref, theta, theta_dot, theta_ddot = arrays
        v_mt, vdot_mt, C, psi, phi, dl0, dv0, dl1, dv1 = self.model.batch(
            self._rows, theta, theta_dot, theta_ddot)
        C = C.reshape(n, 3, self.n_muscles)
        h = None if dt is None else dt / substeps
        grid = None
        if n >= 2:
            C_y, y_ref, Q_y, P_y = lqt.with_force_term(C, tau_ref, self.Q, self.P,
                                                       self.k_force)
            grid = lqt.prepare_grid(t, C_y, y_ref, Q_y, self.R, P_y, h=h, sweeps=self.sweeps)
        return Stage2Reference(offset=offset, substeps=substeps, t=t, tau_ref=tau_ref,
                               theta=theta, theta_dot=theta_dot, theta_ddot=theta_ddot, C=C,
                               v_mt=v_mt, vdot_mt=vdot_mt, phi=phi, psi=psi, dfdl_0=dl0,
                               dfdl_1=dl1, dfdv_0=dv0, dfdv_1=dv1, grid=grid)

    def extend(self, ref: Stage2Reference | None, t: np.ndarray, tau_ref: np.ndarray,
               theta: np.ndarray, theta_dot: np.ndarray, theta_ddot: np.ndarray,
               substeps: int | None = None, dt: float | None = None) -> Stage2Reference:
        """Append input samples (units of ``build``), computing only the new rows and intervals.

        The first call (``ref`` None) fixes ``substeps`` (default: from the step of the first
        two samples, or 1 if only one sample has arrived and ``substeps`` is not given).
        dt [s]: the nominal input step (``build``).
        """
        if ref is not None and np.atleast_1d(t).size == 0:
            return ref   # nothing new (e.g. a final push without samples)
        if ref is None:
            if substeps is None and np.atleast_1d(t).size < 2:
                substeps = 1
            return self.build(t, tau_ref, theta, theta_dot, theta_ddot, substeps=substeps,
                              dt=dt)
        last = ref.rows(ref.end, ref.end + 1)
        joined = [np.concatenate([last[k], np.atleast_2d(x) if k != 't' else np.atleast_1d(x)])
                  for k, x in (('t', t), ('tau_ref', tau_ref), ('theta', theta),
                               ('theta_dot', theta_dot), ('theta_ddot', theta_ddot))]
        new = self.build(*joined, offset=ref.end, substeps=ref.substeps, dt=dt)
        grid = new.grid if ref.grid is None else lqt.concat_grids(ref.grid, new.grid)
        merged = {k: np.concatenate([getattr(ref, k), getattr(new, k)[1:]])
                  for k in ROW_FIELDS}
        return Stage2Reference(offset=ref.offset, substeps=ref.substeps, grid=grid, **merged)


def trim(ref: Stage2Reference, keep_from: int) -> Stage2Reference:
    """Drop rows before global index ``keep_from`` (the last row is always kept)."""
    k = max(0, min(keep_from - ref.offset, ref.n - 1))
    rows = {name: arr[k:] for name, arr in ref.rows(ref.offset, ref.end + 1).items()}
    grid = None if ref.grid is None or k == ref.n - 1 else lqt.tail_grid(ref.grid, k)
    return Stage2Reference(offset=ref.offset + k, substeps=ref.substeps, grid=grid, **rows)


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
                   dt: float | None = None) -> tuple[np.ndarray, ...]:
    """Split each interval into ``substeps``: theta by quintic Hermite (C2, consistent
    theta_dot, theta_ddot), tau_ref linearly (causal: uses only the interval's end samples).

    dt [s]: the input step (default: the mean step of t). Returns (t, tau_ref, theta,
    theta_dot, theta_ddot) with (n - 1) * substeps + 1 rows.
    """
    n = t.size
    h = (t[-1] - t[0]) / (n - 1) if dt is None else dt
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
