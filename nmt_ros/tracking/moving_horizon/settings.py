"""Settings of the moving-horizon estimator (Stage 1, muscle-driven, fixed lag).

The measurement weights are the observations' noise standard deviations (the observation
specification: 5/3/2/1 deg for foot..HAT, 2 % of body weight for the forces, that times the
foot's 0.17 m heel-to-toe length for the moment); everything else is a property of the
estimator, documented with its unit.
"""
from __future__ import annotations

import ast
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import numpy as np

from nmt_ros.tracking.conditioning import cutoff_for_rate
from nmt_ros.tracking.observation_noise import OBSERVATION_NOISE


@dataclass(frozen=True)
class MovingHorizonSettings:
    """Trajectory resolution, window, weights and numerics of the estimator."""

    # --- trajectories and timing
    knot_rate_hz: float = 120.0        # B-spline knots per second (q, a, s, b): 240 gave
                                       # the same torques on the routine at 1.5x the CPU
    update_rate_hz: float = 40.0       # Gauss-Newton updates per second of data: each costs
                                       # about the same at any rate; on 20 s of the routine
                                       # 120 / 60 / 40 / 30 Hz took 1.5 / 0.65 / 0.5 / 0.5
                                       # of a core (30 Hz: 29 restarts); 40 Hz is what a
                                       # live node keeps up with on 2 shared cores
    lag_s: float = 0.05                # refined estimate: this far behind the newest data
    window_s: float = 0.1              # data span of the window (>= lag); older data is
                                       # marginalised into the arrival cost
    # --- the streams' nominal rates (the compiled kernel's sample capacity per knot interval;
    # faster streams still work, with extra kernel calls)
    angle_rate_hz: float = 120.0
    wrench_rate_hz: float = 1080.0
    # mocap stamps this long after the instant they measured [s] (a camera system's
    # latency, stamped on arrival: Vicon and OptiTrack report theirs); subtracted. Measured
    # with 10 ms unaccounted (bench/bench_unseen_faults.py --faults mocap_late, realisations
    # 1-4): landing knee / hip 5.45 / 7.67 -> 9.33 / 10.79 % of peak
    angle_latency_s: float = 0.0
    # mocap stamps taken on the camera's frame clock (frame_clock.FrameClock) with this
    # smoothing fraction per frame (0: the stamps as they are). Uniform stamps pass through
    # bit for bit; +-2 ms of arrival jitter at 120 Hz is cut to ~0.17 ms RMS
    frame_clock_alpha: float = 0.03
    # force-plate channels clipped by a saturated amplifier (plate_saturation): a reading
    # repeating exactly at or beyond this many body weights (forces; moments: times
    # moment_lever_m) is missing, not measured (0: off)
    saturation_min_bw: float = 1.5
    # --- measurement model (the observation specification, OBSERVATION_NOISE)
    angle_sd_deg: tuple[float, float, float, float] = OBSERVATION_NOISE.angle_sd_deg  # foot..HAT
    force_sd_bw: float = OBSERVATION_NOISE.force_sd_bw      # forces' noise, fraction of BW
    moment_lever_m: float = OBSERVATION_NOISE.moment_lever_m  # moment noise = force x lever
    huber_k: float = 10.0              # residuals beyond k SD weigh linearly (outliers; a
                                       # slowly tracked bias must not count as one)
    # --- model error and priors
    # Eq. 1 residual allowed per collocation point: row i is divided by
    # max(dynamics_sd x M_ii, dynamics_sd_floor), i.e. an acceleration error [rad/s^2, m/s^2]
    # (M_ii is constant in absolute-angle coordinates) but at least the floor [N m, N]: the
    # foot (M_11 = 0.03 kg m^2) is nearly massless, its row a moment balance, and its
    # acceleration not worth resolving (3 N m at 100 rad/s^2). At 0.1 the estimate left
    # the truth even on noise-free routine data (a knee-flexion mode growing 2x per 25 ms
    # from 0.25 s of quiet stance); 1.0 is stable there and, measured on the first 20 s
    # of bags/routine (bench/bench_estimator.py), cut the torque errors by a third
    dynamics_sd: float = 1.0
    dynamics_sd_floor: float = 0.5
    # the joint torques published: 'muscle' (the muscles' joint torques) or 'net' (the net
    # joint torques of the estimated motion and ground wrench: the muscles' plus the joint
    # part of Eq. 1's residual, the rest of it put on the HAT; point_functions.output_function).
    # A subject the model only approximates (a lab recording: rigid tendons, nine lumped
    # muscles, a planar rigid trunk) leaves the muscles short where the motion needs more:
    # the real drop jump's push-off, knee 60-80 N m estimated where the motion and forces
    # need 140-220; its estimated motion's net torques follow OpenSim's inverse dynamics
    # (joint_torques_for, README). On the shipped jumper's own routine the model is exact
    # and the muscles' torques are the better estimate: 16 realisations, hip 3.8 -> 5.7 % of
    # peak with 'net' (flight 10 -> 19), so 'muscle' is kept there
    joint_torques: str = 'muscle'
    # kinematic contact: a loaded contact point (its share of the vertical force, from the
    # centre of pressure) stays at the springs' sinkage (load / stiffness) and does not slide
    contact_height_sd_m: float = 0.002
    contact_slip_sd_m_s: float = 0.02
    contact_full_load_bw: float = 0.15  # points are held once the vertical force is this [BW]
    contact_free_load_bw: float = 0.05  # and free below this (airborne; above the noise)
    contact_full_share: float = 0.2    # ... in proportion to their share of it up to this
    contact_release_sd: float = 3.0    # ... unless the motion lifts them by more than this
                                       # many contact_height_sd_m (0: never let go; at 0 a
                                       # rising heel stayed held: quiet-stance torques on the
                                       # routine 2.2/1.9/3.8 -> 1.3/1.2/3.3 % of peak at 3)
    # under load (contact_full_load_bw) the foot's lowest point is on the ground, within this
    # SD [m] (0: off). The release above lets go of any point the motion lifts, and the
    # ground wrench is free, so nothing held the body down: the real drop jump's deep landing
    # floated 0.23 m up at 2.3 BW (two losses of control). At 0.01: none (0.002 and 0.005:
    # one; 0.03: none; those with the row's shares differentiated); 16 realisations of the
    # routine: landing torques 15.6 / 13.0 / 13.9 -> 15.0 / 12.6 / 12.8 % of peak,
    # re-initialisations 2.9 -> 2.7 a minute
    contact_support_sd_m: float = 0.01
    # the foot's mocap angle SD [deg] where the ground does not hold both contact points (a
    # heel rise, a flight; 0: angle_sd_deg's). With a flat foot held by both points the mocap
    # says nothing, but in a push-off the excitations' rate prior kept the foot flat while
    # the heel rose (20 deg behind the truth at lift-off, ankle torque -91 vs -180 N m): at
    # 5 deg the mocap could not pull it. Both changes on 16 realisations of the routine
    # (bench/bench_estimator_seeds.py, against the commit before): jump heights 11.7 -> 8.9 %
    # off, landing torques 15.6 / 13.0 / 13.9 -> 12.4 / 11.5 / 13.8 % of peak, all phases
    # 3.4 / 2.7 / 4.8 -> 3.1 / 2.6 / 4.6, muscles 7.8 -> 8.0 % F0 (quiet stance 5.8 -> 6.0);
    # all foot angles at 2.5 deg instead: quiet-stance muscles 7.2 % F0 (two realisations
    # 10.5-10.8); the real drop jump's foot fit 4.2 -> 2.2 deg RMS
    free_foot_angle_sd_deg: float = 2.5
    share_free: bool = False           # differentiate the load shares (else held, IRLS)
    # the ground wrench's smoothness: a penalty on its second derivative set so that, with the
    # force-plate noise, it acts as a low-pass of this cut-off (a smoothing spline), lowered
    # to wrench_max_cutoff_fraction x the plate's Nyquist frequency. A smoothing spline is
    # not a Butterworth filter (no pole at the cut-off, nothing undefined at Nyquist), so the
    # batch filters' 0.4 is not its limit: at 0.4 (20 Hz on a 100 Hz plate) the estimate
    # rounded the real drop jump's landing impacts (1.52 BW measured, 1.02 estimated). The
    # real drop jump (`nmt track bags/real_dropjump`), 0.4 -> 0.8 (20 -> 40 Hz): vertical /
    # fore-aft force 10.5 / 10.8 -> 4.2 / 3.4 % BW RMS over contact, moment 22 -> 22 N m,
    # angles 2.2 / 2.0 / 4.0 / 1.6 -> 2.2 / 2.7 / 4.0 / 1.6 deg RMS, no loss of control;
    # its marker (TRC) route 13.3 / 11.5 -> 9.0 / 5.8 % BW, moment 49 -> 33 N m, angles
    # equal or better (its one loss of control in the deep landing at both); with 2 % BW of
    # extra plate noise (6 seeds) losses of control 3 -> 1, vertical force 9.4-15.7 ->
    # 3.8-3.9 % BW. (Before the ground support, contact_support_sd_m, 40 Hz had lost
    # control four times on that recording.) 40 -> 70 Hz (plates of 175 Hz and faster;
    # slower ones keep 0.8 x Nyquist, the real drop jump's 100 Hz plate 40 Hz): even on
    # noise- and bias-free observations of the routine the 40 Hz prior rounded the landing
    # impacts (seed 1, landing torques 9.8 / 7.8 / 8.7 % of peak; 100 Hz 4.1 / 5.8 / 9.0).
    # Realisations 1-16 of bags/routine (bench/bench_estimator_seeds.py, 2026-12-05),
    # 40 / 70 / 100 Hz: refined torques 3.0 / 2.1 / 3.8, 2.7 / 2.0 / 3.9, 2.5 / 1.9 / 4.0 %
    # of peak, landing 11.4 / 8.0 / 10.1, 8.4 / 7.5 / 9.6, 7.2 / 6.5 / 8.9, the estimator's
    # muscle forces 8.1 / 6.1 / 4.2 % F0, jump heights 7.3 / 7.4 / 7.0 % off; CPU
    # (bench/bench_estimator.py --duration 60 --lags 0.05) 0.14 / 0.18 / 0.30 s per s of
    # data: above 40 Hz the newest wrench rows stay poorly explained after the step more
    # often, so the rescue's checked iterations run at more updates (at 100 Hz at most),
    # which converges the window, at a CPU the 2x live graph cannot spare (`nmt demo --rate
    # 2`, refined torques p99 from 1 s on 85 / 150 / 245 ms). 70 Hz: the landings most of the
    # way, the hip unchanged, CPU within a quarter of a core; `nmt track --wrench-cutoff 100`
    # where CPU is no limit. The real drop jump resampled to 1000 Hz plates at 100 Hz: in-band
    # r vs OpenSim's 15 Hz ID 0.99 / 0.94 / 0.93 -> 0.98 / 0.95 / 0.94, Fy 2.7 -> 1.9 % BW RMS;
    # at 70 Hz r 0.99 / 0.95 / 0.93, Fy 1.9 % BW, but the shank 1.7 -> 2.1 deg RMS off its IK
    wrench_cutoff_hz: float = 70.0
    wrench_max_cutoff_fraction: float = 0.8
    # around a landing (the plate's vertical force rising through landing_load_bw, below it
    # for 3 ms before and above it for 3 ms after; window.SlidingWindow.landings), within
    # landing_span_s, the SDs of the wrench's 2nd-derivative prior and of the excitations'
    # rate prior are multiplied by these (1: off). An impact is the one place where the
    # ground force and the muscles change within a knot interval; elsewhere the priors keep
    # their smoothing. Noise- and bias-free observations of the routine (seed 1) still gave
    # landing torques of 8-10 % of peak with the priors as everywhere else (see
    # wrench_cutoff_hz). Realisations 1-24 of bags/routine (bench/bench_estimator_seeds.py
    # --json, 2026-12-05), off / 3 and 3: landing torques 9.1 / 8.2 / 10.5 -> 7.2 / 7.1 /
    # 8.7 % of peak (low latency 10.1 / 11.8 / 17.2 -> 8.5 / 9.7 / 15.9), all phases
    # 2.7 / 2.1 / 4.0 -> 2.6 / 2.0 / 3.8, flight 3.1 / 5.6 / 10.1 -> 3.0 / 5.5 / 10.2, the
    # estimator's muscles 6.2 -> 6.3 % F0, jump heights 7.5 -> 7.7 % off, re-initialisations
    # 6 -> 7 in 24 minutes. Also at take-offs (the force falling through the threshold),
    # realisations 1-24: landings 7.1 / 6.6 / 8.4, re-initialisations 6, but a loss of
    # control 90 ms into a flight of the shipped bag (none with landings only). Variants
    # tried at landings and take-offs: the excitation rate alone at 3 (realisations 1-8)
    # landings 7.0 / 6.2 / 7.8 but flight hip 11.7; the wrench alone at 3 (1-4) no gain;
    # both at 2 or 5, or a 10 / 40 ms span, less gain (1-8)
    landing_load_bw: float = 0.1
    landing_span_s: float = 0.02
    landing_wrench_sd_scale: float = 3.0
    landing_rate_sd_scale: float = 3.0
    # the excitations' rate prior tightened in still stance: its SD times still_rate_sd_scale
    # in segments whose plate readings (segment means, ~9 samples) stay within still_band_bw
    # (Fx, Fy [BW], Mz [BW m]; ~5 noise SDs of a mean) of each other over still_span_s
    # around them (the past only at the window's open end), loaded
    # (window.SlidingWindow.still_segments). The plate reads the body's momentum change, so
    # a still plate is a still body. Why: quiet stance's hip error (3.2 % of peak, the
    # truth varying by 1 N m) was the mocap noise passed into the activations at 5-10 Hz
    # (realisation 1, 28-40 s: hip error SD 7.6 N m, 48 % of it at 5-10 Hz; 1.0 N m without
    # the angle noise; the estimated activations with the true motion give it all, the
    # estimated motion with the true activations 0.5 N m). A tighter rate prior everywhere
    # costs the movements (w_du 40: quiet hip 2.8 but landings 8.3 / 8.3 / 9.5 % of peak,
    # realisations 1-4); looser HAT / thigh angle SDs cost the flights (hip 12-14). Judged
    # 99 % of the truth's quiet instants and 17 % of its 'moving' ones (slow stretches),
    # no flight or landing instant (realisation 1). Realisations 1-16 of bags/routine
    # (bench/bench_estimator_seeds.py, 2026-12-06), off -> 0.2: refined torques 2.64 /
    # 1.99 / 3.77 -> 2.67 / 1.85 / 3.09 % of peak (quiet 1.80 / 1.39 / 3.15 -> 1.75 / 1.28
    # / 2.05, moving 4.67 / 2.22 / 3.96 -> 4.84 / 2.21 / 3.87, flight 3.03 / 5.44 / 9.85 ->
    # 3.18 / 5.19 / 10.13, landing 6.86 / 6.76 / 7.91 -> 6.64 / 6.05 / 7.70), low-latency
    # hip 5.96 -> 4.54, re-initialisations 5 -> 1, jump heights 7.9 -> 6.8 % off; but the
    # estimator's own muscle forces 6.2 -> 9.2 % F0 (quiet 4.2 -> 8.1: the co-contraction
    # settles more slowly; not published, Stage 2's forces come from the torques). At 0.3:
    # hip 3.22, 5 re-initialisations, jumps 8.1 %; at 0.1 (1-4): flight hip 11.7. A band of
    # 0.02 BW or a 0.1 s span: ankle over movements worse (1-4)
    still_band_bw: tuple[float, float, float] = (0.03, 0.03, 0.006)
    still_span_s: float = 0.05
    still_rate_sd_scale: float = 0.2
    # the arrival state's translation (where the body is) diffuses in the air: each time
    # airborne segments are marginalised it is made uncertain by this x sqrt(their span)
    # [m / sqrt(s)] (0: never; window.SlidingWindow.drop_before), so the same per second
    # at any update rate (until 2026-12-06 it was an SD per update: 0.05 m, 0.32 m/sqrt(s)
    # at 40 Hz, 0.55 at 120). At 0.32 a flight lost its height: the take-off's height was
    # gone after a few updates and the window's 0.1 s of ballistic arc alone placed the
    # body; bags/routine's 41.1 s flight ended with the ankle 7 cm low, the landing's
    # contact rows then turned the foot 40-70 deg and the window lost control (41.4 s,
    # again at 50.9 s). The shipped jumper's flight is its model's ballistics from a
    # take-off the window saw, so its height is known: 0. 0.32 -> 0: the ankle's height over
    # the 17.0 s flight 60.6 -> 14.0 mm RMS off (tests); realisations 1-16
    # (bench/bench_estimator_seeds.py): refined torques in flight 3.18 / 5.19 / 10.13 ->
    # 2.98 / 5.16 / 9.79 % of peak, landing 6.64 / 6.05 / 7.70 -> 6.47 / 6.00 / 7.60, all
    # 2.67 / 1.85 / 3.09 -> 2.63 / 1.85 / 3.05, re-initialisations 1 -> 2; the shipped
    # realisation 2 -> 0. A lab subject keeps 0.32 (airborne_translation_diffusion_for).
    # One value for both, 0.063 (0.01 m per update), was measured and not kept: the real
    # drop jump as at 0.32, but realisations 1-16 landing knee / hip 6.00 / 7.60 -> 6.82 /
    # 8.32 (realisation 5's 50.8 s landing 42-55 % of peak off for 0.2 s)
    airborne_translation_diffusion_m_sqrt_s: float = 0.0
    # the excitations' prior (the process noise of a muscle-driven estimator): with w_du
    # 0.1 the HAT followed the mocap noise (+-0.5 deg at 3-5 Hz, hip torque +-40 N m in
    # quiet stance); w_du 10 and w_u 50 gave the best torques on the routine (quiet stance
    # hip 8 -> 4 % of peak, low-latency hip 17 -> 5 %)
    excitation_weight: float = 50.0    # w_u: cost w_u int |u|^2 dt [1/s]
    excitation_rate_weight: float = 10.0  # w_du: cost w_du int |du/dt|^2 dt [s]; for a
                                       # lab subject LAB_EXCITATION_RATE_WEIGHT
                                       # (excitation_rate_weight_for)
    bound_weight: float = 1e4          # penalty on excitations outside [0, 1] (per unit^2 s)
    # the force plate's error model (offsets b [N, N, N m], COP offset d [m]): its prior SD at
    # a start and its drift (random walk) per sqrt(s). The moment offset and the COP offset
    # read alike in stance (Fy ~ body weight): the offset drifts slowly (flights pin it), the
    # COP offset carries what scales with the load
    # COP offset prior 5 mm: at 20 mm the estimator explained a push-off's heel rise away
    # as a 66 mm COP offset (foot kept flat, 19 deg off; ankle torque 45 vs 160 N m)
    plate_sd: tuple[float, ...] = (20.0, 20.0, 2.0, 0.005)
    plate_drift_sd: tuple[float, ...] = (2.0, 2.0, 0.05, 0.005)
    # time constants [s] of a decay toward zero (first-order Gauss-Markov; 0: a random walk).
    # The COP offset is unobservable in stance (it reads like the moment), so as a random walk
    # its prior SD grew to ~3 cm over 40 s of standing and a push-off moved it by 2.5-4.9 cm,
    # where it stayed for the next 10-20 s (the estimated moment 14-30 N m off). At 2 s its
    # stationary SD is 5 mm. Measured (bench/bench_estimator_seeds.py, seeds 1-6, 60 s):
    # torques all phases 5.6 / 3.3 / 5.0 -> 4.2 / 2.7 / 4.8 % of peak (quiet stance
    # 4.2 / 2.5 / 3.6 -> 2.3 / 1.5 / 3.1), re-initialisations 19.2 -> 17.5 a minute, muscles
    # 8.1 -> 7.8 % F0 (flight 11.1 -> 13.3); at 1 s about the same (ankle 4.4)
    plate_reversion_s: tuple[float, ...] = (0.0, 0.0, 0.0, 2.0)
    # process noise on the arrival state (the control points the prior covers), per sqrt(s):
    # angles [deg], positions [m], activations, wrench [N] (None: off). It keeps the prior
    # from growing overconfident in what the window's own data can tell
    arrival_noise_sd: tuple[float, float, float, float] | None = (0.2, 0.0005, 0.01, 10.0)
    # --- numerics
    iterations: int = 1                # Gauss-Newton iterations per update (at most)
    check_steps: bool = False          # evaluate each step and keep it only if the cost fell
                                       # (one more kernel call per iteration)
    # an update whose newest data are poorly predicted (mean normalised residual^2 per row
    # above rescue_cost_per_row where the update linearised them, before its step: a
    # movement, a landing, a take-off) gets this many more Levenberg-Marquardt iterations on
    # the whole window, each step checked. Measured on bags/routine: restarts 10 -> 7 (0-20
    # s) and 17 -> 12 (20-60 s), landing torques 14.0 / 10.6 / 13.9 -> 11.2 / 7.0 / 8.6 % of
    # peak, update p99 129 -> 54 ms (fewer cold starts). Threshold 10 -> 5 (2026-12-06;
    # bench/bench_estimator_seeds.py, realisations 1-16): refined torques 2.63 / 1.85 / 3.05
    # -> 2.42 / 1.78 / 2.95 % of peak, moving 4.76 / 2.20 / 3.85 -> 4.18 / 1.95 / 3.59,
    # flight 2.98 / 5.16 / 9.79 -> 2.78 / 4.97 / 8.91, landing 6.47 / 6.00 / 7.60 -> 6.33 /
    # 5.93 / 8.12, the estimator's own muscle forces 9.2 -> 5.7 % F0, jump heights 7.4 ->
    # 6.3 % off, re-initialisations 2 -> 3; 13 -> 41 % of the updates rescued on the shipped
    # routine, CPU ~1.3x. At 3 (1-8): 4 re-initialisations, flight and landing worse. Judged
    # after the step instead (one more kernel call on the newest rows, kept; about 1 % of
    # the updates rescued): landing 5.94 / 5.54 / 7.93 -> 9.5 / 13.0 / 16.1 (1-8): the single step
    # fits the newest rows but leaves the window unconverged, which the iterations fix
    rescue_iterations: int = 3
    rescue_cost_per_row: float = 5.0
    # the rescue's iterations (at most rescue_iterations) where the plate says the body is
    # still over the newest relinearise_s (window.SlidingWindow.still_segments). In still
    # stance the rescues are the force plate's noise (their newest wrench rows ~9 per
    # row, angle rows ~1; 19 % of still updates rescued, 25 % of the others; routine
    # 0-20 s), and rescues were 46 % of the estimator's CPU. One iteration there instead
    # of three (2026-12-07, bench/bench_estimator_seeds.py, realisations 1-16 and 17-28,
    # each against the same run with 3): refined torques 2.47 / 1.93 / 3.01 -> 2.49 /
    # 1.81 / 2.97 and 2.26 / 1.95 / 3.47 -> 2.27 / 1.95 / 3.47 % of peak, quiet stance
    # 1.73 / 1.27 / 2.09 -> 1.74 / 1.27 / 2.08 and 1.66 / 1.26 / 2.07 -> the same,
    # landings 6.63 / 7.40 / 8.73 -> 6.70 / 6.34 / 8.45 and 7.54 / 7.72 / 12.60 -> 7.65 /
    # 7.66 / 12.76, jump heights 6.36 -> 6.34 and 7.52 -> 7.96 % off, re-initialisations
    # 3 -> 4 and 5 -> 6 (in 28 minutes: flips of single events, which 0.05 ms of stamp
    # noise also makes); CPU 0.57-0.59 -> 0.47-0.50 s per s of data (bench/
    # bench_estimator.py --duration 60 --lags 0.05, runs alternated). None at all in still
    # stance (0): quiet hip 2.09 -> 2.18, flight hip 8.97 -> 9.33, 5 re-initialisations
    # (1-16)
    still_rescue_iterations: int = 1
    # new control points at each update continue the angles and the ankle's position at this
    # fraction of the curve's velocity at the window's end (window.SlidingWindow.extend):
    # 16 realisations of bags/routine, re-initialisations a minute 1.25 at 1.0, 0.19 at
    # 0.75, 0.50 at 0.5 (the estimator's muscle forces 7.6 / 7.8 / 8.6 % F0)
    extrapolation_velocity: float = 0.75
    # an update whose (unchecked) step leaves the physical envelope or yields estimates that
    # cannot be published is taken back and replaced by the rescue's checked iterations from
    # where it began, before the window is given up (MovingHorizonEstimator._undo_step).
    # 16 realisations of bags/routine: re-initialisations 3 -> 1 in 16 minutes, the
    # accuracy unchanged; the shipped bag's two in-flight losses of control gone
    undo_broken_steps: bool = True
    relinearise_s: float = 0.03        # the newest data span re-linearised at every update
    relinearise_older: int = 2         # older segments re-linearised per update, in turn
    damping: float = 1e-3              # Levenberg-Marquardt, relative to diag(H)
    start_window_s: float = 0.1        # data in the first (cold) window: long enough to
                                       # tell the rates (a 25 ms start, three mocap samples,
                                       # leaves the shank's rate uncertain by ~250 deg/s, and
                                       # a wrong rate is corrected only as fast as the
                                       # muscles' activation dynamics allow)
    start_iterations: int = 20         # (40: the same accuracy on the routine; a start
                                       # blocks a live node, so it is kept short)
    start_dynamics_sd: tuple[float, ...] = (10.0, 3.0, 1.0, 0.3)  # continuation [m/s^2]
    # a stream that begins in the air: its first update waits up to airborne_start_wait_s
    # of data for the first landing and airborne_landing_s of it, and its window spans the
    # whole fall (MovingHorizonEstimator._awaiting_landing; 0: no wait). Sixteen
    # realisations of bags/routine, which begins with a 0.24 s drop (python
    # bench/bench_estimator_seeds.py --seeds 1,...,16 --duration 1.2): re-initialisations
    # in the first 1.2 s 21 -> 8 (14 in the drop and its landing -> none before 0.75 s), refined
    # torques in flight 3.0 / 12.7 / 27.8 -> 3.4 / 9.6 / 18.2 % of peak, landing 14.3 /
    # 13.4 / 23.8 -> 13.6 / 11.2 / 19.2; over the whole minute (--duration 60) 2.56 -> 2.25
    # a minute, flight 3.2 / 7.1 / 15.2 -> 3.4 / 6.1 / 12.1, jump heights 8.9 -> 8.0 % off
    airborne_start_wait_s: float = 0.35
    airborne_landing_s: float = 0.025
    # --- health (loss of control)
    slow_backlog_s: float = 0.0        # data waiting this long: update every other
                                       # period until caught up (live only; 0 = never). Off
                                       # by default: the live estimates then equal the
                                       # offline ones whatever the timing (the 60 s demo:
                                       # live vs batch 0.00 % of peak, also beside a CPU hog;
                                       # at 0.15 s, 2-7 %), for a p99 latency of 0.87 s
                                       # instead of 0.72 s on an idle machine
    max_backlog_s: float = 5.0         # data waiting this long: skip to the newest (live
                                       # only: a consumer that cannot keep up on average;
                                       # 0 = never). Bursts (re-initialisations at take-offs
                                       # and landings) left the node up to 2.1 s behind
                                       # beside a CPU hog; at 0.5 s the 60 s demo skipped at
                                       # three take-offs (0.5-0.7 s of refined torques lost
                                       # each, and Stage 2 restarted on the gap)
    max_cost_per_row: float = 25.0     # mean normalised residual^2 of the newest data
    recover_after_s: float = 0.05      # that long above the limit -> re-initialise
    flight_force_bw: float = 0.05      # estimated vertical force below this: airborne
    # the physical envelope of a healthy estimate (outside it: loss of control at once)
    max_angle_error_deg: float = 45.0  # a segment angle this far from its 3 newest samples
    # an emitted span's segment angle this far from all of its mocap samples (at least two)
    # is not published: the window's lagged part left the observations. The real drop
    # jump's spans: at most 10.8 deg (100 Hz, IK), 9.6 (100 Hz, markers), 20.1 (resampled
    # to 200 Hz), whose touchdown published a shank 45-64 deg off for 25 ms before this
    max_span_angle_error_deg: float = 30.0
    # a window that would lose control with its foot alone off the mocap (its angle at least
    # reseed_foot_deg from a sample of the window, every other segment within that) first
    # has its foot angle refit to the window's mocap samples and reseed_iterations checked
    # iterations on the whole window (MovingHorizonEstimator._reseed_foot; 0: off). The
    # push-off's heel rise is bistable: a heel the window holds down with a share of the load
    # stays held while the mocap's foot rotates on (the looped routine's 86.7 s push-off: the
    # foot 15-32 deg off for 0.1 s, three checked iterations at every update, then a loss of
    # control). Realisations 1-16 and 17-28 of bags/routine (bench/bench_estimator_seeds.py,
    # against the same seeds without it, 2026-12-07): losses of control 4 -> 3 and 6 -> 5
    # (the 41.08 s take-offs of realisations 8 and 17 kept), refined torques 2.49 / 1.81 /
    # 2.97 -> 2.49 / 1.82 / 2.97 and 2.27 / 1.95 / 3.47 (unchanged) % of peak, landings
    # 6.70 / 6.34 / 8.45 -> 6.69 / 6.34 / 8.44, jump heights 6.34 -> 6.40 % off.
    # Refitting every segment that was off instead (landings too): 4 -> 4, one landing
    # floated and another kept losing control (a landing's window is lost as a whole)
    reseed_foot_deg: float = 15.0
    reseed_iterations: int = 20         # at most (they stop once the cost settles)
    max_rate_rad_s: float = 150.0      # segment rates
    max_force_bw: float = 15.0         # ground force magnitude
    max_translation_m: float = 3.0     # the ankle from the origin
    # the ankle higher than any contact point can hold it (the foot rotated about its farthest
    # point: 0.09 m above standing for the jumper; the routine's truth reaches 0.07) by this
    # margin [m] while the ground carries more than contact_full_load_bw: the contact's
    # release (contact_release_sd) lets go of points the motion lifts, and the ground wrench
    # is a free variable, so a window once settled with the body floating 0.9 m up while the
    # plate read its weight (dynamics, angles and plate all fitted), for 3.5 s of stance.
    # The real drop jump floats in its deep landing (2.3 BW, the ankle 0.23 m up): at a
    # 0.03 m margin it re-initialised four times there, each new window floating again
    # within 75 ms (foot fit 4.2 -> 8.1 deg RMS); at 0.1 twice
    loaded_lift_margin_m: float = 0.1
    max_torque_nm: float = 2000.0      # a published joint torque (the paper tracker's limit)
    max_muscle_force_f0: float = 3.0   # a published musculotendon force, in units of F0

    def with_(self, **kw: object) -> MovingHorizonSettings:
        return replace(self, **kw)

    @classmethod
    def overrides(cls, items: Sequence[str]) -> dict[str, object]:
        """``KEY=VALUE`` strings (a field name, a Python literal: the benchmarks' ``--set``)
        as keyword arguments for ``with_``; an unknown field or a value that is not a
        literal is a ValueError naming it."""
        names = {f.name for f in fields(cls)}
        out: dict[str, object] = {}
        for item in items:
            key, sep, value = item.partition('=')
            if not sep or key not in names:
                raise ValueError(f'{item!r}: not KEY=VALUE with KEY a MovingHorizonSettings '
                                 'field')
            try:
                out[key] = ast.literal_eval(value)
            except (ValueError, SyntaxError) as exc:
                raise ValueError(f'{item!r}: the value is not a Python literal') from exc
        return out

    def angle_sd(self) -> np.ndarray:
        """[4] rad."""
        return np.radians(np.asarray(self.angle_sd_deg, dtype=float))

    def wrench_sd(self, body_weight: float) -> np.ndarray:
        """[3] N, N, N m."""
        f = self.force_sd_bw * body_weight
        return np.array([f, f, f * self.moment_lever_m])

    def wrench_cutoff(self) -> tuple[float, str | None]:
        """The wrench prior's cut-off [Hz] at ``wrench_rate_hz``: ``wrench_cutoff_hz``, at
        most ``wrench_max_cutoff_fraction`` x the Nyquist frequency; and a note saying what
        was lowered (None if nothing)."""
        return cutoff_for_rate(self.wrench_cutoff_hz, self.wrench_rate_hz,
                               self.wrench_max_cutoff_fraction, what='wrench cut-off')

    def landing_relax(self) -> np.ndarray:
        """SD multipliers [2] of the priors near a landing (wrench 2nd derivative,
        excitation rate). The wrench's is at most what takes its cut-off (which grows as the
        square root of the SD) to ``wrench_max_cutoff_fraction`` x Nyquist: none on a plate
        whose cut-off is already there (a 100 Hz plate's 40 Hz)."""
        cutoff, _ = self.wrench_cutoff()
        room = (self.wrench_max_cutoff_fraction * self.wrench_rate_hz / 2 / cutoff) ** 2
        return np.array([min(self.landing_wrench_sd_scale, max(room, 1.0)),
                         self.landing_rate_sd_scale])

    def wrench_accel_sd(self, body_weight: float) -> np.ndarray:
        """Prior SD [3] of the wrench's 2nd derivative (N/s^2 per sqrt(s)): the smoothing
        spline whose cut-off is ``wrench_cutoff()`` for samples at ``wrench_rate_hz`` of the
        wrench noise: lambda = f_s / (sigma^2 (2 pi f_c)^4), sd = 1 / sqrt(lambda)."""
        cutoff, _ = self.wrench_cutoff()
        omega = 2 * np.pi * cutoff
        return self.wrench_sd(body_weight) * omega ** 2 / np.sqrt(self.wrench_rate_hz)

    def validate(self) -> None:
        if self.window_s < self.lag_s + 1.0 / self.update_rate_hz:
            raise ValueError(f'window_s ({self.window_s} s) must exceed lag_s + one update '
                             f'({self.lag_s + 1.0 / self.update_rate_hz:.4f} s)')
        if self.knot_rate_hz < self.update_rate_hz:
            raise ValueError('knot_rate_hz must be at least update_rate_hz')
        if not (np.isfinite(self.wrench_cutoff_hz) and self.wrench_cutoff_hz > 0):
            raise ValueError(f'the wrench cut-off {self.wrench_cutoff_hz} Hz must be positive')
        for name in ('airborne_start_wait_s', 'airborne_landing_s'):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f'{name} ({getattr(self, name)} s) must be 0 or more')
        if self.joint_torques not in ('muscle', 'net'):
            raise ValueError(f"joint_torques {self.joint_torques!r} must be 'muscle' or 'net'")
        if not 0 <= self.extrapolation_velocity <= 1:
            raise ValueError(f'extrapolation_velocity {self.extrapolation_velocity} must be '
                             'in [0, 1]')
        for name in ('landing_wrench_sd_scale', 'landing_rate_sd_scale',
                     'still_rate_sd_scale'):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f'{name} ({getattr(self, name)}) must be positive')
        for name in ('still_span_s', 'airborne_translation_diffusion_m_sqrt_s'):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f'{name} ({getattr(self, name)}) must be 0 or more')
        if len(self.still_band_bw) != 3 or not all(b > 0 for b in self.still_band_bw):
            raise ValueError(f'still_band_bw {self.still_band_bw} must be three positive '
                             'numbers (inf: off)')
        if not (np.isfinite(self.landing_span_s) and self.landing_span_s >= 0):
            raise ValueError(f'landing_span_s ({self.landing_span_s} s) must be 0 or more')
        if not (np.isfinite(self.angle_latency_s) and 0 <= self.angle_latency_s <= 1):
            raise ValueError(f'angle_latency_s ({self.angle_latency_s} s) must be in [0, 1]')
        for name in ('rescue_iterations', 'still_rescue_iterations'):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 0):
                raise ValueError(f'{name} ({getattr(self, name)!r}) must be a whole number, '
                                 '0 or more')
        if not 0 <= self.frame_clock_alpha <= 1:
            raise ValueError(f'frame_clock_alpha {self.frame_clock_alpha} must be in [0, 1]')
        if not (np.isfinite(self.saturation_min_bw) and self.saturation_min_bw >= 0):
            raise ValueError(f'saturation_min_bw ({self.saturation_min_bw}) must be 0 or more')
        if not 0 < self.wrench_max_cutoff_fraction < 1:
            raise ValueError(f'wrench_max_cutoff_fraction {self.wrench_max_cutoff_fraction} '
                             'must be in (0, 1)')


#: w_du for a lab recording's subject. The excitations' rate prior is their process noise:
#: 10 suits the shipped jumper, whose excitations come from a smooth optimal controller, and
#: holds a real person's back where they change within tens of ms. The real drop jump's
#: take-off: with 10 the knee's extensors stayed on into the flight (knee hyperextended
#: against its passive limit, shank 4.0 deg RMS off over the flight). Measured with `nmt
#: track` on four versions of the real drop jump (the shipped import, weighed by its plates
#: at 94.47 kg; the same at 94.5 kg given; IK/GRF resampled to 200/1000 Hz; the marker
#: import), w_du 10 / 2 / 1.5 / 1: worst segment angle 2.6 / 2.0 / 2.3 / 3.0 deg RMS;
#: the flight after the take-off flips between following the IK and a 5 deg knee
#: hyperextension with such small changes (94.47 vs 94.5 kg: shank 2.5 vs 1.3 deg at w_du
#: 1), so the choice is by the worst case. At 2, torques against OpenSim's 15 Hz ID in its
#: band r 0.98 / 0.94 / 0.92, RMS 8 / 10 / 14 % of peak (the shipped bag; 94.5 kg: hip r
#: 0.88, RMS 18 %). On the jumper's routine 2 is worse (seeds 1-4: torques 3.4 / 2.2 / 3.9
#: -> 3.7 / 2.2 / 4.4 % of peak, jump heights 5.8 -> 8.4 % off), so 10 stays its default.
LAB_EXCITATION_RATE_WEIGHT = 2.0


def excitation_rate_weight_for(choice: float, lab_subject: bool) -> float:
    """``MovingHorizonSettings.excitation_rate_weight`` for a choice (> 0: that weight; 0:
    'auto', the default of ``nmt track`` and the skeletal tracker node):
    :data:`LAB_EXCITATION_RATE_WEIGHT` for a lab recording's subject model (a
    subject.yaml), the settings' default for the shipped jumper."""
    if not choice >= 0:
        raise ValueError(f'excitation rate weight {choice} must be > 0 (or 0: auto)')
    if choice > 0:
        return float(choice)
    return (LAB_EXCITATION_RATE_WEIGHT if lab_subject
            else MovingHorizonSettings.excitation_rate_weight)


def landing_rate_sd_scale_for(lab_subject: bool) -> float:
    """``MovingHorizonSettings.landing_rate_sd_scale`` for the subject: the settings'
    default for the shipped jumper; 1 (none) for a lab recording's subject, whose excitation
    rate prior (:data:`LAB_EXCITATION_RATE_WEIGHT`) is already loose everywhere. The real
    drop jump (`nmt track bags/real_dropjump`, 2026-12-05), relaxed at its landings by
    3 / 1.35 / 1: segment angles 3.3 / 2.9 / 2.6 / 0.9, 2.0 / 1.8 / 1.9 / 0.8 and
    1.8 / 1.9 / 1.8 / 0.8 deg RMS, moment 24 / 7 / 8 N m, in-band correlation with OpenSim's
    inverse dynamics 0.97 / 0.92 / 0.91, 0.99 / 0.91 / 0.91 and 0.98 / 0.94 / 0.92."""
    return 1.0 if lab_subject else MovingHorizonSettings.landing_rate_sd_scale


def joint_torques_for(choice: str, lab_subject: bool) -> str:
    """``MovingHorizonSettings.joint_torques`` for a choice 'muscle', 'net' or 'auto' (the
    default of ``nmt track`` and the skeletal tracker node): 'auto' is 'net' for a lab
    recording's subject model (a subject.yaml) and 'muscle' for the shipped jumper."""
    if choice not in ('auto', 'muscle', 'net'):
        raise ValueError(f"joint torques {choice!r} must be 'auto', 'muscle' or 'net'")
    if choice != 'auto':
        return choice
    return 'net' if lab_subject else 'muscle'


#: ``MovingHorizonSettings.airborne_translation_diffusion_m_sqrt_s`` for a lab recording's
#: subject [m / sqrt(s)]. The shipped jumper's flights are the model's own ballistics, so a
#: tracked take-off fixes the height (0). A real subject's model is scaled from mass and
#: height: its flight's arc from the take-off is not exact, and the real drop jump (`nmt
#: track bags/real_dropjump`, 2026-12-06) lost control in its second landing at 2.44 s with
#: 0 (a segment angle 35 deg from the mocap), none with 0.032-0.32; 0.32 (0.05 m per 25 ms
#: update) was everyone's value until then.
LAB_AIRBORNE_TRANSLATION_DIFFUSION_M_SQRT_S = 0.32


def airborne_translation_diffusion_for(lab_subject: bool) -> float:
    """``MovingHorizonSettings.airborne_translation_diffusion_m_sqrt_s`` for the subject:
    :data:`LAB_AIRBORNE_TRANSLATION_DIFFUSION_M_SQRT_S` for a lab recording's subject, the
    settings' default for the shipped jumper."""
    return (LAB_AIRBORNE_TRANSLATION_DIFFUSION_M_SQRT_S if lab_subject
            else MovingHorizonSettings.airborne_translation_diffusion_m_sqrt_s)
