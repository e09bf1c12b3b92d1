"""Inverse dynamics (METHOD.md section 3) on OpenSim files: what ``nmt ivd`` runs.

Inputs are the files OpenSim users have: the exported model's coordinates (.sto/.mot, names
as in ``nmt export-osim``, ``inDegrees`` honoured) and a ground reaction .mot (force, point
of application and free torque in ground, applied to the foot, as in our ExternalLoads
files). Steps:

1. coordinates -> our q = [th1, th2, th3, th4, r1, r2] (th1 = foot_tilt, r = (foot_tx,
   foot_ty), th2 = th1 - ankle_angle, th3 = th2 - knee_angle, th4 = th3 - hip_flexion);
2. optional zero-lag low-pass, OpenSim's ``lowpass_cutoff_frequency_for_coordinates``
   reproduced (odd padding by n/2 samples, 3rd-order Butterworth forward and backward), then
   an interpolating quintic spline per coordinate (spanning the padding, as OpenSim's),
   differentiated twice: by default with natural end conditions, the spline OpenSim's
   InverseDynamicsTool fits, so both agree to rounding on the same files (``not-a-knot``
   ends are more accurate in the last samples of a trial that ends in motion);
3. the ground wrench -> [Fx, Fy, moment about the foot COM] (the model's outputs s), the
   force and its moment about the origin interpolated to the coordinate times if the files
   are sampled differently;
4. ``JumperModel.inverse_dynamics``: residuals on the foot's coordinates (``'foot'``, what
   OpenSim's InverseDynamicsTool reports, the foot being the exported model's root) or a
   residual wrench on the HAT (``'hat'``, bottom-up inverse dynamics);
5. a .sto with OpenSim's column names (``foot_tilt_moment``, ``foot_tx_force``,
   ``foot_ty_force``, ``ankle_angle_moment``, ``knee_angle_moment``, ``hip_flexion_moment``);
   with HAT residuals the last three are ``hat_residual_force_x``, ``hat_residual_force_y``
   (at the HAT centre of mass, ground frame) and ``hat_residual_moment_z``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import make_interp_spline
from scipy.signal import butter, lfilter, lfiltic

from nmt_ros.io.opensim_files import (
    GRF_PREFIX,
    TORQUE_PREFIX,
    GroundLoad,
    read_grf_mot,
    read_table,
    write_table,
)
from nmt_ros.osim.modeldata import EXPORT_COORDINATES

ROTATIONAL = ('foot_tilt', 'ankle_angle', 'knee_angle', 'hip_flexion')
JOINT_LABELS = ('ankle_angle_moment', 'knee_angle_moment', 'hip_flexion_moment')
RESIDUAL_LABELS = {
    'foot': ('foot_tilt_moment', 'foot_tx_force', 'foot_ty_force'),
    'hat': ('hat_residual_force_x', 'hat_residual_force_y', 'hat_residual_moment_z'),
}
FILTER_ORDER = 3
SPLINE_DEGREE = 5


@dataclass
class IvdResult:
    """Inverse dynamics of one trial (arrays over the coordinate samples)."""

    time: np.ndarray            # [n] s
    q: np.ndarray               # [n, 6] ours (after filtering), rad and m
    qd: np.ndarray              # [n, 6]
    qdd: np.ndarray             # [n, 6]
    ground_wrench: np.ndarray   # [n, 3] [Fx, Fy, moment about the foot COM] on the foot
    tau: np.ndarray             # [n, 3] joint torques [ankle, knee, hip] N m
    residual: np.ndarray        # [n, 3] see RESIDUAL_LABELS[residual_at]
    residual_at: str
    labels: tuple[str, ...]     # columns of the output file
    values: np.ndarray          # [n, 6] in the order of labels


def q_from_coordinates(coords: np.ndarray) -> np.ndarray:
    """Exported-model coordinates [n, 6] (EXPORT_COORDINATES order) -> our q [n, 6].

    Linear (the inverse of ``modeldata.opensim_coordinates_from_q``): converts speeds and
    accelerations too.
    """
    c = np.atleast_2d(np.asarray(coords, dtype=float))
    tilt, tx, ty, ankle, knee, hip = (c[:, i] for i in range(6))
    th2 = tilt - ankle
    th3 = th2 - knee
    return np.column_stack([tilt, th2, th3, th3 - hip, tx, ty])


def read_coordinates(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(time [n], exported-model coordinates [n, 6] in rad and m) from a .sto/.mot."""
    table = read_table(path)
    coords = table.columns(EXPORT_COORDINATES).copy()
    if table.in_degrees:
        rot = [EXPORT_COORDINATES.index(c) for c in ROTATIONAL]
        coords[:, rot] = np.radians(coords[:, rot])
    _check_time(table.time, path)
    return table.time, coords


def _check_time(t: np.ndarray, path: str | Path) -> None:
    if t.size < SPLINE_DEGREE + 1:
        raise ValueError(f'{path}: {t.size} samples; at least {SPLINE_DEGREE + 1} are needed')
    if not np.all(np.diff(t) > 0):
        raise ValueError(f'{path}: time must increase strictly')


def _pad_odd(x: np.ndarray, pad: int) -> np.ndarray:
    """x [n, k] extended by ``pad`` samples at each end, reflected about the end points."""
    head = 2.0 * x[:1] - x[pad:0:-1]
    tail = 2.0 * x[-1:] - x[-2:-pad - 2:-1]
    return np.concatenate([head, x, tail])


def _iir_pass(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """One causal pass of the 3rd-order filter whose first 3 outputs equal the inputs."""
    y = x.copy()
    zi = np.stack([lfiltic(b, a, x[2::-1, j], x[2::-1, j]) for j in range(x.shape[1])],
                  axis=-1)
    y[3:] = lfilter(b, a, x[3:], axis=0, zi=zi)[0]
    return y


def lowpass_padded(t: np.ndarray, x: np.ndarray, cutoff_hz: float,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """OpenSim's coordinate filter of x [n, k]: the padded (times, values) it leaves behind.

    ``Storage::pad(n / 2)`` then ``lowpassIIR``: x is padded by n/2 samples reflected about
    each end point (the end values are kept), then a 3rd-order Butterworth runs forward and
    backward (zero lag), each pass starting with its first three outputs equal to its
    inputs. Unevenly sampled signals are first resampled at their median interval. OpenSim's
    InverseDynamicsTool fits its splines to the padded result.
    """
    times, y, _, _ = _opensim_filter(t, x, cutoff_hz)
    return times, y


def _opensim_filter(t: np.ndarray, x: np.ndarray, cutoff_hz: float,
                    ) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """``lowpass_padded`` plus the pad length and whether t was evenly sampled."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    dt = np.diff(t)
    h = float(np.median(dt))
    uniform = np.allclose(dt, h, rtol=1e-6, atol=0.0)
    if uniform:
        grid, xu = t, x
    else:
        grid = t[0] + h * np.arange(int(np.floor((t[-1] - t[0]) / h + 1e-9)) + 1)
        xu = make_interp_spline(t, x, k=3, axis=0)(grid)
    nyquist = 0.5 / h
    if not 0 < cutoff_hz < nyquist:
        raise ValueError(f'low-pass cut-off must be in (0, {nyquist:g}) Hz (the Nyquist '
                         f'frequency of the {1 / h:g} Hz samples), not {cutoff_hz:g}')
    n = grid.size
    if n < 8:
        raise ValueError(f'{n} samples are too few to filter')
    b, a = butter(FILTER_ORDER, cutoff_hz / nyquist)
    pad = n // 2
    y = _iir_pass(b, a, _pad_odd(xu, pad))
    y = _iir_pass(b, a, y[::-1])[::-1]
    steps = h * np.arange(1, pad + 1)
    times = np.concatenate([grid[0] - steps[::-1], grid, grid[-1] + steps])
    return times, y, pad, uniform


def lowpass(t: np.ndarray, x: np.ndarray, cutoff_hz: float) -> np.ndarray:
    """Zero-lag low-pass of x [n, k] (or [n]) at t [n]: ``lowpass_padded`` at the samples."""
    x = np.asarray(x, dtype=float)
    x2 = x[:, None] if x.ndim == 1 else x
    times, y, pad, uniform = _opensim_filter(t, x2, cutoff_hz)
    if uniform:
        y = y[pad:pad + x2.shape[0]]
    else:
        y = make_interp_spline(times, y, k=3, axis=0)(t)
    return y[:, 0] if x.ndim == 1 else y


def differentiate(t: np.ndarray, x: np.ndarray, cutoff_hz: float | None = None,
                  ends: str = 'natural') -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, xd, xdd) [n, k] at t: optional low-pass, then an interpolating quintic spline.

    ``ends='natural'`` (3rd and 4th derivatives zero at both ends) is the spline OpenSim's
    InverseDynamicsTool fits (GCVSpline, degree 5, no smoothing): results then agree with it
    to rounding. It is wrong by design in the last few samples of a trial that ends in
    motion; ``'not-a-knot'`` is more accurate there.
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    t_fit = t
    if cutoff_hz is not None and cutoff_hz > 0:
        t_fit, x = lowpass_padded(t, x, cutoff_hz)   # the spline spans the padding, as OpenSim's
    if ends == 'natural':
        zero = np.zeros(x.shape[1:])
        natural = [(3, zero), (4, zero)]
        bc = (natural, natural)
    elif ends == 'not-a-knot':
        bc = None
    else:
        raise ValueError(f"ends must be 'natural' or 'not-a-knot', not {ends!r}")
    spline = make_interp_spline(t_fit, x, k=SPLINE_DEGREE, bc_type=bc, axis=0)
    return spline(t), spline(t, 1), spline(t, 2)


def load_at(t_grf: np.ndarray, load: GroundLoad, t: np.ndarray) -> tuple[np.ndarray,
                                                                       np.ndarray]:
    """(force [n, 2], moment about the ground origin [n]) of the load at times t.

    Exact when t are sample times of the GRF file; otherwise the force and the moment about
    the origin (not the point, which may jump) are interpolated with cubic splines.
    """
    force = load.force[:, :2]
    m_o = load.moment_about(np.zeros(2))
    if t_grf.size == t.size and np.allclose(t_grf, t, rtol=0.0, atol=1e-9):
        return force, m_o
    tol = 1e-9 + 1e-6 * (t_grf[-1] - t_grf[0])
    if t[0] < t_grf[0] - tol or t[-1] > t_grf[-1] + tol:
        raise ValueError(f'the GRF file covers {t_grf[0]:g}..{t_grf[-1]:g} s but the '
                         f'coordinates {t[0]:g}..{t[-1]:g} s')
    if not np.all(np.diff(t_grf) > 0):
        raise ValueError('GRF time must increase strictly')
    spline = make_interp_spline(t_grf, np.column_stack([force, m_o]), k=min(3, t_grf.size - 1),
                                axis=0)
    out = spline(np.clip(t, t_grf[0], t_grf[-1]))
    return out[:, :2], out[:, 2]


def inverse_dynamics_files(coordinates: str | Path, grf: str | Path,
                           out: str | Path | None = None, lowpass_hz: float | None = None,
                           residuals: str = 'foot', model: object | None = None,
                           prefix: str = GRF_PREFIX, torque_prefix: str = TORQUE_PREFIX,
                           spline_ends: str = 'natural') -> IvdResult:
    """Joint torques from OpenSim coordinate and GRF files (see the module docstring).

    ``model`` is a ``JumperModel`` (default: the shipped one); ``spline_ends`` see
    ``differentiate``. Writes ``out`` (.sto) if given.
    """
    if residuals not in RESIDUAL_LABELS:
        raise ValueError(f"residuals must be 'foot' or 'hat', not {residuals!r}")
    if model is None:
        from nmt_ros.model.jumper import default_model
        model = default_model()
    t, coords = read_coordinates(coordinates)
    t_grf, load = read_grf_mot(grf, prefix, torque_prefix)
    c, cd, cdd = differentiate(t, coords, lowpass_hz, spline_ends)
    q, qd, qdd = (q_from_coordinates(v) for v in (c, cd, cdd))
    force, m_o = load_at(t_grf, load, t)
    coms = model.batch(model.positions, q)[3]           # [n, 2, 4]: foot, shank, thigh, hat
    foot_com = coms[:, :, 0]
    moment = m_o - (foot_com[:, 0] * force[:, 1] - foot_com[:, 1] * force[:, 0])
    wrench = np.column_stack([force, moment])
    tau, resid = model.inverse_dynamics(q, qd, qdd, wrench, residual_at=residuals)
    if residuals == 'foot':
        labels = RESIDUAL_LABELS['foot'] + JOINT_LABELS
        values = np.hstack([resid, tau])
    else:
        labels = JOINT_LABELS + RESIDUAL_LABELS['hat']
        values = np.hstack([tau, resid])
    result = IvdResult(time=t, q=q, qd=qd, qdd=qdd, ground_wrench=wrench, tau=tau,
                       residual=resid, residual_at=residuals, labels=labels, values=values)
    if out is not None:
        write_ivd_sto(out, result, lowpass_hz)
    return result


def write_ivd_sto(path: str | Path, result: IvdResult, lowpass_hz: float | None = None,
                  ) -> Path:
    """The generalized forces of ``result`` as an OpenSim-style .sto."""
    meta = {'residuals': result.residual_at,
            'lowpass_cutoff_frequency_for_coordinates':
                f'{lowpass_hz:g}' if lowpass_hz else '-1',
            'source': 'nmt ivd (nmt_ros JumperModel.inverse_dynamics)'}
    return write_table(path, result.time, result.labels, result.values,
                       name='Inverse Dynamics Generalized Forces', metadata=meta)
