"""The fit of an estimate to the observations and its agreement with an inverse dynamics
table, on synthetic records with known differences."""
import numpy as np
import pytest

from nmt_ros.io.opensim_files import OpenSimTable
from nmt_ros.records import Observations
from nmt_ros.study.observation_fit import ID_COLUMNS, id_agreement, observation_fit

BW = 900.0


def _record():
    t_a = np.arange(0.0, 2.0, 0.01)                  # 100 Hz mocap
    t_w = np.arange(0.0, 2.0, 0.001)                 # 1000 Hz plate
    angles = np.column_stack([np.sin(2 * np.pi * k * t_a / 2.0) for k in range(1, 5)])
    fy = np.where((t_w > 0.5) & (t_w < 1.5), BW * (1 + 0.5 * np.sin(2 * np.pi * t_w)), 0.0)
    wrench = np.column_stack([0.1 * fy, fy, 0.05 * fy])
    return Observations(t_angles=t_a, angles=angles, t_wrench=t_w, wrench=wrench)


def test_exact_estimate_fits_to_zero_and_known_offsets_are_recovered():
    obs = _record()
    t = obs.t_wrench.copy()                          # estimates at the plate's instants
    theta = np.column_stack([np.interp(t, obs.t_angles, obs.angles[:, j]) for j in range(4)])
    s = np.column_stack([np.interp(t, obs.t_wrench, obs.wrench[:, j]) for j in range(3)])
    # linear interpolation of sines between 100 Hz samples: below 0.01 deg here
    fit = observation_fit(obs, t, theta, s, BW)
    assert max(fit['angle_rms_deg'].values()) < 0.05
    assert fit['force_rms_pct_bw']['fy'] < 1e-6 and fit['moment_rms_nm'] < 1e-6
    assert fit['contacts_s']['measured'] == [pytest.approx([0.501, 1.499], abs=1e-9)]
    assert fit['contacts_s']['estimated'] == fit['contacts_s']['measured']
    theta[:, 2] += np.radians(2.0)                   # thigh 2 deg off
    s[:, 1] += np.where(s[:, 1] > 20.0, 0.05 * BW, 0.0)   # Fy 5 % BW high in contact
    s[:, 2] -= 7.0
    s[(t > 0.8) & (t < 0.9), 1] = 0.0                # an estimated flight inside the contact
    fit = observation_fit(obs, t, theta, s, BW)
    runs = fit['contacts_s']['estimated']
    assert len(runs) == 2 and runs[0][1] == pytest.approx(0.8) and runs[1][0] == \
        pytest.approx(0.9)
    s[(t > 0.8) & (t < 0.9), 1] = obs.wrench[(t > 0.8) & (t < 0.9), 1] + 0.05 * BW
    fit = observation_fit(obs, t, theta, s, BW)
    assert fit['angle_rms_deg']['thigh'] == pytest.approx(2.0, abs=0.05)
    assert fit['angle_rms_deg']['foot'] < 0.05
    assert fit['force_rms_pct_bw']['fy'] == pytest.approx(5.0, abs=0.3)
    assert fit['moment_rms_nm'] == pytest.approx(7.0, abs=1e-6)
    # only what the estimate covers counts
    part = t <= 1.0
    fit = observation_fit(obs, t[part], theta[part], s[part], BW)
    assert fit['span_s'] == [0.0, pytest.approx(1.0)]
    loaded = (obs.t_wrench <= 1.0) & (obs.wrench[:, 1] > 20.0)
    assert fit['angle_samples'] == 101 and fit['contact_samples'] == int(loaded.sum())


def test_agreement_with_an_inverse_dynamics_table():
    obs = _record()
    t = obs.t_wrench[::5]
    tau = np.column_stack([100 * np.sin(2 * np.pi * t), -50 * np.cos(3 * t), 200 * t])
    table = OpenSimTable(time=t.copy(), labels=ID_COLUMNS, data=tau.copy())
    same = id_agreement(obs, t, tau, table)
    assert same['samples'] == int((obs.wrench[:, 1] > 20.0).sum())   # the loaded instants
    assert min(same['correlation'].values()) == pytest.approx(1.0)
    assert max(same['rms_pct_peak'].values()) == pytest.approx(0.0, abs=1e-9)
    off = tau + np.array([10.0, 0.0, 0.0])           # ankle 10 N m off: RMS 10 / peak
    got = id_agreement(obs, t, off, table)
    contact = (t > 0.5) & (t < 1.5)
    assert got['rms_pct_peak']['ankle'] == pytest.approx(
        1000.0 / np.abs(tau[contact, 0]).max(), rel=1e-3)
    assert got['correlation']['ankle'] == pytest.approx(1.0)
    flipped = id_agreement(obs, t, -tau, table)
    assert flipped['correlation']['hip'] == pytest.approx(-1.0)
