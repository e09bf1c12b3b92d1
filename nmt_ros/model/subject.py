"""Subject models: the jumper (``data/jumper.yaml``) scaled to a subject.

A :class:`Subject` holds what is measured of a person (from a scaled OpenSim model by
``python -m nmt_ros.osim.subject measure``, or from body mass and stature alone), and
:func:`scale_factors` turns it into a :class:`SubjectScale` by the rules of
``data/subject_scaling.yaml``:

* segment mass factor ``k_m,s`` = subject segment mass / jumper segment mass (two legs lumped as
  the jumper lumps them; with mass and height only, every segment takes ``M / M_jumper``);
* segment length factor ``k_l,s`` = subject joint-centre distance / the jumper's (thigh, shank,
  foot; the HAT takes the leg's mean; with mass and height only, ``H / 1.80 m``);
* inertial parameters: ``m' = k_m m``, COM and joint offsets ``k_l r``, ``Izz' = k_m k_l^2 Izz``;
  contact points scale with the foot, the contact stiffness and horizontal damping with the
  body mass (same static sinkage per unit weight);
* musculotendon paths: ``l_MT'(theta) = k_mus l_MT(theta)`` (so moment arms ``k_mus r``), with
  ``k_mus`` the mean length factor of the segments the muscle runs along; ``l_opt`` and
  ``l_slack`` scale alike (normalised fibre lengths unchanged at every pose);
* strength: ``F0' = F0 (M / M_jumper) ** (2/3)``; passive joint torques by that factor times the
  leg's length factor; with the subject's own .osim, its muscles' strengths instead (below);
* with the subject's own .osim (Rajagopal, gait2392 or gait10dof18musc muscle names), the
  paths of ``subject_paths`` take its muscles' moment arms (:func:`paths_from_moment_arms`):
  the lumped path keeps the scaled jumper's length at the zero pose and its gradient is
  fitted to the F0-weighted mean moment arms of the muscles it lumps (``SubjectScale.paths``,
  stored in ``subject.yaml``), and its F0 and l_opt are theirs (:func:`strengths_from_moment_arms`:
  F0 the members' sum for two legs, l_opt their F0-weighted mean; l_slack moves so that the
  normalised fibre length at the zero pose stays the scaled jumper's). Geometry and strength
  from one model: moment arms from the subject's model with the jumper's fibres would set
  the fibres' normalised speeds per rad/s by the ratio of two models' numbers.
* joint ranges: where the subject's .osim clamps a joint coordinate to a range narrower than
  the jumper's passive joint limits, the passive torque's onset moves to the range's end
  (``SubjectScale.joint_range_rad``; :func:`joint_ranges_from_moment_arms`). The angles the
  lab's IK gives never leave that range (OpenCap's knee stops at 0 deg, the jumper's
  passive knee only at 7.4 deg of hyperextension): without it the real drop jump's estimate
  hyperextended the knee 10-15 deg after the take-off, where the IK's knee stopped at 0.
  And the other way: where a recording reaches so far past a passive limit that the limit
  would carry more than 2 N m/kg there (Subject4's 50 deg of dorsiflexion against the
  jumper's 30-deg wall), that limit's onset moves out to the angles reached
  (``SubjectScale.reached_range_rad``, :func:`reached_joint_ranges`,
  :data:`REACH_WALL_N_M_PER_KG`).

A bag of a lab recording stores its subject as ``BAG/subject.yaml`` (:func:`write_subject`);
:func:`load_subject_model` builds the :class:`~nmt_ros.model.jumper.JumperModel` of a bag (the
shipped jumper when the bag has no subject file).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
import os
from pathlib import Path

import numpy as np
import yaml

from nmt_ros.model.parameters import (
    JOINT_COORDINATES,
    MUSCLES,
    SEGMENTS,
    JumperParameters,
    MusclePath,
    load_parameters,
)

SCALING_FILE = Path(__file__).resolve().parent / 'data' / 'subject_scaling.yaml'
SUBJECT_FILE = 'subject.yaml'
LEG_SEGMENTS = ('thigh', 'shank', 'foot')


def load_rules(path: str | Path | None = None) -> dict:
    """The scaling rules' data file (``data/subject_scaling.yaml``)."""
    with open(path or SCALING_FILE) as f:
        return yaml.safe_load(f)


@dataclass(frozen=True)
class Subject:
    """A person's measures: masses [kg] (two legs lumped), one leg's segment lengths [m]."""

    name: str
    mass_kg: float
    segment_masses_kg: dict[str, float]
    segment_lengths_m: dict[str, float]
    height_m: float | None = None
    source: str = ''


@dataclass(frozen=True)
class SubjectScale:
    """Scale factors applied to the jumper (dimensionless)."""

    mass: dict[str, float]            # per segment
    length: dict[str, float]          # per segment
    muscle_length: dict[str, float]   # per muscle
    strength: float                   # F0 factor
    passive: float                    # passive joint torque factor
    total_mass: float                 # subject / jumper total mass
    # paths from the subject's own model, replacing the scaled jumper's (subject units, m):
    # {muscle: {'coordinates', 'exponents', 'coefficients', 'source', 'moment_arm_rms_m'}}
    paths: dict[str, dict] = field(default_factory=dict)
    # maximum isometric forces [N, two legs] from the subject's own model, replacing the
    # mass rule's F0 for these muscles: {muscle: F0}, and where they come from
    f0_n: dict[str, float] = field(default_factory=dict)
    f0_source: str = ''
    # optimal fibre lengths [m] from the same model (F0-weighted means of the members'); each
    # such muscle's tendon slack length moves so that its normalised fibre length at the
    # zero pose stays the scaled jumper's (the operating point its path was fitted around)
    l_opt_m: dict[str, float] = field(default_factory=dict)
    # the subject model's clamped coordinate ranges [rad, the jumper's signs], per
    # JOINT_COORDINATES name: {name: (lower, upper)}; the passive joint torques start at
    # whichever of these and the jumper's limits is the narrower
    joint_range_rad: dict[str, tuple[float, float]] = field(default_factory=dict)
    # the joint angles a recording of the subject reaches [rad, the jumper's signs]
    # (:func:`reached_joint_ranges`): where a passive limit (after joint_range_rad) would
    # carry more than REACH_WALL_N_M_PER_KG there, its onset moves out to them plus
    # REACH_MARGIN_RAD
    reached_range_rad: dict[str, tuple[float, float]] = field(default_factory=dict)

    def as_dict(self) -> dict:
        out = {'mass': dict(self.mass), 'length': dict(self.length),
               'muscle_length': dict(self.muscle_length), 'strength': self.strength,
               'passive': self.passive, 'total_mass': self.total_mass}
        if self.paths:
            out['paths'] = {n: dict(p) for n, p in self.paths.items()}
        if self.f0_n:
            out['max_isometric_force_n'] = {n: float(v) for n, v in self.f0_n.items()}
            out['max_isometric_force_source'] = self.f0_source
        if self.l_opt_m:
            out['optimal_fiber_length_m'] = {n: float(v) for n, v in self.l_opt_m.items()}
        for key in ('joint_range_rad', 'reached_range_rad'):
            if getattr(self, key):
                out[key] = {n: [float(lo), float(hi)] for n, (lo, hi) in
                            getattr(self, key).items()}
        return out


def subject_from_mass_height(mass_kg: float, height_m: float, name: str = 'subject',
                             params: JumperParameters | None = None,
                             rules: dict | None = None) -> Subject:
    """A subject known by body mass [kg] and stature [m] only: the jumper's proportions."""
    if not (np.isfinite(mass_kg) and 20.0 <= mass_kg <= 250.0):
        raise ValueError(f'body mass {mass_kg} kg is outside 20..250 kg')
    if not (np.isfinite(height_m) and 1.0 <= height_m <= 2.5):
        raise ValueError(f'stature {height_m} m is outside 1.0..2.5 m (give it in metres)')
    p = params or load_parameters()
    r = rules or load_rules()
    km = mass_kg / p.total_mass
    kl = height_m / float(r['reference']['stature_m'])
    ref = r['reference']['segment_lengths_m']
    return Subject(name=name, mass_kg=float(mass_kg), height_m=float(height_m),
                   segment_masses_kg={s: p.segments[s].mass * km for s in SEGMENTS},
                   segment_lengths_m={s: float(ref[s]) * kl for s in LEG_SEGMENTS},
                   source=f'mass {mass_kg} kg and stature {height_m} m (jumper proportions)')


def subject_from_measures(measures: dict, name: str = 'subject',
                          height_m: float | None = None) -> Subject:
    """A subject from ``python -m nmt_ros.osim.subject measure`` output (a scaled .osim)."""
    masses = {s: float(measures['segment_masses_kg'][s]) for s in SEGMENTS}
    lengths = {s: float(measures['segment_lengths_m'][s]) for s in LEG_SEGMENTS}
    for s, v in {**masses, **lengths}.items():
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f'{measures.get("model", "model")}: segment {s} measures {v}: '
                             'not a usable subject model')
    if measures.get('unassigned_bodies'):
        raise ValueError(f'{measures.get("model")}: bodies {measures["unassigned_bodies"]} '
                         'belong to no planar segment (gait2392/Rajagopal names expected)')
    return Subject(name=name, mass_kg=float(sum(masses.values())), height_m=height_m,
                   segment_masses_kg=masses, segment_lengths_m=lengths,
                   source=f'OpenSim model {measures.get("model", "?")}')


def subject_with_mass(subject: Subject, mass_kg: float) -> Subject:
    """The subject with body mass ``mass_kg`` [kg]: every segment mass scaled by the same
    factor (the model's mass distribution kept), lengths unchanged. For a scaled model whose
    masses are not the subject's (e.g. a generic model's masses left unscaled), when the mass
    is known otherwise (weighed, or implied by the force plates)."""
    if not (np.isfinite(mass_kg) and 20.0 <= mass_kg <= 250.0):
        raise ValueError(f'body mass {mass_kg} kg is outside 20..250 kg')
    k = float(mass_kg) / subject.mass_kg
    return replace(subject, mass_kg=float(mass_kg),
                   segment_masses_kg={n: v * k for n, v in subject.segment_masses_kg.items()},
                   source=f'{subject.source}; masses scaled x{k:.4f} to {mass_kg:g} kg')


def scale_factors(subject: Subject, params: JumperParameters | None = None,
                  rules: dict | None = None) -> SubjectScale:
    """The factors that make the jumper this subject (module docstring)."""
    p = params or load_parameters()
    r = rules or load_rules()
    ref = r['reference']['segment_lengths_m']
    mass = {s: subject.segment_masses_kg[s] / p.segments[s].mass for s in SEGMENTS}
    length = {s: subject.segment_lengths_m[s] / float(ref[s]) for s in LEG_SEGMENTS}
    length['hat'] = float(np.mean([length[s] for s in r['hat_length_from']]))
    length = {s: length[s] for s in SEGMENTS}
    muscle_length = {m: float(np.mean([length[s] for s in r['muscle_segments'][m]]))
                     for m in MUSCLES}
    total = subject.mass_kg / p.total_mass
    strength = total ** float(r['strength_exponent'])
    leg = float(np.mean([length['thigh'], length['shank']]))
    return SubjectScale(mass=mass, length=length, muscle_length=muscle_length,
                        strength=float(strength), passive=float(strength * leg),
                        total_mass=float(total))


def scale_parameters(params: JumperParameters, scale: SubjectScale) -> JumperParameters:
    """The jumper's parameters scaled by ``scale`` (a new record; ``params`` unchanged)."""
    segs = {}
    for name, s in params.segments.items():
        km, kl = scale.mass[name], scale.length[name]
        segs[name] = replace(
            s, mass=s.mass * km, izz=s.izz * km * kl * kl, com=s.com * kl,
            distal_joint=None if s.distal_joint is None else s.distal_joint * kl)
    c = params.contact
    contact = replace(c, points=c.points * scale.length['foot'], k_y=c.k_y * scale.total_mass,
                      k_x=c.k_x * scale.total_mass, c_x=c.c_x * scale.total_mass)
    pj = params.passive
    k = pj.k.copy()
    k[:, [0, 2]] *= scale.passive                      # amplitudes k1, k3 (N m)
    lower, upper = pj.theta_lower.copy(), pj.theta_upper.copy()
    for j, name in enumerate(JOINT_COORDINATES):       # the subject model's clamped ranges
        if name in scale.joint_range_rad:
            lo, hi = scale.joint_range_rad[name]
            lower[j], upper[j] = max(lower[j], lo), min(upper[j], hi)
        if name in scale.reached_range_rad:             # ... and the walls it went through
            lo, hi = scale.reached_range_rad[name]
            wall = REACH_WALL_N_M_PER_KG * sum(sg.mass for sg in segs.values())
            if pj.legs * abs(k[j, 0]) * np.exp(k[j, 1] * (hi - upper[j])) > wall:
                upper[j] = hi + REACH_MARGIN_RAD
            if pj.legs * abs(k[j, 2]) * np.exp(k[j, 3] * (lo - lower[j])) > wall:
                lower[j] = lo - REACH_MARGIN_RAD
    passive = replace(pj, k=k, damping=pj.damping * scale.passive, theta_lower=lower,
                      theta_upper=upper)
    m = params.muscles
    kmus = np.array([scale.muscle_length[n] for n in m.names])
    paths = {n: replace(path, coefficients=path.coefficients * scale.muscle_length[n])
             for n, path in m.paths.items()}
    for n, own in scale.paths.items():      # the subject's own geometry
        coords = tuple(own['coordinates'])
        if coords != paths[n].coordinates:
            raise ValueError(f'subject path of {n}: coordinates {coords}, the jumper\'s are '
                             f'{paths[n].coordinates}')
        paths[n] = replace(paths[n], exponents=np.asarray(own['exponents'], dtype=int).reshape(
            -1, len(coords)), coefficients=np.asarray(own['coefficients'], dtype=float))
    f0 = m.f0 * scale.strength
    for n, v in scale.f0_n.items():         # the subject model's own strengths
        f0[m.names.index(n)] = float(v)
    l_opt, l_slack = m.l_opt * kmus, m.l_slack * kmus
    for n, v in scale.l_opt_m.items():      # the subject model's own fibre lengths
        i = m.names.index(n)
        path = paths[n]
        l_zero = float(path.coefficients[np.all(path.exponents == 0, axis=1)].sum())
        l_slack[i] = l_zero - (l_zero - l_slack[i]) * float(v) / l_opt[i]
        l_opt[i] = float(v)
    muscles = replace(m, f0=f0, l_opt=l_opt, l_slack=l_slack, paths=paths)
    return replace(params, segments=segs, contact=contact, passive=passive, muscles=muscles)


def moment_arm_spec(params: JumperParameters | None = None, rules: dict | None = None) -> dict:
    """What ``nmt_ros.osim.subject_process.subject_moment_arms`` samples: the groups of
    ``subject_paths``, each muscle's path coordinates, the paths' ranges [deg] and the step."""
    p = params or load_parameters()
    r = rules or load_rules()
    names = [n for n in r['subject_paths'] if n in p.muscles.paths]
    ranges: dict[str, list[float]] = {}
    for n in names:
        path = p.muscles.paths[n]
        for c, rng in zip(path.coordinates, path.fit_range):
            ranges[c] = [float(v) for v in np.round(np.degrees(rng), 6)]
    return {'groups': {n: list(r['muscle_groups'][n]) for n in names},
            'coordinates': {n: list(p.muscles.paths[n].coordinates) for n in names},
            'ranges_deg': ranges, 'step_deg': float(r['subject_path_step_deg'])}


def _gradient_rows(exponents: np.ndarray, points: np.ndarray) -> np.ndarray:
    """d/dq_k of every monomial prod_j q_j ** e_tj at the points [n, d]: [n, d, terms]."""
    n, d = points.shape
    out = np.zeros((n, d, exponents.shape[0]))
    for k in range(d):
        e = exponents.copy()
        factor = e[:, k].astype(float)
        e[:, k] = np.maximum(e[:, k] - 1, 0)
        out[:, k, :] = factor * np.prod(points[:, None, :] ** e[None, :, :], axis=2)
    return out


def _monomials(coordinates: int, degree: int) -> np.ndarray:
    """Every exponent vector of total degree <= degree [terms, coordinates]."""
    grids = np.array(np.meshgrid(*[np.arange(degree + 1)] * coordinates, indexing='ij'))
    e = grids.reshape(coordinates, -1).T
    return e[e.sum(axis=1) <= degree]


def path_from_moment_arms(path: MusclePath, points: np.ndarray, arms: np.ndarray,
                          max_degree: int = 9, tolerance_m: float = 5e-4,
                          ) -> tuple[MusclePath, float]:
    """A path with ``path``'s length at the zero pose whose moment arms r_j = -dl/dq_j fit
    ``arms`` [n, d] (m) at ``points`` [n, d] (rad) in least squares: the lowest total degree
    from the path's own up to ``max_degree`` whose RMS moment-arm error is within
    ``tolerance_m``. Returns the path and that RMS [m]."""
    points, arms = np.asarray(points, dtype=float), np.asarray(arms, dtype=float)
    d = points.shape[1]
    zero = np.zeros((1, d))
    l0 = float(sum(c * np.prod(zero[0] ** e) for c, e in zip(path.coefficients,
                                                                path.exponents)))
    best = None
    for degree in range(max(int(path.exponents.sum(axis=1).max()), 1), max_degree + 1):
        e = _monomials(d, degree)
        rows = _gradient_rows(e, points).reshape(-1, e.shape[0])
        free = e.sum(axis=1) > 0
        c = np.zeros(e.shape[0])
        c[~free] = l0
        c[free] = np.linalg.lstsq(rows[:, free], -arms.reshape(-1), rcond=None)[0]
        rms = float(np.sqrt(np.mean((rows @ c + arms.reshape(-1)) ** 2)))
        best = (replace(path, exponents=e, coefficients=c), rms)
        if rms <= tolerance_m:
            break
    assert best is not None
    return best


def paths_from_moment_arms(params: JumperParameters, arms: dict) -> dict[str, dict]:
    """``SubjectScale.paths`` from ``subject_moment_arms``'s result, for the subject-scaled
    ``params`` (their paths give each muscle's length at the zero pose)."""
    out = {}
    for n, a in arms['muscles'].items():
        path, rms = path_from_moment_arms(params.muscles.paths[n], np.asarray(a['points_rad']),
                                          np.asarray(a['moment_arms_m']))
        out[n] = {'coordinates': list(path.coordinates),
                  'exponents': path.exponents.tolist(),
                  'coefficients': [float(v) for v in path.coefficients],
                  'source': f"moment arms of {'+'.join(a['members'])} (F0-weighted) in "
                            f"{Path(arms['model']).name}",
                  'moment_arm_rms_m': round(rms, 6)}
    return out


def strengths_from_moment_arms(arms: dict, legs: int = 2,
                               ) -> tuple[dict[str, float], dict[str, float]]:
    """The lumped muscles' maximum isometric forces [N, ``legs`` legs: the members' sum per
    leg] and optimal fibre lengths [m, the members' F0-weighted mean] from
    ``subject_moment_arms``'s result (each group's members as the model has them)."""
    f0, l_opt = {}, {}
    for n, a in arms['muscles'].items():
        w = np.asarray(a['f0_n'], dtype=float)
        f0[n] = float(legs * w.sum())
        l_opt[n] = float(np.dot(w, a['l_opt_m']) / w.sum())
    return f0, l_opt


def joint_ranges_from_moment_arms(arms: dict) -> dict[str, tuple[float, float]]:
    """The clamped coordinate ranges [rad, the jumper's signs] of ``subject_moment_arms``'s
    result (``coordinate_ranges``), for ``SubjectScale.joint_range_rad``."""
    out = {}
    for name, r in (arms.get('coordinate_ranges') or {}).items():
        if name not in JOINT_COORDINATES:
            raise ValueError(f'coordinate range of {name}: not one of {JOINT_COORDINATES}')
        lo, hi = (float(v) for v in r['range_rad'])
        if r.get('clamped') and lo < hi:
            out[name] = (lo, hi)
    return out


#: How far past the angles a recording reaches [rad] a moved passive limit starts (6 deg:
#: there the dorsiflexion wall's torque at the reached angle is 0.04 N m a leg; at 3 deg
#: (0.3 N m) the shipped drop jump's thigh fit went 1.7 -> 2.1 deg RMS, at 0 deg its knee's
#: agreement with OpenSim's inverse dynamics 0.94 -> 0.92; 6 and 10 deg gave the same figures)
REACH_MARGIN_RAD = float(np.deg2rad(6.0))
#: A passive limit that would have to carry more than this [N m per kg of body mass] at an
#: angle a recording reaches contradicts the recording, and its onset moves out to the
#: angles reached (plus REACH_MARGIN_RAD): the limit, not the muscles, would be holding the
#: joint (a landing's whole ankle moment is 2-4 N m/kg). AddBiomechanics' Subject4 lands at
#: 50 deg of dorsiflexion, 20 past the jumper's onset (30 deg), where that exponential wall
#: gives 10^5 N m: its ankle torque was held 110 N m under OpenSim's inverse dynamics
#: (correlation 0.43 -> 0.99 with the onset moved). Below it the limit stays: the shipped
#: subject's drop jumps go 3-5 deg past (0.35-1.15 N m/kg), and moving it there let the
#: unseen DJ4's estimate keep the foot flat while the heel rose (knee correlation 0.85 ->
#: 0.80, foot 2.5 -> 3.9 deg RMS); the soft hip limit at 129 deg of flexion gives 0.5 N m/kg,
#: and moving it let the shipped drop jump's final landing run away (README, Lab recordings).
REACH_WALL_N_M_PER_KG = 2.0


def reached_joint_ranges(theta: np.ndarray, percent: float = 0.5,
                         ) -> dict[str, tuple[float, float]]:
    """The joint angles [rad, JOINT_COORDINATES, the jumper's signs] a recording's segment
    angles theta [n, 4] (foot, shank, thigh, HAT; rad, NaN where missing) reach: the
    ``percent`` and 100 - ``percent`` percentiles of ankle = foot - shank, knee = shank -
    thigh, hip = thigh - HAT (README, Conventions), so one stray frame does not set them.

    Why: the jumper's passive torques (Anderson 1999) stiffen from 30 deg of ankle
    dorsiflexion and 104 deg of hip flexion, but lab subjects land deeper (the shipped drop
    jump: 34 and 120 deg; AddBiomechanics' Subject4: 50 deg at the ankle). A measured angle
    the model forbids makes the estimate fight the data: Subject4's first drop jump had its
    ankle held 14 deg short and its ankle torque 110 N m under OpenSim's inverse dynamics
    (correlation 0.43), the ligament taking the rest (README, Lab recordings)."""
    theta = np.asarray(theta, dtype=float)
    joints = theta[:, :3] - theta[:, 1:4]
    joints = joints[np.isfinite(joints).all(axis=1)]
    if joints.shape[0] == 0:
        return {}
    lo = np.percentile(joints, percent, axis=0)
    hi = np.percentile(joints, 100.0 - percent, axis=0)
    return {n: (float(lo[j]), float(hi[j])) for j, n in enumerate(JOINT_COORDINATES)}


def subject_parameters(subject: Subject, params: JumperParameters | None = None,
                       ) -> tuple[JumperParameters, SubjectScale]:
    p = params or load_parameters()
    scale = scale_factors(subject, p)
    return scale_parameters(p, scale), scale


# ---------------------------------------------------------------------------------------------
# the subject file of a bag
# ---------------------------------------------------------------------------------------------

def write_subject(path: str | os.PathLike, subject: Subject, scale: SubjectScale | None = None,
                  ) -> Path:
    """``subject.yaml``: the subject's measures and the factors applied to the jumper."""
    path = Path(path)
    if path.is_dir():
        path = path / SUBJECT_FILE
    scale = scale or scale_factors(subject)
    doc = {
        'format': 'nmt_ros subject v1',
        'note': ('The jumper model (nmt_ros/model/data/jumper.yaml) scaled to this subject by '
                 'nmt_ros/model/subject.py with the factors under "scale" (rules: '
                 'nmt_ros/model/data/subject_scaling.yaml). Masses kg (two legs lumped), '
                 'lengths m (one leg, joint-centre distances).'),
        'subject': {'name': subject.name, 'mass_kg': subject.mass_kg,
                    'height_m': subject.height_m, 'source': subject.source,
                    'segment_masses_kg': dict(subject.segment_masses_kg),
                    'segment_lengths_m': dict(subject.segment_lengths_m)},
        'scale': scale.as_dict(),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, 'w') as f:
        yaml.safe_dump(doc, f, sort_keys=False, width=99)
    return path


def read_subject(path: str | os.PathLike) -> tuple[Subject, SubjectScale]:
    """The subject and scale factors of a ``subject.yaml`` (or of a bag folder holding one)."""
    path = Path(path)
    if path.is_dir():
        path = path / SUBJECT_FILE
    with open(path) as f:
        doc = yaml.safe_load(f)
    if not isinstance(doc, dict) or doc.get('format') != 'nmt_ros subject v1':
        raise ValueError(f'{path}: not an nmt_ros subject file (format "nmt_ros subject v1")')
    s, k = doc['subject'], doc['scale']
    subject = Subject(name=str(s['name']), mass_kg=float(s['mass_kg']),
                      height_m=None if s.get('height_m') is None else float(s['height_m']),
                      segment_masses_kg={n: float(v) for n, v in s['segment_masses_kg'].items()},
                      segment_lengths_m={n: float(v) for n, v in s['segment_lengths_m'].items()},
                      source=str(s.get('source', '')))
    missing = [n for n in SEGMENTS if n not in k['mass'] or n not in k['length']] + \
        [n for n in MUSCLES if n not in k['muscle_length']]
    if missing:
        raise ValueError(f'{path}: scale factors missing for {missing}')
    scale = SubjectScale(mass={n: float(k['mass'][n]) for n in SEGMENTS},
                         length={n: float(k['length'][n]) for n in SEGMENTS},
                         muscle_length={n: float(k['muscle_length'][n]) for n in MUSCLES},
                         strength=float(k['strength']), passive=float(k['passive']),
                         total_mass=float(k['total_mass']),
                         paths={n: dict(v) for n, v in (k.get('paths') or {}).items()},
                         f0_n={n: float(v) for n, v in
                               (k.get('max_isometric_force_n') or {}).items()},
                         f0_source=str(k.get('max_isometric_force_source', '')),
                         l_opt_m={n: float(v) for n, v in
                                  (k.get('optimal_fiber_length_m') or {}).items()},
                         joint_range_rad={n: (float(v[0]), float(v[1])) for n, v in
                                          (k.get('joint_range_rad') or {}).items()},
                         reached_range_rad={n: (float(v[0]), float(v[1])) for n, v in
                                            (k.get('reached_range_rad') or {}).items()})
    unknown = [n for n in [*scale.paths, *scale.f0_n, *scale.l_opt_m] if n not in MUSCLES]
    if unknown:
        raise ValueError(f'{path}: paths or strengths for unknown muscles {unknown}')
    for key in ('joint_range_rad', 'reached_range_rad'):
        ranges = getattr(scale, key)
        unknown = [n for n in ranges if n not in JOINT_COORDINATES]
        bad = [n for n, (lo, hi) in ranges.items()
               if not (lo <= hi if key == 'reached_range_rad' else lo < hi)]
        if unknown or bad:
            raise ValueError(f'{path}: {key}: unknown coordinates {unknown} or empty ranges '
                             f'{bad} (coordinates {JOINT_COORDINATES}, [lower, upper] rad)')
    return subject, scale


def subject_file(path: str | os.PathLike | None) -> Path | None:
    """The subject file of ``path``: a subject YAML itself, or the ``subject.yaml`` of a bag
    folder (or beside a bag's .mcap file); None when there is none."""
    if path is None or str(path) == '':
        return None
    p = Path(path)
    if p.suffix == '.yaml':
        if not p.is_file():
            raise ValueError(f'{p}: no such subject file')
        return p
    p = p / SUBJECT_FILE if p.is_dir() else p.parent / SUBJECT_FILE
    return p if p.is_file() else None


def load_subject_parameters(path: str | os.PathLike | None) -> JumperParameters:
    """The model parameters of a bag or subject file: its subject applied, or the jumper's."""
    params = load_parameters()
    found = subject_file(path)
    if found is None:
        return params
    _, scale = read_subject(found)
    return scale_parameters(params, scale)


def load_subject_model(path: str | os.PathLike | None) -> object:
    """The :class:`JumperModel` of a bag (folder or .mcap) or of a subject YAML: its
    subject's, or the shipped jumper (the same object as ``default_model()``) when there is
    none."""
    from nmt_ros.model.jumper import JumperModel, default_model
    if subject_file(path) is None:
        return default_model()
    return JumperModel(load_subject_parameters(path))
