"""The collocation transcription (tracking/collocation.py), on its own and under the PO.

Checked against closed forms (the trapezoidal rule on a harmonic oscillator is the Cayley
transform and keeps its energy exactly), against CasADi's derivatives of the whole NLP (the
assembled Hessian and Jacobian, with a free final time, interpolated controls and path
constraints on some nodes), and by round trips (layout, warm-start shift, solver cache).
(The optimal tracker's NLP is checked the same way in test_optimal_tracker.py.)
"""
import gc

import casadi as ca
import numpy as np
import pytest

from nmt_ros.study.reference import JumpOptimizer, POSettings
from nmt_ros.tracking.collocation import (
    WARM_START_IPOPT,
    Block,
    Defect,
    Fixed,
    Interpolated,
    LeastSquares,
    NodeSum,
    Path,
    SolverCache,
    Transcription,
)

OMEGA = 7.0        # rad/s


def oscillator(n, step=0.02, data=True, **kw):
    """x = [position, velocity] of xdd = -omega^2 x, at rest-free start x(0) = [1, 0]; an
    optional least-squares fit of the position to node parameter 'data'."""

    def node(v):
        x = v['x']
        return {'xdot': ca.vertcat(x[1], -OMEGA ** 2 * x[0])}

    costs = [LeastSquares(lambda v: v['x'][0, :] - v['data'])] if data else []
    return Transcription(n, step, [Block('x', 2)], node,
                         [Defect('x', 'xdot'), Fixed('x', 0, (1.0, 0.0), (1.0, 0.0))],
                         costs=costs, node_parameters=[Block('data', 1)] if data else (),
                         **kw)


def cayley(n, h):
    """The trapezoidal rule's exact discrete solution: x_k+1 = (I - hA/2)^-1 (I + hA/2) x_k."""
    a = np.array([[0.0, 1.0], [-OMEGA ** 2, 0.0]])
    step = np.linalg.solve(np.eye(2) - h / 2 * a, np.eye(2) + h / 2 * a)
    x = [np.array([1.0, 0.0])]
    for _ in range(n):
        x.append(step @ x[-1])
    return np.array(x)


def test_defects_are_the_trapezoidal_rule():
    """Fixed start, no cost: the solution is the Cayley recursion, and the discrete energy
    omega^2 x^2 + v^2 stays exactly constant (to round-off) over 2.5 periods."""
    n, h = 112, 0.02
    tr = oscillator(n, h, data=False)
    solver = tr.solver('oscillator', {'print_time': False, 'ipopt': {'print_level': 0,
                                                                    'sb': 'yes'}})
    sol = tr.solve(solver, np.zeros(tr.z_size))
    assert sol.success, sol.status
    x = tr.unpack(sol.z)['x']
    assert np.abs(x - cayley(n, h)).max() < 1e-10
    energy = OMEGA ** 2 * x[:, 0] ** 2 + x[:, 1] ** 2
    assert np.abs(energy - OMEGA ** 2).max() < 1e-9 * OMEGA ** 2


def test_layout_offsets_pack_unpack_and_bounds():
    """z's blocks sit where ``index`` says, in the MX variables the NLP is written in, and
    pack/unpack are inverse (with the variable scales)."""
    rng = np.random.default_rng(0)
    n = 5
    tr = Transcription(n, 0.01, [Block('a', 2), Block('b', 3, scale=100.0)],
                       lambda v: {'r': ca.vertcat(v['a'], v['b'][0] * v['g'][1, 0])},
                       [Path('r', [1, 3])],
                       global_blocks=[Block('g', 2, 3, scale=10.0), Block('t', 1)])
    vals = {'a': rng.normal(size=(n + 1, 2)), 'b': rng.normal(size=(n + 1, 3)),
            'g': rng.normal(size=(2, 3)), 't': rng.normal(size=(1, 1))}
    z = tr.pack(vals)
    back = tr.unpack(z)
    for k, v in vals.items():
        assert np.allclose(back[k], v, rtol=1e-15, atol=0)
    for b in ('a', 'b', 'g', 't'):
        scale = {'b': 100.0, 'g': 10.0}.get(b, 1.0)
        var = np.asarray(ca.Function('v', [tr.z], [tr.variables[b]])(z))
        expected = vals[b].T if b in ('a', 'b') else vals[b]
        assert np.array_equal(var, expected / scale)
    all_idx = np.concatenate([tr.index(b).ravel() for b in ('a', 'b', 'g', 't')])
    assert np.array_equal(np.sort(all_idx), np.arange(tr.z_size))
    lbx, ubx = tr.bounds({'b': -2.0}, {'g': np.full((2, 3), 5.0)})
    assert (lbx[tr.index('b')] == -0.02).all() and (ubx[tr.index('g')] == 0.5).all()
    assert np.isinf(lbx[tr.index('a')]).all() and np.isinf(ubx[tr.index('b')]).all()
    assert tr.g_size == 3 * 2 and tr.lbg.size == tr.g_size      # r [3] at nodes 1 and 3


def _compare_with_casadi(solver, seed, x_fill):
    """Assembled Hessian (upper triangle) and Jacobian vs CasADi's of the whole NLP."""
    nlp = solver.oracle()
    x, p = ca.MX.sym('x', nlp.size1_in(0)), ca.MX.sym('p', nlp.size1_in(1))
    lam_f, lam_g = ca.MX.sym('lam_f'), ca.MX.sym('lam_g', nlp.size1_out(1))
    f, g = nlp(x, p)
    ref_h = ca.Function('h', [x, p, lam_f, lam_g],
                        [ca.triu(ca.hessian(lam_f * f + ca.dot(lam_g, g), x)[0])])
    ref_j = ca.Function('j', [x, p], [g, ca.jacobian(g, x)])
    rng = np.random.default_rng(seed)
    xv = x_fill(rng)
    pv = rng.normal(size=p.numel())
    args = [xv, pv, 0.7, rng.normal(size=lam_g.numel())]
    ours = np.asarray(ca.DM(solver.get_function('nlp_hess_l')(*args)))
    ref = np.asarray(ca.DM(ref_h(*args)))
    assert np.abs(ours - ref).max() < 1e-10 * np.abs(ref).max()
    g_ours, j_ours = solver.get_function('nlp_jac_g')(xv, pv)
    g_ref, j_ref = ref_j(xv, pv)
    # (equal to round-off: an expanded solver's own g is evaluated in SX, ours in MX)
    g_ref = np.asarray(g_ref)
    assert np.abs(np.asarray(g_ours) - g_ref).max() <= 1e-15 * np.abs(g_ref).max()
    j_ref = np.asarray(ca.DM(j_ref))
    assert np.abs(np.asarray(ca.DM(j_ours)) - j_ref).max() < 1e-12 * np.abs(j_ref).max()


def test_po_derivatives_equal_the_nlps_own(model):
    """The PO (free final time, excitations interpolated between control nodes, path
    constraints on some nodes, a terminal cost): assembled derivatives = CasADi's."""
    opt = JumpOptimizer(model, POSettings(n_intervals=8, n_nodes=4))

    def fill(rng):
        z = opt.held_squat_guess(0.25) + 0.05 * rng.normal(size=opt.transcription.z_size)
        z[opt.transcription.index('tf')] = 0.25
        return z

    _compare_with_casadi(opt.solver, 2, fill)


def test_free_final_time_toy_derivatives_equal_the_nlps_own():
    """A free final time with a nonlinear rate and a node-wise weighted cost."""

    def node(v):
        x, u, tf = v['x'], v['u'], v['tf']
        return {'xdot': ca.vertcat(x[1], ca.sin(x[0]) * u - x[1] ** 3),
                'energy': x[0] ** 2 * tf + x[1] ** 2}

    n = 6     # three nonzero interpolation weights per node: three z entries per input
    tr = Transcription(n, 'tf', [Block('x', 2, scale=2.0)], node,
                       [Defect('x', 'xdot'), Path('energy', [2, 5], 0.0, 1.0)],
                       costs=[NodeSum('energy', np.linspace(1.0, 2.0, n + 1))],
                       global_blocks=[Block('u_nodes', 1, 3), Block('tf', 1)],
                       interpolated=[Interpolated('u', 'u_nodes',
                                                  np.abs(np.sin(np.arange(3 * (n + 1))))
                                                  .reshape(3, n + 1))],
                       quadratic_cost=lambda var, _p: ca.sumsqr(var['u_nodes']))
    solver = tr.solver('toy', {'print_time': False, 'ipopt': {'print_level': 0, 'sb': 'yes'}})
    _compare_with_casadi(solver, 3, lambda rng: rng.normal(size=tr.z_size))


def test_a_quadratic_cost_that_is_not_quadratic_is_refused():
    with pytest.raises(ValueError, match='Hessian that depends on z or p'):
        oscillator(4, quadratic_cost=lambda var, _p: ca.sum1(ca.vec(var['x']) ** 4)).hessian()


def test_shift_moves_nodes_and_multipliers_for_a_receding_window():
    """Fit window [0, N] solved; the same fit k nodes later, warm-started from ``shift``:
    the shifted guess holds the solution at nodes k.., the last node repeated, and the new
    solve agrees with the first on the overlap (the fit is exact: data from the solution)."""
    n, h, k = 40, 0.01, 3
    truth = cayley(n + k, h)
    window = oscillator(n, h, data=True)
    opts = {'print_time': False, 'ipopt': {'print_level': 0, 'sb': 'yes'}}
    solver = window.solver('window', opts)
    first = window.solve(solver, np.zeros(window.z_size),
                         window.pack_parameters({'data': truth[:n + 1, :1]}))
    assert first.success
    z0, lam_g0, lam_x0 = window.shift(first, k)
    x_first = window.unpack(first.z)['x']
    x_shift = window.unpack(z0)['x']
    assert np.array_equal(x_shift[:n + 1 - k], x_first[k:])
    assert (x_shift[n + 1 - k:] == x_first[-1]).all()
    defects = first.lam_g[:2 * n].reshape(n, 2)
    assert np.array_equal(lam_g0[:2 * n].reshape(n, 2)[:n - k], defects[k:])
    assert np.array_equal(lam_g0[2 * n:], first.lam_g[2 * n:])     # the fixed start stays
    later = Transcription(n, h, [Block('x', 2)], lambda v: {'xdot': ca.vertcat(
        v['x'][1], -OMEGA ** 2 * v['x'][0])},
        [Defect('x', 'xdot'), Fixed('x', 0, tuple(truth[k]), tuple(truth[k]))],
        costs=[LeastSquares(lambda v: v['x'][0, :] - v['data'])],
        node_parameters=[Block('data', 1)])
    warm = later.solver('later', {**opts, 'ipopt': {**opts['ipopt'], **WARM_START_IPOPT}})
    second = later.solve(warm, z0, later.pack_parameters({'data': truth[k:, :1]}),
                         lam_g0=lam_g0, lam_x0=lam_x0)
    assert second.success
    assert np.abs(later.unpack(second.z)['x'][:n + 1 - k] - x_first[k:]).max() < 1e-9


class _Model:
    """Stands in for a JumperModel: the cache only needs its identity."""


def test_solver_cache_is_bounded_lru_and_per_model():
    cache = SolverCache(2)
    m1, m2 = _Model(), _Model()
    built = []

    def build(tag):
        built.append(tag)
        return tag

    assert cache.get(m1, 'a', lambda: build('1a')) == '1a'
    assert cache.get(m1, 'b', lambda: build('1b')) == '1b'
    assert cache.get(m1, 'a', lambda: build('again')) == '1a'      # hit, now most recent
    assert cache.get(m2, 'a', lambda: build('2a')) == '2a'         # another model: a miss
    assert len(cache) == 2                                          # '1b' evicted
    assert cache.get(m1, 'b', lambda: build('1b again')) == '1b again'
    assert built == ['1a', '1b', '2a', '1b again']
    del m1
    gc.collect()
    assert len(cache) == 1                                          # m1's solver went with it
    m3 = _Model()                                                   # may reuse m1's address
    assert cache.get(m3, 'b', lambda: build('3b')) == '3b'
    with pytest.raises(ValueError):
        SolverCache(0)
