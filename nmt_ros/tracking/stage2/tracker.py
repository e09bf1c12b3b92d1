"""``NeuromuscularTracker``: Stage 2 for the rest of the code (batch and streaming).

A stateless recipe (the state lives in ``MuscleState`` / ``StreamState``) over one model and
one set of settings; it composes the reference builder, the window planner, the forward pass
and the streaming step of this package.
"""
from __future__ import annotations

import numpy as np

from nmt_ros.model.jumper import JumperModel, default_model
from nmt_ros.model.squat import rest_activations_for_posture
from nmt_ros.tracking.stage2 import streaming
from nmt_ros.tracking.stage2.activation import ActivationLaw
from nmt_ros.tracking.stage2.forward_pass import apply_plan, initial_state
from nmt_ros.tracking.stage2.plans import WindowPlan, WindowPlanner
from nmt_ros.tracking.stage2.receding_horizon import run_windows
from nmt_ros.tracking.stage2.references import ReferenceBuilder, Stage2Reference
from nmt_ros.tracking.stage2.results import (
    MuscleState,
    PartClock,
    Stage2Result,
    Stage2Step,
    assemble,
)
from nmt_ros.tracking.stage2.settings import Stage2Settings, load_stage2_settings
from nmt_ros.tracking.stage2.streaming import StreamState


class NeuromuscularTracker:
    """Stage 2 recipe (stateless; the state lives in ``MuscleState`` / ``StreamState``)."""

    def __init__(self, model: JumperModel | None = None,
                 settings: Stage2Settings | None = None) -> None:
        self.model = model if model is not None else default_model()
        if not self.model.has_muscles:
            raise ValueError('the model has no muscle paths')
        self.settings = settings if settings is not None else load_stage2_settings()
        mp = self.model.p.muscles
        self.names = tuple(mp.names)
        self.f0 = np.asarray(mp.f0, dtype=float)
        self.Q, self.R, self.P = self.settings.weights(self.names, self.f0)
        self.activation = ActivationLaw.from_model(self.model)
        self.references = ReferenceBuilder(self.model, self.Q, self.R, self.P,
                                           self.settings.max_step,
                                           sweeps=self.settings.saturation == 'clip',
                                           k_force=self.settings.force_weight(self.f0))
        self.planner = WindowPlanner(self.settings, self.Q, self.R, self.P, self.f0,
                                     self.activation)

    @property
    def constrained(self) -> bool:
        """True for the saturation-aware LQT (``settings.saturation == 'plan'``)."""
        return self.planner.constrained

    # ------------------------------------------------------------------ pieces
    def reference(self, t: np.ndarray, tau_ref: np.ndarray, theta: np.ndarray,
                  theta_dot: np.ndarray, theta_ddot: np.ndarray, offset: int = 0,
                  substeps: int | None = None) -> Stage2Reference:
        """The reference of samples t [n] (s), tau_ref [n, 3] (N m), theta, theta_dot,
        theta_ddot [n, 3] (rad, rad/s, rad/s^2) on the internal grid
        (``ReferenceBuilder.build``)."""
        return self.references.build(t, tau_ref, theta, theta_dot, theta_ddot, offset=offset,
                                     substeps=substeps)

    def initial_state(self, ref: Stage2Reference, a0: np.ndarray) -> MuscleState:
        """Muscle state at the first reference sample from activations a0 [m]."""
        return initial_state(ref, a0)

    def window_samples(self, ref: Stage2Reference, window_length: float | None = None,
                       window_stride: float | None = None) -> tuple[int, int]:
        """(window length, stride) in intervals of the internal grid, from s."""
        return self.planner.window_samples(ref, window_length, window_stride)

    def plan_window(self, ref: Stage2Reference, state: MuscleState, length: int,
                    stride: int) -> WindowPlan:
        """The plan of the window starting at the muscle state (``WindowPlanner.plan``)."""
        return self.planner.plan(ref, state.index, state.a, length, stride)

    def apply(self, plan: WindowPlan, state: MuscleState) -> tuple[MuscleState, Stage2Step]:
        """Advance the muscles over the plan's intervals (``forward_pass.apply_plan``)."""
        return apply_plan(plan, state, self.activation, self.f0)

    # ------------------------------------------------------------------ streaming
    def start_stream(self, a0: np.ndarray, dt: float) -> StreamState:
        """A fresh streaming state: initial activations a0 [m], input sample period dt [s].

        (``nmt_ros.model.squat.rest_activations`` gives a0 from the first torque sample.)
        """
        return streaming.start_stream(self.references, a0, dt)

    def push(self, stream: StreamState, t: np.ndarray, tau_ref: np.ndarray,
             theta: np.ndarray, theta_dot: np.ndarray, theta_ddot: np.ndarray,
             final: bool = False, window_length: float | None = None,
             window_stride: float | None = None) -> tuple[StreamState, list[Stage2Step]]:
        """Feed new input samples; returns the new state and the outputs now computable
        (``streaming.push``)."""
        return streaming.push(self.references, self.planner, stream, t, tau_ref, theta,
                              theta_dot, theta_ddot, final=final, window_length=window_length,
                              window_stride=window_stride)

    # ------------------------------------------------------------------ batch
    def track_motion(self, t: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                     tau: np.ndarray, x0: np.ndarray, t_stop: float, mode: str = 'full',
                     window_length: float | None = None) -> Stage2Result:
        """Stage 2 on a Stage-1 motion: generalised coordinates q, qd, qdd [n, 6] and joint
        torques tau [n, 3] at times t [s], up to ``t_stop`` [s], from the activations that hold
        its first posture at rest on springs anchored at ``x0``."""
        keep = np.asarray(t) <= t_stop
        m = self.model
        theta = [m.batch(m.joint_angles, x[keep])[0] for x in (q, qd, qdd)]
        a0 = rest_activations_for_posture(m, q[0], x0)
        return self.track(t[keep], tau[keep], *theta, a0, mode=mode,
                          window_length=window_length)

    def track(self, t: np.ndarray, tau_ref: np.ndarray, theta: np.ndarray,
              theta_dot: np.ndarray, theta_ddot: np.ndarray, a0: np.ndarray,
              mode: str = 'full', window_length: float | None = None,
              window_stride: float | None = None) -> Stage2Result:
        """Stage 2 on a whole recording: mode 'full' (the paper) or 'windowed'.

        t [n] s; tau_ref [n, 3] N m; theta, theta_dot, theta_ddot [n, 3] (rad, rad/s,
        rad/s^2); a0 [m] initial activations; window length and stride in s. The windowed mode
        is ``push`` fed the whole recording (same plans, same forward pass); its CPU time is
        split between the plans ('plan': bounded LQT + Eqs. 12-13 per window in 'plan' mode;
        'riccati': the batched sweeps in 'clip' mode) and the forward pass ('forward').
        """
        cpu = {'prepare': 0.0, 'plan': 0.0, 'riccati': 0.0, 'forward': 0.0}
        wall = dict(cpu)
        clock = PartClock(cpu, wall)
        with clock('prepare'):
            ref = self.reference(t, tau_ref, theta, theta_dot, theta_ddot)
        muscle = initial_state(ref, a0)
        if mode == 'full':
            length = stride = ref.n - 1
        elif mode == 'windowed':
            length, stride = self.window_samples(ref, window_length, window_stride)
        else:
            raise ValueError(f"mode must be 'full' or 'windowed', not {mode!r}")
        muscle, steps, plans = run_windows(self.planner, ref, muscle,
                                           np.arange(0, ref.n - 1, stride), length, stride,
                                           final=True, clock=clock)
        h = ref.grid.h
        windowed = mode == 'windowed'
        return assemble(ref, steps, muscle, plans, self.R, self.names, mode,
                        self.settings.saturation, cpu, wall,
                        length * h if windowed else None, stride * h if windowed else None)
