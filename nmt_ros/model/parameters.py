"""Model parameters: the one data file (``data/jumper.yaml``) as typed, immutable records.

Every number of the jumper model lives in the data file, next to its source. This module only
reads it, doubles one-leg values for the two-leg lump, and derives nothing else.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

DATA_FILE = Path(__file__).resolve().parent / 'data' / 'jumper.yaml'

SEGMENTS = ('foot', 'shank', 'thigh', 'hat')
JOINTS = ('ankle', 'knee', 'hip')
#: OpenSim coordinate names of the joints (gait10dof18musc names and signs).
JOINT_COORDINATES = ('ankle_angle', 'knee_angle', 'hip_flexion')
MUSCLES = ('gmax', 'ilpso', 'hams', 'bfsh', 'rf', 'vas', 'gas', 'sol', 'ta')
#: Names of the generalized coordinates q.
Q_NAMES = ('th1', 'th2', 'th3', 'th4', 'r1', 'r2')


@dataclass(frozen=True)
class Segment:
    """Rigid segment: mass [kg], Izz about the COM [kg m^2], COM in the segment frame [m]."""

    name: str
    mass: float
    izz: float
    com: np.ndarray
    distal_joint: np.ndarray | None = None


@dataclass(frozen=True)
class ContactParameters:
    """Heel/toe point-contact law (see contact.py); points [2, 2] in the foot frame [m]."""

    point_names: tuple[str, ...]
    points: np.ndarray
    k_y: float
    delta: float
    c_hc: float
    damping_smoothing: float
    k_x: float
    c_x: float
    mu: float
    f_eps: float


@dataclass(frozen=True)
class PassiveJointParameters:
    """Double-exponential ligament torques per joint, already scaled for two legs."""

    k: np.ndarray            # [3 joints, 4]
    theta_lower: np.ndarray  # [3] rad
    theta_upper: np.ndarray  # [3] rad
    damping: np.ndarray      # [3] N m s/rad (two legs)
    legs: int


@dataclass(frozen=True)
class MusclePath:
    """l_MT = sum_k c_k prod_j q_j ** e_kj over the OpenSim coordinates in ``coordinates``."""

    coordinates: tuple[str, ...]
    exponents: np.ndarray      # [n_terms, n_coordinates] int
    coefficients: np.ndarray   # [n_terms]
    # [n_coordinates, 2] rad: where the polynomial is used (data file ``path_ranges_deg``;
    # None: everywhere); beyond, the path is continued linearly (``paths.guarded_polynomial``)
    fit_range: np.ndarray | None = None


@dataclass(frozen=True)
class MuscleParameters:
    """Two-leg musculotendon parameters, arrays of length 9 in ``MUSCLES`` order."""

    names: tuple[str, ...]
    opensim_names: tuple[str, ...]
    f0: np.ndarray               # N, two legs, strength-scaled
    l_opt: np.ndarray            # m
    l_slack: np.ndarray          # m
    alpha_opt: np.ndarray        # rad
    v_max: float                 # optimal fibre lengths per second
    fiber_damping: float
    passive_strain: float
    tau_act: float               # s
    tau_deact: float             # s
    paths: dict[str, MusclePath] = field(default_factory=dict)


@dataclass(frozen=True)
class JumperParameters:
    """All numbers of the jumper model (two legs lumped)."""

    gravity: float
    segments: dict[str, Segment]
    contact: ContactParameters
    passive: PassiveJointParameters
    muscles: MuscleParameters
    source_file: Path

    @property
    def total_mass(self) -> float:
        return float(sum(s.mass for s in self.segments.values()))

    @property
    def body_weight(self) -> float:
        """Body weight [N]."""
        return self.total_mass * self.gravity


def _vec(x: object) -> np.ndarray:
    return np.asarray(x, dtype=float)


def load_parameters(path: str | Path | None = None, **overrides: float) -> JumperParameters:
    """Read the model data file; ``overrides`` may set ``strength_scale``."""
    path = Path(path) if path is not None else DATA_FILE
    with open(path) as f:
        d = yaml.safe_load(f)

    segs = {}
    for name in SEGMENTS:
        s = d['segments'][name]
        segs[name] = Segment(
            name=name, mass=float(s['mass']), izz=float(s['izz']), com=_vec(s['com']),
            distal_joint=_vec(s['distal_joint']) if 'distal_joint' in s else None)

    c = d['contact']
    contact = ContactParameters(
        point_names=tuple(c['points']['names']), points=_vec(c['points']['positions']),
        k_y=float(c['k_y']), delta=float(c['delta']), c_hc=float(c['c_hc']),
        damping_smoothing=float(c['damping_smoothing']), k_x=float(c['k_x']),
        c_x=float(c['c_x']), mu=float(c['mu']), f_eps=float(c['f_eps']))

    pj = d['passive_joints']
    legs = int(pj['legs'])
    passive = PassiveJointParameters(
        k=np.array([pj[j]['k'] for j in JOINT_COORDINATES], dtype=float),
        theta_lower=_vec([pj[j]['theta_lower'] for j in JOINT_COORDINATES]),
        theta_upper=_vec([pj[j]['theta_upper'] for j in JOINT_COORDINATES]),
        damping=np.full(3, float(pj['damping'])) * legs, legs=legs)

    m = d['muscles']
    if tuple(m['names']) != MUSCLES:
        raise ValueError(f'{path}: muscles must be {MUSCLES}, got {m["names"]}')
    scale = float(overrides.get('strength_scale', m['strength_scale']))
    ranges = d.get('path_ranges_deg') or {}
    paths = {}
    for name, p in (d.get('paths') or {}).items():
        if name == 'source':
            continue
        paths[name] = MusclePath(
            coordinates=tuple(p['coordinates']),
            exponents=np.asarray(p['exponents'], dtype=int).reshape(-1, len(p['coordinates'])),
            coefficients=_vec(p['coefficients']),
            fit_range=(np.radians([ranges[c] for c in p['coordinates']])
                       if all(c in ranges for c in p['coordinates']) else None))
    muscles = MuscleParameters(
        names=MUSCLES, opensim_names=tuple(m['opensim_names']),
        f0=_vec(m['max_isometric_force_one_leg']) * int(m['legs']) * scale,
        l_opt=_vec(m['optimal_fiber_length']), l_slack=_vec(m['tendon_slack_length']),
        alpha_opt=_vec(m['pennation_at_optimal']),
        v_max=float(m['max_contraction_velocity']), fiber_damping=float(m['fiber_damping']),
        passive_strain=float(m['passive_fiber_strain_at_one_norm_force']),
        tau_act=float(m['activation_time_constant']),
        tau_deact=float(m['deactivation_time_constant']), paths=paths)

    return JumperParameters(
        gravity=float(d['gravity']['value']), segments=segs, contact=contact,
        passive=passive, muscles=muscles, source_file=path)


def parameters_data(params: JumperParameters) -> dict:
    """The model data file's content for ``params`` (e.g. a subject-scaled jumper): the file
    ``params`` came from, with every number :func:`load_parameters` reads replaced by the
    record's (so ``load_parameters`` of it gives ``params`` back; the sources are kept)."""
    with open(params.source_file) as f:
        d = yaml.safe_load(f)
    for name, s in params.segments.items():
        seg = d['segments'][name]
        seg['mass'] = float(s.mass)
        seg['izz'] = float(s.izz)
        seg['com'] = [float(v) for v in s.com]
        if s.distal_joint is not None:
            seg['distal_joint'] = [float(v) for v in s.distal_joint]
    c, dc = params.contact, d['contact']
    dc['points']['positions'] = [[float(v) for v in row] for row in c.points]
    for key in ('k_y', 'delta', 'c_hc', 'damping_smoothing', 'k_x', 'c_x', 'mu', 'f_eps'):
        dc[key] = float(getattr(c, key))
    pj, dp = params.passive, d['passive_joints']
    for i, j in enumerate(JOINT_COORDINATES):
        dp[j]['k'] = [float(v) for v in pj.k[i]]
        dp[j]['theta_lower'] = float(pj.theta_lower[i])
        dp[j]['theta_upper'] = float(pj.theta_upper[i])
    if not np.allclose(pj.damping, pj.damping[0]):
        raise ValueError('the data file has one passive damping for all joints')
    dp['damping'] = float(pj.damping[0] / int(dp['legs']))
    m, dm = params.muscles, d['muscles']
    per_leg = int(dm['legs']) * float(dm['strength_scale'])
    dm['max_isometric_force_one_leg'] = [float(v) for v in m.f0 / per_leg]
    dm['optimal_fiber_length'] = [float(v) for v in m.l_opt]
    dm['tendon_slack_length'] = [float(v) for v in m.l_slack]
    for name, path in m.paths.items():     # a subject's own path may have other terms
        d['paths'][name]['exponents'] = [[int(e) for e in row] for row in path.exponents]
        d['paths'][name]['coefficients'] = [float(v) for v in path.coefficients]
    d['gravity']['value'] = float(params.gravity)
    return d
