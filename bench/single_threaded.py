"""Imported first by a benchmark script (before numpy): one BLAS thread, as `nmt` and the
nodes run, and the repository on ``sys.path`` (``ROOT``).

A multithreaded BLAS sums in another order, and the estimator's outcome moved with it (seed 2
of bench_estimator_seeds: 3.24 / 2.06 / 4.00 -> 3.32 / 2.15 / 3.99 % of peak, jump heights
6.8 -> 5.5 % off), so figures are comparable only with the threads fixed. The variables are
set only where the user set nothing.
"""
from __future__ import annotations

import os
from pathlib import Path
import sys

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
