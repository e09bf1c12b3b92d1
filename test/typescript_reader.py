"""The TypeScript bag reader of ``test/ts_reader`` run on a bag folder (for
``test_ts_reader`` and the live graph's recordings in ``test_launch``)."""
from __future__ import annotations

import json
from pathlib import Path
import shutil
import subprocess

import pytest

READER = Path(__file__).resolve().parent / 'ts_reader' / 'dist' / 'read_bag.js'


def read_with_typescript(bag: Path) -> dict:
    """The TypeScript reader's summary of ``bag`` (see ``test/ts_reader/src/read_bag.ts``)."""
    if shutil.which('node') is None:
        pytest.skip('node is not installed: the TypeScript reader cannot run')
    if not READER.exists():
        if shutil.which('npm') is None:
            pytest.skip('npm is not installed: the TypeScript reader cannot be built')
        pytest.fail(f'{READER} is missing: build it with `make ts-reader` (npm ci + tsc)')
    done = subprocess.run(['node', str(READER), str(bag)], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)
