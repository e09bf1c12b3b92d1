"""Every topic name of the graph and of our bags, in one place (INTERFACES.md).

Pure constants (the bottom layer): the nodes, ``io.trial_bag``, the study and the CLI name
topics through this module only. What each carries (message type, fields, units) is in
INTERFACES.md and in the README's "Topic meanings".
"""
from __future__ import annotations

# Observations (the lab's instruments; replayed by observation_publisher).
MOCAP_SEGMENT_ANGLES = '/mocap/segment_angles'   # JointState [foot, shank, thigh, hat], 120 Hz
FORCE_PLATE_WRENCH = '/force_plate/wrench'       # WrenchStamped in WRENCH_FRAME, 1080 Hz
OBSERVATIONS = (MOCAP_SEGMENT_ANGLES, FORCE_PLATE_WRENCH)
# Optional, in bags of lab recordings (nmt import-lab): the measured ankle centre, JointState
# [r1, r2] position (m) in the lab's sagittal frame. Batch tools use it to check the motion
# against the measured forces and to start a trial in flight; the live graph ignores it.
MOCAP_ANKLE_POSITION = '/mocap/ankle_position'

#: ``header.frame_id`` of every planar ground wrench (observed, estimated, true): the foot's
#: centre of mass, about which the moment is taken.
WRENCH_FRAME = 'foot_com'

# Stage 1 (skeletal_tracker node; the batch estimates bag).
SKELETAL_JOINT_TORQUES = '/nmt/skeletal/joint_torques'
SKELETAL_SEGMENT_ANGLES = '/nmt/skeletal/segment_angles'
SKELETAL_GENERALIZED_COORDINATES = '/nmt/skeletal/generalized_coordinates'
SKELETAL_GROUND_WRENCH = '/nmt/skeletal/ground_wrench'
SKELETAL_OUTPUTS = (SKELETAL_JOINT_TORQUES, SKELETAL_SEGMENT_ANGLES,
                    SKELETAL_GENERALIZED_COORDINATES, SKELETAL_GROUND_WRENCH)
#: The low-latency (causal) estimates of the same quantities: the topic under
#: ``/nmt/skeletal/low_latency/`` (same types and names).
LOW_LATENCY_PREFIX = '/nmt/skeletal/low_latency'
SKELETAL_LOW_LATENCY = {topic: LOW_LATENCY_PREFIX + topic[len('/nmt/skeletal'):]
                        for topic in SKELETAL_OUTPUTS}

# Stage 2 (muscle_tracker node; the batch estimates bag).
MUSCLE_FORCES = '/nmt/muscle/forces'
MUSCLE_ACTIVATIONS = '/nmt/muscle/activations'
MUSCLE_EXCITATIONS = '/nmt/muscle/excitations'
MUSCLE_OUTPUTS = (MUSCLE_FORCES, MUSCLE_ACTIVATIONS, MUSCLE_EXCITATIONS)

# The IVD baseline (batch estimates bag only).
IVD_JOINT_TORQUES = '/nmt/ivd/joint_torques'

# Every node's status and end-of-stream announcements (DiagnosticArray).
STATUS = '/nmt/status'

# Simulated time published by a bag replay with --clock.
CLOCK = '/clock'

# The truth of a synthetic trial (bags made by `nmt reference`).
TRUTH_SEGMENT_ANGLES = '/truth/segment_angles'
TRUTH_GENERALIZED_COORDINATES = '/truth/generalized_coordinates'
TRUTH_JOINT_TORQUES = '/truth/joint_torques'
TRUTH_GROUND_WRENCH = '/truth/ground_wrench'
TRUTH_MUSCLE_FORCES = '/truth/muscle_forces'
TRUTH_MUSCLE_ACTIVATIONS = '/truth/muscle_activations'
TRUTH_MUSCLE_EXCITATIONS = '/truth/muscle_excitations'
TRUTH_MOCAP_BIAS = '/truth/mocap_bias'
TRUTH_FORCE_PLATE_BIAS = '/truth/force_plate_bias'
# ... and of a routine (`nmt routine`; io/routine_bag.py says what each carries).
TRUTH_CONTACT_ANCHORS = '/truth/contact_anchors'
TRUTH_FORCE_PLATE_DRIFT = '/truth/force_plate_drift'
TRUTH_FORCE_PLATE_SPIKES = '/truth/force_plate_spikes'
TRUTH_MOCAP_SPIKES = '/truth/mocap_spikes'
TRUTH_MOCAP_DROPOUTS = '/truth/mocap_dropouts'
TRUTH_FORCE_PLATE_DROPOUTS = '/truth/force_plate_dropouts'
