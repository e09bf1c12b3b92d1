"""The whole NMT method on one set of observations (Fig. 2B), plus the IVD baseline.

observations -> conditioning -> Stage 1 (SKT: torques, tracked motion) -> Stage 2 (LQT:
muscle forces, activations, excitations) -> NMT forward simulation (the full musculoskeletal
model driven by the Stage-2 excitations, from the tracked initial state: the NMT jump);
and observations -> IVD torques -> open-loop forward simulation (the baseline).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
import time

import numpy as np

from nmt_ros.model.jumper import JumperModel
from nmt_ros.model.simulation import Simulation, held, simulate_excitations
from nmt_ros.records import MuscleEstimates, Observations, SKTResult, TrialEstimates
from nmt_ros.tracking.conditioning import ConditionedObservations, ConditioningSettings, condition
from nmt_ros.tracking.ivd import IVDResult, inverse_dynamics_baseline, simulate_open_loop
from nmt_ros.tracking.skeletal_tracker import (
    SKTSettings,
    SKTState,
    initial_state,
    reference_arrays,
)
from nmt_ros.tracking.stage2 import (
    NeuromuscularTracker,
    Stage2Result,
    load_stage2_settings,
)
from nmt_ros.tracking.streaming import track_stage1

STAGE1_METHODS = ('skt', 'optimal', 'optimal_muscle', 'mhe')
STAGE1_LABELS = {'skt': 'SKT', 'optimal': 'optimal tracking',
                 'optimal_muscle': 'optimal tracking (muscles)',
                 'mhe': 'moving-horizon estimator (refined)'}
#: Records longer than this [s] are not simulated open loop by the NMT simulation (the
#: stance before and after a jump is unstable without feedback): a single push-off is.
NMT_SIMULATION_MAX_S = 2.0


@dataclass(frozen=True)
class NMTSettings:
    """Settings of a full NMT run (defaults: the paper's, with our documented choices)."""

    conditioning: ConditioningSettings = ConditioningSettings()
    skt: SKTSettings = SKTSettings()
    # 'skt' (the paper) | 'optimal' (optimal tracking, free joint torques) |
    # 'optimal_muscle' (optimal tracking with the joint torques made by the muscles) |
    # 'mhe' (the moving-horizon estimator, as live) | 'auto': optimal_muscle from the
    # skeletal tracker's result when the tracker followed the whole record, else mhe
    stage1: str = 'skt'
    stage2_mode: str = 'full'            # 'full' (the paper) | 'windowed'
    window_length_s: float | None = None  # windowed mode: H (default from stage2.yaml)
    stage2_k_r: float | None = None      # Stage 2 effort weight kR (default: stage2.yaml's)
    rate_hz: float = 1080.0
    stage2_margin_s: float = 0.01        # Stage 2 runs until Stage-1 lift-off + this
    flight_s: float = 0.02               # the NMT simulation runs past its lift-off by this
    mhe: object = None                   # MovingHorizonSettings (None: its defaults)


@dataclass
class NMTRun:
    """Everything one NMT run produced."""

    cond: ConditionedObservations
    skt: SKTResult
    ivd: IVDResult
    stage2: Stage2Result | None
    nmt_sim: Simulation | None
    a0: np.ndarray
    cpu_s: dict = field(default_factory=dict)
    stage1_method: str = ''              # the Stage 1 that ran (``NMTSettings.stage1``)

    @property
    def ok(self) -> bool:
        return self.skt.ok and self.stage2 is not None

    def estimates(self) -> TrialEstimates:
        """The run's estimates as the estimates bag carries them."""
        muscles = (None if self.stage2 is None else MuscleEstimates(
            t=self.stage2.t, f=self.stage2.f, a=self.stage2.a, u=self.stage2.u))
        return TrialEstimates(stage1=self.skt, ivd_t=self.ivd.t, ivd_tau=self.ivd.tau,
                              muscles=muscles)


def joint_kinematics(model: JumperModel, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenSim joint angles, rates and accelerations [n, 3] (linear in q)."""
    return tuple(model.batch(model.joint_angles, x)[0] for x in (q, qd, qdd))


def simulate_stage2(model: JumperModel, stage2: Stage2Result, q0: np.ndarray, qd0: np.ndarray,
                    x0: np.ndarray, t_end: float, rate_hz: float = 1080.0) -> Simulation:
    """The NMT forward simulation: the musculoskeletal model driven by Stage 2's excitations
    (held between its samples) from the tracked initial state and Stage 2's activations."""
    x_init = np.concatenate([q0, qd0, stage2.a[0]])
    return simulate_excitations(model, x_init, x0, held(stage2.t, stage2.u), t_end,
                                method='rk4', rate_hz=rate_hz)


def run_nmt(model: JumperModel, obs: Observations, settings: NMTSettings = NMTSettings(),
            progress: callable | None = None, start: SKTState | None = None,
            t_start_s: float = 0.0) -> NMTRun:
    """Stage 1, IVD, Stage 2 and the NMT simulation on ``obs``; CPU seconds per part.

    Tracking starts at ``t_start_s`` of the observations' time (their filter runs over the
    whole recording), which is trial time 0 of every result; ``start``: the tracked model's
    state there when known (a trial that starts in flight), else the static start from the
    observations. Outputs are at k / ``settings.rate_hz``.
    """
    say = progress or (lambda _msg: None)
    cpu: dict[str, float] = {}
    c = time.process_time()
    cond = condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench, settings.conditioning)
    if t_start_s:
        cond = cond.shifted(t_start_s)
        obs = obs.after(t_start_s)
    cpu['conditioning'] = time.process_time() - c
    for note in cond.notes:
        say(f'conditioning: {note}')

    method = settings.stage1
    if method not in STAGE1_METHODS + ('auto',):
        raise ValueError(f'stage1 must be one of {STAGE1_METHODS + ("auto",)}, not {method!r}')
    if method != 'mhe':
        guess = ' (optimal tracking\'s initial guess)' if method != 'skt' else ''
        say(f'Stage 1: skeletal motion tracker{guess}')
        skt = track_stage1(model, cond, settings.skt, settings.rate_hz, start=start)
        cpu['stage1'] = skt.cpu_s + cpu['conditioning']
    if method == 'auto':
        # Optimal tracking is only as good as its initial guess: from a tracker that lost
        # control (the real drop jump's landing) IPOPT settles 16-21 deg and 40 % BW away
        # from the data, where the moving-horizon estimator, which re-initialises, follows
        # it to 1.6-2.7 deg and 9 % BW
        if skt.ok:
            method = 'optimal_muscle'
        else:
            event = skt.events[0] if skt.events else {'t': float('nan'), 'reason': skt.status}
            say(f'the skeletal tracker lost control at {event["t"] + t_start_s:.3f} s '
                f'({event["reason"]}): '
                'Stage 1 is the moving-horizon estimator (optimal tracking needs a guess of '
                'the whole record)')
            method = 'mhe'
    if method == 'mhe':
        from nmt_ros.tracking.moving_horizon.estimator import estimate

        say('Stage 1: moving-horizon estimator (the live estimator fed the whole record)')
        mhe = estimate(model, obs.t_angles, obs.angles, obs.t_wrench, obs.wrench,
                       settings.mhe)
        skt = mhe.refined
        cpu['stage1'] = skt.cpu_s
        for e in mhe.events:
            if e.level != 'info':
                say(f'  {e.level} at {e.t + t_start_s:.3f} s: {e.message}')
    if method in ('optimal', 'optimal_muscle') and skt.t.size >= 2:
        from nmt_ros.tracking.optimal_tracker import OptimalTrackingSettings, track_optimal

        actuation = 'muscle' if method == 'optimal_muscle' else 'torque'
        say(f'Stage 1: optimal tracking of all observations, {actuation} actuation '
            '(from the tracker\'s result)')
        # The tracker's result is only the initial guess: optimal tracking also runs after
        # the tracker lost control (its partial result, the last sample held), and the
        # tracker's result stands if optimal tracking fails. Both events are reported.
        c = time.process_time()
        try:
            opt = track_optimal(model, obs, skt, OptimalTrackingSettings(actuation=actuation))
        except (RuntimeError, ValueError, np.linalg.LinAlgError) as err:   # CasADi, guess
            opt = replace(skt, status=f'error: {type(err).__name__}: {err}'[:300])
        cpu['stage1'] += time.process_time() - c
        if opt.ok:
            opt.events = [{**e, 'reason': f'skeletal tracker (initial guess): {e["reason"]}'}
                          for e in skt.events] + opt.events
            skt = opt
        else:
            say(f'optimal tracking failed ({opt.status}); Stage 1 is the tracker\'s result')
            skt.events = skt.events + [{'t': 0.0, 'reason': f'optimal tracking: {opt.status}'}]
    if method == 'mhe':
        return replace(_run_streamed(model, obs, settings, cond, skt, cpu, say, start),
                       stage1_method=method)
    if not skt.ok:
        say(f'Stage 1 lost control: {skt.events[0]["reason"]} at '
            f'{skt.events[0]["t"] + t_start_s:.3f} s')

    say('IVD baseline')
    c = time.process_time()
    init = (start if start is not None else
            initial_state(model, reference_arrays(cond, np.array([0.0]))[0], settings.skt))
    ivd = inverse_dynamics_baseline(model, cond, init, settings.rate_hz)
    ivd = simulate_open_loop(model, ivd, init, settings.rate_hz)
    cpu['ivd'] = time.process_time() - c

    a0 = np.zeros(9)
    stage2 = nmt_sim = None
    if skt.ok:
        say('Stage 2: neuromuscular tracker (LQT)')
        c = time.process_time()
        t_stop = (skt.liftoff_s if np.isfinite(skt.liftoff_s) else skt.t[-1])
        overrides = {} if settings.stage2_k_r is None else {'k_r': float(settings.stage2_k_r)}
        tracker = NeuromuscularTracker(model, load_stage2_settings(**overrides))
        stage2 = tracker.track_motion(skt.t, skt.q, skt.qd, skt.qdd, skt.tau, skt.x0,
                                      t_stop + settings.stage2_margin_s,
                                      mode=settings.stage2_mode,
                                      window_length=settings.window_length_s)
        a0 = stage2.a[0].copy()
        cpu['stage2'] = time.process_time() - c

        say('NMT forward simulation (muscles driven by the Stage-2 excitations)')
        c = time.process_time()
        nmt_sim = simulate_stage2(model, stage2, skt.q[0], skt.qd[0], skt.x0,
                                  float(stage2.t[-1]) + settings.flight_s, settings.rate_hz)
        cpu['nmt_simulation'] = time.process_time() - c
    cpu['nmt_total'] = cpu['stage1'] + cpu.get('stage2', 0.0)
    return NMTRun(cond=cond, skt=skt, ivd=ivd, stage2=stage2, nmt_sim=nmt_sim, a0=a0, cpu_s=cpu,
                  stage1_method=method)


def _run_streamed(model: JumperModel, obs: Observations, settings: NMTSettings,
                  cond: ConditionedObservations, skt: SKTResult, cpu: dict,
                  say: callable, start: SKTState | None = None) -> NMTRun:
    """The streaming path (Stage 1 by the moving-horizon estimator): Stage 2 by the live
    receding-horizon stream over the whole record (every phase, flights included), the IVD
    baseline, and the NMT simulation only for a single push-off (``NMT_SIMULATION_MAX_S``)."""
    from nmt_ros.tracking.streaming import track_stage2

    say('IVD baseline')
    c = time.process_time()
    init = (start if start is not None else
            initial_state(model, reference_arrays(cond, np.array([0.0]))[0], settings.skt))
    ivd = inverse_dynamics_baseline(model, cond, init, settings.rate_hz)
    if obs.t_wrench[-1] <= NMT_SIMULATION_MAX_S:
        ivd = simulate_open_loop(model, ivd, init, settings.rate_hz)
    cpu['ivd'] = time.process_time() - c
    stage2 = nmt_sim = None
    a0 = np.zeros(len(model.p.muscles.names))
    if skt.t.size >= 2:
        say('Stage 2: neuromuscular tracker (receding windows, as live)')
        c = time.process_time()
        overrides = {} if settings.stage2_k_r is None else {'k_r': float(settings.stage2_k_r)}
        tracker = NeuromuscularTracker(model, load_stage2_settings(**overrides))
        theta, = model.batch(model.joint_angles, skt.q)
        theta_dot, = model.batch(model.joint_angles, skt.qd)
        stage2 = track_stage2(model, skt.t, skt.tau, theta, theta_dot, tracker,
                              settings.window_length_s or 0.1, rate_hz=settings.rate_hz)
        a0 = stage2.a[0].copy()
        cpu['stage2'] = time.process_time() - c
        if skt.t[-1] - skt.t[0] <= NMT_SIMULATION_MAX_S:
            say('NMT forward simulation (muscles driven by the Stage-2 excitations)')
            c = time.process_time()
            k0 = int(np.searchsorted(skt.t, stage2.t[0] - 1e-9))
            nmt_sim = simulate_stage2(model, stage2, skt.q[k0], skt.qd[k0], skt.x0,
                                      float(stage2.t[-1]), settings.rate_hz)
            cpu['nmt_simulation'] = time.process_time() - c
    cpu['nmt_total'] = cpu['stage1'] + cpu.get('stage2', 0.0)
    return NMTRun(cond=cond, skt=skt, ivd=ivd, stage2=stage2, nmt_sim=nmt_sim, a0=a0, cpu_s=cpu)
