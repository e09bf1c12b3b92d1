"""Direct collocation of the jumper's dynamics (trapezoidal rule, implicit Eq. 1): the one
transcription behind the reference jump's parameter optimisation (``study/reference.py``),
offline optimal tracking (``tracking/optimal_tracker.py``) and, next, a moving-horizon
estimator (a window is a short grid with a warm start).

A problem is posed on N intervals (nodes t_k = k h, k = 0..N; h fixed [s], or h = t_f / N with
the final time t_f a decision variable) as:

* variables z: node blocks (``Block``: e.g. q, qd, qdd, a, u), each [rows, N + 1] stored node
  by node, then global blocks (e.g. excitation nodes, t_f, moment-bias coefficients), each
  [rows, cols] stored column by column. A block's physical value is ``scale`` x its variable
  (accelerations ``QDD_SCALE``, torques ``TAU_SCALE``), so IPOPT's variables are of order one.
* parameters p (observations, anchors; a solver serves every trial of the same shape), laid
  out like z: node blocks, then global blocks.
* one node function (SX): what happens at a node, from the node's blocks, inputs interpolated
  linearly from a global block (``Interpolated``: excitation nodes), the global blocks, the
  parameters and per-node constants; it returns named outputs (the scaled Eq. 1 residual
  ``dynamics_residual``, rates, fit residuals, path quantities).
* constraints, in the order given: ``Defect`` (the trapezoidal rule of a node block with its
  rate: another node block, linear, or a node output), ``Path`` (a node output at some nodes,
  bounded), ``Fixed`` (a block's variables at one node);
* cost: ``LeastSquares`` (of a residual written column by column from the node quantities)
  and ``NodeSum`` (of a scalar node output), plus a quadratic term (constant Hessian:
  smoothness, effort, angle fit, an arrival cost).

Derivatives are assembled, not differentiated whole: every nonlinear term involves one node's
inputs, so one node's Lagrangian Hessian and constraint Jacobian are built once (SX, common
subexpressions removed), mapped over the nodes and summed into place by constant sparse
matrices. Where each node input sits in z and where each node output enters g are computed
from the layout (``Transcription._input_map``, ``_output_rows``); the quadratic cost adds a
constant Hessian and the linear constraints a constant Jacobian. The values equal CasADi's
derivatives of the whole NLP (tested) without building them: the muscle-driven tracking NLP
of the reference jump builds in under 1 s of CPU (differentiating the whole NLP: 10-17 s and
1.1 GB), the PO's of N = 100 in 3-5 s (15 s when CasADi differentiated the expanded NLP);
bench/bench_collocation.py.

Solvers are expensive to build and cheap to reuse: ``solvers`` (a ``SolverCache``) keeps the
most recently used few, keyed by the model (weakly: never confused with another model) and the
problem's shape. ``Transcription.solve`` takes initial multipliers and ``shift`` moves a
solution forward by whole nodes: the warm start of a receding window.
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field
import weakref

import casadi as ca
import numpy as np

from nmt_ros.model.jumper import JumperModel

QDD_SCALE = 100.0   # rad/s^2 or m/s^2 per unit of an acceleration variable
TAU_SCALE = 100.0   # N m per unit of a torque variable
RESIDUAL_MOMENT_SCALE = 100.0   # N m per unit of a rotational row of Eq. 1 (forces: per BW)
#: Solvers kept by ``solvers``: a fifth distinct problem shape evicts the least recently
#: used. A muscle-driven tracking solver of 200-270 nodes holds about 10 MB once built
#: (bench/bench_collocation.py), so the cache holds about 40 MB at most; building one costs
#: 0.5-1 s of CPU, solving it 5-10 s, so four shapes cover a study's trials or an estimator's
#: window lengths without rebuilding.
SOLVER_CACHE_SIZE = 4

#: IPOPT options of a warm-started solve (``Transcription.solve`` with the multipliers of a
#: previous solution, e.g. shifted by ``Transcription.shift``): start from the given point and
#: multipliers, barely pushed off the bounds, with a small barrier. On the muscle-driven
#: tracking NLP of the jump with its last 5 force samples changed: 31 iterations against 45
#: from the tracker's guess (1e-6: 28, but 167 against 38 when all the data change; the
#: primal point alone: 108); bench/bench_collocation.py.
WARM_START_IPOPT = {'warm_start_init_point': 'yes', 'warm_start_bound_push': 1e-9,
                    'warm_start_mult_bound_push': 1e-9, 'mu_init': 1e-4}


def dynamics_residual(model: JumperModel, q: ca.SX, qd: ca.SX, qdd: ca.SX, tau: ca.SX,
                      x0: ca.SX) -> ca.SX:
    """Eq. 1 as an implicit residual, M qdd - (I + S + T (tau + tau_pas)) [6], with its rows
    scaled to order one: the four rotational rows per ``RESIDUAL_MOMENT_SCALE`` N m, the two
    translational rows per body weight."""
    scale = ca.DM([1 / RESIDUAL_MOMENT_SCALE] * 4 + [1 / model.p.body_weight] * 2)
    return scale * model.dynamics_residual(q, qd, qdd, tau, x0)


@dataclass(frozen=True)
class Block:
    """Named variables or parameters: [rows] at every node (node blocks) or [rows, cols]
    once (global blocks, stored column by column). Physical value = ``scale`` x variable."""

    name: str
    rows: int
    cols: int = 1
    scale: float = 1.0


@dataclass(frozen=True, eq=False)
class Interpolated:
    """A node input [rows] linear in global block ``source`` G [rows, m]: G @ weights[:, k] at
    node k (``weights`` [m, N + 1]), e.g. excitations between control nodes."""

    name: str
    source: str
    weights: np.ndarray


@dataclass(frozen=True)
class Defect:
    """The trapezoidal rule x_k+1 - x_k - h/2 (r_k + r_k+1) = 0 ([rows x N], interval by
    interval) of node block ``state`` with the rate ``rate``: a node block (linear in z unless
    the step is free) or a node output. Physical units."""

    state: str
    rate: str


@dataclass(frozen=True)
class Path:
    """Node output ``output`` at ``nodes`` (all if None; node by node) within [lower, upper]."""

    output: str
    nodes: Sequence[int] | None = None
    lower: float = 0.0
    upper: float = 0.0


@dataclass(frozen=True)
class Fixed:
    """The variables of node block ``block`` at node ``node`` within [lower, upper] (in
    variable units; a value or one per row)."""

    block: str
    node: int = 0
    lower: float | tuple[float, ...] = 0.0
    upper: float | tuple[float, ...] = 0.0


@dataclass(frozen=True, eq=False)
class LeastSquares:
    """Cost sum_k |r_k|^2 with r = ``residual(v)`` [rows, columns]: written column by column
    from the node quantities ``v`` by name (outputs, inputs, parameters, constants; globals
    whole), it is evaluated over the grid (N + 1 columns) for the cost and at one node (one
    column) for the Hessian."""

    residual: Callable[[dict[str, ca.SX | ca.MX]], ca.SX | ca.MX]


@dataclass(frozen=True, eq=False)
class NodeSum:
    """Cost sum_k weights[k] o_k of scalar node output ``output`` (``weights`` [N + 1])."""

    output: str
    weights: np.ndarray


@dataclass
class Solution:
    """IPOPT's answer: variables and multipliers (warm start of the next solve)."""

    z: np.ndarray
    lam_g: np.ndarray
    lam_x: np.ndarray
    f: float
    success: bool
    status: str
    iterations: int
    stats: dict = field(repr=False, default_factory=dict)


NodeFunction = Callable[[dict[str, ca.SX]], dict[str, ca.SX]]
QuadraticCost = Callable[[dict[str, ca.MX], dict[str, ca.MX]], ca.MX]


class Transcription:
    """One NLP on a collocation grid (see the module docstring).

    ``step``: h [s], or the name of a global block [1, 1] holding the final time t_f [s]
    (h = t_f / N). ``node_function(v)`` gets every node input by name (physical values of the
    node blocks, interpolated inputs and global blocks, the parameters and ``node_constants``
    [N + 1, rows]) and returns named outputs [rows]. ``quadratic_cost(variables, parameters)``
    (variables in variable units) must have a constant Hessian in z: it is checked.
    """

    def __init__(self, n_intervals: int, step: float | str, node_blocks: Sequence[Block],
                 node_function: NodeFunction, constraints: Sequence[Defect | Path | Fixed],
                 costs: Sequence[LeastSquares | NodeSum] = (),
                 global_blocks: Sequence[Block] = (),
                 interpolated: Sequence[Interpolated] = (),
                 node_parameters: Sequence[Block] = (),
                 global_parameters: Sequence[Block] = (),
                 node_constants: dict[str, np.ndarray] | None = None,
                 quadratic_cost: QuadraticCost | None = None) -> None:
        if n_intervals < 1:
            raise ValueError(f'a collocation grid needs at least 1 interval, not {n_intervals}')
        self.n = int(n_intervals)
        self.nodes = self.n + 1
        self.node_blocks = tuple(node_blocks)
        self.global_blocks = tuple(global_blocks)
        self.interpolated = tuple(interpolated)
        self.node_parameters = tuple(node_parameters)
        self.global_parameters = tuple(global_parameters)
        self.node_constants = {k: np.asarray(v, dtype=float)
                               for k, v in (node_constants or {}).items()}
        self.constraints = tuple(constraints)
        self.costs = tuple(costs)
        self._check_names()
        self.free_time = isinstance(step, str)
        if self.free_time and self._global(step).rows * self._global(step).cols != 1:
            raise ValueError(f'the final time {step!r} must be a global block [1, 1]')
        self.step = step
        self.z_offsets, self.z_size = self._offsets(self.node_blocks, self.global_blocks)
        self.p_offsets, self.p_size = self._offsets(self.node_parameters,
                                                    self.global_parameters)
        self.z = ca.MX.sym('z', self.z_size)
        self.p = ca.MX.sym('p', self.p_size)
        self._build_node(node_function)
        self.variables = self._split(self.z, self.node_blocks, self.global_blocks,
                                     self.z_offsets)
        self.parameters = self._split(self.p, self.node_parameters, self.global_parameters,
                                      self.p_offsets)
        self.values = self._grid_values()
        self.outputs = {k: self.values[k] for k in self._out_names}
        self.g, self.lbg, self.ubg = self._constraints(self.outputs)
        self.g_size = self.g.numel()
        self._quadratic = (quadratic_cost(self.variables, self.parameters)
                           if quadratic_cost is not None else None)
        self.f = self._cost(self.values, self._quadratic)

    # ------------------------------------------------------------------ layout
    def _check_names(self) -> None:
        names = ([b.name for b in self.node_blocks + self.global_blocks
                  + self.node_parameters + self.global_parameters]
                 + [i.name for i in self.interpolated] + list(self.node_constants))
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f'names used twice in the transcription: {sorted(dup)}')
        for c, v in self.node_constants.items():
            if v.ndim != 2 or v.shape[0] != self.nodes:
                raise ValueError(f'node constant {c!r} must be [{self.nodes}, rows], '
                                 f'not {v.shape}')
        for i in self.interpolated:
            src = self._global(i.source)
            if i.weights.shape != (src.cols, self.nodes):
                raise ValueError(f'interpolation weights of {i.name!r} must be '
                                 f'[{src.cols}, {self.nodes}], not {i.weights.shape}')

    def _global(self, name: str) -> Block:
        for b in self.global_blocks:
            if b.name == name:
                return b
        raise ValueError(f'no global block {name!r}')

    def _offsets(self, node_blocks: tuple[Block, ...], global_blocks: tuple[Block, ...],
                 ) -> tuple[dict[str, int], int]:
        offsets, off = {}, 0
        for b in node_blocks:
            offsets[b.name] = off
            off += b.rows * self.nodes
        for b in global_blocks:
            offsets[b.name] = off
            off += b.rows * b.cols
        return offsets, off

    def _split(self, x: ca.MX, node_blocks: tuple[Block, ...],
               global_blocks: tuple[Block, ...], offsets: dict[str, int]) -> dict[str, ca.MX]:
        out = {}
        for b in node_blocks:
            o = offsets[b.name]
            out[b.name] = ca.reshape(x[o:o + b.rows * self.nodes], b.rows, self.nodes)
        for b in global_blocks:
            o = offsets[b.name]
            out[b.name] = ca.reshape(x[o:o + b.rows * b.cols], b.rows, b.cols)
        return out

    def index(self, name: str) -> np.ndarray:
        """Positions in z of a block's variables: [N + 1, rows] (node block) or [rows, cols]."""
        for b in self.node_blocks:
            if b.name == name:
                return self.z_offsets[name] + np.arange(b.rows * self.nodes).reshape(
                    self.nodes, b.rows)
        b = self._global(name)
        return self.z_offsets[name] + np.arange(b.rows * b.cols).reshape(b.cols, b.rows).T

    def pack(self, values: dict[str, np.ndarray], fill: float = 0.0) -> np.ndarray:
        """z from physical values: node blocks [N + 1, rows] (or [rows], every node), global
        blocks [rows, cols]; missing blocks are ``fill``."""
        unknown = sorted(set(values) - {b.name for b in self.node_blocks + self.global_blocks})
        if unknown:
            raise ValueError(f'no such variable blocks: {unknown}')
        z = np.full(self.z_size, float(fill))
        for b in self.node_blocks + self.global_blocks:
            if b.name in values:
                v = np.asarray(values[b.name], dtype=float)
                idx = self.index(b.name)
                if v.ndim > idx.ndim or any(d not in (1, e) for d, e in
                                            zip(v.shape[::-1], idx.shape[::-1])):
                    raise ValueError(f'block {b.name!r} is {list(idx.shape)}, not '
                                     f'{list(v.shape)}')
                z[idx] = np.broadcast_to(v, idx.shape) / b.scale
        return z

    def unpack(self, z: np.ndarray) -> dict[str, np.ndarray]:
        """Physical values of every block: node blocks [N + 1, rows], globals [rows, cols]."""
        z = np.asarray(z, dtype=float).ravel()
        return {b.name: z[self.index(b.name)] * b.scale
                for b in self.node_blocks + self.global_blocks}

    def pack_parameters(self, values: dict[str, np.ndarray]) -> np.ndarray:
        """p from every parameter block: node blocks [N + 1, rows], global [rows, cols]."""
        names = {b.name for b in self.node_parameters + self.global_parameters}
        if set(values) != names:
            raise ValueError(f'parameters needed: {sorted(names)}, given: {sorted(values)}')
        p = np.zeros(self.p_size)
        for b in self.node_parameters + self.global_parameters:
            v = np.asarray(values[b.name], dtype=float)
            node = b in self.node_parameters
            shape = (self.nodes, b.rows) if node else (b.rows, b.cols)
            if v.shape != shape and not (not node and v.size == b.rows * b.cols == v.shape[0]):
                raise ValueError(f'parameter {b.name!r} must be {list(shape)}, not '
                                 f'{list(v.shape)}')
            p[self.p_offsets[b.name] + np.arange(v.size)] = (
                v.ravel() if node else v.reshape(shape).ravel(order='F'))
        return p

    def bounds(self, lower: dict[str, float | np.ndarray] | None = None,
               upper: dict[str, float | np.ndarray] | None = None,
               ) -> tuple[np.ndarray, np.ndarray]:
        """(lbx, ubx) from physical bounds per block (as ``pack``); unbounded elsewhere."""
        return (self.pack(lower or {}, fill=-np.inf), self.pack(upper or {}, fill=np.inf))

    # ------------------------------------------------------------------ the node
    def _build_node(self, node_function: NodeFunction) -> None:
        """The node inputs ``_inputs`` (name, size) and the node function ``_node`` of
        (local inputs, node parameters, node constants, global parameters), all physical.

        For the derivatives, ``_var`` are the local inputs in variable units and ``_outs`` the
        outputs as the node function computes them from ``_var`` (scaled to physical units,
        common subexpressions shared); ``_v_node`` holds every node quantity by name."""
        sources = {i.source for i in self.interpolated}
        self._inputs: list[tuple[str, int]] = (
            [(b.name, b.rows) for b in self.node_blocks]
            + [(i.name, self._global(i.source).rows) for i in self.interpolated]
            + [(b.name, b.rows * b.cols) for b in self.global_blocks if b.name not in sources])
        n_loc = sum(s for _, s in self._inputs)
        loc = ca.SX.sym('local', n_loc)
        self._pn = ca.SX.sym('node_parameters', sum(b.rows for b in self.node_parameters))
        self._pc = ca.SX.sym('node_constants',
                             sum(v.shape[1] for v in self.node_constants.values()))
        self._pg = ca.SX.sym('global_parameters',
                             sum(b.rows * b.cols for b in self.global_parameters))
        scales = {b.name: b.scale for b in self.node_blocks + self.global_blocks}
        scales.update({i.name: scales[i.source] for i in self.interpolated})
        self._scales = scales
        self._var = ca.SX.sym('local_variables', n_loc)
        v = self._named_inputs(loc)
        outs = node_function(v)
        clash = sorted(set(outs) & set(v))
        if clash:
            raise ValueError(f'node outputs named like node inputs: {clash}')
        used = ([c.output for c in self.constraints if isinstance(c, Path)]
                + [c.rate for c in self.constraints if isinstance(c, Defect)
                   and c.rate not in scales]
                + [c.output for c in self.costs if isinstance(c, NodeSum)])
        missing = sorted({u for u in used if u not in outs})
        if missing:
            raise ValueError(f'the node function does not return {missing}')
        self._out_names = list(outs)
        for k in self._out_names:
            if outs[k].size2() != 1:
                raise ValueError(f'node output {k!r} must be a column, not {outs[k].shape}')
        for c in self.costs:
            if isinstance(c, NodeSum) and outs[c.output].numel() != 1:
                raise ValueError(f'NodeSum output {c.output!r} must be a scalar')
        self._node = ca.Function('collocation_node', [loc, self._pn, self._pc, self._pg],
                                 [outs[k] for k in self._out_names], {'cse': True})
        physical = []
        off = 0
        for name, size in self._inputs:
            x = self._var[off:off + size]
            physical.append(x if scales[name] == 1.0 else scales[name] * x)
            off += size
        physical = ca.vertcat(*physical)
        self._outs = dict(zip(self._out_names,
                              self._node.call([physical, self._pn, self._pc, self._pg])))
        self._v_node = {**self._named_inputs(physical), **self._outs}
        self._h_local = (float(self.step) if not self.free_time
                         else self._v_node[self.step] / self.n)                # h [s]

    def _named_inputs(self, loc: ca.SX) -> dict[str, ca.SX]:
        """Every node input by name: the local inputs ``loc`` (physical) cut into blocks,
        the parameters and the node constants."""
        shapes = {b.name: (b.rows, b.cols) for b in self.global_blocks}
        v: dict[str, ca.SX] = {}
        off = 0
        for name, size in self._inputs:
            v[name] = ca.reshape(loc[off:off + size], *shapes.get(name, (size, 1)))
            off += size
        for sym, blocks in ((self._pn, [(b.name, b.rows, 1) for b in self.node_parameters]),
                            (self._pc, [(k, c.shape[1], 1)
                                        for k, c in self.node_constants.items()]),
                            (self._pg, [(b.name, b.rows, b.cols)
                                        for b in self.global_parameters])):
            off = 0
            for name, rows, cols in blocks:
                v[name] = ca.reshape(sym[off:off + rows * cols], rows, cols)
                off += rows * cols
        return v

    def _node_arguments(self, physical: bool) -> list[ca.MX]:
        """Arguments of the node function mapped over the grid, each [size, N + 1]: the local
        inputs in physical units (``physical``) or in variable units (the derivatives')."""
        big_n = self.nodes
        interp = {i.name: i for i in self.interpolated}
        loc = []
        for name, _ in self._inputs:
            if name in interp:
                x = ca.mtimes(self.variables[interp[name].source],
                              ca.DM(interp[name].weights))
            elif any(b.name == name for b in self.node_blocks):
                x = self.variables[name]
            else:
                x = ca.repmat(ca.vec(self.variables[name]), 1, big_n)
            scale = self._scales[name]
            loc.append(scale * x if physical and scale != 1.0 else x)
        pn = [self.parameters[b.name] for b in self.node_parameters]
        pc = [ca.DM(c.T) for c in self.node_constants.values()]
        pg = [ca.vec(self.parameters[b.name]) for b in self.global_parameters]
        return [ca.vertcat(*loc), ca.vertcat(*pn) if pn else ca.DM(0, big_n),
                ca.vertcat(*pc) if pc else ca.DM(0, big_n),
                ca.repmat(ca.vertcat(*pg), 1, big_n) if pg else ca.DM(0, big_n)]

    def _grid_values(self) -> dict[str, ca.MX]:
        """Every node quantity over the grid by name (MX): the node outputs [rows, N + 1],
        node blocks (physical) [rows, N + 1], interpolated inputs, node parameters and
        constants [rows, N + 1], global blocks (physical) and parameters [rows, cols]."""
        outs = self._node.map(self.nodes, 'serial')(*self._node_arguments(physical=True))
        outs = outs if isinstance(outs, (list, tuple)) else [outs]
        v = dict(zip(self._out_names, outs))
        interp = {i.name: i for i in self.interpolated}
        for name, _ in self._inputs:
            x = (ca.mtimes(self.variables[interp[name].source], ca.DM(interp[name].weights))
                 if name in interp else self.variables[name])
            v[name] = x if self._scales[name] == 1.0 else self._scales[name] * x
        v.update(self.parameters)
        v.update({k: ca.DM(c.T) for k, c in self.node_constants.items()})
        return v

    # ------------------------------------------------------------------ g and f
    def _physical(self, name: str) -> ca.MX:
        b = next(b for b in self.node_blocks if b.name == name)
        x = self.variables[name]
        return x if b.scale == 1.0 else b.scale * x

    def _nodes_of(self, c: Path) -> np.ndarray:
        nodes = np.arange(self.nodes) if c.nodes is None else np.asarray(c.nodes, dtype=int)
        if nodes.size == 0 or nodes.min() < 0 or nodes.max() > self.n or (
                np.diff(nodes) <= 0).any():
            raise ValueError(f'path constraint {c.output!r}: nodes must increase within '
                             f'0..{self.n}, not {list(nodes)}')
        return nodes

    def _constraints(self, outs: dict[str, ca.MX]) -> tuple[ca.MX, np.ndarray, np.ndarray]:
        """g (in the order of ``constraints``) and its bounds, from the node outputs."""
        h = self.step if not self.free_time else self.variables[self.step] / self.n
        blocks = {b.name: b for b in self.node_blocks}
        g, lbg, ubg = [], [], []
        for c in self.constraints:
            if isinstance(c, Defect):
                if c.state not in blocks:
                    raise ValueError(f'defect of {c.state!r}: not a node block')
                if c.rate in blocks:
                    if self.free_time:
                        raise ValueError(f'defect of {c.state!r}: with a free final time '
                                         'every rate is nonlinear; make it a node output')
                    rate = self._physical(c.rate)
                else:
                    rate = outs[c.rate]
                x = self._physical(c.state)
                if rate.size1() != x.size1():
                    raise ValueError(f'defect of {c.state!r}: rate {c.rate!r} has '
                                     f'{rate.size1()} rows, the state {x.size1()}')
                expr = ca.vec(x[:, 1:] - x[:, :-1] - h / 2 * (rate[:, 1:] + rate[:, :-1]))
                lo = hi = 0.0
            elif isinstance(c, Path):
                nodes = self._nodes_of(c)
                o = outs[c.output]
                expr = ca.vec(o if nodes.size == self.nodes else o[:, nodes.tolist()])
                lo, hi = c.lower, c.upper
            elif isinstance(c, Fixed):
                if c.block not in blocks or not 0 <= c.node <= self.n:
                    raise ValueError(f'fixed {c.block!r} at node {c.node}: no such block/node')
                expr = self.variables[c.block][:, c.node]
                lo, hi = c.lower, c.upper
            else:
                raise TypeError(f'not a constraint: {c!r}')
            g.append(expr)
            lbg.append(np.broadcast_to(np.asarray(lo, dtype=float), (expr.numel(),)))
            ubg.append(np.broadcast_to(np.asarray(hi, dtype=float), (expr.numel(),)))
        return ca.vertcat(*g), np.concatenate(lbg), np.concatenate(ubg)

    def _cost(self, values: dict[str, ca.MX], quadratic: ca.MX | None) -> ca.MX:
        terms = []
        for c in self.costs:
            if isinstance(c, LeastSquares):
                terms.append(ca.sumsqr(c.residual(values).T))     # channel by channel
            else:
                w = np.asarray(c.weights, dtype=float)
                k = np.flatnonzero(w)
                terms.append(ca.mtimes(values[c.output][:, k.tolist()], ca.DM(w[k])))
        if quadratic is not None:
            terms.append(quadratic)
        if not terms:
            return ca.MX(0)
        f = terms[0]
        for t in terms[1:]:
            f = f + t
        return f

    def nlp(self) -> dict[str, ca.MX]:
        """CasADi's NLP dict: x = z, p, f, g."""
        return {'x': self.z, 'p': self.p, 'f': self.f, 'g': self.g}

    # ------------------------------------------------------------------ assembly
    def _input_map(self) -> tuple[np.ndarray, np.ndarray]:
        """(index [N + 1, n_local, T], coef [N + 1, n_local, T]): local input i at node k is
        sum_t coef[k, i, t] z[index[k, i, t]] (T terms; unused terms have coef 0)."""
        big_n = self.nodes
        interp = {i.name: i for i in self.interpolated}
        terms = max([1] + [int((i.weights != 0).sum(axis=0).max()) for i in self.interpolated])
        n_loc = int(self._var.numel())
        index = np.zeros((big_n, n_loc, terms), dtype=int)
        coef = np.zeros((big_n, n_loc, terms))
        k = np.arange(big_n)[:, None]
        off = 0
        for name, size in self._inputs:
            cols = slice(off, off + size)
            if name in interp:
                src = self._global(interp[name].source)
                w = interp[name].weights
                for node in range(big_n):
                    nz = np.flatnonzero(w[:, node])
                    index[node, cols, :nz.size] = (self.z_offsets[src.name]
                                                   + src.rows * nz[None, :]
                                                   + np.arange(size)[:, None])
                    coef[node, cols, :nz.size] = w[nz, node][None, :]
            elif any(b.name == name for b in self.node_blocks):
                index[:, cols, 0] = self.z_offsets[name] + size * k + np.arange(size)[None, :]
                coef[:, cols, 0] = 1.0
            else:
                index[:, cols, 0] = self.z_offsets[name] + np.arange(size)[None, :]
                coef[:, cols, 0] = 1.0
            off += size
        return index, coef

    def _output_rows(self) -> tuple[list[ca.SX], list[tuple[np.ndarray, np.ndarray]]]:
        """The nonlinear constraint rows of a node: (their expressions, in g order; per
        expression the g rows [N + 1, rows, 2] it enters at each node (-1: none) and the
        coefficients [2])."""
        big_n, n = self.nodes, self.n
        exprs, places = [], []
        off = 0
        for c in self.constraints:
            if isinstance(c, Path):
                o = self._outs[c.output]
                nodes = self._nodes_of(c)
                rows = np.full((big_n, o.numel(), 2), -1)
                rows[nodes, :, 0] = off + o.numel() * np.arange(nodes.size)[:, None] \
                    + np.arange(o.numel())[None, :]
                exprs.append(o)
                places.append((rows, np.array([1.0, 0.0])))
                off += o.numel() * nodes.size
            elif isinstance(c, Defect):
                size = next(b.rows for b in self.node_blocks if b.name == c.state)
                if c.rate in self._outs:
                    r = self._outs[c.rate]
                    kk = np.arange(big_n)[:, None]
                    rows = np.full((big_n, size, 2), -1)
                    i = np.arange(size)[None, :]
                    rows[1:, :, 0] = (off + size * (kk[1:] - 1) + i)   # interval k - 1: right end
                    rows[:-1, :, 1] = (off + size * kk[:-1] + i)        # interval k: left end
                    if self.free_time:     # the rate times h (a function of t_f) enters g
                        exprs.append(self._h_local * r)
                        places.append((rows, np.array([-0.5, -0.5])))
                    else:
                        exprs.append(r)
                        places.append((rows, np.full(2, -self.step / 2)))
                off += size * n
            else:
                off += next(b.rows for b in self.node_blocks if b.name == c.block)
        return exprs, places

    def jacobian(self) -> ca.Function:
        """IPOPT's constraint Jacobian (x, p) -> (g, jac_g_x), assembled from one node's."""
        big_n, nz = self.nodes, self.z_size
        exprs, places = self._output_rows()
        v = ca.vertcat(*exprs) if exprs else ca.SX(0, 1)
        dep = np.unique(np.asarray(ca.jacobian_sparsity(v, self._var).get_triplet()[1],
                                   dtype=int))
        jk = ca.jacobian(v, self._var[dep.tolist()])
        r_loc, c_loc = (np.asarray(a, dtype=int) for a in jk.sparsity().get_triplet())
        c_loc = dep[c_loc] if c_loc.size else c_loc
        jk_fn = ca.Function('node_jacobian', [self._var, self._pn, self._pc, self._pg],
                            [ca.vertcat(*jk.nonzeros())], {'cse': True})
        # Where each row of v enters g, at each node (up to 2 places).
        row_g = np.concatenate([r for r, _ in places], axis=1) if places else np.zeros(
            (big_n, 0, 2), dtype=int)
        row_c = np.concatenate([np.broadcast_to(c, (r.shape[1], 2)) for r, c in places]) \
            if places else np.zeros((0, 2))
        index, coef = self._input_map()
        m = r_loc.size
        src = np.arange(big_n)[:, None] * m + np.arange(m)[None, :]           # [N, m]
        out_r, out_c, out_s, out_v = [], [], [], []
        for slot in range(2):
            g_rows = row_g[:, r_loc, slot]                                      # [N, m]
            for t in range(index.shape[2]):
                c_t = coef[:, c_loc, t]
                sel = (g_rows >= 0) & (c_t != 0)
                out_r.append(g_rows[sel])
                out_c.append(index[:, c_loc, t][sel])
                out_s.append(src[sel])
                out_v.append((c_t * row_c[r_loc, slot][None, :])[sel])
        # The linear part of g (node outputs replaced by zeros) has a constant Jacobian.
        zero = {k: ca.MX(o.size1(), big_n) for k, o in self.outputs.items()}
        lin_g, _, _ = self._constraints(zero)
        lin = ca.Function('linear_jacobian', [self.z], [ca.jacobian(lin_g, self.z)])(
            np.zeros(nz))
        r_l, c_l = (np.asarray(a, dtype=int) for a in lin.sparsity().get_triplet())
        n_node = m * big_n
        out_r.append(r_l)
        out_c.append(c_l)
        out_s.append(n_node + np.arange(r_l.size))
        out_v.append(np.ones(r_l.size))
        sp, gather = _gather(*(np.concatenate(a) for a in (out_r, out_c, out_s, out_v)),
                             (self.g_size, nz), n_node + r_l.size)
        nodes = jk_fn.map(big_n, 'serial')(*self._node_arguments(physical=False))
        values = ca.mtimes(gather, ca.vertcat(ca.vec(nodes), ca.DM(lin.nonzeros())))
        return ca.Function('nlp_jac_g', [self.z, self.p], [self.g, ca.MX(sp, values)],
                           ['x', 'p'], ['g', 'jac_g_x'])

    def hessian(self) -> ca.Function:
        """IPOPT's Hessian of the Lagrangian (x, p, lam_f, lam_g) -> upper triangle,
        assembled from one node's Lagrangian and the quadratic cost's constant Hessian."""
        big_n, nz = self.nodes, self.z_size
        sigmas = [ca.SX.sym(f'sigma_{j}') for j in range(len(self.costs))]
        lag_terms = [s * (ca.sumsqr(c.residual(self._v_node)) if isinstance(c, LeastSquares)
                          else self._outs[c.output]) for s, c in zip(sigmas, self.costs)]
        lf = ca.MX.sym('lam_f')
        lg = ca.MX.sym('lam_g', self.g_size)
        multipliers, multiplier_args = [], []
        off = 0
        for c in self.constraints:
            if isinstance(c, Path):
                o = self._outs[c.output]
                nodes = self._nodes_of(c)
                lam = ca.SX.sym(f'lam_{c.output}', o.numel())
                lag_terms.append(ca.dot(lam, o))
                block = ca.reshape(lg[off:off + o.numel() * nodes.size], o.numel(), nodes.size)
                if nodes.size != big_n:    # zero at the nodes the constraint leaves free
                    pick = ca.DM.triplet(list(range(nodes.size)), nodes.tolist(),
                                         ca.DM.ones(nodes.size), nodes.size, big_n)
                    block = ca.mtimes(block, pick)
                multipliers.append(lam)
                multiplier_args.append(block)
                off += o.numel() * nodes.size
            elif isinstance(c, Defect):
                size = next(b.rows for b in self.node_blocks if b.name == c.state)
                if c.rate in self._outs:   # node k is the right end of interval k - 1 and
                    mu = ca.SX.sym(f'mu_{c.state}', size)   # the left end of interval k
                    lag_terms.append(-self._h_local / 2 * ca.dot(mu, self._outs[c.rate]))
                    lam = ca.reshape(lg[off:off + size * self.n], size, self.n)
                    zero = ca.MX.zeros(size, 1)
                    multipliers.append(mu)
                    multiplier_args.append(ca.horzcat(zero, lam) + ca.horzcat(lam, zero))
                off += size * self.n
            else:
                off += next(b.rows for b in self.node_blocks if b.name == c.block)
        if not lag_terms:
            lag = ca.SX(0)
        else:
            lag = lag_terms[0]
            for t in lag_terms[1:]:
                lag = lag + t
        hk, _ = ca.hessian(lag, self._var)
        r_loc, c_loc = (np.asarray(v, dtype=int) for v in hk.sparsity().get_triplet())
        hk_fn = ca.Function('node_hessian', [self._var, self._pn, self._pc, self._pg,
                                             *sigmas, *multipliers],
                            [ca.vertcat(*hk.nonzeros())], {'cse': True})
        hc = self._constant_hessian()
        r_c, c_c = (np.asarray(v, dtype=int) for v in hc.sparsity().get_triplet())
        index, coef = self._input_map()
        m, terms = r_loc.size, index.shape[2]
        src = np.broadcast_to(np.arange(big_n)[:, None] * m + np.arange(m)[None, :],
                              (big_n, m))
        rr, cc, ss, vv = [], [], [], []
        for s in range(terms):
            for t in range(terms):
                v = coef[:, r_loc, s] * coef[:, c_loc, t]
                sel = v != 0
                rr.append(index[:, r_loc, s][sel])
                cc.append(index[:, c_loc, t][sel])
                ss.append(src[sel])
                vv.append(v[sel])
        rr = np.concatenate(rr + [r_c])
        cc = np.concatenate(cc + [c_c])
        ss = np.concatenate(ss + [m * big_n + np.arange(r_c.size)])
        vv = np.concatenate(vv + [np.ones(r_c.size)])
        upper = np.flatnonzero(rr <= cc)                  # IPOPT takes the upper triangle
        sp, gather = _gather(rr[upper], cc[upper], ss[upper], vv[upper], (nz, nz),
                             m * big_n + r_c.size)
        sigma_args = [lf * ca.DM(np.asarray(c.weights, dtype=float)[None, :])
                      if isinstance(c, NodeSum) else ca.repmat(lf, 1, big_n)
                      for c in self.costs]
        nodes = hk_fn.map(big_n, 'serial')(
            *self._node_arguments(physical=False), *sigma_args,
            *multiplier_args)
        values = ca.mtimes(gather, ca.vertcat(ca.vec(nodes), lf * ca.DM(hc.nonzeros())))
        return ca.Function('nlp_hess_l', [self.z, self.p, lf, lg], [ca.MX(sp, values)],
                           ['x', 'p', 'lam_f', 'lam_g'], ['hess_gamma_x_x'])

    def _constant_hessian(self) -> ca.DM:
        """The Hessian of the quadratic cost in z (checked constant)."""
        if self._quadratic is None:
            return ca.DM(self.z_size, self.z_size)
        zs, ps = ca.SX.sym('z', self.z_size), ca.SX.sym('p', self.p_size)
        quad = ca.Function('quad', [self.z, self.p], [self._quadratic]).expand()
        hc = ca.hessian(quad(zs, ps), zs)[0]
        if ca.depends_on(hc, ca.vertcat(zs, ps)):
            raise ValueError('the quadratic cost has a Hessian that depends on z or p: '
                             'put its nonlinear part in the node function')
        return ca.evalf(ca.substitute(hc, ca.vertcat(zs, ps),
                                      ca.DM.zeros(self.z_size + self.p_size)))

    # ------------------------------------------------------------------ solving
    def solver(self, name: str, options: dict) -> ca.Function:
        """IPOPT on this NLP with the assembled Hessian and Jacobian (``options``: nlpsol's)."""
        return ca.nlpsol(name, 'ipopt', self.nlp(),
                         {**options, 'hess_lag': self.hessian(), 'jac_g': self.jacobian()})

    def solve(self, solver: ca.Function, z0: np.ndarray, p: np.ndarray | None = None,
              lbx: np.ndarray | None = None, ubx: np.ndarray | None = None,
              lam_g0: np.ndarray | None = None, lam_x0: np.ndarray | None = None,
              ) -> Solution:
        """One solve from z0 (and, for a warm start, the multipliers of a previous one; IPOPT
        uses them with its option ``warm_start_init_point``)."""
        args = {'x0': z0, 'lbg': self.lbg, 'ubg': self.ubg,
                'lbx': -np.inf if lbx is None else lbx, 'ubx': np.inf if ubx is None else ubx}
        if self.p_size:
            args['p'] = p
        if lam_g0 is not None:
            args['lam_g0'] = lam_g0
        if lam_x0 is not None:
            args['lam_x0'] = lam_x0
        sol = solver(**args)
        stats = solver.stats()
        return Solution(z=np.asarray(sol['x']).ravel(), lam_g=np.asarray(sol['lam_g']).ravel(),
                        lam_x=np.asarray(sol['lam_x']).ravel(), f=float(sol['f']),
                        success=bool(stats['success']), status=str(stats['return_status']),
                        iterations=int(stats['iter_count']), stats=stats)

    def shift(self, solution: Solution, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(z0, lam_g0, lam_x0) for the same problem k nodes later: every node block and
        node-wise multiplier moves k nodes earlier and the last node's value fills the end;
        globals and their multipliers stay (a receding window's warm start)."""
        if not 0 <= k <= self.n:
            raise ValueError(f'shift by 0..{self.n} nodes, not {k}')
        take = np.minimum(np.arange(self.nodes) + k, self.n)
        perm = np.arange(self.z_size)
        for b in self.node_blocks:
            idx = self.index(b.name)
            perm[idx] = idx[take]
        g_perm = np.arange(self.g_size)
        keep = np.ones(self.g_size, dtype=bool)
        off = 0
        for c in self.constraints:
            if isinstance(c, Defect):
                size = next(b.rows for b in self.node_blocks if b.name == c.state)
                rows = off + np.arange(size * self.n).reshape(self.n, size)
                g_perm[rows] = rows[np.minimum(np.arange(self.n) + k, self.n - 1)]
                off += size * self.n
            elif isinstance(c, Path):
                nodes = self._nodes_of(c)
                size = self._outs[c.output].numel()
                rows = off + np.arange(size * nodes.size).reshape(nodes.size, size)
                pos = {int(j): i for i, j in enumerate(nodes)}
                for i, j in enumerate(nodes):
                    src = pos.get(int(min(j + k, self.n)))
                    if src is None:
                        keep[rows[i]] = False
                    else:
                        g_perm[rows[i]] = rows[src]
                off += size * nodes.size
            else:
                off += next(b.rows for b in self.node_blocks if b.name == c.block)
        lam_g = np.where(keep, solution.lam_g[g_perm], 0.0)
        return solution.z[perm], lam_g, solution.lam_x[perm]


def _gather(rows_out: np.ndarray, cols_out: np.ndarray, source: np.ndarray,
            coef: np.ndarray, shape: tuple[int, int], n_in: int) -> tuple[ca.Sparsity, ca.DM]:
    """Sparsity of the sum of entries (rows_out, cols_out) and the constant matrix that
    sums source values (with coefficients) into its nonzeros (column-major order)."""
    keys = cols_out * shape[0] + rows_out
    uniq = np.unique(keys)
    sp = ca.Sparsity.triplet(shape[0], shape[1], (uniq % shape[0]).tolist(),
                             (uniq // shape[0]).tolist())
    gather = ca.DM.triplet(np.searchsorted(uniq, keys).tolist(), source.tolist(),
                           ca.DM(coef.tolist()), uniq.size, n_in)
    return sp, gather


class SolverCache:
    """At most ``size`` solvers, the least recently used evicted first, keyed by a model and a
    hashable problem key. The model is held by a weak reference: a solver is never served to
    another model (a key on id(model) can be reused by a new model at the same address), and a
    model's solvers go when the model is garbage collected."""

    def __init__(self, size: int) -> None:
        if size < 1:
            raise ValueError(f'a solver cache holds at least 1 solver, not {size}')
        self.size = int(size)
        self._entries: OrderedDict[tuple, object] = OrderedDict()

    def get(self, model: JumperModel, key: Hashable, build: Callable[[], object]) -> object:
        """The cached solver for (model, key), built by ``build()`` on a miss."""
        entry = (weakref.ref(model), key)
        if entry in self._entries:
            self._entries.move_to_end(entry)
            return self._entries[entry]
        value = build()
        self._entries[(weakref.ref(model, self._forget), key)] = value
        while len(self._entries) > self.size:
            self._entries.popitem(last=False)
        return value

    def _forget(self, dead: weakref.ref) -> None:
        for entry in [e for e in self._entries if e[0] is dead]:
            del self._entries[entry]

    def __len__(self) -> int:
        return len(self._entries)

    def clear(self) -> None:
        self._entries.clear()


#: The solvers of the trackers (and estimators) built on this transcription.
solvers = SolverCache(SOLVER_CACHE_SIZE)
