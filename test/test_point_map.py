"""``PointMap`` / ``JumperModel.batch``: many points through a mapped function's buffers equal
CasADi's own evaluation point by point, also for sparse outputs (moment arms with structural
zeros: a buffer holds only nonzeros, so they go through a dense wrapper)."""
from __future__ import annotations

import casadi as ca
import numpy as np

from nmt_ros.model.point_map import PointMap


def _point_by_point(fn: ca.Function, *args: np.ndarray) -> list[np.ndarray]:
    n = args[0].shape[0]
    out = [[] for _ in range(fn.n_out())]
    for j in range(n):
        res = fn(*[a[j] for a in args])
        res = res if isinstance(res, (list, tuple)) else [res]
        for k, r in enumerate(res):
            r = np.asarray(ca.densify(r))
            out[k].append(r.ravel() if fn.size2_out(k) == 1 else r)
    return [np.array(o) for o in out]


def test_batch_equals_point_by_point_for_dense_and_sparse_functions(model) -> None:
    rng = np.random.default_rng(4)
    n = 23
    cases = [(model.moment_arm_matrix, [rng.normal(size=(n, 3)) * 0.4]),
             (model.muscle_torques, [rng.normal(size=(n, 6)) * 0.2, rng.normal(size=(n, 6)),
                                     rng.uniform(size=(n, 9))]),
             (model.joint_angles, [rng.normal(size=(n, 6))])]
    assert not model.moment_arm_matrix.sparsity_out(0).is_dense()   # the case that matters
    for fn, args in cases:
        want = _point_by_point(fn, *args)
        for got in (model.batch(fn, *args), PointMap(fn)(*args)):
            assert len(got) == len(want)
            for g, w in zip(got, want):
                assert g.shape == w.shape
                np.testing.assert_allclose(g, w, rtol=0, atol=1e-12)
    # a constant argument ([k]) is the same at every point
    q, qd, x0 = rng.normal(size=(n, 6)) * 0.2, rng.normal(size=(n, 6)), np.array([0.05, 0.0])
    got = model.batch(model.contact_outputs, q, qd, x0)
    want = _point_by_point(model.contact_outputs, q, qd, np.tile(x0, (n, 1)))
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=0, atol=1e-12)


def test_views_of_the_buffers_hold_the_outputs_until_the_next_call(model) -> None:
    """``copy=False`` hands out the buffers themselves: equal to the copies, overwritten by
    the next call with as many points (what ``SegmentKernel``'s single caller relies on)."""
    rng = np.random.default_rng(5)
    pm = PointMap(model.moment_arm_matrix)
    a, b = rng.normal(size=(7, 3)) * 0.4, rng.normal(size=(7, 3)) * 0.4
    view = pm(a, copy=False)[0]
    np.testing.assert_array_equal(view, pm(a)[0])
    kept = view.copy()
    pm(b, copy=False)
    np.testing.assert_array_equal(view, pm(b)[0])
    assert not np.array_equal(view, kept)
