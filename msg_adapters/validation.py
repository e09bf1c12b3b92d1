"""Input checks shared by the adapters; every failure is a ``ValueError`` whose message names
the problem (field, index, joint), ready to be reported on ``/nmt/status``."""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


def check_names(names: Any, what: str = 'names') -> tuple[str, ...]:
    """Non-empty, unique strings."""
    if isinstance(names, str):
        raise ValueError(f'{what} must be a sequence of strings, not one string {names!r}')
    out = tuple(names)
    if not out:
        raise ValueError(f'{what} is empty')
    bad = [n for n in out if not isinstance(n, str) or not n]
    if bad:
        raise ValueError(f'{what} must be non-empty strings, got {bad!r}')
    if len(set(out)) != len(out):
        dup = sorted({n for n in out if out.count(n) > 1})
        raise ValueError(f'{what} has duplicates: {dup}')
    return out


def check_finite(values: np.ndarray, what: str, labels: Sequence[str] | None = None,
                 allow_nan: bool = False) -> None:
    """Reject NaN/inf (only inf when ``allow_nan``: a NaN then marks a missing value, e.g. an
    occluded marker); the message names the first bad element (and its label)."""
    bad = np.isinf(values) if allow_nan else ~np.isfinite(values)
    if bad.any():
        idx = np.unravel_index(int(np.flatnonzero(bad)[0]), values.shape)
        label = ''
        if labels is not None and values.ndim >= 1:
            label = f' ({labels[idx[-1]]})'
        where = idx[0] if len(idx) == 1 else tuple(int(i) for i in idx)
        raise ValueError(f'{what} has a non-finite value {values[idx]} at index {where}{label}')


def as_vector(values: Any, n: int, what: str, labels: Sequence[str] | None = None) -> np.ndarray:
    """A finite float64 vector of length ``n``."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != (n,):
        raise ValueError(f'{what} must have length {n}, got shape {arr.shape}')
    check_finite(arr, what, labels)
    return arr


def as_matrix(values: Any, n: int, k: int, what: str,
              labels: Sequence[str] | None = None, allow_nan: bool = False) -> np.ndarray:
    """A finite float64 ``[n, k]`` array (``allow_nan``: NaN allowed, inf still refused)."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != (n, k):
        raise ValueError(f'{what} must have shape ({n}, {k}), got {arr.shape}')
    check_finite(arr, what, labels, allow_nan=allow_nan)
    return arr


def reorder_index(got: Sequence[str], expected: Sequence[str], what: str = 'names') -> np.ndarray:
    """Indices taking ``got``-ordered columns to ``expected`` order; ValueError if any is
    missing (extra names in ``got`` are ignored)."""
    position = {name: i for i, name in enumerate(got)}
    missing = [name for name in expected if name not in position]
    if missing:
        raise ValueError(f'{what}: missing {missing} (got {list(got)})')
    return np.fromiter((position[name] for name in expected), dtype=np.intp,
                       count=len(expected))
