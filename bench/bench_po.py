"""Benchmark: the reference jump's parameter optimisation (run by hand: python bench/bench_po.py).

Times the multi-start PO (5 starts, N = 50) with its mesh refinement (N = 100) and the stiff
forward simulation of the optimum, as ``nmt reference`` runs them; prints CPU and wall time,
iterations, and the agreement checks. The paper: > 24 h of CPU, 21,000 evaluations.
"""
import json
import time

from nmt_ros.model.jumper import default_model
from nmt_ros.study.reference import make_reference


def main() -> None:
    model = default_model()
    c0, w0 = time.process_time(), time.perf_counter()
    ref = make_reference(model, starts=5)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    its = [r.iterations for r in ref.starts] + [ref.po.iterations]
    print(json.dumps({
        'po_cpu_s': ref.cpu_s, 'po_wall_s': ref.wall_s, 'with_simulation_cpu_s': cpu,
        'with_simulation_wall_s': wall, 'iterations_per_solve': its,
        'iterations_total': sum(its), 'checks': ref.checks,
        'paper_cpu_ratio': 24 * 3600 / ref.cpu_s}, indent=1))


if __name__ == '__main__':
    main()
