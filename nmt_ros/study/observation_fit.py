"""How well a Stage-1 estimate explains what was measured, and how its joint torques compare
with OpenSim's inverse dynamics: the figures a lab recording without a truth can be judged by.

* Segment angles: RMS of estimate - observation [deg] at the mocap instants the estimate
  covers (the estimate interpolated onto them), per segment (foot, shank, thigh, HAT).
* Ground wrench, over contact (measured vertical force above ``contact_n``): RMS of
  estimate - measurement of Fx and Fy [% body weight] and of the moment about the foot COM
  [N m], at the force-plate instants the estimate covers; and the contact timing: each
  contact's first and last loaded instant, measured and estimated.
* Joint torques against an OpenSim inverse dynamics table (``nmt_ros.osim.lab_id``: both
  legs summed, nmt_ros signs) over the same contact instants: Pearson correlation and RMS
  difference in % of the table's peak, per joint (ankle, knee, hip); against a table whose
  coordinates and plates were low-passed alike, with the estimate low-passed the same way
  (and as published).
"""
from __future__ import annotations

import numpy as np

from nmt_ros.io.opensim_files import OpenSimTable
from nmt_ros.records import Observations

SEGMENTS = ('foot', 'shank', 'thigh', 'hat')
JOINTS = ('ankle', 'knee', 'hip')
#: Columns of ``nmt_ros.osim.lab_id``'s table: both legs summed, nmt_ros signs.
ID_COLUMNS = ('ankle_angle_moment', 'knee_angle_moment', 'hip_flexion_moment')


def _onto(t_new: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Columns of y [n, k] linearly interpolated onto t_new [m] -> [m, k]."""
    return np.column_stack([np.interp(t_new, t, y[:, j]) for j in range(y.shape[1])])


def _runs(t: np.ndarray, loaded: np.ndarray) -> list[list[float]]:
    """[first, last] instant of each run of consecutive loaded samples."""
    edges = np.diff(np.concatenate([[0], loaded.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [[float(t[a]), float(t[b])] for a, b in zip(starts, ends)]


def _covered(t_obs: np.ndarray, t_est: np.ndarray) -> np.ndarray:
    return (t_obs >= t_est[0] - 1e-9) & (t_obs <= t_est[-1] + 1e-9)


def observation_fit(obs: Observations, t_est: np.ndarray, theta_est: np.ndarray,
                    s_est: np.ndarray, body_weight_n: float, contact_n: float = 20.0,
                    ) -> dict:
    """The estimate (instants t_est [s, the observations' time], segment angles theta_est
    [n, 4] rad, ground wrench s_est [n, 3] N, N, N m) against ``obs`` (see the module)."""
    t_est = np.asarray(t_est, dtype=float)
    ka = _covered(obs.t_angles, t_est)
    d_deg = np.degrees(_onto(obs.t_angles[ka], t_est, theta_est) - obs.angles[ka])
    ok = np.isfinite(d_deg)
    angle_rms = [float(np.sqrt(np.mean(d_deg[ok[:, j], j] ** 2))) if ok[:, j].any()
                 else float('nan') for j in range(4)]
    kw = _covered(obs.t_wrench, t_est)
    t_w, meas = obs.t_wrench[kw], obs.wrench[kw]
    est = _onto(t_w, t_est, s_est)
    contact = meas[:, 1] > contact_n
    out = {'span_s': [float(t_est[0]), float(t_est[-1])],
           'angle_rms_deg': dict(zip(SEGMENTS, angle_rms)),
           'angle_samples': int(ka.sum()), 'contact_n': contact_n,
           'contact_samples': int(contact.sum())}
    if contact.any():
        err = (est - meas)[contact]
        out['force_rms_pct_bw'] = {'fx': float(100 * np.sqrt(np.mean(err[:, 0] ** 2))
                                               / body_weight_n),
                                   'fy': float(100 * np.sqrt(np.mean(err[:, 1] ** 2))
                                               / body_weight_n)}
        out['moment_rms_nm'] = float(np.sqrt(np.mean(err[:, 2] ** 2)))
    out['contacts_s'] = {'measured': _runs(t_w, contact),
                         'estimated': _runs(t_w, est[:, 1] > contact_n)}
    return out


def reference_band_hz(table: OpenSimTable) -> float | None:
    """The cut-off [Hz] an inverse dynamics table was computed at when its coordinates and
    plates were low-passed alike (``nmt_ros.osim.lab_id --lowpass F --grf-lowpass F``);
    None for any other table."""
    try:
        kin = float(table.metadata.get('lowpass_hz', '-1'))
        grf = float(table.metadata.get('grf_lowpass_hz', '-1'))
    except ValueError:
        return None
    return kin if kin > 0 and grf == kin else None


def id_agreement(obs: Observations, t_est: np.ndarray, tau_est: np.ndarray,
                 table: OpenSimTable, contact_n: float = 20.0) -> dict:
    """Joint torques tau_est [n, 3] N m (ankle, knee, hip) against an OpenSim inverse dynamics
    ``table`` over the measured contact instants the estimate covers (see the module). A
    table computed with coordinates and plates low-passed alike (``reference_band_hz``) is
    compared with the estimate low-passed by OpenSim's own coordinate filter at that cut-off
    (``nmt_ros.io.ivd_opensim.lowpass``; the same band: the reference holds nothing above
    it), and with the estimate as published under ``as_published``."""
    t_est = np.asarray(t_est, dtype=float)
    tau_est = np.asarray(tau_est, dtype=float)
    kw = _covered(obs.t_wrench, t_est)
    t_w = obs.t_wrench[kw][obs.wrench[kw, 1] > contact_n]
    t_w = t_w[(t_w >= table.time[0] - 1e-9) & (t_w <= table.time[-1] + 1e-9)]
    if t_w.size < 3:
        return {'samples': int(t_w.size)}
    ref = np.column_stack([np.interp(t_w, table.time, table.column(c)) for c in ID_COLUMNS])

    def scores(tau: np.ndarray) -> tuple[dict, dict]:
        est = _onto(t_w, t_est, tau)
        corr, rms = {}, {}
        for j, name in enumerate(JOINTS):
            corr[name] = float(np.corrcoef(est[:, j], ref[:, j])[0, 1])
            rms[name] = float(100 * np.sqrt(np.mean((est[:, j] - ref[:, j]) ** 2))
                              / np.abs(ref[:, j]).max())
        return corr, rms

    out: dict = {'samples': int(t_w.size),
                 'peak_nm': dict(zip(JOINTS, np.abs(ref).max(axis=0).tolist()))}
    band = reference_band_hz(table)
    corr, rms = scores(tau_est)
    if band is not None and t_est.size >= 10 and band < 0.5 / np.median(np.diff(t_est)):
        from nmt_ros.io.ivd_opensim import lowpass

        out['as_published'] = {'correlation': corr, 'rms_pct_peak': rms}
        out['band_hz'] = band
        corr, rms = scores(lowpass(t_est, tau_est, band))
    out.update(correlation=corr, rms_pct_peak=rms)
    return out


def format_fit(fit: dict, agreement: dict | None = None, filtered: dict | None = None) -> str:
    """One to three lines for a report (``agreement``: against the unfiltered inverse
    dynamics, ``filtered``: against the one low-passed at 15 Hz, ``id_agreement``'s)."""
    a = fit['angle_rms_deg']
    text = (f'fit to the observations ({fit["span_s"][0]:.3f}..{fit["span_s"][1]:.3f} s): '
            f'segment angles {" / ".join(f"{a[s]:.1f}" for s in SEGMENTS)} deg RMS '
            '(foot, shank, thigh, HAT)')
    if 'force_rms_pct_bw' in fit:
        f = fit['force_rms_pct_bw']
        text += (f'; over contact ({fit["contact_samples"]} force samples above '
                 f'{fit["contact_n"]:g} N): Fy {f["fy"]:.1f} / Fx {f["fx"]:.1f} % BW RMS, '
                 f'moment {fit["moment_rms_nm"]:.0f} N m RMS')
    def figures(a: dict) -> str:
        c, r = a['correlation'], a['rms_pct_peak']
        return (f'correlation {" / ".join(f"{c[j]:.2f}" for j in JOINTS)}, RMS '
                f'{" / ".join(f"{r[j]:.0f}" for j in JOINTS)} % of its peak')
    for a in (agreement, filtered):
        if not (a and 'correlation' in a):
            continue
        if 'band_hz' in a:
            text += (f'\njoint torques vs OpenSim inverse dynamics with coordinates and plates '
                     f'low-passed at {a["band_hz"]:g} Hz, over contact: {figures(a)} (ankle, '
                     f'knee, hip; the estimate low-passed alike; as published: '
                     f'{figures(a["as_published"])})')
        else:
            text += ('\njoint torques vs OpenSim inverse dynamics over contact: '
                     f'{figures(a)} (ankle, knee, hip)')
    return text
