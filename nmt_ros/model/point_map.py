"""A CasADi point function evaluated on many points at once through its buffers.

``fn.map(n)`` called with numpy arrays converts every argument and result through CasADi's
DM (per element: ``toarray``), which cost more than the evaluation itself for the small
compiled functions of Stage 2 (``bench/bench_stage2_stream.py --profile``). A ``PointMap``
binds numpy arrays to the mapped function's buffers once per point count and only copies.
"""
from __future__ import annotations

import casadi as ca
import numpy as np


class PointMap:
    """A point function evaluated on P points at once through CasADi's buffers (no
    conversions): arguments [P, k] arrays (points in rows), outputs [P, rows] for column
    outputs and [P, rows, cols] for matrices. One map per P is kept (a few sizes recur). A
    function with sparse inputs or outputs is evaluated through a dense wrapper (a buffer holds
    only the structural nonzeros)."""

    def __init__(self, fn: ca.Function, keep: int = 16) -> None:
        self.fn = dense(fn)
        self.keep = keep
        self._maps: dict[int, tuple] = {}

    def _map(self, n: int) -> tuple:
        if n not in self._maps:
            if len(self._maps) >= self.keep:
                self._maps.pop(next(iter(self._maps)))
            mapped = self.fn.map(n, 'serial')
            buf, trigger = mapped.buffer()
            args = [np.zeros((n, self.fn.size1_in(i))) for i in range(self.fn.n_in())]
            outs = [np.zeros((n, self.fn.size2_out(i), self.fn.size1_out(i)))
                    for i in range(self.fn.n_out())]
            for i, x in enumerate(args):
                buf.set_arg(i, memoryview(x.reshape(-1)))
            for i, x in enumerate(outs):
                buf.set_res(i, memoryview(x.reshape(-1)))
            self._maps[n] = (buf, trigger, args, outs)
        return self._maps[n]

    def __call__(self, *args: np.ndarray, copy: bool = True) -> list[np.ndarray]:
        """The outputs at the P points given (``copy`` False: views of the buffers, valid
        until the next call with as many points; for a caller that uses them at once)."""
        n = np.shape(args[0])[0]
        _, trigger, ins, outs = self._map(n)
        for dst, src in zip(ins, args):
            dst[...] = src
        trigger()
        res = []
        for i, o in enumerate(outs):
            view = o[:, 0, :] if self.fn.size2_out(i) == 1 else o.transpose(0, 2, 1)
            res.append(view.copy() if copy else view)
        return res


def dense(fn: ca.Function) -> ca.Function:
    """``fn`` itself when its inputs and outputs are dense, else a wrapper with dense ones."""
    ins = [fn.sparsity_in(i) for i in range(fn.n_in())]
    outs = [fn.sparsity_out(i) for i in range(fn.n_out())]
    if all(sp.is_dense() for sp in ins + outs):
        return fn
    args = [ca.MX.sym(fn.name_in(i), sp.size1(), sp.size2()) for i, sp in enumerate(ins)]
    res = fn(*[ca.project(a, sp) for a, sp in zip(args, ins)])
    res = res if isinstance(res, (list, tuple)) else [res]
    return ca.Function(f'{fn.name()}_dense', args, [ca.densify(r) for r in res],
                       fn.name_in(), fn.name_out())
