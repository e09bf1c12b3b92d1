"""Human-readable summaries of metrics.json: terminal lines and the markdown report."""
from __future__ import annotations

import numpy as np

from nmt_ros.model.parameters import JOINTS, MUSCLES, SEGMENTS
from nmt_ros.study.pipeline import STAGE1_LABELS

#: What Seth & Pandy (2007) report (METHOD.md section 5).
PAPER = {'po_cpu_s': 24 * 3600.0, 'po_evaluations': 21000, 'po_jump_cm': 60.1,
         'nmt_jump_cm': 58.8, 'skt_cpu_s': 28.0, 'stage2_cpu_s': 56.0, 'nmt_cpu_s': 84.0}


def _fmt(d: dict, names: tuple[str, ...], fmt: str = '{:.1f}') -> str:
    return ', '.join(f'{n} {fmt.format(d[n])}' for n in names if n in d)


def summary_lines(m: dict) -> list[str]:
    """A short terminal summary of the main figures."""
    a = m['actual']
    lines = [f'actual jump: {a["jump_height_m"] * 100:.2f} cm, lift-off {a["liftoff_s"]:.4f} s']
    s = m['skt']
    name = STAGE1_LABELS[m.get('stage1_method', 'skt')]
    name = name if name == 'SKT' else f'Stage 1 by {name}'
    lines.append(f'{name} ({s["status"]}, CPU {s["cpu_s"]:.2f} s): torque RMS % of peak '
                 f'{_fmt(s["torque_rms_pct_peak"], JOINTS)}; angles RMS deg '
                 f'{_fmt(s["angle_rms_deg"], SEGMENTS, "{:.2f}")} (filtered obs '
                 f'{_fmt(s["filtered_observation_angle_rms_deg"], SEGMENTS, "{:.2f}")}); GRF '
                 f'RMS {s["grf_rms_n"]["fore_aft"]:.1f} / {s["grf_rms_n"]["vertical"]:.1f} N; '
                 f'moment RMS {s["moment_rms_nm"]:.1f} N m')
    i = m['ivd']
    lines.append(f'IVD: torque RMS % of peak {_fmt(i["torque_rms_pct_peak"], JOINTS)}; its '
                 f'simulation lifts off at {i["liftoff_s"]:.4f} s, jump '
                 f'{i["jump_height_m"] * 100:.1f} cm ({i["simulation"]})')
    if 'nmt' in m:
        n = m['nmt']
        lines.append(f'NMT (CPU {n["cpu_s"]:.2f} s): jump {n["jump_height_m"] * 100:.2f} cm '
                     f'({(n["jump_height_m"] / a["jump_height_m"] - 1) * 100:+.1f} %), lift-off '
                     f'{n["liftoff_s"]:.4f} s; torque RMS % of peak '
                     f'{_fmt(n["torque_rms_pct_peak"], JOINTS)}')
        lines.append('NMT muscle force RMS % F0: '
                     + _fmt(n['muscle_force_rms_pct_f0'], MUSCLES))
    return lines


def _row(name: str, ours: str, paper: str) -> str:
    return f'| {name} | {ours} | {paper} |'


def markdown_report(m: dict, title: str = 'nmt_ros: the Seth & Pandy (2007) study') -> str:
    """The report of ``nmt reproduce``: the table of results next to the paper's numbers."""
    a, s, i = m['actual'], m['skt'], m['ivd']
    out = [f'# {title}', '', 'Errors: RMS over the ground-contact phase of the actual jump. '
           'Jump height: ballistic apex of the whole-body centre of mass minus its height '
           'standing upright.', '', '| quantity | nmt_ros | paper |', '|---|---|---|']
    if 'po' in m:
        p = m['po']
        out.append(_row('PO CPU time', f'{p["cpu_s"]:.1f} s ({p["iterations"]} IPOPT '
                        'iterations, 5-start)', '> 24 h (21,000 evaluations)'))
    out.append(_row('actual jump height', f'{a["jump_height_m"] * 100:.1f} cm',
                    f'{PAPER["po_jump_cm"]} cm'))
    out.append(_row('actual lift-off', f'{a["liftoff_s"] * 1000:.1f} ms', '-'))
    out.append(_row('SKT CPU', f'{s["cpu_s"]:.2f} s', f'{PAPER["skt_cpu_s"]:.0f} s'))
    if 'nmt' in m:
        n = m['nmt']
        out.append(_row('Stage 2 CPU', f'{n["cpu_s_parts"].get("stage2", float("nan")):.2f} s',
                        f'{PAPER["stage2_cpu_s"]:.0f} s'))
        out.append(_row('NMT CPU (Stage 1 + 2)', f'{n["cpu_s"]:.2f} s',
                        f'{PAPER["nmt_cpu_s"]:.0f} s'))
        if 'po' in m:
            out.append(_row('PO / NMT CPU ratio', f'{m["po"]["cpu_s"] / n["cpu_s"]:.0f}',
                            '~1000'))
        out.append(_row('NMT jump height', f'{n["jump_height_m"] * 100:.1f} cm '
                        f'({(n["jump_height_m"] / a["jump_height_m"] - 1) * 100:+.1f} %)',
                        f'{PAPER["nmt_jump_cm"]} cm (-2.2 %)'))
        out.append(_row('NMT lift-off error',
                        f'{(n["liftoff_s"] - a["liftoff_s"]) * 1000:+.1f} ms', '-'))
    out.append(_row('IVD simulation', f'lifts off at {i["liftoff_s"] * 1000:.1f} ms, jump '
                    f'{i["jump_height_m"] * 100:.1f} cm', 'leaves the ground early'))
    out += ['', '## Stage 1 (skeletal motion tracker) vs inverse dynamics', '',
            '| joint | SKT torque RMS (N m, % peak) | IVD torque RMS (N m, % peak) |',
            '|---|---|---|']
    for j in JOINTS:
        out.append(f'| {j} | {s["torque_rms_nm"][j]:.1f} ({s["torque_rms_pct_peak"][j]:.1f} %)'
                   f' | {i["torque_rms_nm"][j]:.1f} ({i["torque_rms_pct_peak"][j]:.1f} %) |')
    out += ['', '| segment | SKT angle RMS (deg) | filtered observation RMS (deg) |',
            '|---|---|---|']
    for g in SEGMENTS:
        out.append(f'| {g} | {s["angle_rms_deg"][g]:.2f} | '
                   f'{s["filtered_observation_angle_rms_deg"][g]:.2f} |')
    out += ['', f'Ground forces RMS: fore-aft {s["grf_rms_n"]["fore_aft"]:.1f} N, vertical '
            f'{s["grf_rms_n"]["vertical"]:.1f} N; moment {s["moment_rms_nm"]:.1f} N m '
            f'(filtered observation {s["filtered_observation_moment_rms_nm"]:.1f} N m).']
    if 'nmt' in m:
        n = m['nmt']
        out += ['', '## Stage 2 (neuromuscular tracker): muscle forces vs the actual', '',
                '| muscle | RMS (N) | RMS (% F0) | correlation | peak F/F0 NMT | peak F/F0 '
                'actual | onset NMT (ms) | onset actual (ms) |',
                '|---|---|---|---|---|---|---|---|']
        for k in MUSCLES:
            on_n = n['recruitment_onset_s'][k]
            on_a = a.get('recruitment_onset_s', {}).get(k, float('nan'))
            out.append(
                f'| {k} | {n["muscle_force_rms_n"][k]:.0f} | '
                f'{n["muscle_force_rms_pct_f0"][k]:.1f} | '
                f'{n["muscle_force_correlation"][k]:.2f} | '
                f'{n["muscle_peak_force_over_f0"][k]:.2f} | '
                f'{n["actual_peak_force_over_f0"][k]:.2f} | '
                f'{on_n * 1000 if np.isfinite(on_n) else float("nan"):.0f} | '
                f'{on_a * 1000 if np.isfinite(on_a) else float("nan"):.0f} |')
        out += ['', 'Torque tracking by Stage 2 (C f vs the Stage-1 torques), RMS % of peak: '
                + _fmt(n['stage2_tracking_rms_pct_peak'], JOINTS) + '.',
                'NMT torques vs the actual, RMS % of peak: '
                + _fmt(n['torque_rms_pct_peak'], JOINTS) + '.']
    return '\n'.join(out) + '\n'
