"""Skeleton and contact dynamics against independent truths (round trips, conservation)."""
from dataclasses import replace

import numpy as np
from scipy.integrate import solve_ivp

from nmt_ros.model.jumper import JumperModel
from nmt_ros.model.parameters import load_parameters


def random_states(n, rng, airborne=False):
    """States within the joints' range of motion (the ligament torques stay moderate)."""
    th1 = rng.uniform(-0.3, 0.6, n)
    ankle, knee, hip = (rng.uniform(-0.6, 0.6, n), rng.uniform(-2.0, 0.0, n),
                        rng.uniform(-0.3, 1.8, n))
    th2 = th1 - ankle
    th3 = th2 - knee
    q = np.column_stack([
        th1, th2, th3, th3 - hip, rng.uniform(-0.05, 0.05, n),
        rng.uniform(0.5, 1.0, n) if airborne else rng.uniform(0.045, 0.07, n)])
    qd = rng.normal(0, 2.0, (n, 6))
    qd[:, 4:] *= 0.2
    return q, qd


def test_forward_then_inverse_dynamics_recovers_torques(model):
    """1000 random states in contact: FD with random torques, then bottom-up ID with the model's
    own contact outputs as the measured ground wrench gives the torques back to 1e-9."""
    rng = np.random.default_rng(1)
    n = 1000
    q, qd = random_states(n, rng)
    tau = rng.normal(0, 150.0, (n, 3))
    x0 = rng.uniform(-0.05, 0.15, (n, 2))
    qdd, = model.batch(model.forward_dynamics, q, qd, tau, x0)
    s, = model.batch(model.contact_outputs, q, qd, x0)
    assert np.abs(s[:, 1]).max() > 100.0  # the contact is really loaded in this sample set
    for where in ('hat', 'foot'):
        tau_id, resid = model.inverse_dynamics(q, qd, qdd, s, residual_at=where)
        rel = np.abs(tau_id - tau).max() / np.abs(tau).max()
        assert rel < 1e-9, (where, rel)
        assert np.abs(resid).max() < 1e-7


def test_contact_generalized_forces_equal_outputs_applied_at_foot_com(model):
    """S (Eq. 1) equals the wrench s (Eq. 2b) applied at the foot COM (same moment point)."""
    rng = np.random.default_rng(2)
    q, qd = random_states(200, rng)
    x0 = rng.uniform(-0.05, 0.15, (200, 2))
    S, = model.batch(model.contact_generalized, q, qd, x0)
    s, = model.batch(model.contact_outputs, q, qd, x0)
    jf, _ = model._com_jacobians(q)
    S2 = np.einsum('nij,ni->nj', jf, s[:, :2])
    S2[:, 0] += s[:, 2]
    np.testing.assert_allclose(S, S2, rtol=1e-10, atol=1e-8)


def test_energy_conserved_in_free_flight_without_muscles_or_ligaments():
    """No contact, no muscles, no passive joint torques: total energy drift < 1e-6 over 1 s."""
    p = load_parameters()
    zero_passive = replace(p.passive, k=np.zeros_like(p.passive.k),
                           damping=np.zeros_like(p.passive.damping))
    m = JumperModel(replace(p, passive=zero_passive))
    q0 = np.array([0.1, -0.3, 0.5, -0.2, 0.0, 3.0])  # far above the ground: springs silent
    qd0 = np.array([3.0, -2.0, 4.0, 1.0, 0.5, 4.0])
    x0 = np.zeros(2)

    def rhs(_t, y):
        return np.concatenate([y[6:], m.call(m.forward_dynamics, y[:6], y[6:], np.zeros(3),
                                             x0)[0]])

    sol = solve_ivp(rhs, (0.0, 1.0), np.concatenate([q0, qd0]), method='DOP853',
                    rtol=1e-12, atol=1e-12, dense_output=False)
    assert sol.success
    e, = m.batch(m.energy, sol.y[:6].T, sol.y[6:].T)
    drift = np.abs(e[:, 0] - e[0, 0]).max() / abs(e[0, 0])
    assert drift < 1e-6, drift
    # ...and the swing really exchanged kinetic and potential energy.
    com = m.batch(m.com, sol.y[:6].T)[0]
    assert np.ptp(com[:, 1]) > 1.0


def test_ballistic_com_in_flight(model):
    """In flight the COM follows a parabola with g whatever the joints do."""
    q, qd = random_states(50, np.random.default_rng(3), airborne=True)
    q[:, 5] += 2.0
    tau = np.random.default_rng(4).normal(0, 100, (50, 3))
    qdd, = model.batch(model.forward_dynamics, q, qd, tau, np.zeros(2))
    acc, = model.batch(model.com_acceleration, q, qd, qdd)
    np.testing.assert_allclose(acc[:, 0], 0.0, atol=1e-9)
    np.testing.assert_allclose(acc[:, 1], -model.p.gravity, atol=1e-9)
