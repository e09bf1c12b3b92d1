"""CasADi functions compiled to C: the hot per-sample model functions of the estimators.

CasADi evaluates SX functions in its virtual machine; the same function generated as C and
compiled with the machine's C compiler runs 7-10 times faster (the estimator's dynamics
Jacobian: 130 -> 15 microseconds per point on this 2-core machine). ``compiled(fn)`` returns
the compiled function, built once per machine and cached by the hash of its C source (so a
changed model or formula gets a new library), or ``fn`` itself when no compiler is available
(``compile_problem()`` says why; the estimator reports it). The cache lives in
``$NMT_CACHE_DIR`` or ``~/.cache/nmt_ros``. One process compiles a library while the others
that need it wait on a lock file (the nodes start together; on 2 cores several compilers of the
same source only slow each other down), and libraries are written to a temporary name and
renamed, so no process loads a half-written file. ``notes()`` lists what was compiled and how
long it took (a node reports it on ``/nmt/status``).
"""
from __future__ import annotations

import fcntl
import functools
import hashlib
import os
from pathlib import Path
import platform
import shutil
import subprocess
import tempfile
import time

import casadi as ca

#: Flags of the compiler; part of the cache key. GCC's partial-redundancy elimination and code
#: hoisting (both in -O2) spend 82 % of the compile on CasADi's long straight-line code: the
#: estimator's segment kernel (1.8 MB of C) compiled in 85-90 s at -O2 and in 12.8 s without
#: them, and evaluated as fast (108-157 vs 112-171 us per segment over three repeats; -O1:
#: 10 s, 121-171 us), GCC 12.2 on this 2-core machine.
#: ``-march=native`` with ``-ffp-contract=off`` (no fused multiply-adds, so every operation
#: rounds as in the portable build): the kernel 11 % faster with bit-identical outputs
#: (``bench/bench_kernel.py``: 68.3 against 76.5 us per segment, outputs within 0.0 of the
#: portable build's, 2026-12-07); a library built so runs only on this kind of CPU, so the
#: cache key holds the CPU's identity (``_machine``). A compiler that refuses these flags
#: builds with ``PORTABLE_CFLAGS``. Since the kernel's J'J is part of its SX code
#: (``segment_kernel``, 2026-12-07) it compiles in ~30 s instead of ~15 (once per machine).
CFLAGS = ('-O2', '-fno-tree-pre', '-fno-code-hoisting', '-march=native', '-ffp-contract=off',
          '-fPIC', '-shared')
PORTABLE_CFLAGS = tuple(f for f in CFLAGS if f not in ('-march=native',))

_PROBLEMS: list[str] = []
_NOTES: list[str] = []
_LOADED: dict[tuple[str, str], ca.Function] = {}


def cache_dir() -> Path:
    """Where compiled libraries are kept (created on demand)."""
    root = os.environ.get('NMT_CACHE_DIR') or os.path.join(
        os.environ.get('XDG_CACHE_HOME') or os.path.expanduser('~/.cache'), 'nmt_ros')
    path = Path(root) / 'casadi'
    path.mkdir(parents=True, exist_ok=True)
    return path


def compiler() -> str | None:
    """The C compiler used ($CC, cc or gcc), or None."""
    for name in (os.environ.get('CC'), 'cc', 'gcc'):
        if name and shutil.which(name):
            return name
    return None


def compile_problem() -> str | None:
    """Why the last ``compiled`` call fell back to CasADi's virtual machine (None: it did not)."""
    return _PROBLEMS[-1] if _PROBLEMS else None


def notes() -> list[str]:
    """What this process compiled (name, seconds), oldest first."""
    return list(_NOTES)


def compiled(fn: ca.Function) -> ca.Function:
    """``fn`` generated as C, compiled and loaded (cached); ``fn`` itself if that fails."""
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / f'{fn.name()}.c'
        gen = ca.CodeGenerator(src.name, {'with_header': False})
        gen.add(fn)
        cwd = os.getcwd()
        try:
            os.chdir(tmp)
            gen.generate()
        finally:
            os.chdir(cwd)
        code = src.read_text()
        digest = hashlib.sha256((code + ' '.join(CFLAGS) + ca.__version__
                                 + _machine()).encode()).hexdigest()
        key = (fn.name(), digest)
        if key in _LOADED:
            return _LOADED[key]
        lib = cache_dir() / f'{fn.name()}_{digest[:20]}.so'
        if not lib.exists():
            cc = compiler()
            if cc is None:
                _PROBLEMS.append(f'no C compiler found: {fn.name()} runs in the CasADi VM')
                return fn
            with open(lib.with_suffix('.lock'), 'w') as lock:
                fcntl.flock(lock, fcntl.LOCK_EX)     # released when the file closes
                if not lib.exists():                 # another process may have made it
                    problem = _compile(cc, src, lib)
                    if problem is not None:
                        _PROBLEMS.append(problem)
                        return fn
    loaded = ca.external(fn.name(), str(lib))
    _LOADED[key] = loaded
    return loaded


@functools.cache
def _machine() -> str:
    """The CPU's identity for the cache key (architecture, model and instruction-set flags
    where the system tells them): a ``-march=native`` library is not loaded on another CPU
    that shares the cache."""
    ident = [platform.machine()]
    try:
        with open('/proc/cpuinfo') as f:
            for line in f:
                if not line.strip():
                    break                   # the first processor's block is enough
                if line.split(':', 1)[0].strip() in ('model name', 'flags', 'Features',
                                                     'CPU part'):
                    ident.append(line.strip())
    except OSError:
        ident.append(platform.processor())
    return '\n'.join(ident)


def _compile(cc: str, src: Path, lib: Path) -> str | None:
    """Compile ``src`` to ``lib`` (staged, then renamed); the problem, or None."""
    start = time.perf_counter()
    part = src.with_suffix('.so')
    proc = subprocess.run([cc, *CFLAGS, str(src), '-o', str(part)],
                          capture_output=True, text=True)
    if proc.returncode != 0:            # a compiler without -march=native: the portable build
        proc = subprocess.run([cc, *PORTABLE_CFLAGS, str(src), '-o', str(part)],
                              capture_output=True, text=True)
    if proc.returncode != 0:
        return f'{cc} failed on {src.stem}: {proc.stderr.strip()[:300]}'
    staged = lib.with_suffix(f'.{os.getpid()}.tmp')
    shutil.copyfile(part, staged)
    os.replace(staged, lib)
    _NOTES.append(f'compiled {src.stem} to {lib.name} in {time.perf_counter() - start:.1f} s '
                  '(once per machine and model)')
    return None
