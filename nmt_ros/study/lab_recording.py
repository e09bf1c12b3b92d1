"""A lab recording as the planar jumper's observations, and as an observation bag.

Three ways in, one result (:class:`LabRecording`: segment angles and ground wrench at the
recording's own rates and times, the subject, and what was done):

* :func:`import_ik`: an OpenSim inverse-kinematics .mot posed on the subject's .osim (in an
  OpenSim subprocess) gives each leg's body-fixed landmarks (hip, knee and ankle centres, the
  calcaneus' subtalar and MTP joint centres, hips and shoulders for the trunk);
* :func:`import_markers` (:func:`import_trc`, :func:`import_c3d`): markers named by a marker
  map (``nmt_ros.io.marker_map``), short gaps filled and reported;
* the ground reaction from an OpenSim GRF .mot (plates found by their column names, or named by
  an ExternalLoads .xml) or from the C3D's own force plates.

Segment angles, the leg combination (mean of left and right) and the plate sum follow
``nmt_ros.study.sagittal``. The trunk (HAT) angle is the hips-to-shoulders line's, i.e. the
trunk's absolute angle (pelvis tilt plus lumbar extension in OpenSim's coordinates). The
wrench's moment is about the foot COM of the subject-scaled planar model placed on the
combined ankle centre and foot angle, resampled (cubic) onto the force samples; force samples
outside the motion's time span are dropped and counted.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
import hashlib
import json
import os
from pathlib import Path
import tempfile

import numpy as np

from nmt_ros import topics
from nmt_ros.io.force_plates import read_plates
from nmt_ros.io.marker_map import LEG_LANDMARKS, LEG_LINES, SIDES, landmark, markers_used
from nmt_ros.io.opensim_files import (
    GroundLoad,
    read_table,
    without_repeated_rows,
    write_table,
)
from nmt_ros.io.trc import MarkerTable, read_trc
from nmt_ros.model.parameters import JOINT_COORDINATES, SEGMENTS, load_parameters
from nmt_ros.model.subject import Subject, SubjectScale, scale_factors, scale_parameters
from nmt_ros.records import Observations
from nmt_ros.study import sagittal
from nmt_ros.study.sagittal import SagittalFrame
from nmt_ros.tracking.conditioning import sample_rate

#: Largest marker gap filled by interpolation [s] unless told otherwise.
MAX_GAP_S = 0.1


@dataclass
class LabRecording:
    """Observations of a lab trial (trial time = the recording's own time, s)."""

    t_angles: np.ndarray          # [n1] s
    angles: np.ndarray            # [n1, 4] rad, foot, shank, thigh, hat (legs combined)
    t_wrench: np.ndarray          # [n2] s
    wrench: np.ndarray            # [n2, 3] N, N, N m about the planar foot COM
    ankle: np.ndarray             # [n1, 2] m, the combined ankle centre (sagittal), at t_angles
    subject: Subject
    scale: SubjectScale
    sides: dict = field(default_factory=dict)    # per leg: angles [n1, 3] (foot, shank, thigh)
    facts: dict = field(default_factory=dict)    # what was read and done (to custom_data)


def file_fact(path: str | os.PathLike) -> dict:
    p = Path(path)
    return {'file': p.name, 'sha256': hashlib.sha256(p.read_bytes()).hexdigest()}


def _repeated_rows(path: str | os.PathLike, times_s: list[float]) -> list[dict]:
    """Repair records of the rows a file repeated exactly (``without_repeated_rows``)."""
    return [{'what': f'{Path(path).name}: row repeated exactly', 't_start_s': t,
             't_end_s': t, 'samples': 1, 'how': 'dropped'} for t in times_s]


def _check_uniform(t: np.ndarray, what: str) -> None:
    """ValueError naming ``what`` unless the sample times t [s] are uniformly spaced."""
    try:
        sample_rate(t)
    except ValueError as err:
        raise ValueError(f'{what}: {err}') from None


def _rate(t: np.ndarray) -> float:
    return float(1.0 / np.median(np.diff(t))) if t.size > 1 else float('nan')


# ---------------------------------------------------------------------------------------------
# shared assembly
# ---------------------------------------------------------------------------------------------

def _subject_foot_com(subject: Subject, scale: SubjectScale | None,
                      ) -> tuple[SubjectScale, np.ndarray]:
    scale = scale or scale_factors(subject)
    params = scale_parameters(load_parameters(), scale)
    return scale, params.segments['foot'].com


def _check_orientation(frame: SagittalFrame, heel: np.ndarray, toe: np.ndarray,
                       hip: np.ndarray, ankle: np.ndarray, what: str) -> None:
    fwd = float(np.nanmean((toe - heel)[..., 0]))
    up = float(np.nanmean((hip - ankle)[..., 1]))
    if up <= 0:
        raise ValueError(f'{what}: the hips are below the ankles along up = {frame.up}: give '
                         'the lab axis that points up (--up)')
    if fwd <= 0:
        raise ValueError(f'{what}: the feet point backward along forward = {frame.forward} '
                         '(the subject faces the other way): give --forward')


def _assemble(t_kin: np.ndarray, side_angles: dict[str, np.ndarray], hat: np.ndarray,
              ankle: dict[str, np.ndarray], t_force: np.ndarray, loads: list[GroundLoad],
              frame: SagittalFrame, subject: Subject, scale: SubjectScale | None,
              facts: dict) -> LabRecording:
    """Combine legs, sum plates about the planar foot COM, pack a LabRecording."""
    sources = facts.get('sources', {})
    for t, keys, stream in ((t_kin, ('ik', 'trc', 'c3d'), 'motion'),
                            (t_force, ('grf', 'c3d'), 'forces')):
        name = next((sources[k]['file'] for k in keys if k in sources), stream)
        _check_uniform(t, stream if name == stream else f'{name} ({stream})')
    combined, lr_rms = {}, {}
    for k, seg in enumerate(('foot', 'shank', 'thigh')):
        combined[seg], lr_rms[seg] = sagittal.combine_legs(side_angles['r'][:, k],
                                                           side_angles['l'][:, k])
    angles = np.column_stack([combined['foot'], combined['shank'], combined['thigh'], hat])
    scale, com_foot = _subject_foot_com(subject, scale)
    ankle_mid = 0.5 * (ankle['r'] + ankle['l'])
    com = sagittal.foot_com(ankle_mid, angles[:, 0], com_foot)
    keep = (t_force >= t_kin[0] - 1e-9) & (t_force <= t_kin[-1] + 1e-9)
    if not keep.any():
        raise ValueError(f'the force samples ({t_force[0]:.3f}..{t_force[-1]:.3f} s) do not '
                         f'overlap the motion ({t_kin[0]:.3f}..{t_kin[-1]:.3f} s)')
    t_w = t_force[keep]
    loads = [GroundLoad(ld.force[keep], ld.point[keep], ld.torque[keep]) for ld in loads]
    wrench = sagittal.sagittal_wrench(loads, frame, sagittal.resample(t_kin, com, t_w))
    facts = dict(facts)
    facts.update({
        'angles_rate_hz': _rate(t_kin), 'wrench_rate_hz': _rate(t_w),
        'frame': {'forward': frame.forward, 'up': frame.up},
        'legs': 'mean of the left and right segment angles (nmt_ros.study.sagittal)',
        'left_right_rms_deg': {k: float(np.rad2deg(v)) for k, v in lr_rms.items()},
        'wrench_samples_dropped': int((~keep).sum()),
        'wrench_moment_about': 'planar foot COM: mean ankle centre + R(foot) c_foot (subject)',
    })
    return LabRecording(t_angles=t_kin, angles=angles, t_wrench=t_w, wrench=wrench,
                        ankle=ankle_mid, subject=subject, scale=scale, sides=side_angles,
                        facts=facts)


# ---------------------------------------------------------------------------------------------
# the three routes
# ---------------------------------------------------------------------------------------------

def ik_segment_angles(lm: dict[str, np.ndarray], frame: SagittalFrame,
                      ) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, np.ndarray]]:
    """Per-leg [n, 3] (foot, shank, thigh), HAT [n] angles and ankle centres [n, 2] from the
    landmarks of ``python -m nmt_ros.osim.subject kinematics`` (OpenSim ground frame)."""
    lines = {'foot': ('subtalar', 'mtp'), 'shank': ('ankle', 'knee'), 'thigh': ('knee', 'hip')}
    opensim = SagittalFrame('+x', '+y')
    sides, ankle = {}, {}
    for s in SIDES:
        cols = []
        for a, b in lines.values():
            phi = sagittal.direction_angle(frame.project(lm[f'{s}_{a}']),
                                           frame.project(lm[f'{s}_{b}']))
            phi0 = float(sagittal.direction_angle(opensim.project(lm[f'default_{s}_{a}']),
                                                  opensim.project(lm[f'default_{s}_{b}'])))
            cols.append(sagittal.segment_angle(phi, phi0))
        sides[s] = np.column_stack(cols)
        ankle[s] = frame.project(lm[f'{s}_ankle'])

    def mid(name: str, prefix: str = '') -> np.ndarray:
        return 0.5 * (lm[f'{prefix}r_{name}'] + lm[f'{prefix}l_{name}'])

    phi = sagittal.direction_angle(frame.project(mid('hip_pelvis')),
                                   frame.project(mid('shoulder')))
    phi0 = float(sagittal.direction_angle(opensim.project(mid('hip_pelvis', 'default_')),
                                          opensim.project(mid('shoulder', 'default_'))))
    return sides, sagittal.segment_angle(phi, phi0), ankle


def import_ik(ik: str | os.PathLike, grf: str | os.PathLike, model: str | os.PathLike,
              subject: Subject, external_loads: str | os.PathLike | None = None,
              frame: SagittalFrame | None = None) -> LabRecording:
    """IK .mot + GRF .mot on the subject's .osim (module docstring)."""
    from nmt_ros.osim.subject_process import ik_landmarks
    frame = frame or SagittalFrame('+x', '+y')
    table, repeated = without_repeated_rows(read_table(ik))
    with tempfile.TemporaryDirectory() as tmp:
        posed = ik
        if repeated:    # OpenSim refuses a file with a repeated row: pose a copy without
            posed = write_table(Path(tmp) / Path(ik).name, table.time, table.labels,
                                table.data, in_degrees=table.in_degrees, name=table.name)
        lm = ik_landmarks(model, posed)
    t = lm['time']
    if t.size < 4 or np.any(np.diff(t) <= 0):
        raise ValueError(f'{ik}: time must increase over at least 4 rows')
    for s in SIDES:
        _check_orientation(frame, frame.project(lm[f'{s}_subtalar']),
                           frame.project(lm[f'{s}_mtp']), frame.project(lm[f'{s}_hip']),
                           frame.project(lm[f'{s}_ankle']), str(ik))
    sides, hat, ankle = ik_segment_angles(lm, frame)
    t_f, loads, names, grf_repeated = read_plates(grf, external_loads)
    facts = {'route': 'ik', 'plates': names,
             'repairs': _repeated_rows(ik, repeated) + _repeated_rows(grf, grf_repeated),
             'sources': {'ik': file_fact(ik), 'grf': file_fact(grf), 'model': file_fact(model),
                         **({'external_loads': file_fact(external_loads)}
                            if external_loads else {})},
             'ik_coordinates_at_default': [str(c) for c in lm['coordinates_at_default']],
             'segments': {'foot': 'subtalar -> MTP joint centres (calcaneus)',
                          'shank': 'ankle -> knee centre', 'thigh': 'knee -> hip centre',
                          'hat': 'hip centres -> shoulder joints (trunk: pelvis tilt + lumbar '
                                 'extension)'}}
    return _assemble(t, sides, hat, ankle, t_f, loads, frame, subject, None, facts)


def marker_segment_angles(markers: MarkerTable, marker_map: dict, frame: SagittalFrame,
                          max_gap_s: float = MAX_GAP_S,
                          ) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, np.ndarray],
                                     list[dict]]:
    """Per-leg [n, 3] (foot, shank, thigh), HAT [n], ankle centres [n, 2], gap repairs."""
    missing = [n for n in markers_used(marker_map) if n not in markers.names]
    if missing:     # another lab's marker set: say all that is missing and what to do
        raise ValueError(
            f'the marker map {marker_map.get("name", "")!r} '
            f'({Path(marker_map.get("source_file", "")).name}) needs markers '
            f'{markers.source or "the recording"} does not have: {", ".join(missing)} '
            f'(it has: {", ".join(markers.names)}). Give a map of this lab\'s names with '
            '--marker-map MAP.yaml (format: nmt_ros/io/marker_map.py; calibrate its zero '
            'angles on a model carrying those markers with python -m '
            'nmt_ros.study.marker_calibration --model M.osim --map MAP.yaml), or import '
            "the lab's OpenSim IK with --ik")
    pos, repairs = {}, []
    for name in markers_used(marker_map):
        pos[name], fixed = sagittal.fill_gaps(markers.time, markers.marker(name), max_gap_s,
                                              f'marker {name}')
        repairs += fixed
    zero = marker_map.get('zero_deg')
    offsets = marker_map.get('ankle_offset_m')
    if zero is None or offsets is None:
        raise ValueError(f'{marker_map.get("source_file", "marker map")}: not calibrated (no '
                         'zero_deg / ankle_offset_m): give --model or run python -m '
                         'nmt_ros.study.marker_calibration --model M.osim --map MAP')
    sides, ankle = {}, {}
    for s in SIDES:
        p = {k: frame.project(landmark(marker_map, s, k, pos)) for k in LEG_LANDMARKS}
        _check_orientation(frame, p['heel'], p['toe'], p['hip'], p['ankle'],
                           markers.source or 'markers')
        cols = [sagittal.segment_angle(sagittal.direction_angle(p[a], p[b]),
                                       np.deg2rad(float(zero[s][seg])))
                for seg, (a, b) in LEG_LINES.items()]
        sides[s] = np.column_stack(cols)
        ankle[s] = p['ankle'] + sagittal.rotate(sides[s][:, 1], np.asarray(offsets[s], float))
    hip = frame.project(landmark(marker_map, None, 'hip', pos))
    shoulder = frame.project(landmark(marker_map, None, 'shoulder', pos))
    hat = sagittal.segment_angle(sagittal.direction_angle(hip, shoulder),
                                 np.deg2rad(float(zero['hat'])))
    return sides, hat, ankle, repairs


def import_markers(markers: MarkerTable, t_force: np.ndarray, loads: list[GroundLoad],
                   marker_map: dict, subject: Subject, frame: SagittalFrame | None = None,
                   max_gap_s: float = MAX_GAP_S, facts: dict | None = None) -> LabRecording:
    """Markers (any source) + plates (lab frame) -> LabRecording."""
    frame = frame or SagittalFrame(**marker_map.get('frame', {}))
    sides, hat, ankle, repairs = marker_segment_angles(markers, marker_map, frame, max_gap_s)
    info = dict(facts or {})
    info.update({'marker_map': {'name': marker_map.get('name', ''),
                                'file': Path(marker_map.get('source_file', '')).name,
                                'calibrated_on': marker_map.get('calibrated_on', '')},
                 'repairs': [*info.get('repairs', []), *repairs], 'max_gap_s': max_gap_s})
    return _assemble(markers.time, sides, hat, ankle, t_force, loads, frame, subject, None,
                     info)


def import_trc(trc: str | os.PathLike, grf: str | os.PathLike, marker_map: dict,
               subject: Subject, external_loads: str | os.PathLike | None = None,
               frame: SagittalFrame | None = None, max_gap_s: float = MAX_GAP_S,
               ) -> LabRecording:
    """TRC markers + OpenSim GRF .mot."""
    markers = read_trc(trc)
    t_f, loads, names, grf_repeated = read_plates(grf, external_loads)
    facts = {'route': 'trc', 'plates': names, 'repairs': _repeated_rows(grf, grf_repeated),
             'sources': {'trc': file_fact(trc), 'grf': file_fact(grf),
                         **({'external_loads': file_fact(external_loads)}
                            if external_loads else {})}}
    return import_markers(markers, t_f, loads, marker_map, subject, frame, max_gap_s, facts)


def import_c3d(c3d: str | os.PathLike, marker_map: dict, subject: Subject,
               grf: str | os.PathLike | None = None,
               external_loads: str | os.PathLike | None = None,
               frame: SagittalFrame | None = None, max_gap_s: float = MAX_GAP_S,
               ) -> LabRecording:
    """C3D markers and force plates (or a GRF .mot given instead of the C3D's plates)."""
    from nmt_ros.io.c3d import read_c3d
    markers, t_f, loads, c3d_facts = read_c3d(c3d)
    sources = {'c3d': file_fact(c3d)}
    repairs: list[dict] = []
    names = [f'plate {k + 1}' for k in range(len(loads))]
    if grf is not None:
        t_f, loads, names, grf_repeated = read_plates(grf, external_loads)
        sources['grf'] = file_fact(grf)
        repairs = _repeated_rows(grf, grf_repeated)
    elif not loads:
        raise ValueError(f'{c3d}: no force plates (FORCE_PLATFORM group); give --grf')
    facts = {'route': 'c3d', 'plates': names, 'sources': sources, 'repairs': repairs,
             'c3d': {k: v for k, v in c3d_facts.items() if k != 'plates'}}
    return import_markers(markers, t_f, loads, marker_map, subject, frame, max_gap_s, facts)


# ---------------------------------------------------------------------------------------------
# the whole import: subject, route, momentum balance
# ---------------------------------------------------------------------------------------------

#: Implied and model body mass differing by more than this fraction is warned about.
MASS_TOLERANCE = 0.05


def lab_subject(name: str, model: str | os.PathLike | None = None,
                mass_kg: float | None = None, height_m: float | None = None,
                ) -> tuple[Subject, dict | None]:
    """The subject of an import and the model's measures (None without a model).

    From the .osim (its masses and segment lengths; with ``mass_kg`` its masses scaled to
    that body mass), or from mass and stature alone (the jumper's proportions).
    """
    from nmt_ros.model.subject import (
        subject_from_mass_height,
        subject_from_measures,
        subject_with_mass,
    )
    if model is not None:
        if height_m is not None:
            raise ValueError('--height goes without --model (the model gives the lengths)')
        from nmt_ros.osim.subject_process import measure_model
        measures = measure_model(model)
        subject = subject_from_measures(measures, name)
        if mass_kg is not None:
            subject = subject_with_mass(subject, mass_kg)
        return subject, measures
    if mass_kg is not None and height_m is not None:
        return subject_from_mass_height(mass_kg, height_m, name), None
    raise ValueError('no subject: give --model SUBJECT.osim [--mass KG], or --mass KG '
                     '--height M')


def import_lab(*, ik: Path | None = None, trc: Path | None = None, c3d: Path | None = None,
               grf: Path | None = None, external_loads: Path | None = None,
               model: Path | None = None, mass_kg: float | str | None = None,
               height_m: float | None = None, name: str | None = None,
               marker_map: Path | None = None, forward: str | None = None,
               up: str | None = None, max_gap_s: float | None = None,
               subject_paths: bool = True) -> LabRecording:
    """``nmt import-lab``: one route (IK, TRC or C3D) to a :class:`LabRecording` with its
    subject and the momentum balance checked (:func:`check_momentum`); with a model and
    ``subject_paths``, the muscle paths of its own geometry (:func:`with_subject_paths`).
    ``mass_kg``: a mass [kg]; 'implied': the body mass the force plates imply
    (:func:`with_implied_mass`); 'model': the model's own masses; None (the default) with a
    model: the model's masses unless the plates imply a mass more than
    :data:`MASS_TOLERANCE` away from them, then the implied one, said in the warnings
    (:func:`with_consistent_mass`)."""
    from nmt_ros.io.marker_map import load_marker_map
    from nmt_ros.study.marker_calibration import calibrate
    routes = {'ik': ik, 'trc': trc, 'c3d': c3d}
    given = [r for r, v in routes.items() if v is not None]
    if len(given) != 1:
        raise ValueError('give exactly one of --ik, --trc, --c3d')
    route = given[0]
    if route in ('ik', 'trc') and grf is None:
        raise ValueError(f'--{route} needs --grf')
    if route == 'ik' and model is None:
        raise ValueError('--ik needs --model (the .osim the IK was solved with)')
    source = Path(routes[route])
    if isinstance(mass_kg, str) and mass_kg not in ('implied', 'model'):
        raise ValueError(f"--mass {mass_kg!r}: a mass in kg, 'implied' or 'model'")
    if mass_kg == 'model' and model is None:
        raise ValueError("--mass model needs --model (the .osim whose masses to keep)")
    implied = mass_kg == 'implied'
    consistent = mass_kg is None and model is not None
    if implied and model is None:
        mass_kg = load_parameters().total_mass    # the jumper's proportions, re-weighed below
    subject, measures = lab_subject(name or source.stem, model,
                                    None if isinstance(mass_kg, str) and model is not None
                                    else mass_kg, height_m)
    kw = {} if max_gap_s is None else {'max_gap_s': max_gap_s}
    if route == 'ik':
        frame = SagittalFrame(forward or '+x', up or '+y')
        rec = import_ik(ik, grf, model, subject, external_loads, frame)
    else:
        mmap = load_marker_map(marker_map)
        if measures is not None and all(n in measures['markers_m'] for n in markers_used(mmap)):
            mmap = {**calibrate(mmap, measures), 'source_file': mmap['source_file']}
        frame_map = mmap.get('frame', {})
        frame = SagittalFrame(forward or frame_map.get('forward', '+x'),
                              up or frame_map.get('up', '+y'))
        if route == 'trc':
            rec = import_trc(trc, grf, mmap, subject, external_loads, frame, **kw)
        else:
            rec = import_c3d(c3d, mmap, subject, grf, external_loads, frame, **kw)
    check_momentum(rec)
    if implied:
        rec = with_implied_mass(rec)
    elif consistent:
        rec = with_consistent_mass(rec)
    if model is not None and subject_paths:
        rec = with_subject_paths(rec, model)
    return with_reached_ranges(rec)


def with_reached_ranges(rec: LabRecording) -> LabRecording:
    """The recording with the joint angles it reaches in its subject
    (``SubjectScale.reached_range_rad``, ``nmt_ros.model.subject.reached_joint_ranges``):
    where a passive joint limit would carry more than ``REACH_WALL_N_M_PER_KG`` there, its
    onset moves out to them, said in ``facts['passive_onset_moved_deg']`` and a warning."""
    from nmt_ros.model.subject import (
        REACH_MARGIN_RAD,
        REACH_WALL_N_M_PER_KG,
        reached_joint_ranges,
    )
    reached = reached_joint_ranges(rec.angles)
    jumper = load_parameters()
    before = scale_parameters(jumper, rec.scale)
    out = replace(rec, scale=replace(rec.scale, reached_range_rad=reached))
    after = scale_parameters(jumper, out.scale)
    moved = {}
    for j, name in enumerate(JOINT_COORDINATES):
        for end, was, now in (('lower', before.passive.theta_lower[j],
                               after.passive.theta_lower[j]),
                              ('upper', before.passive.theta_upper[j],
                               after.passive.theta_upper[j])):
            if now != was:
                moved[f'{name} {end}'] = [round(float(np.degrees(was)), 1),
                                          round(float(np.degrees(now)), 1)]
    out.facts['reached_range_deg'] = {n: [round(float(np.degrees(v)), 1) for v in r]
                                      for n, r in reached.items()}
    out.facts['passive_onset_moved_deg'] = moved
    if moved:
        out.facts.setdefault('warnings', []).append(
            'the recording reaches joint angles where the model\'s passive joint limits would '
            f'carry more than {REACH_WALL_N_M_PER_KG:g} N m/kg (the limit, not the muscles, '
            f'holding the joint); their onset moves out to {np.degrees(REACH_MARGIN_RAD):.0f} '
            'deg past the angles reached (deg, before -> after): '
            + ', '.join(f'{k} {a} -> {b}' for k, (a, b) in moved.items()))
    return out


def _supported_stretch_hint(estimates: list[dict]) -> str:
    """'; if the plates carry ...' naming the mass the impulse over the longest supported
    stretch implies (``momentum_balance``, reported, never imposed), or '' without one."""
    hint = next((e for e in estimates if e['method'] == 'impulse over a supported stretch'),
                None)
    if hint is None:
        return ''
    (a, b), m = hint['interval_s'], hint['mass_kg']
    return (f'; if the plates carry the whole body throughout {a:.2f}..{b:.2f} s, its impulse '
            f'implies {m:.1f} kg (give --mass {m:.1f})')


def with_implied_mass(rec: LabRecording) -> LabRecording:
    """The recording with its subject weighed by its own force plates: every segment mass
    scaled to the body mass the momentum balance implies (``check_momentum``; the segment
    angles, the wrench about the foot COM and the COM's course do not depend on the total
    mass), the balance checked again. A recording that implies no mass is an error."""
    from nmt_ros.model.subject import subject_with_mass
    mass = rec.facts.get('momentum_balance', {}).get('implied_mass_kg')
    if mass is None:
        raise ValueError('--mass implied: the recording implies no body mass (neither a quiet '
                         'stance on the plates nor a contact between two flights); give '
                         '--mass KG' + _supported_stretch_hint(rec.facts.get(
                             'momentum_balance', {}).get('estimates', [])))
    subject = subject_with_mass(rec.subject, float(mass))
    subject = replace(subject, source=f'{subject.source} (the mass the force plates imply)')
    said = ('no body mass could be estimated', 'the force plates imply a body mass',
            'supported by something that is not on a force plate')   # by check_momentum
    kept = [w for w in rec.facts.get('warnings', []) if not any(x in w for x in said)]
    out = replace(rec, subject=subject, scale=scale_factors(subject),
                  facts={**rec.facts, 'warnings': kept, 'mass_from': 'implied by the recording'})
    check_momentum(out)
    return out


def with_consistent_mass(rec: LabRecording) -> LabRecording:
    """The recording with a body mass its forces agree with: the subject model's own when
    the force plates imply a mass within :data:`MASS_TOLERANCE` of it (or imply none), else
    the implied one (:func:`with_implied_mass`), said in ``facts['warnings']``.

    A scaled .osim need not carry its subject's mass: OpenCap's models keep the generic
    Rajagopal segment masses (the shipped drop jump: 75.3 kg, where the plates weigh the
    subject at 94.5 kg). A model whose centre of mass cannot follow the forces it is asked
    to match makes the tracker fight the data: with 75.3 kg the shipped drop jump's
    estimate lost control at the second landing and fit the vertical force to 4.4 % BW,
    with the implied mass 3.5 % BW and no loss of control (README, "Lab recordings")."""
    mb = rec.facts.get('momentum_balance', {})
    mass = mb.get('implied_mass_kg')
    if mass is None or abs(mass / rec.subject.mass_kg - 1.0) <= MASS_TOLERANCE:
        return rec
    model_mass = rec.subject.mass_kg
    out = with_implied_mass(rec)
    out.facts['warnings'].append(
        f'the force plates imply a body mass of {mass:.1f} kg ({mb["implied_mass_method"]}), '
        f'{100 * (mass / model_mass - 1):+.1f} % from the model\'s {model_mass:.1f} kg (more '
        f'than {100 * MASS_TOLERANCE:g} %): the subject model uses {mass:.1f} kg, its '
        'segment masses scaled to it (--mass model keeps the model\'s masses, --mass KG sets '
        'the measured one)')
    out.facts['mass_from'] = (f'implied by the recording (the model\'s {model_mass:.1f} kg '
                              f'differ by more than {100 * MASS_TOLERANCE:g} %)')
    return out


def with_subject_paths(rec: LabRecording, model: str | os.PathLike) -> LabRecording:
    """The recording with its subject's muscle paths taken from the subject's own model
    (``subject_scaling.yaml`` ``muscle_groups``; ``nmt_ros.model.subject``,
    ``paths_from_moment_arms``), with its muscles' strengths and fibre lengths and its
    clamped joint ranges (``joint_ranges_from_moment_arms``); groups the model lacks keep
    the scaled jumper's path and are reported in ``facts['subject_paths']``."""
    from nmt_ros.model.subject import (
        joint_ranges_from_moment_arms,
        moment_arm_spec,
        paths_from_moment_arms,
        strengths_from_moment_arms,
    )
    from nmt_ros.osim.subject_process import subject_moment_arms
    try:
        arms = subject_moment_arms(model, moment_arm_spec())
    except ValueError as exc:          # a model OpenSim cannot pose as the jumper's joints
        rec.facts['subject_paths'] = {'from_model': [], 'error': str(exc)}
        rec.facts.setdefault('warnings', []).append(
            f"muscle paths: the scaled jumper's ({model} gave no moment arms: {exc})")
        return rec
    scale = replace(rec.scale, paths={}, f0_n={}, f0_source='', l_opt_m={},
                    joint_range_rad={})
    paths = paths_from_moment_arms(scale_parameters(load_parameters(), scale), arms)
    f0, l_opt = strengths_from_moment_arms(arms)
    ranges = joint_ranges_from_moment_arms(arms)
    facts = {'from_model': sorted(paths),
             'joint_range_deg': {n: [round(float(np.degrees(v)), 2) for v in r]
                                 for n, r in ranges.items()},
             'max_isometric_force_n': {n: round(v, 1) for n, v in f0.items()},
             'optimal_fiber_length_m': {n: round(v, 4) for n, v in l_opt.items()},
             'moment_arm_fit_rms_mm': {n: round(1e3 * p['moment_arm_rms_m'], 3)
                                       for n, p in paths.items()},
             'kept_jumper': {n: f'none of {" | ".join(m)} in the model'
                             for n, m in arms['missing'].items()}}
    rec.facts['subject_paths'] = facts
    source = (f'{Path(model).name}: the members\' max_isometric_force summed (two legs) and '
              'optimal_fiber_length F0-weighted')
    return replace(rec, scale=replace(scale, paths=paths, f0_n=f0, l_opt_m=l_opt,
                                      f0_source=source if f0 else '',
                                      joint_range_rad=ranges))


def check_momentum(rec: LabRecording) -> dict:
    """The recording's momentum balance with its subject's model
    (``nmt_ros.study.momentum_balance``): the implied body mass, the unmeasured support and
    its step-off, in ``rec.facts['momentum_balance']``; a warning in ``rec.facts['warnings']``
    when the implied mass differs from the subject's by more than :data:`MASS_TOLERANCE`."""
    from nmt_ros.model.jumper import JumperModel
    from nmt_ros.model.subject import scale_parameters
    from nmt_ros.study.momentum_balance import momentum_balance
    model = JumperModel(scale_parameters(load_parameters(), rec.scale))
    mb = momentum_balance(model, rec.t_angles, rec.angles, rec.t_angles, rec.ankle,
                          rec.t_wrench, rec.wrench)
    report = mb.report(rec.subject.mass_kg)
    rec.facts['momentum_balance'] = report
    warnings = rec.facts.setdefault('warnings', [])
    implied = mb.implied
    if implied is None:
        warnings.append('no body mass could be estimated from the recording (neither a quiet '
                        'stance on the plates nor a contact between two flights)'
                        + _supported_stretch_hint(report['estimates']))
    elif abs(implied.mass_kg / rec.subject.mass_kg - 1.0) > MASS_TOLERANCE:
        warnings.append(
            f'the force plates imply a body mass of {implied.mass_kg:.1f} kg '
            f'({implied.method}, {implied.interval_s[0]:.3f}..{implied.interval_s[1]:.3f} s), '
            f'{100 * (implied.mass_kg / rec.subject.mass_kg - 1):+.1f} % from the model\'s '
            f'{rec.subject.mass_kg:.1f} kg (more than {100 * MASS_TOLERANCE:g} %): check the '
            'model\'s masses, or give the measured mass with --mass')
    if mb.unmeasured_support_s is not None:
        a, b = mb.unmeasured_support_s
        warnings.append(f'{a:.3f}..{b:.3f} s: the body is supported by something that is not '
                        f'on a force plate (the COM does not fall while the plates read no '
                        f'load); step-off at {b:.3f} s, where `nmt track` starts by default')
    return report


# ---------------------------------------------------------------------------------------------
# the bag
# ---------------------------------------------------------------------------------------------

def write_lab_bag(out: str | os.PathLike, rec: LabRecording) -> Path:
    """The recording as an observation bag (trial time = recording time) + ``subject.yaml``."""
    from nmt_ros.io.trial_bag import write_trial_bag
    from nmt_ros.model.subject import write_subject
    obs = Observations(t_angles=rec.t_angles, angles=rec.angles, t_wrench=rec.t_wrench,
                       wrench=rec.wrench, frame_id=topics.WRENCH_FRAME,
                       t_ankle=rec.t_angles, ankle=rec.ankle)
    s = rec.subject
    custom = {
        'nmt.subject': {'name': s.name, 'mass_kg': s.mass_kg, 'height_m': s.height_m,
                        'body_weight_n': s.mass_kg * load_parameters().gravity,
                        'source': s.source, 'model_file': 'subject.yaml',
                        'implied_mass_kg': rec.facts.get('momentum_balance', {}).get(
                            'implied_mass_kg')},
        'nmt.source': rec.facts.get('sources', {}),
        'nmt.import': {k: v for k, v in rec.facts.items() if k != 'sources'},
    }
    write_trial_bag(out, obs, custom_data=custom)
    write_subject(Path(out), s, rec.scale)
    return Path(out)


def summary(rec: LabRecording) -> dict:
    """Figures of an import, for printing."""
    f = rec.facts
    contact = rec.wrench[:, 1] > 0.02 * rec.subject.mass_kg * 9.80665
    return {'route': f.get('route'), 'frames': int(rec.t_angles.size),
            'angles_rate_hz': round(f['angles_rate_hz'], 3),
            'force_samples': int(rec.t_wrench.size),
            'wrench_rate_hz': round(f['wrench_rate_hz'], 3),
            'time_s': [float(rec.t_angles[0]), float(rec.t_angles[-1])],
            'subject_mass_kg': round(rec.subject.mass_kg, 3),
            'implied_mass_kg': f.get('momentum_balance', {}).get('implied_mass_kg'),
            'implied_mass_method': f.get('momentum_balance', {}).get('implied_mass_method'),
            'step_off_s': f.get('momentum_balance', {}).get('step_off_s'),
            'peak_vertical_force_bw': round(float(rec.wrench[:, 1].max())
                                            / (rec.subject.mass_kg * 9.80665), 3),
            'contact_s': float(contact.sum() / f['wrench_rate_hz']),
            'left_right_rms_deg': {k: round(v, 2) for k, v in f['left_right_rms_deg'].items()},
            'repairs': len(f.get('repairs', [])),
            'angle_range_deg': {n: [round(float(np.rad2deg(rec.angles[:, i].min())), 1),
                                    round(float(np.rad2deg(rec.angles[:, i].max())), 1)]
                                for i, n in enumerate(SEGMENTS)}}


def summary_json(rec: LabRecording) -> str:
    return json.dumps(summary(rec), indent=1)
