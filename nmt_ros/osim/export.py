"""Write the jumper model as an OpenSim 4 model (.osim), from the model data file alone.

    python -m nmt_ros.osim.export --out jumper.osim [--with-contact-spheres]

Bodies foot, shank, thigh, hat with the data file's masses, COMs and Izz (about the COM;
Ixx = Iyy = Izz, irrelevant in the plane). Body frames are the data file's segment frames:
foot origin at the ankle centre, shank origin at the knee centre, thigh and hat origins at
the hip centre.

The tree is foot -> shank -> thigh -> hat, the foot being the root:

- ``ground_foot``: PlanarJoint, coordinates ``foot_tilt`` (= th1, absolute foot angle),
  ``foot_tx``, ``foot_ty`` (= ankle centre in ground, r1 and r2).
- ``ankle`` (foot -> shank), ``knee`` (shank -> thigh), ``hip`` (thigh -> hat): CustomJoints
  with one rotation whose coordinates are exactly OpenSim's gait10dof18musc coordinates
  ``ankle_angle`` = th1 - th2 (+dorsiflexion), ``knee_angle`` = th2 - th3 (-flexion),
  ``hip_flexion`` = th3 - th4 (+flexion). Because the tree runs distal to proximal (the
  reverse of gait10dof18musc's pelvis-rooted tree) the child turns by minus the coordinate
  relative to its parent, hence the rotation axis (0, 0, -1).

Muscles: DeGrooteFregly2016Muscle with rigid tendons (``ignore_tendon_compliance``) named as
in the data file (gmax ... ta), F0 = one-leg F0 x legs x strength_scale; path =
FunctionBasedPath whose length function is the data file's fitted polynomial as an OpenSim
MultivariatePolynomialFunction (moment arms = -dl/dq, which FunctionBasedPath takes from the
function's analytic first derivative). Note that OpenSim's own activation dynamics (tanh
blend, ``activation_dynamics_smoothing``) is not our affine Zajac form: cross-checks set the
activation directly.

Passive joint torques: ExpressionBasedCoordinateForce on each joint coordinate, the data
file's formula legs * (k1 exp(k2 (q - theta_upper)) + k3 exp(k4 (q - theta_lower)) - b qdot).

Contact: our contact law (smoothed springs with an anchored horizontal spring) has no exact
OpenSim element, so none is added; cross-checks apply our contact forces as ExternalLoads.
``--with-contact-spheres`` adds APPROXIMATE SmoothSphereHalfSpaceForces (2D_gait.osim
parameters, radius 0.03 m, lowest sphere points at the data file's heel and toe points) for
visualisation or Moco experiments only; they do not reproduce our contact forces.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys

import numpy as np
import opensim as osim

from nmt_ros.osim.fit_paths import quiet_opensim, to_opensim_function
from nmt_ros.osim.modeldata import (
    DATA_FILE,
    JOINT_COORDINATES,
    MUSCLES,
    load_model_data,
    muscle_paths,
)

MODEL_NAME = 'nmt_ros_jumper'
SEGMENTS = ('foot', 'shank', 'thigh', 'hat')
# joint name -> (parent body, child body, coordinate)
JOINTS = {
    'ankle': ('foot', 'shank', 'ankle_angle'),
    'knee': ('shank', 'thigh', 'knee_angle'),
    'hip': ('thigh', 'hat', 'hip_flexion'),
}
COORDINATE_PATHS = {
    'foot_tilt': '/jointset/ground_foot/foot_tilt',
    'foot_tx': '/jointset/ground_foot/foot_tx',
    'foot_ty': '/jointset/ground_foot/foot_ty',
    'ankle_angle': '/jointset/ankle/ankle_angle',
    'knee_angle': '/jointset/knee/knee_angle',
    'hip_flexion': '/jointset/hip/hip_flexion',
}
# Coordinate ranges (deg), informative only (not clamped): the path-fitting ranges.
JOINT_RANGES_DEG = {'ankle_angle': (-50.0, 45.0), 'knee_angle': (-120.0, 5.0),
                    'hip_flexion': (-20.0, 120.0)}
# Approximate contact spheres (--with-contact-spheres): 2D_gait.osim's smooth-sphere values.
SPHERE_RADIUS = 0.03
SPHERE_PARAMETERS = {'stiffness': 3067776.0, 'dissipation': 2.0, 'static_friction': 0.8,
                     'dynamic_friction': 0.8, 'viscous_friction': 0.5,
                     'transition_velocity': 0.2}


def _vec3(xy: object, z: float = 0.0) -> osim.Vec3:
    x, y = (float(v) for v in xy)
    return osim.Vec3(x, y, z)


def _one_rotation_joint(name: str, parent: osim.PhysicalFrame, location_in_parent: osim.Vec3,
                        child: osim.PhysicalFrame, location_in_child: osim.Vec3,
                        coordinate: str) -> osim.CustomJoint:
    """CustomJoint: child rotates by -coordinate about z relative to parent."""
    st = osim.SpatialTransform()
    axes = [(0, 0, -1), (1, 0, 0), (0, 1, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
    for i, axis in enumerate(axes):
        ta = st.updTransformAxis(i)
        ta.setAxis(osim.Vec3(*axis))
        if i == 0:
            names = osim.ArrayStr()
            names.append(coordinate)
            ta.setCoordinateNames(names)
            ta.set_function(osim.LinearFunction(1.0, 0.0))
        else:
            ta.set_function(osim.Constant(0.0))
    zero = osim.Vec3(0.0, 0.0, 0.0)
    joint = osim.CustomJoint(name, parent, location_in_parent, zero, child, location_in_child,
                             zero, st)
    return joint


def _passive_expression(k: list[float], theta_lower: float, theta_upper: float,
                        damping: float, legs: int) -> str:
    k1, k2, k3, k4 = (repr(float(v)) for v in k)
    return (f'{legs}*({k1}*exp({k2}*(q-({theta_upper!r})))'
            f'+{k3}*exp({k4}*(q-({theta_lower!r})))-{damping!r}*qdot)')


def build_model(data: dict | None = None, with_contact_spheres: bool = False) -> osim.Model:
    """The jumper as an osim.Model (initSystem() already called)."""
    data = data if data is not None else load_model_data()
    model = osim.Model()
    model.setName(MODEL_NAME)
    model.setGravity(osim.Vec3(0.0, -float(data['gravity']['value']), 0.0))

    seg = data['segments']
    bodies = {}
    for name in SEGMENTS:
        s = seg[name]
        izz = float(s['izz'])
        body = osim.Body(name, float(s['mass']), _vec3(s['com']),
                         osim.Inertia(izz, izz, izz, 0.0, 0.0, 0.0))
        model.addBody(body)
        bodies[name] = body

    ground = model.getGround()
    root = osim.PlanarJoint('ground_foot', ground, osim.Vec3(0.0, 0.0, 0.0),
                            osim.Vec3(0.0, 0.0, 0.0), bodies['foot'],
                            osim.Vec3(0.0, 0.0, 0.0), osim.Vec3(0.0, 0.0, 0.0))
    for which, name in ((osim.PlanarJoint.Coord_RotationZ, 'foot_tilt'),
                        (osim.PlanarJoint.Coord_TranslationX, 'foot_tx'),
                        (osim.PlanarJoint.Coord_TranslationY, 'foot_ty')):
        root.updCoordinate(which).setName(name)
    # Default pose: upright, heel and toe points on the floor.
    lowest = min(float(y) for _, y in data['contact']['points']['positions'])
    root.updCoordinate(osim.PlanarJoint.Coord_TranslationY).setDefaultValue(-lowest)
    model.addJoint(root)

    # Joint centres: the parent's frame origin is the joint; in the child it is the child's
    # distal joint (the data file gives it in the segment's own frame).
    locations = {
        'ankle': (osim.Vec3(0, 0, 0), _vec3(seg['shank']['distal_joint'])),
        'knee': (osim.Vec3(0, 0, 0), _vec3(seg['thigh']['distal_joint'])),
        'hip': (osim.Vec3(0, 0, 0), osim.Vec3(0, 0, 0)),
    }
    for jname, (parent, child, coord) in JOINTS.items():
        in_parent, in_child = locations[jname]
        joint = _one_rotation_joint(jname, bodies[parent], in_parent, bodies[child], in_child,
                                    coord)
        model.addJoint(joint)
    model.finalizeFromProperties()
    for coord, (lo, hi) in JOINT_RANGES_DEG.items():
        c = model.updCoordinateSet().get(coord)
        c.setRangeMin(float(np.radians(lo)))
        c.setRangeMax(float(np.radians(hi)))
        c.setDefaultValue(0.0)

    # Passive joint torques.
    pj = data['passive_joints']
    legs = int(pj['legs'])
    for coord in JOINT_COORDINATES:
        p = pj[coord]
        force = osim.ExpressionBasedCoordinateForce(
            coord, _passive_expression(p['k'], float(p['theta_lower']),
                                       float(p['theta_upper']), float(pj['damping']), legs))
        force.setName(f'passive_{coord}')
        model.addForce(force)

    # Muscles with polynomial paths.
    m = data['muscles']
    if tuple(m['names']) != MUSCLES:
        raise ValueError(f'muscles must be {MUSCLES}')
    scale = float(m['strength_scale'])
    mlegs = int(m['legs'])
    paths = muscle_paths(data)
    for i, name in enumerate(MUSCLES):
        mus = osim.DeGrooteFregly2016Muscle()
        mus.setName(name)
        mus.set_max_isometric_force(float(m['max_isometric_force_one_leg'][i]) * mlegs * scale)
        mus.set_optimal_fiber_length(float(m['optimal_fiber_length'][i]))
        mus.set_tendon_slack_length(float(m['tendon_slack_length'][i]))
        mus.set_pennation_angle_at_optimal(float(m['pennation_at_optimal'][i]))
        mus.set_max_contraction_velocity(float(m['max_contraction_velocity']))
        mus.set_fiber_damping(float(m['fiber_damping']))
        mus.set_passive_fiber_strain_at_one_norm_force(
            float(m['passive_fiber_strain_at_one_norm_force']))
        mus.set_ignore_tendon_compliance(True)
        mus.set_activation_time_constant(float(m['activation_time_constant']))
        mus.set_deactivation_time_constant(float(m['deactivation_time_constant']))
        coords, exps, coefs = paths[name]
        fbp = osim.FunctionBasedPath()
        fbp.setName('path')
        cpaths = osim.StdVectorString()
        for c in coords:
            cpaths.append(COORDINATE_PATHS[c])
        fbp.setCoordinatePaths(cpaths)
        fbp.setLengthFunction(to_opensim_function(exps, coefs))
        mus.set_path(fbp)
        model.addForce(mus)

    if with_contact_spheres:
        add_contact_spheres(model, data)

    model.finalizeConnections()
    model.initSystem()
    return model


def add_contact_spheres(model: osim.Model, data: dict) -> None:
    """APPROXIMATE foot-ground contact (see module docstring): one smooth sphere per point."""
    floor = osim.ContactHalfSpace(osim.Vec3(0, 0, 0), osim.Vec3(0, 0, -np.pi / 2),
                                  model.getGround(), 'floor')
    model.addContactGeometry(floor)
    foot = model.getBodySet().get('foot')
    c = data['contact']['points']
    for name, (x, y) in zip(c['names'], c['positions']):
        sphere = osim.ContactSphere(SPHERE_RADIUS, osim.Vec3(float(x), float(y) + SPHERE_RADIUS,
                                                             0.0), foot, f'{name}_sphere')
        model.addContactGeometry(sphere)
        force = osim.SmoothSphereHalfSpaceForce(f'contact_{name}', sphere, floor)
        for key, value in SPHERE_PARAMETERS.items():
            getattr(force, f'set_{key}')(value)
        model.addForce(force)


def export_osim(path: str | Path, with_contact_spheres: bool = False,
                data_file: str | Path | None = None) -> Path:
    """Write the jumper model to ``path`` (.osim); returns the path."""
    path = Path(path)
    model = build_model(load_model_data(data_file if data_file else DATA_FILE),
                        with_contact_spheres)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not model.printToXML(str(path)):
        raise RuntimeError(f'OpenSim could not write {path}')
    return path


def probe_model(path: str | Path, n: int = 10, seed: int = 0) -> dict:
    """What OpenSim computes with an exported model at n random poses (for tests).

    Returns plain lists: coordinate names and values, each body's angle and origin in ground
    and its mass properties, muscle properties, lengths, lengthening speeds and moment arms
    about every coordinate, and the passive joint generalized forces.
    """
    model = osim.Model(str(path))
    state = model.initSystem()
    coords = [model.getCoordinateSet().get(i) for i in range(model.getNumCoordinates())]
    names = [c.getName() for c in coords]
    rng = np.random.default_rng(seed)
    out: dict = {'coordinates': names, 'gravity': [model.getGravity()[i] for i in range(3)],
                 'bodies': {}, 'muscles': {}, 'poses': [],
                 'forces': {f.getName(): f.getConcreteClassName() for f in model.getForceSet()}}
    for body in model.getBodySet():
        inertia = body.getInertia().getMoments()
        out['bodies'][body.getName()] = {
            'mass': body.getMass(), 'com': [body.getMassCenter()[i] for i in range(3)],
            'inertia': [inertia[i] for i in range(3)]}
    muscles = [model.getMuscles().get(i) for i in range(model.getMuscles().getSize())]
    for mus in muscles:
        dg = osim.DeGrooteFregly2016Muscle.safeDownCast(mus)
        out['muscles'][mus.getName()] = {
            'class': mus.getConcreteClassName(),
            'path_class': mus.getPath().getConcreteClassName(),
            'max_isometric_force': mus.getMaxIsometricForce(),
            'optimal_fiber_length': mus.getOptimalFiberLength(),
            'tendon_slack_length': mus.getTendonSlackLength(),
            'pennation_angle_at_optimal': mus.getPennationAngleAtOptimalFiberLength(),
            'max_contraction_velocity': mus.getMaxContractionVelocity(),
            'ignore_tendon_compliance': bool(mus.get_ignore_tendon_compliance()),
            'fiber_damping': dg.get_fiber_damping(),
            'passive_fiber_strain_at_one_norm_force':
                dg.get_passive_fiber_strain_at_one_norm_force(),
            'activation_time_constant': dg.get_activation_time_constant(),
            'deactivation_time_constant': dg.get_deactivation_time_constant()}
    passive = {f.getName(): osim.ExpressionBasedCoordinateForce.safeDownCast(f)
               for f in model.getForceSet()
               if f.getConcreteClassName() == 'ExpressionBasedCoordinateForce'}
    for _ in range(n):
        lo = np.array([max(c.getRangeMin(), -1.0) for c in coords])
        hi = np.array([min(c.getRangeMax(), 1.0) for c in coords])
        q = rng.uniform(lo, hi)
        qd = rng.uniform(-2.0, 2.0, len(names))
        for c, v, vd in zip(coords, q, qd):
            c.setValue(state, float(v), False)
            c.setSpeedValue(state, float(vd))
        model.realizeVelocity(state)
        pose = {'q': q.tolist(), 'qdot': qd.tolist(), 'bodies': {}, 'length': {},
                'lengthening_speed': {}, 'moment_arm': {}, 'passive': {}}
        for body in model.getBodySet():
            tf = body.getTransformInGround(state)
            angles = tf.R().convertRotationToBodyFixedXYZ()
            pose['bodies'][body.getName()] = {
                'angles_xyz': [angles[i] for i in range(3)],
                'origin': [tf.p()[i] for i in range(3)]}
        for mus in muscles:
            pose['length'][mus.getName()] = mus.getLength(state)
            pose['lengthening_speed'][mus.getName()] = mus.getLengtheningSpeed(state)
            pose['moment_arm'][mus.getName()] = [mus.computeMomentArm(state, c) for c in coords]
        for name, f in passive.items():
            pose['passive'][name] = f.calcExpressionForce(state)
        out['poses'].append(pose)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m nmt_ros.osim.export',
                                     description='Write the jumper as an OpenSim 4 model.')
    parser.add_argument('--out', type=Path, help='output .osim file')
    parser.add_argument('--with-contact-spheres', action='store_true',
                        help='add approximate smooth contact spheres at heel and toe')
    parser.add_argument('--data-file', type=Path, default=DATA_FILE)
    parser.add_argument('--probe', type=Path, metavar='MODEL',
                        help='print (JSON) what OpenSim computes with MODEL at random poses')
    parser.add_argument('--poses', type=int, default=10, help='number of poses for --probe')
    args = parser.parse_args(argv)
    quiet_opensim()
    if args.probe:
        json.dump(probe_model(args.probe, args.poses), sys.stdout)
        sys.stdout.write('\n')
        return 0
    if not args.out:
        parser.error('--out is required')
    out = export_osim(args.out, args.with_contact_spheres, args.data_file)
    print(f'wrote {out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
