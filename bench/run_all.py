"""Run every benchmark in bench/ (``make bench``); each prints its own figures."""
from pathlib import Path
import subprocess
import sys

HERE = Path(__file__).resolve().parent

for script in sorted(HERE.glob('bench_*.py')):
    print(f'===== {script.name}', flush=True)
    subprocess.run([sys.executable, str(script)], check=False)
