"""The body description (study/body_scene.py) against the model's own kinematics and paths,
and the movie (study/body_movie.py) drawn from it."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from nmt_ros.model.jumper import default_model
from nmt_ros.model.muscle_geometry import load_muscle_geometry
from nmt_ros.model.parameters import MUSCLES, load_parameters
from nmt_ros.osim.path_points import path_points
from nmt_ros.study.body_scene import (
    GRF_SCALE_M_PER_BW,
    BodyDescription,
    center_of_pressure_x,
    muscle_color,
    muscle_width_m,
)


@pytest.fixture(scope='module')
def body() -> BodyDescription:
    return BodyDescription()


def random_states(n: int, seed: int = 0) -> np.ndarray:
    """Segment angles inside the path fit's range (hip -20..120, knee -120..5, ankle
    -50..45 deg), ankle centre anywhere."""
    rng = np.random.default_rng(seed)
    hat = rng.uniform(-0.6, 0.3, n)
    hip = np.radians(rng.uniform(-15, 115, n))
    knee = np.radians(rng.uniform(-115, 0, n))
    ankle = np.radians(rng.uniform(-45, 40, n))
    thigh = hat + hip
    shank = thigh + knee
    foot = shank + ankle
    return np.column_stack([foot, shank, thigh, hat, rng.uniform(-1, 1, n),
                            rng.uniform(0.0, 0.6, n)])


def test_stick_figure_is_the_models_kinematics(body: BodyDescription) -> None:
    model = default_model()
    q = random_states(50)
    poses = body.poses(q)
    for qi, pose in zip(q, poses):
        ankle, knee, hip, coms, contacts, com = model.call(model.positions, qi)
        np.testing.assert_allclose(pose.joints['ankle'], qi[4:6], atol=1e-12)
        np.testing.assert_allclose(pose.joints['knee'], knee, atol=1e-12)
        np.testing.assert_allclose(pose.joints['hip'], hip, atol=1e-12)
        np.testing.assert_allclose(pose.contact_points, np.asarray(contacts).T, atol=1e-12)
        np.testing.assert_allclose(pose.com, com, atol=1e-12)
        # foot: heel, ankle, toe, heel; shank knee->ankle; thigh hip->knee
        heel, toe = np.asarray(contacts).T
        np.testing.assert_allclose(pose.segments['foot'], [heel, qi[4:6], toe, heel],
                                   atol=1e-12)
        np.testing.assert_allclose(pose.segments['shank'], [knee, qi[4:6]], atol=1e-12)
        np.testing.assert_allclose(pose.segments['thigh'], [hip, knee], atol=1e-12)
        # the shank is 0.43 m long whatever the pose (a rigid segment)
        assert np.hypot(*(knee - qi[4:6])) == pytest.approx(0.43, abs=1e-12)


def test_toe_and_heel_by_hand(body: BodyDescription) -> None:
    """Upright foot on the ground: heel and toe where the data file puts them."""
    p = load_parameters()
    q = np.array([0.0, 0.0, 0.0, 0.0, 0.2, default_model().ankle_height])
    pose = body.pose(q)
    np.testing.assert_allclose(pose.contact_points,
                               np.array([0.2, q[5]]) + p.contact.points, atol=1e-12)
    assert pose.contact_points[:, 1] == pytest.approx([0.0, 0.0], abs=1e-12)
    # rotate the foot by 90 deg about the ankle: the toe (x, y) goes to (-y, x)
    q[0] = np.pi / 2
    toe = body.pose(q).contact_points[1] - q[4:6]
    np.testing.assert_allclose(toe, [-p.contact.points[1, 1], p.contact.points[1, 0]],
                               atol=1e-12)


def test_paths_have_the_models_musculotendon_lengths(body: BodyDescription) -> None:
    """The drawn paths are the geometry the length polynomials were fitted to (OpenSim's
    GeometryPath): their 3-D lengths equal the model's l_MT within the fit's error (RMS
    < 0.1 mm, worst 0.25 mm) over the fit's range, for every muscle; the knee's translation
    counts (up to 22 mm of it)."""
    model = default_model()
    q = random_states(300, seed=1)
    theta = model.batch(model.joint_angles, q)[0]
    lmt = model.batch(model.musculotendon_lengths, theta)[0]
    err = body.path_lengths(q) - lmt
    assert np.abs(err).max() < 5e-4
    assert np.sqrt(np.mean(err ** 2, axis=0)).max() < 1.5e-4
    # without the knee's translation the knee-crossing paths are centimetres off
    pinned = BodyDescription(geometry=replace(body.geometry, knee=None))
    assert np.abs(pinned.path_lengths(q) - lmt).max() > 0.01


def test_conditional_point_switches_with_its_coordinate(body: BodyDescription) -> None:
    """The iliopsoas's pelvis point (psoas_r-P3) is on the path for hip flexion <= 45 deg."""
    q = np.zeros((2, 6))
    q[:, 5] = 1.0
    q[1, 2] = np.radians(60.0)                 # thigh forward: hip flexion 60 deg
    xyz, active = body.muscle_paths_3d(q)['ilpso']
    assert active[0].tolist() == [True, True, True, True, True]
    assert active[1].tolist() == [True, True, False, True, True]
    poses = body.poses(q)
    assert [len(m.points) for m in poses[0].muscles if m.name == 'ilpso'] == [5]
    assert [len(m.points) for m in poses[1].muscles if m.name == 'ilpso'] == [4]


def test_path_points_come_from_the_osim_file() -> None:
    """The data file holds what the generator reads from gait10dof18musc.osim now."""
    fresh = path_points()
    geometry = load_muscle_geometry()
    for name in MUSCLES:
        assert len(geometry.points[name]) == len(fresh[name])
        for point, entry in zip(geometry.points[name], fresh[name]):
            assert point.segment == entry['segment']
            if 'xyz' in entry:
                np.testing.assert_allclose(point.xyz, entry['xyz'], atol=1e-12)


def test_center_of_pressure_of_a_point_force() -> None:
    """A force applied at (x, 0) written as a wrench about the foot COM: the COP is x."""
    rng = np.random.default_rng(3)
    n = 100
    c = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(0.02, 0.1, n)])
    x = rng.uniform(-1, 1, n)
    f = np.column_stack([rng.uniform(-300, 300, n), rng.uniform(50, 3000, n)])
    moment = (x - c[:, 0]) * f[:, 1] - (0.0 - c[:, 1]) * f[:, 0]      # (p - c) x F
    np.testing.assert_allclose(center_of_pressure_x(c, np.column_stack([f, moment])), x,
                               atol=1e-12)
    unloaded = np.column_stack([f[:, 0], np.full(n, 5.0), moment])
    assert np.isnan(center_of_pressure_x(c, unloaded)).all()


def test_ground_force_arrow_and_muscle_forces(body: BodyDescription) -> None:
    model = default_model()
    q = np.array([0.0, -0.4, 0.7, -0.5, 0.1, model.ankle_height])
    foot_com = np.asarray(model.call(model.positions, q)[3])[:, 0]
    f = np.array([40.0, 900.0])
    x_cop = 0.15
    moment = (x_cop - foot_com[0]) * f[1] + foot_com[1] * f[0]
    forces = body.f0 * np.linspace(0.0, 1.2, 9)
    pose = body.pose(q, forces, np.array([f[0], f[1], moment]))
    np.testing.assert_allclose(pose.cop, [x_cop, 0.0], atol=1e-12)
    np.testing.assert_allclose(pose.grf_tip - pose.cop,
                               f * GRF_SCALE_M_PER_BW / model.p.body_weight, atol=1e-12)
    np.testing.assert_allclose([m.force_n for m in pose.muscles], forces)
    np.testing.assert_allclose([m.fraction for m in pose.muscles], np.linspace(0, 1.2, 9))
    widths = [m.width_m for m in pose.muscles]
    assert widths == sorted(widths) and widths[-1] == widths[-2] == muscle_width_m(1.0)
    np.testing.assert_allclose(pose.muscles[0].color, muscle_color(0.0))
    # unknown forces and wrench: drawn idle, no arrow
    idle = body.pose(q)
    assert idle.cop is None and idle.ground_force is None
    assert all(np.isnan(m.force_n) for m in idle.muscles)


def test_bad_shapes_are_refused(body: BodyDescription) -> None:
    with pytest.raises(ValueError, match='6 columns'):
        body.poses(np.zeros((3, 5)))
    with pytest.raises(ValueError, match='forces must be'):
        body.poses(np.zeros((3, 6)), forces=np.zeros((3, 8)))
