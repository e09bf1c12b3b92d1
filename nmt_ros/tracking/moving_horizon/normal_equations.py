"""Banded Gauss-Newton normal equations of the moving-horizon estimator, and marginalisation.

Unknowns: NV values per control point (the layout of ``residuals.LAYOUT``), control points in
time order, then NX window-wide parameters (the force plate's error model,
``residuals.PLATE``). Every residual touches four consecutive control points (a spline
segment) and possibly the parameters, so H = J'J is banded (half bandwidth 4 NV - 1) with a
dense border of NX columns: solved by LAPACK's banded Cholesky (pbtrf/pbtrs) and a Schur
complement on the border.

Sign convention: ``g = -J' r`` (the steepest-descent direction), so a step solves H dz = g.

Marginalisation (the arrival cost): eliminating the oldest control points m from the
quadratic model 1/2 dz' H dz - g' dz leaves, on the kept variables k,

    H_p = H_kk - H_km H_mm^-1 H_mk,   g_p = g_k - H_km H_mm^-1 g_m,

a prior on the next control points (and the parameters) linearised where the eliminated terms
were. ``diffuse`` adds process noise to some of the prior's variables in information form
(Woodbury), so that slowly drifting parameters stay free to drift.
"""
from __future__ import annotations

from dataclasses import dataclass
import functools

import numba
import numpy as np
from scipy.linalg import get_lapack_funcs

from nmt_ros.tracking.moving_horizon.residuals import NX


@dataclass
class Prior:
    """Quadratic arrival cost 1/2 d'H d - g'd, d = [c_first..c_first+k-1, x0] - lin."""

    first: int                # global index of the first control point it covers
    n_ctrl: int
    H: np.ndarray             # [n_ctrl NV + NX]^2
    g: np.ndarray             # [n_ctrl NV + NX]
    lin: np.ndarray           # linearisation point [n_ctrl NV + NX]

    def shifted(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(H, g) of the prior at the point z (same layout as ``lin``)."""
        return self.H, self.g - self.H @ (z - self.lin)


class NormalEquations:
    """H (banded + border) and g of one Gauss-Newton step over n control points."""

    def __init__(self, n_ctrl: int, nv: int, nx: int = NX) -> None:
        self.nv = nv
        self.nx = nx
        self.nb = 4 * nv                 # variables of one segment
        self.n_ctrl = n_ctrl
        self.n = n_ctrl * nv
        self.kd = self.nb - 1
        self.ab = np.zeros((self.kd + 1, self.n))
        self.g = np.zeros(self.n)
        self.Hcx = np.zeros((self.n, nx))
        self.Hxx = np.zeros((nx, nx))
        self.gx = np.zeros(nx)

    def add_segments(self, seg: np.ndarray, H: np.ndarray, g: np.ndarray,
                     band: np.ndarray | None = None) -> None:
        """Add segment blocks: ``seg`` [S] (local index of the segment's first control
        point), H [S, nb + NX, nb + NX], g [S, nb + NX]; ``band`` [S, kd + 1, nb]: the
        blocks' upper band form (``band_form`` of H[:, :nb, :nb]) if already made."""
        nb = self.nb
        if band is None:
            band = band_form(H, nb)
        _add_blocks(self.ab, self.g, self.Hcx, np.asarray(seg, dtype=np.int64), H, g, band,
                    self.nv, nb)
        self.Hxx += H[:, nb:, nb:].sum(0)
        self.gx += g[:, nb:].sum(0)

    def add_dense(self, first: int, k: int, H: np.ndarray, g: np.ndarray) -> None:
        """Add a dense block over control points first..first+k-1 (local) and x0."""
        m = k * self.nv
        if m > self.nb:
            raise ValueError('a dense block wider than a segment does not fit the band')
        lo = first * self.nv
        i, j = _triu(m)
        self.ab[self.kd + i - j, lo + j] += H[:m, :m][i, j]
        self.g[lo:lo + m] += g[:m]
        self.Hcx[lo:lo + m] += H[:m, m:]
        self.Hxx += H[m:, m:]
        self.gx += g[m:]

    def diagonal(self) -> np.ndarray:
        return np.concatenate([self.ab[self.kd], np.diag(self.Hxx)])

    def solve(self, damping: np.ndarray) -> np.ndarray:
        """dz = (H + diag(damping))^-1 g; raises LinAlgError if not positive definite.

        The system is equilibrated first (Jacobi scaling to a unit diagonal): its entries
        span thirteen orders of magnitude (accelerations of stiff rows against newtons), and
        an unpivoted banded Cholesky would otherwise lose positive definiteness by rounding.
        """
        n, kd = self.n, self.kd
        # a relative floor on the damping: directions the data do not reach (the window's
        # newest control points) stay positive definite after rounding
        diag = self.diagonal()
        damping = damping + RELATIVE_DAMPING * diag
        d = 1.0 / np.sqrt(np.maximum(diag + damping, 1e-300))
        dc, dx_ = d[:n], d[n:]
        ab = self.ab.copy()
        ab[kd] += damping[:n]
        # rows clipped to 0 where the band has no entry: those entries of ab are zero (no
        # block reaches them) and stay zero
        scale = dc[_band_rows(n, kd)]
        scale *= dc[None, :]
        ab *= scale
        c, info = _PBTRF(ab, lower=0)
        if info != 0:
            raise np.linalg.LinAlgError(f'normal equations not positive definite ({info})')
        hcx = self.Hcx * dc[:, None] * dx_[None, :]
        y, info = _PBTRS(c, np.column_stack([self.g * dc, hcx]), lower=0)
        y1, y2 = y[:, 0], y[:, 1:]
        hxx = (self.Hxx + np.diag(damping[n:])) * dx_[:, None] * dx_[None, :]
        dx = np.linalg.solve(hxx - hcx.T @ y2, self.gx * dx_ - hcx.T @ y1)
        return np.concatenate([(y1 - y2 @ dx) * dc, dx * dx_])


#: Damping added relative to the diagonal of H in every solve (see ``solve``).
RELATIVE_DAMPING = 1e-9

_PBTRF, _PBTRS, _POTRF, _POTRS = get_lapack_funcs(('pbtrf', 'pbtrs', 'potrf', 'potrs'),
                                                  (np.zeros((2, 2)),))
def band_form(H: np.ndarray, nb: int | None = None) -> np.ndarray:
    """Upper band form [S, nb, nb] of the leading nb x nb blocks (default: all) of square
    blocks H [S, n, n] (half bandwidth nb - 1: row kd + i - j, column j holds H[i, j]; zero
    outside the block)."""
    return _band_form(H, H.shape[-1] if nb is None else nb)


def warm_up() -> None:
    """Load (or, on a machine without their cache, compile) the compiled loops below now,
    for the arrays the estimator passes, not in a stream's first window."""
    nv, nb = 2, 8
    H = np.zeros((1, nb + NX, nb + NX))
    NormalEquations(4, nv).add_segments(np.zeros(1, dtype=np.int64), H, np.zeros((1, nb + NX)),
                                        band_form(H, nb))


# The two loops below compiled (numba): as numpy they were 8 % of the estimator's time, in
# per-call overhead (a gather and a scatter of the band entries per kept block, three slice
# additions per segment); the same additions in the same order, so the same results.
@numba.njit(cache=True)
def _band_form(H: np.ndarray, nb: int) -> np.ndarray:
    """``band_form``: LAPACK's upper band layout, kd = nb - 1: band[s, kd + i - j, j] =
    H[s, i, j] for 0 <= i <= j < nb."""
    S, kd = H.shape[0], nb - 1
    band = np.zeros((S, nb, nb))
    for s in range(S):
        for r in range(nb):
            for j in range(kd - r, nb):
                band[s, r, j] = H[s, j - kd + r, j]
    return band


@numba.njit(cache=True)
def _add_blocks(ab: np.ndarray, g_c: np.ndarray, hcx: np.ndarray, seg: np.ndarray,
                H: np.ndarray, g: np.ndarray, band: np.ndarray, nv: int, nb: int) -> None:
    """``NormalEquations.add_segments``' per-segment additions, segment after segment."""
    nx = hcx.shape[1]
    for k in range(seg.size):
        lo = seg[k] * nv
        for r in range(band.shape[1]):
            for j in range(nb):
                ab[r, lo + j] += band[k, r, j]
        for j in range(nb):
            g_c[lo + j] += g[k, j]
            for c in range(nx):
                hcx[lo + j, c] += H[k, j, nb + c]


@functools.cache
def _band_rows(n: int, kd: int) -> np.ndarray:
    """Row of each entry of an n-column upper band matrix [kd + 1, n], clipped to 0 where
    that row does not exist."""
    rows = np.arange(n)[None, :] - (kd - np.arange(kd + 1))[:, None]
    return np.maximum(rows, 0)


@functools.cache
def _triu(m: int) -> tuple[np.ndarray, np.ndarray]:
    return np.triu_indices(m)


def marginalize(H: np.ndarray, g: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Eliminate the first m variables of the dense quadratic (H, g): (H_p, g_p) on the rest."""
    if not (np.isfinite(H).all() and np.isfinite(g).all()):
        raise np.linalg.LinAlgError('non-finite values in the marginalised quadratic')
    Hmm, Hmk, Hkk = H[:m, :m], H[:m, m:], H[m:, m:]
    c, info = _POTRF(Hmm + 1e-12 * np.eye(m) * max(1.0, float(np.abs(np.diag(Hmm)).max())),
                     lower=0)
    if info != 0:
        raise np.linalg.LinAlgError(f'marginalised block not positive definite ({info})')
    X, info = _POTRS(c, np.column_stack([Hmk, g[:m]]), lower=0)
    Hp = Hkk - Hmk.T @ X[:, :-1]
    gp = g[m:] - Hmk.T @ X[:, -1]
    return 0.5 * (Hp + Hp.T), gp


def diffuse_along(H: np.ndarray, g: np.ndarray, E: np.ndarray, variance: np.ndarray,
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The prior (H, g) after zero-mean noise of ``variance`` [k] along the directions E
    [n, k] (a common shift of several variables, say): as ``diffuse`` with E for the unit
    vectors."""
    HE = H @ E
    K = np.linalg.inv(np.diag(1.0 / np.asarray(variance, dtype=float)) + E.T @ HE)
    H2 = H - HE @ K @ HE.T
    return 0.5 * (H2 + H2.T), g - HE @ (K @ (E.T @ g))


def diffuse(H: np.ndarray, g: np.ndarray, idx: np.ndarray, variance: np.ndarray,
            ) -> tuple[np.ndarray, np.ndarray]:
    """The prior (H, g) after zero-mean noise of ``variance`` is added to variables ``idx``:
    H' = (H^-1 + E V E')^-1 = H - H E (V^-1 + E' H E)^-1 E' H (no inverse of H, which may
    be singular), and g' = H' H^-1 g = g - H E (V^-1 + E' H E)^-1 E' g (the mean kept)."""
    variance = np.asarray(variance, dtype=float)
    idx = np.asarray(idx)[variance > 0]
    variance = variance[variance > 0]
    if idx.size == 0:
        return H, g
    HE = H[:, idx]
    K = np.linalg.inv(np.diag(1.0 / variance) + HE[idx])
    H2 = H - HE @ K @ HE.T
    return 0.5 * (H2 + H2.T), g - HE @ (K @ g[idx])
