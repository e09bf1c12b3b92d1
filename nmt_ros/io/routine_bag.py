"""A routine as a rosbag2 bag: the trial layout (``trial_bag``) plus the routine's own truth.

Every topic of a synthetic trial bag (observations, ``/truth/*``, the bias topics), and:
  /truth/contact_anchors       JointState [heel, toe]: position = the contact anchors x0 (m)
                               in force at each truth sample (re-placed at every touchdown)
With faults, what tells them apart (the bias topics then carry bias + drift + spikes, so
noise = observation - truth - bias still holds at every sample that is not NaN):
  /truth/force_plate_drift     WrenchStamped: the drifting additive offset alone
  /truth/force_plate_spikes    WrenchStamped: the spikes alone
  /truth/mocap_spikes          JointState [foot..hat]: the angle spikes alone (rad)
  /truth/mocap_dropouts        JointState [foot..hat]: position 0 ok, 1 occluded, 2 NaN frame
  /truth/force_plate_dropouts  JointState [wrench]: position 0 ok, 2 NaN sample
The routine's facts go in metadata.yaml ``custom_data`` (``nmt.routine.*``, JSON values).
"""
from __future__ import annotations

import json
import os

import numpy as np

from msg_adapters.joint_state import joint_states_from_arrays
from msg_adapters.wrench import wrenches_from_arrays
from nmt_ros.io.bags import BagInfo, BagWriter, bag_info
from nmt_ros.io.trial_bag import _time_ordered, _wrench_arrays, to_stamps_ns, trial_messages
from nmt_ros.model.parameters import SEGMENTS
from nmt_ros.study.trial import TRIAL_EPOCH_NS, Observations, Truth

ANCHORS_TOPIC = '/truth/contact_anchors'
CONTACT_POINTS = ('heel', 'toe')
#: Chunk size of the routine bags: large chunks compress better (zstd), and readers of a
#: minutes-long routine read it whole anyway.
CHUNK_SIZE = 4 * 1024 * 1024


def routine_messages(obs: Observations, truth: Truth, components: dict, anchors: np.ndarray,
                     epoch_ns: int = TRIAL_EPOCH_NS) -> list[tuple[str, int, object]]:
    """All (topic, stamp_ns, message) of a routine, sorted by time then topic."""
    base = trial_messages(obs, truth, components, epoch_ns)
    st = to_stamps_ns(truth.t, epoch_ns)
    extra = [(ANCHORS_TOPIC, st, joint_states_from_arrays(st, CONTACT_POINTS,
                                                          position=anchors))]
    if 'wrench_drift' in components:
        sa = to_stamps_ns(obs.t_angles, epoch_ns)
        sw = to_stamps_ns(obs.t_wrench, epoch_ns)
        for topic, key in (('/truth/force_plate_drift', 'wrench_drift'),
                           ('/truth/force_plate_spikes', 'wrench_spikes')):
            f, tq = _wrench_arrays(components[key])
            extra.append((topic, sw, wrenches_from_arrays(sw, obs.frame_id, f, tq)))
        extra += [
            ('/truth/mocap_spikes', sa, joint_states_from_arrays(
                sa, SEGMENTS, position=components['angle_spikes'])),
            ('/truth/mocap_dropouts', sa, joint_states_from_arrays(
                sa, SEGMENTS, position=components['angle_dropout'].astype(float))),
            ('/truth/force_plate_dropouts', sw, joint_states_from_arrays(
                sw, ('wrench',), position=components['wrench_dropout'].astype(float)[:, None])),
        ]
    merged = base + _time_ordered(extra)
    merged.sort(key=lambda r: (r[1], r[0]))
    return merged


def write_routine_bag(path: str | os.PathLike, obs: Observations, truth: Truth,
                      components: dict, anchors: np.ndarray, custom_data: dict | None = None,
                      epoch_ns: int = TRIAL_EPOCH_NS) -> BagInfo:
    """Write a routine as a bag folder (refuses an existing non-empty folder).

    ``custom_data`` values that are not strings are stored as JSON. The trial keys
    ``nmt.liftoff_s`` (the first lift-off) and ``nmt.contact_anchors_m`` (the anchors at
    t = 0) are written as in trial bags, so trial readers open a routine too.
    """
    data = {'nmt.trial_epoch_ns': str(epoch_ns),
            'nmt.liftoff_s': repr(float(truth.liftoff_s)),
            'nmt.contact_anchors_m': json.dumps([float(v) for v in anchors[0]])}
    for k, v in (custom_data or {}).items():
        data[k] = v if isinstance(v, str) else json.dumps(v)
    with BagWriter(path, custom_data=data, flush_period_s=None,
                   chunk_size=CHUNK_SIZE) as bag:
        for topic, stamp, msg in routine_messages(obs, truth, components, anchors, epoch_ns):
            bag.write(topic, msg, stamp, stamp)
    return bag_info(path)
