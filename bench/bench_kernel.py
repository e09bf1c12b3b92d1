"""The estimator's compiled segment kernel under different C compiler flags: CPU per segment
on a real window and how far the outputs move.

    python bench/bench_kernel.py [--bag bags/routine] [--at 5] [--repeats 3]
                                 [--cflags "-O2 -fPIC -shared" ...]

The kernel (``tracking.moving_horizon.segment_kernel``) is generated as C once, compiled with
``model.compiled.CFLAGS`` and with each ``--cflags`` set (in a temporary folder, not the
cache), and evaluated on the inputs of a whole-window linearisation of the bag at ``--at``
seconds (the estimator fed the bag up to there, as the node feeds it). The flag sets are
timed in turn, ``--repeats`` rounds, so that a machine whose speed drifts affects them
alike; per set: the fastest and median round [us per segment] and the largest output
difference relative to the largest output of the first set. Compiling takes 15-45 s a set.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import subprocess
import sys
import tempfile
import time

import casadi as ca
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nmt_ros.io.trial_bag import read_observations  # noqa: E402
from nmt_ros.model import compiled as compiled_module  # noqa: E402
from nmt_ros.model.point_map import PointMap  # noqa: E402
from nmt_ros.model.subject import load_subject_model  # noqa: E402
from nmt_ros.tracking.moving_horizon import segment_kernel  # noqa: E402
from nmt_ros.tracking.moving_horizon.estimator import MovingHorizonEstimator  # noqa: E402
from nmt_ros.tracking.moving_horizon.settings import MovingHorizonSettings  # noqa: E402


def window_inputs(bag: Path, at_s: float) -> tuple[MovingHorizonEstimator, list[np.ndarray]]:
    """The estimator fed ``bag`` up to ``at_s`` and the kernel's inputs of a linearisation
    of its whole window there."""
    obs = read_observations(bag)
    est = MovingHorizonEstimator(load_subject_model(bag), MovingHorizonSettings())
    a, w = obs.t_angles < at_s, obs.t_wrench < at_s
    est.feed(obs.t_angles[a], obs.angles[a], obs.t_wrench[w], obs.wrench[w])
    win = est.window
    if win is None:
        raise SystemExit(f'no window at {at_s} s (a re-initialisation): try another --at')
    captured: list[np.ndarray] = []
    kernel = win.kernel
    real = kernel.map

    def spy(*args: np.ndarray, copy: bool = True) -> list[np.ndarray]:
        captured.extend(np.array(a) for a in args)
        return real(*args, copy=copy)

    kernel.map = spy
    try:
        win.evaluate(win.segments, win.C, win.plate)
    finally:
        kernel.map = real
    return est, captured


def build(fn: ca.Function, flags: list[str], folder: Path, tag: str) -> ca.Function:
    src = folder / f'{fn.name()}.c'
    if not src.exists():
        gen = ca.CodeGenerator(src.name, {'with_header': False})
        gen.add(fn)
        gen.generate(str(folder) + '/')
    lib = folder / f'{tag}.so'
    start = time.perf_counter()
    subprocess.run([compiled_module.compiler() or 'cc', *flags, str(src), '-o', str(lib)],
                   check=True)
    print(f'[{tag}] compiled in {time.perf_counter() - start:.1f} s: {" ".join(flags)}',
          flush=True)
    return ca.external(fn.name(), str(lib))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--bag', default=str(ROOT / 'bags' / 'routine'))
    ap.add_argument('--at', type=float, default=5.0, help='data time of the window [s]')
    ap.add_argument('--repeats', type=int, default=3)
    ap.add_argument('--calls', type=int, default=200, help='kernel calls per round')
    ap.add_argument('--cflags', action='append', default=[],
                    help='another flag set to compare (quoted, space separated)')
    args = ap.parse_args()
    est, inputs = window_inputs(Path(args.bag), args.at)
    n_seg = inputs[0].shape[0]
    # the kernel as a CasADi function, before compilation (same model and settings)
    raw: list[ca.Function] = []
    keep = segment_kernel.compiled
    segment_kernel.compiled = lambda fn: raw.append(fn) or fn
    try:
        segment_kernel.build_kernel(est.model, est.kernel_spec)
    finally:
        segment_kernel.compiled = keep
    sets = [list(compiled_module.CFLAGS)] + [s.split() for s in args.cflags]
    with tempfile.TemporaryDirectory() as tmp:
        maps = [PointMap(build(raw[0], flags, Path(tmp), f'set{k}'))
                for k, flags in enumerate(sets)]
        outputs = [m(*inputs) for m in maps]
        scale = max(float(np.abs(o).max()) for o in outputs[0])
        rounds: list[list[float]] = [[] for _ in maps]
        for _ in range(args.repeats):
            for k, m in enumerate(maps):
                start = time.process_time()
                for _ in range(args.calls):
                    m(*inputs, copy=False)
                rounds[k].append((time.process_time() - start) / args.calls / n_seg * 1e6)
    print(f'{args.bag} at {args.at:g} s: {n_seg} segments a call, {args.calls} calls a round, '
          f'{args.repeats} rounds')
    for k, flags in enumerate(sets):
        diff = max(float(np.abs(a - b).max()) for a, b in zip(outputs[k], outputs[0])) / scale
        label = 'CFLAGS' if k == 0 else f'set{k}'
        print(f'  {label:7s} {min(rounds[k]):7.1f} us per segment (median '
              f'{np.median(rounds[k]):7.1f}), outputs within {diff:.1e} of the largest: '
              f'{" ".join(flags)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
