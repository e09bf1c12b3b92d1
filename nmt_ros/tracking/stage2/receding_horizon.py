"""Windows in turn: plan each window and apply it over its stride (batch and streaming).

The full horizon is one window over the whole reference; receding windows of H intervals
start every ``stride`` intervals (P = 0 at t_k + H). 'clip' plans do not depend on the muscle
state and are swept together; 'plan' plans are made one after the other from the state the
previous window left. Latency of the windowed estimate: H plus a stride.
"""
from __future__ import annotations

import numpy as np

from nmt_ros.tracking.stage2.forward_pass import apply_plan
from nmt_ros.tracking.stage2.plans import WindowPlan, WindowPlanner
from nmt_ros.tracking.stage2.references import Stage2Reference
from nmt_ros.tracking.stage2.results import MuscleState, PartClock, Stage2Step


def run_windows(planner: WindowPlanner, ref: Stage2Reference, muscle: MuscleState,
                starts: np.ndarray, length: int, stride: int, final: bool = False,
                clock: PartClock | None = None,
                ) -> tuple[MuscleState, list[Stage2Step], list[WindowPlan]]:
    """Plan and apply the windows starting at global samples ``starts`` in turn.

    ``length``, ``stride`` in intervals of the internal grid; ``final``: no more samples (the
    last windows end at the last sample). CPU and wall time go to ``clock`` ('riccati' for the
    batched 'clip' sweeps, 'plan' for the 'plan' plans, 'forward' for applying them).
    """
    starts = np.atleast_1d(np.asarray(starts, dtype=int))
    clock = clock if clock is not None else PartClock()
    steps: list[Stage2Step] = []
    plans: list[WindowPlan] = []
    if starts.size == 0:
        return muscle, steps, plans
    if not final and starts.max() + length > ref.end:
        raise ValueError('window needs reference samples not received yet')
    activation, f0 = planner.activation, planner.f0
    if not planner.constrained:
        with clock('riccati'):
            plans = planner.clip_plans(ref, starts, length, stride, final=final)
        with clock('forward'):
            for plan in plans:
                muscle, step = apply_plan(plan, muscle, activation, f0)
                steps.append(step)
        return muscle, steps, plans
    for start in starts:
        if muscle.index != start:
            raise ValueError(f'muscle state at sample {muscle.index}, window at {start}')
        with clock('plan'):
            plan = planner.plan(ref, muscle.index, muscle.a, length, stride)
        with clock('forward'):
            muscle, step = apply_plan(plan, muscle, activation, f0)
        plans.append(plan)
        steps.append(step)
    return muscle, steps, plans
