"""Muscles, paths and the static squat against independent truths."""
import numpy as np

from nmt_ros.model.squat import solve_static_squat


def random_joint_states(n, rng):
    """Joint angles over the jump's range of motion and random joint speeds."""
    theta = np.column_stack([np.radians(rng.uniform(-30, 40, n)),
                             np.radians(rng.uniform(-120, 0, n)),
                             np.radians(rng.uniform(0, 110, n))])
    return theta, rng.normal(0, 5.0, (n, 3))


def test_joint_power_equals_minus_muscle_power(model):
    """sum_i F_i ldot_MT,i + tau . thetadot = 0 to 1e-9: moment arms are -dl/dtheta."""
    rng = np.random.default_rng(5)
    theta, theta_dot = random_joint_states(1000, rng)
    a = rng.uniform(0, 1, (1000, 9))
    lmt, = model.batch(model.musculotendon_lengths, theta)
    vmt, = model.batch(model.musculotendon_velocities, theta, theta_dot)
    f, = model.batch(model.muscle_force, a, lmt, vmt)
    C, = model.batch(model.moment_arm_matrix, theta)
    tau = np.einsum('nij,nj->ni', C, f)
    muscle_power = (f * vmt).sum(axis=1)
    joint_power = (tau * theta_dot).sum(axis=1)
    scale = np.abs(muscle_power).max()
    assert scale > 1e3  # the test is not vacuous
    np.testing.assert_allclose(joint_power + muscle_power, 0.0, atol=1e-9 * scale)
    # Moment arms against central differences of the lengths (independent of AD).
    h = 1e-6
    for j in range(3):
        e = np.zeros(3)
        e[j] = h
        lp, = model.batch(model.musculotendon_lengths, theta + e)
        lm, = model.batch(model.musculotendon_lengths, theta - e)
        np.testing.assert_allclose(C[:, j, :], -(lp - lm) / (2 * h), atol=1e-8)


def test_muscle_torques_of_the_full_model_match_paths_and_forces(model):
    """The musculoskeletal ODE's muscle torques are C(theta) F(a, l(theta), v(theta, thetad))."""
    rng = np.random.default_rng(6)
    theta, theta_dot = random_joint_states(50, rng)
    q = np.zeros((50, 6))
    q[:, 0] = rng.uniform(-0.2, 0.2, 50)
    q[:, 1] = q[:, 0] - theta[:, 0]
    q[:, 2] = q[:, 1] - theta[:, 1]
    q[:, 3] = q[:, 2] - theta[:, 2]
    qd = np.zeros((50, 6))
    qd[:, 1] = -theta_dot[:, 0]
    qd[:, 2] = qd[:, 1] - theta_dot[:, 1]
    qd[:, 3] = qd[:, 2] - theta_dot[:, 2]
    a = rng.uniform(0, 1, (50, 9))
    tau, f = model.batch(model.muscle_torques, q, qd, a)
    lmt, = model.batch(model.musculotendon_lengths, theta)
    vmt, = model.batch(model.musculotendon_velocities, theta, theta_dot)
    f2, = model.batch(model.muscle_force, a, lmt, vmt)
    np.testing.assert_allclose(f, f2, rtol=1e-12, atol=1e-9)


def test_force_depends_directly_on_activation_so_eq9_holds(model):
    """dF/da > 0 wherever the fibre can pull: relative degree one in the excitation (Eq. 9)."""
    rng = np.random.default_rng(7)
    theta, theta_dot = random_joint_states(200, rng)
    lmt, = model.batch(model.musculotendon_lengths, theta)
    vmt, = model.batch(model.musculotendon_velocities, theta, 0.2 * theta_dot)
    _, dfda, _, _ = model.batch(model.muscle_force_partials, np.full((200, 9), 0.5), lmt, vmt)
    assert (dfda > 0).mean() > 0.99
    drift, gain = model.batch(model.activation_affine, rng.uniform(0, 1, (200, 9)))
    assert (gain > 0).all()   # adot = drift + gain u: affine, invertible in u


def test_static_squat_holds(model):
    """Residual accelerations < 1e-6 with activations within [0, 1]."""
    sq = solve_static_squat(model)
    assert np.abs(sq.residual_qdd).max() < 1e-6
    assert (sq.a >= 0).all() and (sq.a <= 1).all()
    assert sq.a.max() > 0.1            # the muscles really hold the squat
    s = model.call(model.contact_outputs, sq.q, np.zeros(6), sq.x0)[0]
    np.testing.assert_allclose(s[1], model.p.body_weight, rtol=1e-9)  # springs carry BW
    assert abs(s[0]) < 1e-9            # no fore-aft force at rest


def test_paths_beyond_their_range_continue_to_first_order(model):
    """Inside ``path_ranges_deg`` the lengths are the fitted polynomials exactly; beyond, the
    first-order continuation from the range's edge: lengths continuous, moment arms (central
    differences, independent of AD) those of the edge and bounded far beyond."""
    import casadi as ca

    from nmt_ros.model.paths import polynomial

    m = model.p.muscles
    coords = ('ankle_angle', 'knee_angle', 'hip_flexion')
    rng = np.random.default_rng(11)
    lo = np.array([min(p.fit_range[p.coordinates.index(c), 0] for p in m.paths.values()
                       if c in p.coordinates) for c in coords])
    hi = np.array([max(p.fit_range[p.coordinates.index(c), 1] for p in m.paths.values()
                       if c in p.coordinates) for c in coords])
    inside = lo + (hi - lo) * rng.uniform(0.02, 0.98, (200, 3))
    lmt, = model.batch(model.musculotendon_lengths, inside)
    for i, name in enumerate(m.names):
        p = m.paths[name]
        x = ca.SX.sym('x', len(p.coordinates))
        raw = ca.Function('raw', [x], [polynomial([x[k] for k in range(x.numel())],
                                                  p.exponents, p.coefficients)])
        cols = [coords.index(c) for c in p.coordinates]
        want = np.array([float(raw(inside[n, cols])) for n in range(200)])
        np.testing.assert_allclose(lmt[:, i], want, rtol=0, atol=1e-12)
    # beyond each edge of each coordinate (the others inside): moment arms frozen at the edge
    h = 1e-6
    for j in range(3):
        for edge, sign in ((lo[j], -1.0), (hi[j], 1.0)):
            base = inside[:20].copy()
            at = base.copy()
            at[:, j] = edge - sign * 2 * h               # just inside
            C_edge, = model.batch(model.moment_arm_matrix, at)
            for beyond in (0.1, 0.5, 1.5):               # rad past the edge
                far = base.copy()
                far[:, j] = edge + sign * beyond
                C_far, = model.batch(model.moment_arm_matrix, far)
                e = np.zeros(3)
                e[j] = h
                lp, = model.batch(model.musculotendon_lengths, far + e)
                lm, = model.batch(model.musculotendon_lengths, far - e)
                np.testing.assert_allclose(C_far[:, j, :], -(lp - lm) / (2 * h), atol=1e-7)
                np.testing.assert_allclose(C_far[:, j, :], C_edge[:, j, :], atol=1e-5)
            # continuous lengths across the edge
            a, b = base.copy(), base.copy()
            a[:, j], b[:, j] = edge - sign * h, edge + sign * h
            la, = model.batch(model.musculotendon_lengths, a)
            lb, = model.batch(model.musculotendon_lengths, b)
            assert np.abs(la - lb).max() < 1e-6
    # moment arms stay anatomical far beyond (the raw 9th-order polynomials reach 0.8 m)
    far = np.array([[np.radians(-90.0), np.radians(-200.0), np.radians(200.0)],
                    [np.radians(90.0), np.radians(60.0), np.radians(-90.0)]])
    C_far, = model.batch(model.moment_arm_matrix, far)
    assert np.abs(C_far).max() < 0.1
