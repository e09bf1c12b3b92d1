"""A routine as a rosbag2 bag: the topics of a synthetic trial bag (``trial_bag``) plus the
routine's own truth.

Topics, with the rate of each group:
* at the force-plate rate (1080 Hz): /force_plate/wrench, /truth/ground_wrench,
  /truth/force_plate_bias, and
  /truth/contact_anchors       JointState [heel, toe]: position = the contact anchors x0 (m),
                               published at t = 0 and whenever they change (at a touchdown,
                               the instant of the first sample under the new anchors): the
                               anchors in force at any time are those of the last message;
* at the mocap rate (120 Hz): /mocap/segment_angles, /truth/mocap_bias;
* at ``truth_rate_hz`` (1080 Hz as in trial bags, or 120 Hz, the mocap instants, to keep a
  minutes-long bag small): /truth/segment_angles, /truth/generalized_coordinates,
  /truth/joint_torques, /truth/muscle_forces, /truth/muscle_activations,
  /truth/muscle_excitations (fields as in ``trial_bag``).
With faults, what tells them apart (the bias topics then carry bias + drift + spikes, so
noise = observation - truth - bias holds at every sample that is not NaN):
  /truth/force_plate_drift     WrenchStamped, 1080 Hz: the drifting additive offset alone
  /truth/force_plate_spikes    WrenchStamped at the spiked samples only: the spike alone
  /truth/mocap_spikes          JointState [foot..hat] at the spiked frames only (rad)
  /truth/mocap_dropouts        JointState [foot..hat] at the affected frames only: position
                               1 occluded, 2 NaN frame, 0 not affected
  /truth/force_plate_dropouts  JointState [wrench] at the NaN samples only: position 2
A bag written with ``with_truth=False`` (the faulty twin of a clean routine bag of the same
seed: same truth, same smooth bias) leaves out the truth topics and the drift: the drift is
exactly this bag's /truth/force_plate_bias minus the clean bag's, minus the spikes (all
components are dyadic-rounded, so the sums and differences are exact).
Values are written as given; ``study.routine_output`` rounds every array to float32
precision first (zstd then compresses the bags ~2x) and makes the observations from the
rounded truth, so the identity above is exact in the bag.
The routine's facts go in metadata.yaml ``custom_data`` (``nmt.routine.*``, JSON values).
"""
from __future__ import annotations

import json
import os

import numpy as np

from msg_adapters.joint_state import joint_states_from_arrays
from msg_adapters.wrench import wrenches_from_arrays
from nmt_ros import topics
from nmt_ros.io.bags import BagInfo, BagWriter, bag_info
from nmt_ros.io.trial_bag import (
    _muscle_topics,
    _time_ordered,
    _wrench_arrays,
    to_stamps_ns,
)
from nmt_ros.model.parameters import JOINTS, Q_NAMES, SEGMENTS
from nmt_ros.records import TRIAL_EPOCH_NS, Observations, Truth

CONTACT_POINTS = ('heel', 'toe')
#: Chunk size of the routine bags: large chunks compress better (zstd), and readers of a
#: minutes-long routine read it whole anyway.
CHUNK_SIZE = 4 * 1024 * 1024


def routine_messages(obs: Observations, truth: Truth, components: dict, anchors: np.ndarray,
                     truth_rate_hz: float = 1080.0, epoch_ns: int = TRIAL_EPOCH_NS,
                     with_truth: bool = True) -> list[tuple[str, int, object]]:
    """All (topic, stamp_ns, message) of a routine, sorted by time then topic. ``truth`` is
    on the 1080 Hz grid; the kinematic and muscle truth is taken every
    1080 / ``truth_rate_hz`` samples."""
    from nmt_ros.model.jumper import default_model

    step = int(round(1080.0 / truth_rate_hz))
    if step < 1 or abs(1080.0 / step - truth_rate_hz) > 1e-9:
        raise ValueError(f'truth_rate_hz must divide 1080 Hz, not {truth_rate_hz}')
    model = default_model()
    nan = 'wrench_drift' in components         # observations may hold NaN (faults)
    sa = to_stamps_ns(obs.t_angles, epoch_ns)
    sw = to_stamps_ns(obs.t_wrench, epoch_ns)
    st = to_stamps_ns(truth.t, epoch_ns)
    k = np.arange(0, truth.t.size, step)
    ss = st[k]
    q, qd = truth.q[k], truth.qd[k]
    theta, = model.batch(model.joint_angles, q)
    theta_dot, = model.batch(model.joint_angles, qd)
    lmt, = model.batch(model.musculotendon_lengths, theta)
    vmt, = model.batch(model.musculotendon_velocities, theta, theta_dot)
    theta, theta_dot, lmt, vmt = (as_float32(v) for v in (theta, theta_dot, lmt, vmt))
    f_obs, t_obs = _wrench_arrays(obs.wrench)
    f_tr, t_tr = _wrench_arrays(truth.s)
    f_b, t_b = _wrench_arrays(components['wrench_bias'])
    change = np.r_[True, np.any(np.diff(anchors, axis=0) != 0, axis=1)]
    sc = st[change]
    truth_topics = [
        (topics.TRUTH_SEGMENT_ANGLES, ss, joint_states_from_arrays(
            ss, SEGMENTS, position=q[:, :4], velocity=qd[:, :4])),
        (topics.TRUTH_GENERALIZED_COORDINATES, ss, joint_states_from_arrays(
            ss, Q_NAMES, position=q, velocity=qd)),
        (topics.TRUTH_JOINT_TORQUES, ss, joint_states_from_arrays(
            ss, JOINTS, position=theta, velocity=theta_dot, effort=truth.tau[k])),
        (topics.TRUTH_GROUND_WRENCH, st, wrenches_from_arrays(st, topics.WRENCH_FRAME, f_tr,
                                                              t_tr)),
        (topics.TRUTH_CONTACT_ANCHORS, sc, joint_states_from_arrays(sc, CONTACT_POINTS,
                                                     position=anchors[change])),
    ]
    truth_topics += _muscle_topics((topics.TRUTH_MUSCLE_FORCES, topics.TRUTH_MUSCLE_ACTIVATIONS,
                                    topics.TRUTH_MUSCLE_EXCITATIONS), ss, lmt, vmt, truth.f[k],
                                   truth.a[k], truth.u[k])
    out = [
        (topics.MOCAP_SEGMENT_ANGLES, sa, joint_states_from_arrays(
            sa, SEGMENTS, position=obs.angles, allow_nan=nan)),
        (topics.FORCE_PLATE_WRENCH, sw, wrenches_from_arrays(sw, obs.frame_id, f_obs, t_obs,
                                                allow_nan=nan)),
        (topics.TRUTH_MOCAP_BIAS, sa, joint_states_from_arrays(
            sa, SEGMENTS, position=components['angle_bias'])),
        (topics.TRUTH_FORCE_PLATE_BIAS, sw, wrenches_from_arrays(sw, obs.frame_id, f_b, t_b)),
    ] + (truth_topics if with_truth else [])
    if 'wrench_drift' in components:
        if with_truth:
            f, tq = _wrench_arrays(components['wrench_drift'])
            out.append((topics.TRUTH_FORCE_PLATE_DRIFT, sw,
                        wrenches_from_arrays(sw, obs.frame_id, f, tq)))
        spk_w = np.flatnonzero(np.any(components['wrench_spikes'] != 0, axis=1))
        f, tq = _wrench_arrays(components['wrench_spikes'][spk_w])
        out.append((topics.TRUTH_FORCE_PLATE_SPIKES, sw[spk_w],
                    wrenches_from_arrays(sw[spk_w], obs.frame_id, f, tq)))
        spk_a = np.flatnonzero(np.any(components['angle_spikes'] != 0, axis=1))
        out.append((topics.TRUTH_MOCAP_SPIKES, sa[spk_a], joint_states_from_arrays(
            sa[spk_a], SEGMENTS, position=components['angle_spikes'][spk_a])))
        drop_a = np.flatnonzero(np.any(components['angle_dropout'] != 0, axis=1))
        out.append((topics.TRUTH_MOCAP_DROPOUTS, sa[drop_a], joint_states_from_arrays(
            sa[drop_a], SEGMENTS, position=components['angle_dropout'][drop_a].astype(float))))
        drop_w = np.flatnonzero(components['wrench_dropout'] != 0)
        out.append((topics.TRUTH_FORCE_PLATE_DROPOUTS, sw[drop_w], joint_states_from_arrays(
            sw[drop_w], ('wrench',),
            position=components['wrench_dropout'][drop_w].astype(float)[:, None])))
    return _time_ordered([o for o in out if len(o[1])])


def as_float32(x: np.ndarray) -> np.ndarray:
    """x rounded to the nearest float32 value, as float64 (NaN kept)."""
    return np.asarray(x, dtype=np.float64).astype(np.float32).astype(np.float64)


def write_routine_bag(path: str | os.PathLike, obs: Observations, truth: Truth,
                      components: dict, anchors: np.ndarray, custom_data: dict | None = None,
                      truth_rate_hz: float = 1080.0, epoch_ns: int = TRIAL_EPOCH_NS,
                      with_truth: bool = True) -> BagInfo:
    """Write a routine as a bag folder (refuses an existing non-empty folder).

    ``custom_data`` values that are not strings are stored as JSON. The trial keys
    ``nmt.liftoff_s`` (the first lift-off) and ``nmt.contact_anchors_m`` (the anchors at
    t = 0) are written as in trial bags, so trial readers open a routine too.
    """
    data = {'nmt.trial_epoch_ns': str(epoch_ns), 'nmt.routine.truth_rate_hz': repr(truth_rate_hz),
            'nmt.liftoff_s': repr(float(truth.liftoff_s)),
            'nmt.contact_anchors_m': json.dumps([float(v) for v in anchors[0]])}
    for k, v in (custom_data or {}).items():
        data[k] = v if isinstance(v, str) else json.dumps(v)
    with BagWriter(path, custom_data=data, flush_period_s=None,
                   chunk_size=CHUNK_SIZE) as bag:
        for topic, stamp, msg in routine_messages(obs, truth, components, anchors,
                                                  truth_rate_hz, epoch_ns, with_truth):
            bag.write(topic, msg, stamp, stamp)
    return bag_info(path)
