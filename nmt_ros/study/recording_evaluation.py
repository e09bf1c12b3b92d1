"""Offline evaluation of a recording of the live graph: what it did, read back from the bag
(``nmt demo``, bench, tests; no ROS graph needed).

From a bag recorded by the ``recorder`` node while the graph processed a trial:

- counts: per topic, messages published (the producers' final ``/nmt/status`` records, the
  observation publisher's for the observations) against messages recorded;
- latency: for each estimate message, the time the recorder received it minus the time it
  received the force-plate sample with the same header stamp (the bag's log times, one
  clock): the delay from an observation's arrival to the estimate for that instant,
  look-ahead and windows included (``latency_ms(..., clock='publish')``: the publishers'
  source timestamps instead);
- CPU: each node's share of one core while active (its status ``cpu_share``);
- accuracy against the truth topics of the source bag over the replayed span (contact:
  the truth's feet carry weight; phase by phase), the jump
  height of the tracked motion, and the agreement with the batch trackers run on the same
  observations with the graph's settings (Stage 1 ``track_stage1``; Stage 2 windowed with the same
  window and stride, fed the batch Stage-1 output).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from msg_adapters.cdr_header import header_stamps_ns
from nmt_ros import topics
from nmt_ros.io.bags import bag_info, read_arrays, read_bag, read_raw
from nmt_ros.model.parameters import JOINTS, MUSCLES, Q_NAMES

if TYPE_CHECKING:
    from nmt_ros.records import Truth
    from nmt_ros.tracking.moving_horizon.settings import MovingHorizonSettings

DATA_TOPICS = topics.OBSERVATIONS + topics.SKELETAL_OUTPUTS + topics.MUSCLE_OUTPUTS
NODES = ('observation_publisher', 'skeletal_tracker', 'muscle_tracker', 'recorder')


@dataclass(frozen=True)
class TopicTimes:
    """Header stamps, publish (source) times and log (receive) times of one topic [ns]."""

    stamp_ns: np.ndarray
    publish_ns: np.ndarray
    log_ns: np.ndarray


def topic_times(bag: str | os.PathLike, topic: str) -> TopicTimes:
    blobs, pub, log = [], [], []
    for raw in read_raw(bag, [topic]):
        blobs.append(raw.data)
        pub.append(raw.publish_time_ns)
        log.append(raw.log_time_ns)
    return TopicTimes(header_stamps_ns(blobs), np.asarray(pub, dtype=np.int64),
                      np.asarray(log, dtype=np.int64))


def delays_ms(estimate: TopicTimes, observation: TopicTimes,
              clock: str = 'receive') -> tuple[np.ndarray, np.ndarray]:
    """(stamps [ns], delays [ms]) of the estimates that have an observation with the same
    stamp: between the recorder's receive times of the two (``clock`` 'receive', one clock,
    what a consumer of both topics sees) or their publishers' source times ('publish')."""
    if clock not in ('receive', 'publish'):
        raise ValueError(f"clock must be 'receive' or 'publish', got {clock!r}")
    field = 'log_ns' if clock == 'receive' else 'publish_ns'
    order = np.argsort(observation.stamp_ns, kind='stable')
    obs_stamps = observation.stamp_ns[order]
    if obs_stamps.size == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    idx = np.clip(np.searchsorted(obs_stamps, estimate.stamp_ns), 0, obs_stamps.size - 1)
    ok = obs_stamps[idx] == estimate.stamp_ns
    delay = (getattr(estimate, field)[ok] - getattr(observation, field)[order][idx[ok]]) / 1e6
    return estimate.stamp_ns[ok], delay


def latency_ms(estimate: TopicTimes, observation: TopicTimes,
               clock: str = 'receive', after_s: float = 0.0) -> dict[str, float]:
    """Delay [ms] of the estimates after the observations with the same stamps (``delays_ms``):
    n, p50, p99, max, min; ``after_s`` > 0: of the instants at least that long after the
    first observation [s] only (the start-up left out, as the estimator issue's coverage
    rule counts from the first second)."""
    stamps, delay = delays_ms(estimate, observation, clock)
    if after_s > 0 and observation.stamp_ns.size:
        delay = delay[stamps >= observation.stamp_ns.min() + round(after_s * 1e9)]
    return _percentiles(delay)


def _percentiles(delay: np.ndarray) -> dict[str, float]:
    if delay.size == 0:
        return {'n': 0, 'p50_ms': math.nan, 'p99_ms': math.nan, 'max_ms': math.nan,
                'min_ms': math.nan}
    return {'n': int(delay.size), 'p50_ms': float(np.percentile(delay, 50)),
            'p99_ms': float(np.percentile(delay, 99)), 'max_ms': float(delay.max()),
            'min_ms': float(delay.min())}


def latency_by_phase(estimate: TopicTimes, observation: TopicTimes, truth: Truth,
                     epoch_ns: int) -> dict[str, dict[str, float]]:
    """``latency_ms`` per phase of the truth (``study.phase_scores.truth_phases``: quiet
    stance, movement, flight, landing): where in a routine the estimates come late."""
    from nmt_ros.study.phase_scores import PHASES, truth_phases

    stamps, delay = delays_ms(estimate, observation)
    t = (stamps - epoch_ns) * 1e-9
    k = np.clip(np.rint(np.interp(t, truth.t, np.arange(truth.t.size))).astype(int), 0,
                truth.t.size - 1)
    masks = truth_phases(truth)
    return {name: _percentiles(delay[masks[name][k]]) for name in PHASES}


def final_statuses(bag: str | os.PathLike) -> dict[str, dict[str, str]]:
    """Node -> values of its last summary record on /nmt/status (node names without '/')."""
    from msg_adapters.diagnostics import from_diagnostic_array

    out: dict[str, dict[str, str]] = {}
    names = {t.name for t in bag_info(bag).topics}
    if topics.STATUS not in names:
        return out
    for msg in read_bag(bag, [topics.STATUS]):
        _, records = from_diagnostic_array(msg.msg)
        for r in records:
            if ':' not in r.name:
                out[r.name.lstrip('/')] = dict(r.values, message=r.message, level=r.level)
    return out


def _float(values: Mapping[str, Any], key: str, default: float = math.nan) -> float:
    try:
        return float(values[key])
    except (KeyError, TypeError, ValueError):
        return default


def message_counts(recording: str | os.PathLike,
                   statuses: Mapping[str, Mapping[str, str]]) -> dict[str, dict[str, int]]:
    """Topic -> {'published': n (from the producers' status, -1 unknown), 'recorded': n}."""
    recorded = {t.name: t.message_count for t in bag_info(recording).topics}
    published: dict[str, int] = {}
    for node in ('observation_publisher', 'skeletal_tracker', 'muscle_tracker'):
        for key, value in statuses.get(node, {}).items():
            if key.startswith('published.'):
                published[key[len('published.'):]] = int(value)
    return {topic: {'published': published.get(topic, -1), 'recorded': recorded.get(topic, 0)}
            for topic in DATA_TOPICS if topic in recorded or topic in published}


def _rms(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(np.asarray(x) ** 2, axis=0))


def _named(names: tuple[str, ...], values: np.ndarray, digits: int = 4) -> dict[str, float]:
    return {n: round(float(v), digits) for n, v in zip(names, np.ravel(values))}


def _columns(series: Any, names: tuple[str, ...], field: str) -> np.ndarray:
    return np.column_stack([series.column(n, field) for n in names])


def mhe_settings_from_status(values: Mapping[str, Any]) -> MovingHorizonSettings:
    """The skeletal tracker's estimator settings (``MovingHorizonSettings``) from the
    'setting.*' values of its /nmt/status (what the node ran with; defaults where absent):
    the offline estimator then makes the estimates the node published."""
    from nmt_ros.tracking.moving_horizon.settings import MovingHorizonSettings

    d = MovingHorizonSettings()
    # every float setting the node reported (a hand-kept list of them had missed two a
    # lab subject's file sets: the batch reference then ran on the jumper's)
    floats = [f.name for f in fields(d) if isinstance(getattr(d, f.name), float)]
    return d.with_(iterations=int(_float(values, 'setting.iterations', d.iterations)),
                   joint_torques=str(values.get('setting.joint_torques', d.joint_torques)),
                   **{k: _float(values, f'setting.{k}', getattr(d, k)) for k in floats})


def batch_reference(source: str | os.PathLike, settings: Mapping[str, str]) -> dict:
    """Batch Stage 1 and windowed Stage 2 on the source observations, graph settings: the
    bag's subject model (``BAG/subject.yaml``, else the jumper) and, like the skeletal
    tracker, only the samples from its ``start_s`` on."""
    from nmt_ros.io.trial_bag import read_observations
    from nmt_ros.model.subject import load_subject_model
    from nmt_ros.tracking.conditioning import ConditioningSettings, condition
    from nmt_ros.tracking.moving_horizon.estimator import estimate
    from nmt_ros.tracking.skeletal_tracker import SKTSettings
    from nmt_ros.tracking.stage2 import NeuromuscularTracker, load_stage2_settings
    from nmt_ros.tracking.streaming import initial_activations, track_stage1

    sk, mu = settings.get('skeletal_tracker', {}), settings.get('muscle_tracker', {})
    model = load_subject_model(source)
    obs = read_observations(source)
    duration = _float(settings.get('observation_publisher', {}), 'setting.duration_s', 0.0)
    if duration > 0:                 # the replay's part only (the publisher's rule)
        t_end = min(obs.t_angles[0], obs.t_wrench[0]) + duration + 1e-10
        obs = obs.before(t_end)
    start = _float(sk, 'setting.start_s', 0.0)
    if start > 0:                    # the node leaves the samples before start_s out
        obs = obs.after(start)       # (on a time from there: shifted back below)
    cs = ConditioningSettings(angle_cutoff_hz=_float(sk, 'setting.angle_cutoff_hz', 10.0),
                              force_cutoff_hz=_float(sk, 'setting.force_cutoff_hz', 50.0))
    if sk.get('setting.estimator', 'skt') == 'mhe':
        # the same estimator object the node runs, fed the whole recording (offline = live)
        res = estimate(model, obs.t_angles, obs.angles, obs.t_wrench, obs.wrench,
                       mhe_settings_from_status(sk)).refined
    else:
        skt = SKTSettings()
        skt = skt.with_(substeps=int(_float(sk, 'setting.substeps', skt.substeps)),
                        bias_rate=_float(sk, 'setting.bias_rate', skt.bias_rate))
        res = track_stage1(model, condition(obs.t_angles, obs.angles, obs.t_wrench,
                                            obs.wrench, cs),
                           skt, _float(sk, 'setting.wrench_rate_hz', 1080.0))
    out = {'t': res.t + start, 'tau': res.tau, 'status': res.status,
           'epoch_ns': obs.info['epoch_ns']}
    if res.ok:
        th, thd, thdd = (model.batch(model.joint_angles, x)[0] for x in (res.q, res.qd, res.qdd))
        t2, tau2 = res.t, res.tau
        rate = _float(mu, 'setting.input_rate_hz', _float(sk, 'setting.wrench_rate_hz', 1080.0))
        n = int(round((res.t[-1] - res.t[0]) * rate)) + 1
        if n != res.t.size:   # instants Stage 1 withheld: bridged linearly, as the node's gate
            t2 = res.t[0] + np.arange(n) / rate
            tau2, th, thd, thdd = (np.column_stack([np.interp(t2, res.t, x[:, k])
                                                    for k in range(x.shape[1])])
                                   for x in (res.tau, th, thd, thdd))
        a0, _ = initial_activations(model, th[0], tau2[0], thd[0])
        stride = _float(mu, 'setting.window_stride_s', 0.02)
        stage2 = load_stage2_settings(saturation=mu.get('setting.saturation', 'plan'))
        s2 = NeuromuscularTracker(model, stage2).track(
            t2, tau2, th, thd, thdd, a0, mode='windowed',
            window_length=_float(mu, 'setting.window_length_s', 0.03),
            window_stride=stride if stride > 0 else None)
        out.update(f=s2.f, t2=s2.t + start)
    return out


def jump_table(model: Any, truth: Any, t: np.ndarray, q: np.ndarray, qd: np.ndarray,
           liftoffs: np.ndarray) -> dict:
    """Every jump of the truth (its flights of at least 0.1 s) with the tracked motion's
    height from the tracker's lift-off nearest to it (within 0.1 s; none: not tracked)."""
    from nmt_ros.study.metrics import jump_heights, takeoffs

    actual_lo = takeoffs(truth.t, truth.s[:, 1], 1.0)
    actual = jump_heights(model, truth.t, truth.q, truth.qd, actual_lo)
    rows = []
    for lo, h in zip(actual_lo, actual):
        near = liftoffs[np.abs(liftoffs - lo) <= 0.1] if liftoffs.size else liftoffs
        covered = near.size and t.size and t[0] <= near[0] <= t[-1]
        tracked = (float(jump_heights(model, t, q, qd, near[:1])[0]) if covered
                   else math.nan)
        rows.append({'liftoff_s': round(float(lo), 4), 'actual_m': round(float(h), 4),
                     'tracked_m': round(tracked, 4),
                     'error_pct': round(float(100 * (tracked - h) / h), 2)})
    errors = np.array([r['error_pct'] for r in rows], dtype=float)
    ok = np.isfinite(errors)
    return {'jumps': rows, 'tracked': int(ok.sum()),
            'mean_abs_error_pct': round(float(np.abs(errors[ok]).mean()), 2) if ok.any()
            else math.nan}


def _phase_summary(model: Any, truth: Any, recording: Path, epoch: int, t: np.ndarray,
                   tau: np.ndarray, forces: tuple[np.ndarray, np.ndarray] | None,
                   low_topic: str | None) -> dict[str, Any]:
    """Refined (and low-latency) estimates against the truth, phase by phase (muscle forces
    scored at the torques' instants where both were recorded)."""
    from nmt_ros.study.phase_scores import phase_scores

    f = None
    if forces is not None:
        stamps = epoch + np.rint(t * 1e9).astype(np.int64)
        pos = np.clip(np.searchsorted(forces[0], stamps), 0, forces[0].size - 1)
        both = forces[0][pos] == stamps
        t, tau, f = t[both], tau[both], forces[1][pos[both]]
    out = {'refined': phase_scores(model, truth, t, tau, f)}
    if low_topic is not None:
        lt = read_arrays(recording, low_topic)
        out['low_latency'] = phase_scores(model, truth, (lt.stamp_ns - epoch) * 1e-9,
                                          _columns(lt, JOINTS, 'effort'))
    return out


def graph_summary(recording: str | os.PathLike, source: str | os.PathLike | None = None,
                  *, batch: bool = True) -> dict[str, Any]:
    """The demo's numbers (see the module docstring) as a JSON-ready dict."""
    from nmt_ros.model.contact import liftoff_time
    from nmt_ros.model.jumper import default_model
    from nmt_ros.study.metrics import jump_from, takeoffs
    from nmt_ros.tracking.skeletal_tracker import SKTSettings

    recording = Path(recording)
    statuses = final_statuses(recording)
    summary: dict[str, Any] = {'recording': str(recording)}
    summary['counts'] = counts = message_counts(recording, statuses)
    summary['lossless'] = all(c['published'] == c['recorded'] for c in counts.values()
                              if c['published'] >= 0)
    obs = topic_times(recording, topics.FORCE_PLATE_WRENCH)
    summary['latency_ms'] = {
        'joint_torques': latency_ms(topic_times(recording, topics.SKELETAL_JOINT_TORQUES), obs),
        'muscle_forces': latency_ms(topic_times(recording, topics.MUSCLE_FORCES), obs)}
    low = topics.SKELETAL_LOW_LATENCY[topics.SKELETAL_JOINT_TORQUES]
    recorded = {t.name for t in bag_info(recording).topics}
    if low in recorded:
        summary['latency_ms']['low_latency_joint_torques'] = latency_ms(
            topic_times(recording, low), obs)
    # the same from the first second on: a stream that begins in the air waits for its
    # landing (the estimator's airborne start), which sets the p99 of a short routine
    summary['latency_after_1s_ms'] = {
        name: latency_ms(topic_times(recording, topic), obs, after_s=1.0)
        for name, topic in (('joint_torques', topics.SKELETAL_JOINT_TORQUES),
                            ('muscle_forces', topics.MUSCLE_FORCES),
                            ('low_latency_joint_torques', low)) if topic in recorded}
    summary['cpu'] = {n: {'share': round(_float(statuses.get(n, {}), 'cpu_share'), 3),
                          'cpu_s': round(_float(statuses.get(n, {}), 'cpu_s_active'), 3),
                          'wall_s': round(_float(statuses.get(n, {}), 'wall_s_active'), 3)}
                      for n in NODES if n in statuses}
    summary['settings'] = {n: {k[len('setting.'):]: v for k, v in statuses.get(n, {}).items()
                               if k.startswith('setting.')} for n in NODES if n in statuses}
    summary['node_states'] = {n: statuses[n].get('state', '?') for n in NODES if n in statuses}
    rejected = {n: int(_float(statuses.get(n, {}), 'rejected_total', 0)) for n in NODES
                if n in statuses}
    summary['rejected'] = rejected
    # the skeletal tracker's losses of control (each re-initialised from the newest data)
    if 'skeletal_tracker' in statuses:
        summary['losses_of_control'] = int(_float(statuses['skeletal_tracker'], 'restarts', 0))

    model = default_model()
    jt = read_arrays(recording, topics.SKELETAL_JOINT_TORQUES)
    names = {t.name for t in bag_info(recording).topics}
    epoch = int(statuses.get('skeletal_tracker', {}).get('epoch_ns', jt.stamp_ns[0]))
    t = (jt.stamp_ns - epoch) * 1e-9
    tau = _columns(jt, JOINTS, 'effort')
    forces = None
    if topics.MUSCLE_FORCES in names and len(read_arrays(recording, topics.MUSCLE_FORCES)):
        fs = read_arrays(recording, topics.MUSCLE_FORCES)
        forces = (fs.stamp_ns, _columns(fs, MUSCLES, 'effort'))
    tracked = {}
    tracked_jumps = None
    coords, ground = topics.SKELETAL_GENERALIZED_COORDINATES, topics.SKELETAL_GROUND_WRENCH
    if coords in names and ground in names:
        gc, gw = read_arrays(recording, coords), read_arrays(recording, ground)
        tg = (gc.stamp_ns - epoch) * 1e-9
        # the tracker's own lift-off rule: its force falls below the plate's noise level
        lo = liftoff_time((gw.stamp_ns - epoch) * 1e-9, gw.force[:, 1],
                          SKTSettings().liftoff_force_bw * model.p.body_weight)
        tracked = jump_from(model, tg, _columns(gc, Q_NAMES, 'position'),
                            _columns(gc, Q_NAMES, 'velocity'), lo)
        # every jump of a long record: the tracker's lift-offs (same rule, each flight)
        tracked_jumps = (tg, _columns(gc, Q_NAMES, 'position'),
                         _columns(gc, Q_NAMES, 'velocity'),
                         takeoffs((gw.stamp_ns - epoch) * 1e-9, gw.force[:, 1],
                                  SKTSettings().liftoff_force_bw * model.p.body_weight))
    summary['tracked'] = {k: round(v, 4) for k, v in tracked.items()}
    if source is None:
        return summary
    from nmt_ros.io.trial_bag import has_truth, read_truth

    if has_truth(source):
        truth = read_truth(source)
        actual = jump_from(model, truth.t, truth.q, truth.qd, truth.liftoff_s)
        summary['actual'] = {k: round(v, 4) for k, v in actual.items()}
        if obs.stamp_ns.size:
            # scored over the part of the record that was replayed (nmt demo --duration)
            truth = truth.between((obs.stamp_ns.min() - epoch) * 1e-9 - 1e-6,
                                  (obs.stamp_ns.max() - epoch) * 1e-9 + 1e-6)
        if tracked_jumps is not None:
            summary['jumps'] = jump_table(model, truth, *tracked_jumps)
        idx = np.clip(np.rint(np.interp(t, truth.t, np.arange(truth.t.size))).astype(int), 0,
                      truth.t.size - 1)
        # contact: the truth's feet carry weight (every stance of a long record; the paper's
        # clip: up to its lift-off)
        on_ground = truth.s[:, 1] > SKTSettings().liftoff_force_bw * model.p.body_weight
        contact = on_ground[idx]
        peaks = np.abs(truth.tau[on_ground]).max(axis=0)
        err = _rms(tau[contact] - truth.tau[idx[contact]])
        summary['vs_truth'] = {'torque_rms_nm': _named(JOINTS, err, 2),
                               'torque_rms_pct_peak': _named(JOINTS, 100 * err / peaks, 2)}
        summary['phases'] = _phase_summary(model, truth, recording, epoch, t, tau, forces,
                                           low if low in recorded else None)
        summary['latency_by_phase_ms'] = {
            'joint_torques': latency_by_phase(
                topic_times(recording, topics.SKELETAL_JOINT_TORQUES), obs, truth, epoch)}
        if forces is not None:
            summary['latency_by_phase_ms']['muscle_forces'] = latency_by_phase(
                topic_times(recording, topics.MUSCLE_FORCES), obs, truth, epoch)
            tf = (forces[0] - epoch) * 1e-9
            fidx = np.clip(np.rint(np.interp(tf, truth.t, np.arange(truth.t.size))).astype(int),
                           0, truth.t.size - 1)
            fc = on_ground[fidx]
            ferr = _rms(forces[1][fc] - truth.f[fidx[fc]])
            summary['vs_truth']['muscle_force_rms_n'] = _named(MUSCLES, ferr, 1)
            summary['vs_truth']['muscle_force_rms_pct_f0'] = _named(
                MUSCLES, 100 * ferr / model.p.muscles.f0, 2)
    if batch:
        ref = batch_reference(source, statuses)
        keys = np.rint(ref['t'] * 1e9).astype(np.int64) + ref['epoch_ns']
        pos = np.searchsorted(keys, jt.stamp_ns)
        ok = (pos < keys.size) & (keys[np.clip(pos, 0, keys.size - 1)] == jt.stamp_ns)
        peak = np.abs(ref['tau']).max(axis=0)
        d = _rms(tau[ok] - ref['tau'][pos[ok]])
        summary['vs_batch'] = {'samples': int(ok.sum()), 'of': int(keys.size),
                               'torque_rms_pct_peak': _named(JOINTS, 100 * d / peak, 3)}
        if forces is not None and 'f' in ref:
            k2 = np.rint(ref['t2'] * 1e9).astype(np.int64) + ref['epoch_ns']
            p2 = np.searchsorted(k2, forces[0])
            ok2 = (p2 < k2.size) & (k2[np.clip(p2, 0, k2.size - 1)] == forces[0])
            d2 = _rms(forces[1][ok2] - ref['f'][p2[ok2]]) / model.p.muscles.f0
            summary['vs_batch']['muscle_force_rms_pct_f0'] = _named(MUSCLES, 100 * d2, 3)
            summary['vs_batch']['muscle_samples'] = int(ok2.sum())
    return summary


def format_summary(s: Mapping[str, Any]) -> str:
    """The demo's printed report."""
    lines = []
    if 'actual' in s or s.get('tracked'):
        act = s.get('actual', {}).get('jump_height_m', math.nan)
        trk = s.get('tracked', {}).get('jump_height_m', math.nan)
        jumps = s.get('jumps')
        if jumps and len(jumps['jumps']) > 1:
            lines.append(f"jump heights, {len(jumps['jumps'])} jumps (tracked vs truth, m): " +
                         ', '.join(f"{j['liftoff_s']:.1f} s {j['tracked_m']:.3f} vs "
                                   f"{j['actual_m']:.3f}" for j in jumps['jumps']) +
                         f"; mean |error| {jumps['mean_abs_error_pct']:.1f} % over the "
                         f"{jumps['tracked']} tracked")
        elif 'actual' in s:
            lines.append(f'jump height: tracked motion {trk:.3f} m, actual (truth) {act:.3f} m '
                         f'(difference {100 * (trk - act):+.1f} cm)')
        else:
            lines.append(f'jump height: tracked motion {trk:.3f} m (the bag has no truth)')
    vt = s.get('vs_truth')
    if vt:
        lines.append('joint torques vs truth (RMS, contact phase): ' + ', '.join(
            f'{j} {vt["torque_rms_nm"][j]:.1f} N m ({vt["torque_rms_pct_peak"][j]:.1f} % peak)'
            for j in JOINTS))
        if 'muscle_force_rms_n' in vt:
            lines.append('muscle forces vs truth (RMS, contact phase, N / % F0): ' + ', '.join(
                f'{m} {vt["muscle_force_rms_n"][m]:.0f}/{vt["muscle_force_rms_pct_f0"][m]:.1f}'
                for m in MUSCLES))
    for kind, scores in s.get('phases', {}).items():
        from nmt_ros.study.phase_scores import format_phase_scores

        lines.append(f'{kind} estimates vs truth by phase (RMS):')
        lines += ['  ' + x for x in format_phase_scores(scores).splitlines()]
    vb = s.get('vs_batch')
    if vb:
        line = ('live graph vs batch trackers: torques ' + ', '.join(
            f'{j} {v:.2f}' for j, v in vb['torque_rms_pct_peak'].items()) + ' % of peak')
        if 'muscle_force_rms_pct_f0' in vb:
            line += (f'; muscle forces max {max(vb["muscle_force_rms_pct_f0"].values()):.2f} '
                     '% F0 RMS')
        lines.append(line)
    lat = s.get('latency_ms', {})
    for name, v in lat.items():
        lines.append(f'latency observation -> {name}: p50 {v["p50_ms"]:.1f} ms, '
                     f'p99 {v["p99_ms"]:.1f} ms, max {v["max_ms"]:.1f} ms ({v["n"]} samples)')
    after = {n: v for n, v in s.get('latency_after_1s_ms', {}).items() if v['n']}
    if after:
        lines.append('  from the first second on, p50 / p99 ms: ' + ', '.join(
            f'{n} {v["p50_ms"]:.0f} / {v["p99_ms"]:.0f}' for n, v in after.items()))
    for name, phases in s.get('latency_by_phase_ms', {}).items():
        lines.append(f'  {name} by phase, p50 / p99 ms: ' + ', '.join(
            f'{p} {v["p50_ms"]:.0f} / {v["p99_ms"]:.0f}' for p, v in phases.items()
            if v['n']))
    cpu = s.get('cpu', {})
    if cpu:
        lines.append('CPU share while active (1.0 = one core): ' + ', '.join(
            f'{n} {v["share"]:.2f}' for n, v in cpu.items()))
    counts = s.get('counts', {})
    lines.append('messages (published / recorded):' + ('' if s.get('lossless') else
                                                        '  MISMATCH'))
    for topic, c in counts.items():
        pub = c['published'] if c['published'] >= 0 else '?'
        lines.append(f'  {topic:42s} {pub!s:>6} / {c["recorded"]:<6}')
    rej = {n: v for n, v in s.get('rejected', {}).items() if v}
    if rej:
        lines.append(f'rejected samples: {rej}')
    if 'losses_of_control' in s:
        n = s['losses_of_control']
        lines.append('skeletal tracker losses of control: ' + (
            'none' if not n else f'{n} (each re-initialised from the newest observations; '
            'when: the ERROR records of /nmt/status in the recording)'))
    return '\n'.join(lines)
