"""OpenSim file formats written without OpenSim (``nmt_ros.io.opensim_files``).

Round trips in this process; OpenSim itself (a subprocess: it cannot share a process with
casadi) reads what we write: ``TimeSeriesTable``, ``Storage`` and ``ExternalLoads``.
"""
from __future__ import annotations

import json
from pathlib import Path
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from nmt_ros.io import opensim_files as of

REPO = Path(__file__).resolve().parents[1]


def _random_table(rng: np.random.Generator, n: int = 17) -> tuple[np.ndarray, np.ndarray]:
    t = np.cumsum(rng.uniform(1e-4, 1e-2, n))
    data = rng.normal(size=(n, 4)) * 10.0 ** rng.integers(-9, 9, (n, 4))
    return t, data


def test_table_round_trip_is_exact(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    t, data = _random_table(rng)
    labels = ['a', 'b_c', 'knee_angle', 'x y']
    path = of.write_table(tmp_path / 'x.sto', t, labels, data, in_degrees=True,
                          metadata={'source': 'test'})
    text = path.read_text().splitlines()
    assert text[:6] == ['x', 'version=1', f'nRows={t.size}', 'nColumns=5', 'inDegrees=yes',
                        'source=test']
    assert text[6] == 'endheader'
    assert text[7].split('\t') == ['time', *labels]
    table = of.read_table(path)
    assert table.labels == tuple(labels)
    assert table.in_degrees
    assert table.name == 'x'
    assert table.metadata['source'] == 'test'
    np.testing.assert_array_equal(table.time, t)
    np.testing.assert_array_equal(table.data, data)
    np.testing.assert_array_equal(table.columns(['knee_angle', 'a']), data[:, [2, 0]])
    with pytest.raises(ValueError, match='missing column.*hip_flexion.*foot_tx'):
        table.columns(['a', 'hip_flexion', 'foot_tx'])


def test_reads_opensim_writer_formats(tmp_path: Path) -> None:
    # STOFileAdapter (version 3, no nRows) and an old .mot with spaces and a name line.
    (tmp_path / 'v3.sto').write_text(
        'inDegrees=no\nDataType=double\nversion=3\nOpenSimVersion=4.6\nendheader\n'
        'time\tfoot_tilt\tfoot_tx\n0\t1\t2\n0.1\t-1.5e-05\t3\n')
    table = of.read_table(tmp_path / 'v3.sto')
    assert table.labels == ('foot_tilt', 'foot_tx') and not table.in_degrees
    np.testing.assert_array_equal(table.data, [[1, 2], [-1.5e-5, 3]])
    (tmp_path / 'old.mot').write_text(
        'Coordinates\nversion=1\nnRows=2\nnColumns=2\ninDegrees=yes\n\nUnits are S.I.\n'
        'endheader\ntime      knee_angle\n 0.0  -10.0\n 0.5  -20.0\n')
    table = of.read_table(tmp_path / 'old.mot')
    assert table.name == 'Coordinates' and table.in_degrees
    np.testing.assert_array_equal(table.column('knee_angle'), [-10.0, -20.0])
    (tmp_path / 'bad.sto').write_text('version=1\ntime\ta\n0\t1\n')
    with pytest.raises(ValueError, match='endheader'):
        of.read_table(tmp_path / 'bad.sto')


def test_grf_mot_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    n = 9
    t = np.linspace(0.0, 0.08, n)
    force, point, torque = rng.normal(size=(3, n, 3))
    path = of.write_grf_mot(tmp_path / 'grf.mot', t, force, point, torque)
    table = of.read_table(path)
    assert list(table.labels) == [
        'ground_force_vx', 'ground_force_vy', 'ground_force_vz', 'ground_force_px',
        'ground_force_py', 'ground_force_pz', 'ground_torque_x', 'ground_torque_y',
        'ground_torque_z']
    t2, load = of.read_grf_mot(path)
    np.testing.assert_array_equal(t2, t)
    for got, want in zip(load, (force, point, torque)):
        np.testing.assert_array_equal(got, want)
    # Planar inputs are padded with z = 0; no torque means zero torque.
    of.write_grf_mot(tmp_path / 'p.mot', t, force[:, :2], point[:, :2], prefix='r_grf',
                     torque_prefix='r_tq')
    _, load = of.read_grf_mot(tmp_path / 'p.mot', prefix='r_grf', torque_prefix='r_tq')
    np.testing.assert_array_equal(load.force[:, 2], 0.0)
    np.testing.assert_array_equal(load.torque, 0.0)
    with pytest.raises(ValueError, match='ground_force_vx'):
        of.read_grf_mot(tmp_path / 'p.mot')


def test_ground_wrench_to_cop_is_exact() -> None:
    rng = np.random.default_rng(3)
    n = 400
    # Heel and toe on (or near) the ground; the foot loaded, then unloading to zero.
    points = np.stack([np.column_stack([rng.uniform(-0.1, 0.0, n), rng.uniform(0.2, 0.3, n)]),
                       rng.uniform(-2e-3, 2e-3, (n, 2))], axis=1)        # [n, 2, k]
    load_profile = np.clip(np.linspace(1.5, -0.3, n), 0.0, None)
    fy = rng.uniform(0.0, 800.0, (n, 2)) * load_profile[:, None]
    fx = rng.uniform(-0.5, 0.5, (n, 2)) * fy
    forces = np.stack([fx, fy], axis=1)
    load = of.ground_wrench_to_cop(points, forces, fy_min=10.0)
    ref = rng.normal(size=(n, 2))
    direct = (((points[:, 0] - ref[:, [0]]) * forces[:, 1]
               - (points[:, 1] - ref[:, [1]]) * forces[:, 0]).sum(axis=1))
    np.testing.assert_allclose(load.moment_about(ref), direct, rtol=0, atol=1e-9)
    np.testing.assert_allclose(load.force[:, :2], forces.sum(axis=2), rtol=0, atol=1e-12)
    assert np.all(load.point[:, 1:] == 0.0) and np.all(load.force[:, 2] == 0.0)
    assert np.all(load.torque[:, :2] == 0.0)
    total_fy = forces[:, 1].sum(axis=1)
    loaded = total_fy >= 20.0
    # The point is the centre of pressure where loaded (no free torque there) ...
    np.testing.assert_allclose(load.torque[loaded, 2], 0.0, atol=1e-9)
    # ... and holds the last one once unloaded.
    last = np.flatnonzero(loaded)[-1]
    unloaded = np.arange(n) > last
    unloaded &= total_fy <= 10.0
    assert unloaded.sum() > 50
    np.testing.assert_allclose(load.point[unloaded, 0], load.point[last, 0], atol=0)
    # Never loaded: the mean x of the points.
    none = of.ground_wrench_to_cop(points[:3], np.zeros((3, 2, 2)))
    np.testing.assert_allclose(none.point[:, 0], points[:3, 0].mean(axis=1))


def test_external_loads_xml_round_trip(tmp_path: Path) -> None:
    (tmp_path / 'data').mkdir()
    xml = of.write_external_loads_xml(tmp_path / 'loads.xml', tmp_path / 'data' / 'grf.mot')
    datafile, forces = of.read_external_loads_xml(xml)
    assert datafile.resolve() == (tmp_path / 'data' / 'grf.mot').resolve()
    assert '<datafile>data/grf.mot</datafile>' in xml.read_text()
    (f,) = forces
    assert (f.applied_to_body, f.force_expressed_in_body, f.point_expressed_in_body) == (
        'foot', 'ground', 'ground')
    assert (f.force_identifier, f.point_identifier, f.torque_identifier) == (
        'ground_force_v', 'ground_force_p', 'ground_torque_')


OPENSIM_READER = textwrap.dedent('''
    import json, sys
    import opensim as osim
    out = {}
    for key, path in (('sto', sys.argv[1]), ('mot', sys.argv[2])):
        table = osim.TimeSeriesTable(path)
        storage = osim.Storage(path)
        labels = storage.getColumnLabels()
        columns = []
        for j in range(1, labels.getSize()):
            col = osim.ArrayDouble()
            storage.getDataColumn(labels.get(j), col)
            columns.append([col.get(i) for i in range(col.getSize())])
        t = osim.ArrayDouble()
        storage.getTimeColumn(t)
        out[key] = {
            'table_labels': list(table.getColumnLabels()),
            'table_time': list(table.getIndependentColumn()),
            'table_values': table.getMatrix().to_numpy().tolist(),
            'in_degrees': table.getTableMetaDataAsString('inDegrees'),
            'keys': list(table.getTableMetaDataKeys()),
            'storage_labels': [labels.get(j) for j in range(labels.getSize())],
            'storage_in_degrees': storage.isInDegrees(),
            'storage_time': [t.get(i) for i in range(t.getSize())],
            'storage_columns': columns,
        }
    loads = osim.ExternalLoads(sys.argv[3], True)
    force = loads.get(0)
    out['loads'] = {
        'size': loads.getSize(), 'datafile': loads.getDataFileName(),
        'body': force.get_applied_to_body(),
        'force_in': force.get_force_expressed_in_body(),
        'point_in': force.get_point_expressed_in_body(),
        'ids': [force.get_force_identifier(), force.get_point_identifier(),
                force.get_torque_identifier()],
    }
    grf = osim.Storage(sys.argv[2])
    force.setDataSource(grf)
    out['loads']['applies'] = [force.appliesForce(), force.specifiesPoint(),
                               force.appliesTorque()]
    print(json.dumps(out))
''')


@pytest.mark.opensim
def test_opensim_reads_our_files(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    n = 12
    t = np.linspace(0.0, 0.011, n)
    coords = rng.normal(size=(n, 6))
    labels = ['foot_tilt', 'foot_tx', 'foot_ty', 'ankle_angle', 'knee_angle', 'hip_flexion']
    sto = of.write_table(tmp_path / 'coordinates.sto', t, labels, coords, in_degrees=True,
                         metadata={'source': 'nmt ivd (a test)', 'residuals': 'hat'})
    force, point, torque = rng.normal(size=(3, n, 3))
    mot = of.write_grf_mot(tmp_path / 'grf.mot', t, force, point, torque)
    xml = of.write_external_loads_xml(tmp_path / 'loads.xml', mot)
    proc = subprocess.run([sys.executable, '-c', OPENSIM_READER, str(sto), str(mot), str(xml)],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    for key, want_labels, want in (('sto', labels, coords),
                                   ('mot', of.grf_labels(), np.hstack([force, point, torque]))):
        got = out[key]
        assert got['table_labels'] == want_labels
        assert got['storage_labels'] == ['time', *want_labels]
        np.testing.assert_array_equal(got['table_time'], t)
        np.testing.assert_array_equal(got['storage_time'], t)
        # Our decimals are exact: OpenSim parses back the very same doubles.
        np.testing.assert_array_equal(got['table_values'], want)
        np.testing.assert_array_equal(np.transpose(got['storage_columns']), want)
    assert out['sto']['in_degrees'] == 'yes' and out['sto']['storage_in_degrees']
    assert {'source', 'residuals'} <= set(out['sto']['keys'])
    assert out['mot']['in_degrees'] == 'no' and not out['mot']['storage_in_degrees']
    loads = out['loads']
    assert loads['size'] == 1 and loads['datafile'] == 'grf.mot'
    assert (loads['body'], loads['force_in'], loads['point_in']) == ('foot', 'ground', 'ground')
    assert loads['ids'] == ['ground_force_v', 'ground_force_p', 'ground_torque_']
    assert loads['applies'] == [True, True, True]
    # (test_opensim_id_crosscheck.py checks that OpenSim's InverseDynamicsTool applies it.)
    print(f'\nOpenSim read {sto.name}, {mot.name}, {xml.name}: exact values, labels, flags')
