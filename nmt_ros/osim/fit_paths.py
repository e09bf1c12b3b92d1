"""Polynomial musculotendon paths fitted with OpenSim's PolynomialPathFitter.

    python -m nmt_ros.osim.fit_paths             # fit, write jumper.yaml, validate, report
    python -m nmt_ros.osim.fit_paths --check     # validate the paths already in jumper.yaml
    python -m nmt_ros.osim.fit_paths --check --json -    # ... report as JSON on stdout

Source: the 9 right-leg muscles of ``data/opensim/gait10dof18musc.osim`` (GeometryPath with
conditional and moving path points). Each muscle is fitted on its own reduced copy of that
model: only that muscle, and every joint except the ones it spans welded at 0 (pelvis and
left leg included), so the fitter sees exactly the coordinates of ``MUSCLE_COORDINATES``.

How the fitter is driven (OpenSim 4.6):
- ``PolynomialPathFitter`` samples around a "reference trajectory" with a Latin hypercube
  whose random permutations come from an unseeded ``std::random_device``; its fits are
  therefore not reproducible. We give it the sampling grid itself as the trajectory (one
  frame per grid point, ``FIT_STEP_DEG`` apart over ``FIT_RANGES_DEG``) and zero-width
  sampling bounds, so every Latin hypercube sample coincides with its grid point. The
  fitter's outlier filter then drops those duplicates (its log says 50 % of samples
  removed), and the least-squares problem it solves is exactly "lengths and moment arms of
  OpenSim's GeometryPath at the grid points": the fit is deterministic, bit for bit.
- The fitter minimises the squared errors of length and of moment arms (as ``-dl/dq``)
  together, and raises the polynomial order from ``MIN_ORDER`` until the RMS errors are below
  ``LENGTH_TOLERANCE`` and ``MOMENT_ARM_TOLERANCE`` (or ``MAX_ORDER`` is reached).

Ranges (deg): hip_flexion -20..120, knee_angle -120..5, ankle_angle -50..45. The knee stops
at -120 deg (not -130): gait10dof18musc's knee translation splines and the moving path points
of rect_fem and vasti are defined only on [-120, +120] deg, and beyond -120 deg OpenSim's own
lengths get a kink (its ``computeMomentArm`` and ``-dl/dq`` then disagree by ~26 mm). The
iliopsoas conditional path point (psoas_r-P3) is active for hip flexion in [-90, 45] deg, so
its switch sits at 45 deg, inside every range the jump uses; the moment arm has a kink there
(a polynomial smooths it) and the iliopsoas moment arm turns negative above ~98 deg flexion.

Our evaluator convention (model data file): ``l_MT = sum_k c_k prod_j q_j ** e_kj``.
OpenSim's ``MultivariatePolynomialFunction(coefficients, dimension, order)`` stores all terms
of total degree <= order, exponent of the first coordinate slowest and of the last fastest,
each ascending (see ``modeldata.opensim_exponents``); ``to_opensim_function`` and
``from_opensim_function`` convert, and ``opensim_equivalence_error`` checks the two agree.
"""
from __future__ import annotations

import argparse
from collections.abc import Sequence
import datetime
import itertools
import json
import os
from pathlib import Path
import sys
import tempfile
import textwrap
import time

import numpy as np
import opensim as osim

from nmt_ros.osim.modeldata import (
    DATA_FILE,
    MUSCLE_COORDINATES,
    MUSCLES,
    OPENSIM_MUSCLES,
    REPO_ROOT,
    SOURCE_MODEL,
    load_model_data,
    muscle_paths,
    opensim_exponents,
    polynomial_gradient,
    polynomial_value,
    yaml_float,
)

REPORT_FILE = REPO_ROOT / 'nmt_ros' / 'model' / 'data' / 'paths_fit_report.json'
BEGIN_MARK = '# BEGIN GENERATED PATHS'
END_MARK = '# END GENERATED PATHS'
SIDE = '_r'

# Fitting grid (deg): a bit wider than the jump's range of motion (see module docstring).
FIT_RANGES_DEG = {'hip_flexion': (-20.0, 120.0), 'knee_angle': (-120.0, 5.0),
                  'ankle_angle': (-50.0, 45.0)}
MUSCLE_FIT_RANGES_DEG: dict[str, dict[str, tuple[float, float]]] = {}
FIT_STEP_DEG = {1: 1.0, 2: 2.0}          # grid step by number of coordinates
MIN_ORDER = 2
MAX_ORDER = 9
LENGTH_TOLERANCE = 1.0e-4                # m, RMS over the fitting grid
MOMENT_ARM_TOLERANCE = 1.0e-4            # m, RMS over the fitting grid
MOMENT_ARM_THRESHOLD = 1.0e-3            # m, fitter's test for "path depends on coordinate"

# Acceptance: OpenSim's own GeometryPath vs our polynomial over the jump's range of motion.
VALIDATION_RANGES_DEG = {'hip_flexion': (0.0, 110.0), 'knee_angle': (-120.0, 0.0),
                         'ankle_angle': (-30.0, 40.0)}
VALIDATION_STEP_DEG = {1: 0.25, 2: 1.0}
TARGET_LENGTH_RMS = 1.0e-3               # m
TARGET_LENGTH_MAX = 3.0e-3               # m
EQUIVALENCE_TOLERANCE = 1.0e-12          # m, our evaluator vs MultivariatePolynomialFunction


def quiet_opensim(level: str = 'error') -> None:
    """Keep OpenSim from writing opensim.log into the working directory and from chattering."""
    osim.Logger.removeFileSink()
    osim.Logger.setLevelString(level)


# ---------------------------------------------------------------------------------------------
# Coefficient conventions
# ---------------------------------------------------------------------------------------------

def to_opensim_function(exponents: np.ndarray,
                        coefficients: np.ndarray) -> osim.MultivariatePolynomialFunction:
    """Our explicit (exponents, coefficients) -> OpenSim MultivariatePolynomialFunction."""
    e = np.asarray(exponents, dtype=int)
    c = np.asarray(coefficients, dtype=float)
    if e.ndim != 2 or e.shape[0] != c.size or (e < 0).any():
        raise ValueError('exponents must be [n_terms, dimension] non-negative integers')
    dimension = e.shape[1]
    if not 1 <= dimension <= 6:
        raise ValueError('MultivariatePolynomialFunction supports 1 to 6 dimensions')
    order = int(e.sum(axis=1).max())
    index = {powers: k for k, powers in enumerate(opensim_exponents(dimension, order))}
    packed = np.zeros(len(index))
    seen = set()
    for powers, value in zip(map(tuple, e.tolist()), c):
        if powers in seen:
            raise ValueError(f'duplicate term {powers}')
        seen.add(powers)
        packed[index[powers]] = value
    return osim.MultivariatePolynomialFunction(osim.Vector(packed.tolist()), dimension, order)


def from_opensim_function(
        function: osim.Function) -> tuple[np.ndarray, np.ndarray]:
    """OpenSim MultivariatePolynomialFunction -> our (exponents [n, dim], coefficients [n])."""
    f = osim.MultivariatePolynomialFunction.safeDownCast(function)
    if f is None:
        raise TypeError(f'expected a MultivariatePolynomialFunction, got '
                        f'{function.getConcreteClassName()}')
    v = f.getCoefficients()
    coefficients = np.array([v.get(i) for i in range(v.size())])
    exponents = np.array(opensim_exponents(f.getDimension(), f.getOrder()), dtype=int)
    if exponents.shape[0] != coefficients.size:
        raise ValueError(f'{coefficients.size} coefficients for dimension {f.getDimension()}, '
                         f'order {f.getOrder()} (expected {exponents.shape[0]})')
    return exponents, coefficients


def opensim_values(function: osim.Function, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenSim's calcValue and first derivatives of ``function`` at points q [n, dim]."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    values = np.empty(q.shape[0])
    grads = np.empty(q.shape)
    for i, row in enumerate(q):
        x = osim.Vector(row.tolist())
        values[i] = function.calcValue(x)
        for j in range(q.shape[1]):
            which = osim.StdVectorInt()
            which.append(j)
            grads[i, j] = function.calcDerivative(which, x)
    return values, grads


def opensim_equivalence_error(exponents: np.ndarray, coefficients: np.ndarray,
                              n: int = 200, seed: int = 0,
                              half_width: float = 2.2) -> dict[str, float]:
    """Max |ours - OpenSim| of value and gradient at n random points in [-w, w]^dim (rad)."""
    e = np.asarray(exponents, dtype=int)
    f = to_opensim_function(e, coefficients)
    q = np.random.default_rng(seed).uniform(-half_width, half_width, (n, e.shape[1]))
    values, grads = opensim_values(f, q)
    ours = polynomial_value(e, coefficients, q)
    ours_grad = polynomial_gradient(e, coefficients, q)
    back_e, back_c = from_opensim_function(f)
    round_trip = polynomial_value(back_e, back_c, q)
    return {'value': float(np.max(np.abs(ours - values))),
            'gradient': float(np.max(np.abs(ours_grad - grads))),
            'round_trip': float(np.max(np.abs(ours - round_trip)))}


# ---------------------------------------------------------------------------------------------
# Fitting
# ---------------------------------------------------------------------------------------------

def load_source_model(path: Path = SOURCE_MODEL) -> osim.Model:
    return osim.Model(str(path))


def fit_ranges(name: str) -> dict[str, tuple[float, float]]:
    return {c: MUSCLE_FIT_RANGES_DEG.get(name, {}).get(c, FIT_RANGES_DEG[c])
            for c in MUSCLE_COORDINATES[name]}


def grid(ranges_deg: dict[str, tuple[float, float]], step_deg: float) -> np.ndarray:
    """Cartesian grid [n, dim] in rad over the given ranges (inclusive), coordinate order kept."""
    axes = []
    for lo, hi in ranges_deg.values():
        n = int(round((hi - lo) / step_deg)) + 1
        axes.append(np.radians(np.linspace(lo, hi, n)))
    return np.array(list(itertools.product(*axes)))


def reduced_model(name: str, source: Path = SOURCE_MODEL) -> osim.Model:
    """gait10dof18musc with only muscle ``name`` (right leg) and all other joints welded."""
    model = load_source_model(source)
    keep = OPENSIM_MUSCLES[MUSCLES.index(name)] + SIDE
    forces = model.updForceSet()
    for i in reversed(range(forces.getSize())):
        if forces.get(i).getName() != keep:
            forces.remove(i)
    free = {c + SIDE for c in MUSCLE_COORDINATES[name]}
    weld = []
    for coord in model.updCoordinateSet():
        if coord.getName() not in free:
            coord.setDefaultValue(0.0)
            joint = coord.getJoint().getName()
            if joint not in weld:
                weld.append(joint)
    model.finalizeConnections()
    for joint in weld:
        osim.ModelFactory.replaceJointWithWeldJoint(model, joint)
    model.finalizeConnections()
    model.initSystem()
    return model


def fit_muscle(name: str, threads: int | None = None) -> dict:
    """Fit one muscle with PolynomialPathFitter; returns coordinates, exponents, coefficients."""
    coords = MUSCLE_COORDINATES[name]
    ranges = fit_ranges(name)
    points = grid(ranges, FIT_STEP_DEG[len(coords)])
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix='nmt_fit_paths_') as tmp:
        model = reduced_model(name)
        model_file = Path(tmp) / f'{name}.osim'
        model.printToXML(str(model_file))

        table = osim.TimeSeriesTable()
        labels = osim.StdVectorString()
        for c in coords:
            labels.append(model.getCoordinateSet().get(c + SIDE).getAbsolutePathString()
                          + '/value')
        table.setColumnLabels(labels)
        for i, row in enumerate(points):
            table.appendRow(0.01 * i, osim.RowVector(row.tolist()))
        table.addTableMetaDataString('inDegrees', 'no')

        fitter = osim.PolynomialPathFitter()
        fitter.setModel(osim.ModelProcessor(str(model_file)))
        fitter.setCoordinateValues(osim.TableProcessor(table))
        fitter.setOutputDirectory(str(Path(tmp) / 'out'))
        fitter.setMinimumPolynomialOrder(MIN_ORDER)
        fitter.setMaximumPolynomialOrder(MAX_ORDER)
        fitter.setPathLengthTolerance(LENGTH_TOLERANCE)
        fitter.setMomentArmTolerance(MOMENT_ARM_TOLERANCE)
        fitter.setMomentArmThreshold(MOMENT_ARM_THRESHOLD)
        # Zero-width sampling: the Latin hypercube samples coincide with the grid points.
        fitter.setGlobalCoordinateSamplingBounds(osim.Vec2(-1e-300, 1e-300))
        fitter.setNumSamplesPerFrame(1)
        fitter.setUseStepwiseRegression(False)
        fitter.setNumParallelThreads(threads or max(1, min(4, os.cpu_count() or 1)))
        fitter.run()

        result_files = list((Path(tmp) / 'out').glob('*_FunctionBasedPathSet.xml'))
        if len(result_files) != 1:
            raise RuntimeError(f'{name}: PolynomialPathFitter wrote no path set')
        fitted = osim.SetFunctionBasedPaths(str(result_files[0]))
        if fitted.getSize() != 1:
            raise RuntimeError(f'{name}: expected one fitted path, got {fitted.getSize()}')
        path = fitted.get(0)
        paths = path.getCoordinatePaths()
        got = tuple(paths[i].split('/')[-1].removesuffix(SIDE) for i in range(len(paths)))
        if got != coords:
            raise RuntimeError(f'{name}: the fitter chose coordinates {got}, expected {coords}')
        exponents, coefficients = from_opensim_function(path.getLengthFunction())
    return {'coordinates': list(coords), 'exponents': exponents, 'coefficients': coefficients,
            'order': int(exponents.sum(axis=1).max()), 'fit_ranges_deg': ranges,
            'fit_points': int(points.shape[0]), 'seconds': time.perf_counter() - t0}


def fit_all(names: Sequence[str] = MUSCLES, threads: int | None = None,
            verbose: bool = True) -> dict[str, dict]:
    fits = {}
    for name in names:
        fits[name] = fit_muscle(name, threads)
        if verbose:
            f = fits[name]
            print(f'fitted {name:5s} on {"+".join(f["coordinates"]):24s} order {f["order"]} '
                  f'({f["exponents"].shape[0]} terms, {f["fit_points"]} grid points, '
                  f'{f["seconds"]:.1f} s)', file=sys.stderr)
    return fits


# ---------------------------------------------------------------------------------------------
# Data file
# ---------------------------------------------------------------------------------------------

def _wrapped_list(items: list[str], indent: int, width: int = 99) -> str:
    """A YAML flow sequence of pre-formatted items, wrapped (between items) under ``indent``."""
    one_line = '[' + ', '.join(items) + ']'
    if indent + len(one_line) <= width:
        return one_line
    pad = ' ' * (indent + 2)
    lines, line = [], ''
    for item in items:
        piece = item if not line else line + ', ' + item
        if line and len(pad) + len(piece) + 1 > width:
            lines.append(line + ',')
            line = item
        else:
            line = piece
    lines.append(line + ']')
    return '[\n' + '\n'.join(pad + x for x in lines)


def source_text(fits: dict[str, dict], date: str) -> str:
    orders = ', '.join(f'{n} {fits[n]["order"]}' for n in MUSCLES)
    ranges = ', '.join(f'{c} {lo:g}..{hi:g}' for c, (lo, hi) in FIT_RANGES_DEG.items())
    special = ''.join(
        f' {n}: ' + ', '.join(f'{c} {lo:g}..{hi:g}' for c, (lo, hi) in r.items()) + '.'
        for n, r in MUSCLE_FIT_RANGES_DEG.items())
    return (
        f'OpenSim {osim.GetVersion()} PolynomialPathFitter on '
        f'{SOURCE_MODEL.relative_to(REPO_ROOT)} (right-leg muscles, one reduced model per '
        f'muscle with all other joints welded at 0: pelvis, left leg, lumbar). Lengths and '
        f'moment arms of the GeometryPath on a regular grid (deg): {ranges}; step '
        f'{FIT_STEP_DEG[1]:g} deg (1 coordinate), {FIT_STEP_DEG[2]:g} deg (2 coordinates); '
        f'zero-width Latin hypercube bounds so the samples are the grid points '
        f'(deterministic).{special} Order chosen by the fitter in {MIN_ORDER}..{MAX_ORDER} for '
        f'RMS length < {LENGTH_TOLERANCE:g} m and RMS moment arm < {MOMENT_ARM_TOLERANCE:g} m '
        f'(moment_arm_threshold {MOMENT_ARM_THRESHOLD:g} m, no stepwise regression); orders: '
        f'{orders}. Generated {date} by `python -m nmt_ros.osim.fit_paths`; validation in '
        f'nmt_ros/model/data/paths_fit_report.json.')


def paths_yaml(fits: dict[str, dict], date: str) -> str:
    """The text between the BEGIN/END GENERATED PATHS markers."""
    lines = ['paths:', '  source: >-']
    lines += ['    ' + s for s in textwrap.wrap(source_text(fits, date), width=95)]
    for name in MUSCLES:
        f = fits[name]
        exps = [_wrapped_list([str(int(v)) for v in row], 0) for row in f['exponents']]
        coefs = [yaml_float(v) for v in f['coefficients']]
        lines.append(f'  {name}:')
        lines.append(f'    coordinates: [{", ".join(f["coordinates"])}]')
        lines.append('    exponents: ' + _wrapped_list(exps, 4))
        lines.append('    coefficients: ' + _wrapped_list(coefs, 4))
    return '\n'.join(lines) + '\n'


def replace_generated_block(text: str, block: str) -> str:
    """Replace what lies between the marker lines; everything else stays byte-identical."""
    begin = text.index(BEGIN_MARK + '\n') + len(BEGIN_MARK) + 1
    end = text.index(END_MARK, begin)
    if text.rfind('\n', 0, end) != end - 1:
        raise ValueError(f'{END_MARK!r} must start a line')
    return text[:begin] + block + text[end:]


def write_paths(fits: dict[str, dict], data_file: Path = DATA_FILE,
                date: str | None = None) -> None:
    date = date or datetime.date.today().isoformat()
    text = data_file.read_text()
    new = replace_generated_block(text, paths_yaml(fits, date))
    data_file.write_text(new)
    # Read back: the file must give the very same numbers.
    back = muscle_paths(load_model_data(data_file))
    for name in MUSCLES:
        coords, e, c = back[name]
        if (coords != tuple(fits[name]['coordinates'])
                or not np.array_equal(e, fits[name]['exponents'])
                or not np.array_equal(c, fits[name]['coefficients'])):
            raise RuntimeError(f'{name}: the data file does not read back exactly')


# ---------------------------------------------------------------------------------------------
# Validation against OpenSim's GeometryPath
# ---------------------------------------------------------------------------------------------

def geometry_path_samples(model: osim.Model, state: osim.State, names: Sequence[str],
                          coords: Sequence[str], points: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """OpenSim lengths [n, m] and moment arms [n, m, dim] of muscles ``names`` at grid points
    (other coordinates at their current values)."""
    coord_objs = [model.getCoordinateSet().get(c + SIDE) for c in coords]
    muscles = [model.getMuscles().get(OPENSIM_MUSCLES[MUSCLES.index(n)] + SIDE) for n in names]
    gpaths = [m.getGeometryPath() for m in muscles]
    lengths = np.empty((points.shape[0], len(names)))
    arms = np.empty((points.shape[0], len(names), len(coords)))
    for i, row in enumerate(points):
        for c, v in zip(coord_objs, row):
            c.setValue(state, float(v), False)
        model.realizePosition(state)
        for k, p in enumerate(gpaths):
            lengths[i, k] = p.getLength(state)
            for j, c in enumerate(coord_objs):
                arms[i, k, j] = p.computeMomentArm(state, c)
    for c in coord_objs:
        c.setValue(state, 0.0, False)
    return lengths, arms


def check(data_file: Path = DATA_FILE, equivalence_points: int = 200) -> dict:
    """Validate the data file's paths against gait10dof18musc's GeometryPaths; a report dict."""
    t0 = time.perf_counter()
    data = load_model_data(data_file)
    paths = muscle_paths(data)
    model = load_source_model()
    state = model.initSystem()
    for coord in model.getCoordinateSet():   # pelvis, left leg, lumbar at 0 (as in the fit)
        if coord.getName() != 'pelvis_ty':
            coord.setValue(state, 0.0, False)

    groups: dict[tuple[str, ...], list[str]] = {}
    for name in MUSCLES:
        groups.setdefault(paths[name][0], []).append(name)

    muscles = {}
    grids = {}
    for coords, names in groups.items():
        ranges = {c: VALIDATION_RANGES_DEG[c] for c in coords}
        step = VALIDATION_STEP_DEG[len(coords)]
        points = grid(ranges, step)
        grids['+'.join(coords)] = {'ranges_deg': {c: list(r) for c, r in ranges.items()},
                                   'step_deg': step, 'points': int(points.shape[0]),
                                   'muscles': names}
        lengths, arms = geometry_path_samples(model, state, names, coords, points)
        for k, name in enumerate(names):
            _, e, c = paths[name]
            dl = polynomial_value(e, c, points) - lengths[:, k]
            dr = -polynomial_gradient(e, c, points) - arms[:, k, :]
            eq = opensim_equivalence_error(e, c, n=equivalence_points,
                                           seed=MUSCLES.index(name))
            sample_q = np.random.default_rng(100 + MUSCLES.index(name)).uniform(
                -2.0, 2.0, (8, len(coords)))
            sample_l, _ = opensim_values(to_opensim_function(e, c), sample_q)
            muscles[name] = {
                'coordinates': list(coords),
                'order': int(e.sum(axis=1).max()),
                'terms': int(e.shape[0]),
                'length_rms_mm': float(np.sqrt(np.mean(dl ** 2)) * 1e3),
                'length_max_mm': float(np.max(np.abs(dl)) * 1e3),
                'length_range_mm': [float(lengths[:, k].min() * 1e3),
                                    float(lengths[:, k].max() * 1e3)],
                'moment_arm_rms_mm': float(np.sqrt(np.mean(dr ** 2)) * 1e3),
                'moment_arm_max_mm': float(np.max(np.abs(dr)) * 1e3),
                'moment_arm_by_coordinate_mm': {
                    cn: {'rms': float(np.sqrt(np.mean(dr[:, j] ** 2)) * 1e3),
                         'max': float(np.max(np.abs(dr[:, j])) * 1e3)}
                    for j, cn in enumerate(coords)},
                'opensim_equivalence_max_abs': eq,
                'opensim_samples': {'q': sample_q.tolist(), 'length': sample_l.tolist()},
            }
            muscles[name]['pass'] = bool(
                muscles[name]['length_rms_mm'] < TARGET_LENGTH_RMS * 1e3
                and muscles[name]['length_max_mm'] < TARGET_LENGTH_MAX * 1e3
                and max(eq.values()) <= EQUIVALENCE_TOLERANCE)
    report = {
        'opensim_version': osim.GetVersion(),
        'source_model': str(SOURCE_MODEL.relative_to(REPO_ROOT)),
        'data_file': str(Path(data_file).resolve().relative_to(REPO_ROOT))
        if Path(data_file).resolve().is_relative_to(REPO_ROOT) else str(data_file),
        'convention': 'l_MT = sum_k c_k prod_j q_j ** e_kj (q rad); moment arm = -dl/dq',
        'reference': 'GeometryPath.getLength and computeMomentArm of the unmodified model, '
                     'right-leg coordinates on the grid, all other coordinates 0',
        'targets_mm': {'length_rms': TARGET_LENGTH_RMS * 1e3,
                       'length_max': TARGET_LENGTH_MAX * 1e3},
        'equivalence_tolerance_m': EQUIVALENCE_TOLERANCE,
        'grids': grids,
        'muscles': {n: muscles[n] for n in MUSCLES},
        'pass': all(muscles[n]['pass'] for n in MUSCLES),
    }
    report['_seconds'] = time.perf_counter() - t0
    return report


def format_table(report: dict) -> str:
    head = (f'{"muscle":6s} {"coordinates":24s} {"ord":>3s} {"L rms":>7s} {"L max":>7s} '
            f'{"r rms":>7s} {"r max":>7s} {"equiv":>8s}  (mm; equiv in m)')
    lines = [head, '-' * len(head)]
    for name, m in report['muscles'].items():
        eq = max(m['opensim_equivalence_max_abs'].values())
        lines.append(f'{name:6s} {"+".join(m["coordinates"]):24s} {m["order"]:3d} '
                     f'{m["length_rms_mm"]:7.3f} {m["length_max_mm"]:7.3f} '
                     f'{m["moment_arm_rms_mm"]:7.3f} {m["moment_arm_max_mm"]:7.3f} '
                     f'{eq:8.1e}  {"ok" if m["pass"] else "FAIL"}')
    lines.append(f'targets: length RMS < {report["targets_mm"]["length_rms"]:g} mm, '
                 f'max < {report["targets_mm"]["length_max"]:g} mm; '
                 f'{"all pass" if report["pass"] else "FAILED"}')
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m nmt_ros.osim.fit_paths',
        description='Fit polynomial musculotendon paths with OpenSim and validate them.')
    parser.add_argument('--check', action='store_true',
                        help='only validate the paths already in the data file')
    parser.add_argument('--data-file', type=Path, default=DATA_FILE)
    parser.add_argument('--json', default=None, metavar='FILE',
                        help=f'where to write the report ("-" = stdout; default '
                             f'{REPORT_FILE.relative_to(REPO_ROOT)})')
    parser.add_argument('--threads', type=int, default=None)
    args = parser.parse_args(argv)
    quiet_opensim()
    out = sys.stderr if args.json == '-' else sys.stdout

    t0 = time.perf_counter()
    if not args.check:
        fits = fit_all(threads=args.threads)
        write_paths(fits, args.data_file)
        print(f'wrote {len(fits)} paths to {args.data_file} '
              f'({time.perf_counter() - t0:.1f} s)', file=out)
    report = check(args.data_file)
    seconds = report.pop('_seconds')
    print(format_table(report), file=out)
    print(f'validation: {seconds:.1f} s', file=out)
    text = json.dumps(report, indent=2) + '\n'
    if args.json == '-':
        sys.stdout.write(text)
    else:
        target = Path(args.json) if args.json else REPORT_FILE
        target.write_text(text)
        print(f'report: {target}', file=out)
    return 0 if report['pass'] else 1


if __name__ == '__main__':
    sys.exit(main())
