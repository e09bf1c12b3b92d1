"""A trial (observations, and truth when synthetic) as a rosbag2 bag, and back.

Topics (INTERFACES.md); JointState fields follow their ROS meaning where one exists:
  /mocap/segment_angles        JointState [foot, shank, thigh, hat], position (rad), 120 Hz
  /force_plate/wrench          WrenchStamped, force.x fore-aft, force.y vertical (N),
                               torque.z moment about the foot COM (N m), frame_id 'foot_com'
  /mocap/ankle_position        JointState [r1, r2], position (m): the measured ankle centre
                               (optional; lab recordings)
  /truth/segment_angles        JointState, position + velocity, 1080 Hz
  /truth/generalized_coordinates  JointState [th1..th4, r1, r2], position + velocity
  /truth/joint_torques         JointState [ankle, knee, hip]: position/velocity = OpenSim
                               joint angle/rate, effort = torque (N m)
  /truth/muscle_forces         JointState [gmax..ta]: position = musculotendon length (m),
                               velocity = lengthening speed (m/s), effort = force (N)
  /truth/muscle_activations    JointState, position = activation (0..1)
  /truth/muscle_excitations    JointState, position = excitation (0..1)
  /truth/ground_wrench         WrenchStamped (as the force plate, without noise and bias)
  /truth/mocap_bias, /truth/force_plate_bias   the bias that was added (noise = obs - truth
                               - bias), so anyone can check the synthesis independently.
Header stamps are ``TRIAL_EPOCH_NS`` + trial time; the log time equals the stamp.
Trial facts (lift-off, anchors, settings) go in metadata.yaml ``custom_data``.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from msg_adapters.joint_state import joint_states_from_arrays
from msg_adapters.wrench import wrenches_from_arrays
from nmt_ros import topics
from nmt_ros.io.bags import BagInfo, BagWriter, bag_info, read_topics_arrays
from nmt_ros.model.jumper import JumperModel
from nmt_ros.model.parameters import JOINTS, MUSCLES, Q_NAMES, SEGMENTS
from nmt_ros.records import TRIAL_EPOCH_NS, Observations, TrialEstimates, Truth
from nmt_ros.tracking.conditioning import nominal_rate

#: Names of the ankle-position JointState: the model's coordinates r1, r2 (m).
ANKLE_NAMES = ('r1', 'r2')


def to_stamps_ns(t: np.ndarray, epoch_ns: int = TRIAL_EPOCH_NS) -> np.ndarray:
    """Trial times [s] -> header stamps [ns] (rounded to the nanosecond)."""
    return epoch_ns + np.rint(np.asarray(t, dtype=float) * 1e9).astype(np.int64)


def _wrench_arrays(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = w.shape[0]
    force = np.column_stack([w[:, 0], w[:, 1], np.zeros(n)])
    torque = np.column_stack([np.zeros(n), np.zeros(n), w[:, 2]])
    return force, torque


def trial_messages(obs: Observations, truth: Truth | None = None,
                   components: dict | None = None,
                   epoch_ns: int = TRIAL_EPOCH_NS) -> list[tuple[str, int, object]]:
    """All (topic, stamp_ns, message) of a trial, sorted by time then topic."""
    out: list[tuple[str, np.ndarray, list]] = []
    sa = to_stamps_ns(obs.t_angles, epoch_ns)
    sw = to_stamps_ns(obs.t_wrench, epoch_ns)
    out.append((topics.MOCAP_SEGMENT_ANGLES, sa,
                joint_states_from_arrays(sa, SEGMENTS, position=obs.angles)))
    f, tq = _wrench_arrays(obs.wrench)
    out.append((topics.FORCE_PLATE_WRENCH, sw, wrenches_from_arrays(sw, obs.frame_id, f, tq)))
    if obs.ankle is not None:
        sk = to_stamps_ns(obs.t_ankle, epoch_ns)
        out.append((topics.MOCAP_ANKLE_POSITION, sk,
                    joint_states_from_arrays(sk, ANKLE_NAMES, position=obs.ankle)))
    if truth is not None:
        from nmt_ros.model.jumper import default_model
        model = default_model()
        st = to_stamps_ns(truth.t, epoch_ns)
        theta, = model.batch(model.joint_angles, truth.q)
        theta_dot, = model.batch(model.joint_angles, truth.qd)
        lmt, = model.batch(model.musculotendon_lengths, theta)
        vmt, = model.batch(model.musculotendon_velocities, theta, theta_dot)
        tf_, tt = _wrench_arrays(truth.s)
        out += [
            (topics.TRUTH_SEGMENT_ANGLES, st, joint_states_from_arrays(
                st, SEGMENTS, position=truth.q[:, :4], velocity=truth.qd[:, :4])),
            (topics.TRUTH_GENERALIZED_COORDINATES, st, joint_states_from_arrays(
                st, Q_NAMES, position=truth.q, velocity=truth.qd)),
            (topics.TRUTH_JOINT_TORQUES, st, joint_states_from_arrays(
                st, JOINTS, position=theta, velocity=theta_dot, effort=truth.tau)),
            (topics.TRUTH_GROUND_WRENCH, st,
             wrenches_from_arrays(st, topics.WRENCH_FRAME, tf_, tt)),
        ]
        out += _muscle_topics((topics.TRUTH_MUSCLE_FORCES, topics.TRUTH_MUSCLE_ACTIVATIONS,
                               topics.TRUTH_MUSCLE_EXCITATIONS), st, lmt, vmt, truth.f, truth.a,
                              truth.u)
    if components is not None:
        bf, bt = _wrench_arrays(components['wrench_bias'])
        out += [
            (topics.TRUTH_MOCAP_BIAS, sa, joint_states_from_arrays(
                sa, SEGMENTS, position=components['angle_bias'])),
            (topics.TRUTH_FORCE_PLATE_BIAS, sw, wrenches_from_arrays(sw, obs.frame_id, bf, bt)),
        ]
    return _time_ordered(out)


def _time_ordered(per_topic: list[tuple[str, np.ndarray, list]],
                  ) -> list[tuple[str, int, object]]:
    """(topic, stamps, messages) blocks -> (topic, stamp, message) sorted by time, topic."""
    rows = [(stamp, k, i) for k, (_, stamps, _) in enumerate(per_topic)
            for i, stamp in enumerate(stamps.tolist())]
    rows.sort()
    return [(per_topic[k][0], stamp, per_topic[k][2][i]) for stamp, k, i in rows]


def _muscle_topics(topics: tuple[str, str, str], stamps: np.ndarray, l_mt: np.ndarray,
                   v_mt: np.ndarray, f: np.ndarray, a: np.ndarray, u: np.ndarray,
                   ) -> list[tuple[str, np.ndarray, list]]:
    """Forces (length, speed, force), activations and excitations of the 9 muscles."""
    forces, activations, excitations = topics
    return [(forces, stamps, joint_states_from_arrays(stamps, MUSCLES, position=l_mt,
                                                      velocity=v_mt, effort=f)),
            (activations, stamps, joint_states_from_arrays(stamps, MUSCLES, position=a)),
            (excitations, stamps, joint_states_from_arrays(stamps, MUSCLES, position=u))]


def write_trial_bag(path: str | os.PathLike, obs: Observations, truth: Truth | None = None,
                    components: dict | None = None, custom_data: dict | None = None,
                    epoch_ns: int = TRIAL_EPOCH_NS) -> BagInfo:
    """Write a trial as a bag folder (refuses an existing non-empty folder)."""
    data = {'nmt.trial_epoch_ns': str(epoch_ns)}
    if truth is not None:
        data['nmt.liftoff_s'] = repr(float(truth.liftoff_s))
        data['nmt.contact_anchors_m'] = json.dumps([float(v) for v in truth.x0])
    for k, v in (custom_data or {}).items():
        data[k] = v if isinstance(v, str) else json.dumps(v)
    with BagWriter(path, custom_data=data, flush_period_s=None) as bag:
        for topic, stamp, msg in trial_messages(obs, truth, components, epoch_ns):
            bag.write(topic, msg, stamp, stamp)
    return bag_info(path)


def _custom(path: Path) -> dict:
    return dict(bag_info(path).custom_data or {})


def read_observations(path: str | os.PathLike, epoch_ns: int | None = None) -> Observations:
    """The observation topics of any bag carrying them, as arrays (trial time from t0).

    Trial time 0 is ``nmt.trial_epoch_ns`` when the bag says so, else the first stamp.
    """
    path = Path(path)
    wanted = [topics.MOCAP_SEGMENT_ANGLES, topics.FORCE_PLATE_WRENCH]
    has_ankle = topics.MOCAP_ANKLE_POSITION in {t.name for t in bag_info(path).topics}
    arrays = read_topics_arrays(path, wanted + [topics.MOCAP_ANKLE_POSITION] * has_ankle)
    ang, wr = arrays[topics.MOCAP_SEGMENT_ANGLES], arrays[topics.FORCE_PLATE_WRENCH]
    if epoch_ns is None:
        epoch_ns = int(_custom(path).get('nmt.trial_epoch_ns',
                                         min(ang.stamp_ns[0], wr.stamp_ns[0])))
    angles = np.column_stack([ang.column(n) for n in SEGMENTS])
    wrench = np.column_stack([wr.force[:, 0], wr.force[:, 1], wr.torque[:, 2]])
    t_ankle = ankle = None
    if has_ankle:
        an = arrays[topics.MOCAP_ANKLE_POSITION]
        t_ankle = (an.stamp_ns - epoch_ns) * 1e-9
        ankle = np.column_stack([an.column(n) for n in ANKLE_NAMES])
    return Observations(t_angles=(ang.stamp_ns - epoch_ns) * 1e-9, angles=angles,
                        t_wrench=(wr.stamp_ns - epoch_ns) * 1e-9, wrench=wrench,
                        frame_id=wr.frame_id, info={'epoch_ns': epoch_ns},
                        t_ankle=t_ankle, ankle=ankle)


def observation_rates(path: str | os.PathLike) -> tuple[float, float]:
    """(segment-angle rate, force-plate rate) [Hz] of a bag, from its header stamps (the
    median sample interval of each observation topic, rounded to 1 mHz: ``nominal_rate``)."""
    rates = []
    pair = (topics.MOCAP_SEGMENT_ANGLES, topics.FORCE_PLATE_WRENCH)
    arrays = read_topics_arrays(Path(path), pair)
    for topic in pair:
        stamps = np.sort(arrays[topic].stamp_ns)
        dt = np.diff(stamps)
        dt = dt[dt > 0]
        if dt.size == 0:
            raise ValueError(f'{path}: {topic} has fewer than two distinct stamps')
        rates.append(nominal_rate(1e9 / float(np.median(dt))))
    return rates[0], rates[1]


def has_truth(path: str | os.PathLike) -> bool:
    names = {t.name for t in bag_info(path).topics}
    return topics.TRUTH_GENERALIZED_COORDINATES in names


def read_truth(path: str | os.PathLike) -> Truth:
    """The ``/truth/*`` topics of a synthetic bag as a :class:`Truth` (qdd by differences)."""
    path = Path(path)
    custom = _custom(path)
    epoch_ns = int(custom.get('nmt.trial_epoch_ns', TRIAL_EPOCH_NS))
    arrays = read_topics_arrays(path, [
        topics.TRUTH_GENERALIZED_COORDINATES, topics.TRUTH_JOINT_TORQUES,
        topics.TRUTH_GROUND_WRENCH, topics.TRUTH_MUSCLE_ACTIVATIONS,
        topics.TRUTH_MUSCLE_EXCITATIONS, topics.TRUTH_MUSCLE_FORCES])
    gc = arrays[topics.TRUTH_GENERALIZED_COORDINATES]
    t = (gc.stamp_ns - epoch_ns) * 1e-9
    q = np.column_stack([gc.column(n) for n in Q_NAMES])
    qd = np.column_stack([gc.column(n, 'velocity') for n in Q_NAMES])

    def muscles(topic: str, field: str) -> np.ndarray:
        js = arrays[topic]
        return np.column_stack([js.column(n, field) for n in MUSCLES])

    jt = arrays[topics.TRUTH_JOINT_TORQUES]
    gw = arrays[topics.TRUTH_GROUND_WRENCH]
    s = np.column_stack([gw.force[:, 0], gw.force[:, 1], gw.torque[:, 2]])
    if gw.stamp_ns.size != gc.stamp_ns.size or (gw.stamp_ns != gc.stamp_ns).any():
        # a truth written at the mocap rate (routines) keeps the wrench at the plate's:
        # onto the common grid (its instants are plate instants, so this selects samples)
        t_w = (gw.stamp_ns - epoch_ns) * 1e-9
        s = np.column_stack([np.interp(t, t_w, s[:, k]) for k in range(3)])
    return Truth(
        t=t, q=q, qd=qd, qdd=np.gradient(qd, t, axis=0),
        a=muscles(topics.TRUTH_MUSCLE_ACTIVATIONS, 'position'),
        u=muscles(topics.TRUTH_MUSCLE_EXCITATIONS, 'position'),
        f=muscles(topics.TRUTH_MUSCLE_FORCES, 'effort'),
        tau=np.column_stack([jt.column(n, 'effort') for n in JOINTS]),
        s=s, point_forces=np.full((t.size, 2, 2), np.nan),
        x0=np.asarray(json.loads(custom['nmt.contact_anchors_m']), dtype=float),
        liftoff_s=float(custom['nmt.liftoff_s']), info={'epoch_ns': epoch_ns})


def estimate_messages(model: JumperModel, estimates: TrialEstimates,
                      epoch_ns: int = TRIAL_EPOCH_NS) -> list[tuple[str, int, object]]:
    """The /nmt/* estimate topics of a batch run, stamped with observation time."""
    out = []
    skt = estimates.stage1
    st = to_stamps_ns(skt.t, epoch_ns)
    theta, = model.batch(model.joint_angles, skt.q)
    theta_dot, = model.batch(model.joint_angles, skt.qd)
    f, tq = _wrench_arrays(skt.s)
    out += [
        (topics.SKELETAL_JOINT_TORQUES, st, joint_states_from_arrays(
            st, JOINTS, position=theta, velocity=theta_dot, effort=skt.tau)),
        (topics.SKELETAL_SEGMENT_ANGLES, st, joint_states_from_arrays(
            st, SEGMENTS, position=skt.q[:, :4], velocity=skt.qd[:, :4])),
        (topics.SKELETAL_GENERALIZED_COORDINATES, st, joint_states_from_arrays(
            st, Q_NAMES, position=skt.q, velocity=skt.qd)),     # as the live graph: the body
        (topics.SKELETAL_GROUND_WRENCH, st,
         wrenches_from_arrays(st, topics.WRENCH_FRAME, f, tq)),
    ]
    si = to_stamps_ns(estimates.ivd_t, epoch_ns)
    out.append((topics.IVD_JOINT_TORQUES, si, joint_states_from_arrays(
        si, JOINTS, effort=estimates.ivd_tau)))
    if estimates.muscles is not None:
        s2 = estimates.muscles
        ss = to_stamps_ns(s2.t, epoch_ns)
        # Stage 2 runs on the Stage-1 grid (gaps filled by interpolation, as live)
        th, thd = (np.column_stack([np.interp(s2.t, skt.t, x[:, j]) for j in range(3)])
                   for x in (theta, theta_dot))
        lmt, = model.batch(model.musculotendon_lengths, th)
        vmt, = model.batch(model.musculotendon_velocities, th, thd)
        out += _muscle_topics(topics.MUSCLE_OUTPUTS, ss, lmt, vmt, s2.f, s2.a, s2.u)
    return _time_ordered(out)


def write_estimates_bag(path: str | os.PathLike, model: JumperModel, estimates: TrialEstimates,
                        epoch_ns: int = TRIAL_EPOCH_NS, custom_data: dict | None = None,
                        ) -> BagInfo:
    """A batch run's estimates as a bag folder (topics of ``estimate_messages``)."""
    data = {'nmt.trial_epoch_ns': str(epoch_ns)}
    data.update({k: v if isinstance(v, str) else json.dumps(v)
                 for k, v in (custom_data or {}).items()})
    with BagWriter(path, custom_data=data, flush_period_s=None) as bag:
        for topic, stamp, msg in estimate_messages(model, estimates, epoch_ns):
            bag.write(topic, msg, stamp, stamp)
    return bag_info(path)
