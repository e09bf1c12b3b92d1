"""A movie of a bag: the body scene (``body_scene``) drawn with matplotlib, beside
time-synchronised plots of the ground force and the main muscle forces.

The frames are sampled at ``fps`` from the bag's header times; each takes the newest
coordinates, forces and wrench at or before its instant (the same rule as the live scene).
The source is the estimates (``/nmt/skeletal/generalized_coordinates``, ``/nmt/muscle/forces``,
``/nmt/skeletal/ground_wrench``) when the bag has them, else the truth (``/truth/*``).
Writers: ``.mp4`` through ffmpeg (matplotlib's FFMpegWriter, when ffmpeg is installed),
``.gif`` through Pillow.
"""
from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path

import numpy as np

from nmt_ros.io.bags import bag_info, read_arrays
from nmt_ros.model.parameters import MUSCLES, Q_NAMES
from nmt_ros.model.subject import load_subject_model
from nmt_ros.study.body_scene import BodyDescription, BodyPose, muscle_width_m
from nmt_ros.topics import (
    MUSCLE_FORCES,
    SKELETAL_GENERALIZED_COORDINATES,
    SKELETAL_GROUND_WRENCH,
    TRUTH_GENERALIZED_COORDINATES,
    TRUTH_GROUND_WRENCH,
    TRUTH_MUSCLE_FORCES,
)

#: The muscles plotted beside the body (the prime movers of a jump).
MAIN_MUSCLES = ('gmax', 'hams', 'vas', 'gas', 'sol')
SOURCES = {
    'estimates': (SKELETAL_GENERALIZED_COORDINATES, MUSCLE_FORCES, SKELETAL_GROUND_WRENCH),
    'truth': (TRUTH_GENERALIZED_COORDINATES, TRUTH_MUSCLE_FORCES, TRUTH_GROUND_WRENCH),
}


@dataclass
class MovieData:
    """What the movie shows, sampled at the frame instants ``t_s[n]`` (s from the start)."""

    source: str
    t_s: np.ndarray              # [n] frame times
    q: np.ndarray                # [n, 6]
    forces: np.ndarray           # [n, 9] N (NaN when the bag has none)
    wrench: np.ndarray           # [n, 3] N, N, N m (NaN when the bag has none)
    series_t_s: np.ndarray       # [m] times of the plotted series
    series_wrench: np.ndarray    # [m, 3]
    forces_t_s: np.ndarray       # [k]
    series_forces: np.ndarray    # [k, 9]


def choose_source(bag: str | os.PathLike, source: str = 'auto') -> str:
    """'estimates' when the bag has estimated coordinates (or as asked), else 'truth'."""
    topics = {t.name for t in bag_info(bag).topics}
    if source != 'auto':
        if SOURCES[source][0] not in topics:
            raise ValueError(f'{bag} has no {SOURCES[source][0]} (topics: {sorted(topics)})')
        return source
    for name in ('estimates', 'truth'):
        if SOURCES[name][0] in topics:
            return name
    raise ValueError(f'{bag} has neither {SOURCES["estimates"][0]} nor '
                     f'{SOURCES["truth"][0]}: nothing to draw')


def _newest_at(stamps: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index of the newest sample at or before each ``t`` (the first sample before them)."""
    return np.clip(np.searchsorted(stamps, t, side='right') - 1, 0, len(stamps) - 1)


def load_movie_data(bag: str | os.PathLike, *, fps: float = 30.0, start_s: float = 0.0,
                    duration_s: float | None = None, source: str = 'auto') -> MovieData:
    """Read the bag's scene topics and sample them at ``fps`` from ``start_s`` (s after the
    coordinates' first stamp) for ``duration_s`` (default: to the end)."""
    source = choose_source(bag, source)
    q_topic, f_topic, w_topic = SOURCES[source]
    topics = {t.name for t in bag_info(bag).topics}
    qs = read_arrays(bag, q_topic)
    if len(qs) == 0:
        raise ValueError(f'{bag}: {q_topic} has no messages')
    t0 = int(qs.stamp_ns[0])
    q_all = qs.position[:, [qs.names.index(n) for n in Q_NAMES]]
    q_t = (qs.stamp_ns - t0) / 1e9
    end = q_t[-1] if duration_s is None else min(q_t[-1], start_s + duration_s)
    if end <= start_s:
        raise ValueError(f'{bag}: nothing to render from {start_s} s (the coordinates end '
                         f'at {q_t[-1]:.3f} s)')
    t = np.arange(start_s, end + 1e-9, 1.0 / fps)
    q = q_all[_newest_at(q_t, t)]
    forces = np.full((len(t), len(MUSCLES)), np.nan)
    f_t, f_all = np.empty(0), np.empty((0, len(MUSCLES)))
    if f_topic in topics:
        fs = read_arrays(bag, f_topic)
        f_t = (fs.stamp_ns - t0) / 1e9
        f_all = fs.effort[:, [fs.names.index(n) for n in MUSCLES]]
        forces = f_all[_newest_at(f_t, t)]
        forces[t < f_t[0]] = np.nan
    wrench = np.full((len(t), 3), np.nan)
    w_t, w_all = np.empty(0), np.empty((0, 3))
    if w_topic in topics:
        ws = read_arrays(bag, w_topic)
        w_t = (ws.stamp_ns - t0) / 1e9
        w_all = np.column_stack([ws.force[:, 0], ws.force[:, 1], ws.torque[:, 2]])
        wrench = w_all[_newest_at(w_t, t)]
        wrench[t < w_t[0]] = np.nan
    keep_w = (w_t >= start_s) & (w_t <= end)
    keep_f = (f_t >= start_s) & (f_t <= end)
    return MovieData(source=source, t_s=t, q=q, forces=forces, wrench=wrench,
                     series_t_s=w_t[keep_w], series_wrench=w_all[keep_w],
                     forces_t_s=f_t[keep_f], series_forces=f_all[keep_f])


def render_movie(data: MovieData, out: str | os.PathLike, *, body: BodyDescription,
                 fps: float = 30.0, dpi: int = 80, title: str = '') -> Path:
    """Draw ``data`` frame by frame into ``out`` (.mp4 with ffmpeg, .gif with Pillow)."""
    import matplotlib

    matplotlib.use('Agg')
    from matplotlib import animation
    from matplotlib.patches import FancyArrowPatch
    import matplotlib.pyplot as plt

    out = Path(out)
    suffix = out.suffix.lower()
    if suffix == '.mp4':
        if not animation.FFMpegWriter.isAvailable():
            raise ValueError('writing .mp4 needs ffmpeg, which is not installed; write a .gif '
                             '(Pillow) instead')
        writer = animation.FFMpegWriter(fps=fps, bitrate=800)
    elif suffix == '.gif':
        writer = animation.PillowWriter(fps=fps)
    else:
        raise ValueError(f'the movie must be .mp4 or .gif, not {out.name!r}')
    poses: list[BodyPose] = body.poses(data.q, data.forces, data.wrench)
    bw = body.body_weight_n

    fig = plt.figure(figsize=(8.0, 4.0), dpi=dpi)
    ax = fig.add_axes([0.0, 0.02, 0.42, 0.9])
    ax_f = fig.add_axes([0.52, 0.56, 0.45, 0.36])
    ax_m = fig.add_axes([0.52, 0.11, 0.45, 0.36], sharex=ax_f)
    x_mid = float(np.nanmedian(data.q[:, 4]))
    top = max(2.0, float(np.nanmax(data.q[:, 5])) + 1.6)
    ax.set_xlim(x_mid - 0.75 * top / 2, x_mid + 0.75 * top / 2)
    ax.set_ylim(-0.1, top - 0.1)
    ax.set_aspect('equal')
    ax.axis('off')
    ax.axhline(0.0, color='0.5', lw=1)
    height_pt = ax.get_window_extent().height * 72.0 / dpi
    pt_per_m = height_pt / top

    bones = {name: ax.plot([], [], color='0.55', lw=5, solid_capstyle='round', zorder=2)[0]
             for name in poses[0].segments}
    muscles = {m.name: ax.plot([], [], lw=2, solid_capstyle='round', zorder=3)[0]
               for m in poses[0].muscles}
    joints = ax.plot([], [], 'o', color='0.25', ms=5, zorder=4)[0]
    com = ax.plot([], [], 'o', color='#f2bf1a', ms=8, mec='k', mew=0.5, zorder=5)[0]
    arrow = FancyArrowPatch((0, 0), (0, 0), arrowstyle='-|>', mutation_scale=12,
                            color='#1a9933', lw=2, zorder=6)
    ax.add_patch(arrow)
    clock = ax.text(0.02, 0.97, '', transform=ax.transAxes, va='top', fontsize=9)
    if title:
        fig.suptitle(title, fontsize=10, x=0.5, y=0.99)

    ax_f.plot(data.series_t_s, data.series_wrench[:, 1] / bw, color='#1a9933', lw=1,
              label='vertical')
    ax_f.plot(data.series_t_s, data.series_wrench[:, 0] / bw, color='#7f4fc9', lw=1,
              label='fore-aft')
    ax_f.set_ylabel('ground force [BW]', fontsize=8)
    ax_f.legend(fontsize=7, loc='upper right', frameon=False)
    f0 = body.f0
    for name in MAIN_MUSCLES:
        j = MUSCLES.index(name)
        ax_m.plot(data.forces_t_s, data.series_forces[:, j] / f0[j], lw=1, label=name.upper())
    ax_m.set_ylabel('muscle force [F0]', fontsize=8)
    ax_m.set_xlabel(f'time [s] ({data.source})', fontsize=8)
    ax_m.legend(fontsize=7, loc='upper right', frameon=False, ncol=len(MAIN_MUSCLES))
    ax_m.set_ylim(0.0, 1.1)
    ax_f.set_xlim(data.t_s[0], data.t_s[-1])
    for a in (ax_f, ax_m):
        a.tick_params(labelsize=7)
    cursors = [a.axvline(data.t_s[0], color='k', lw=0.8) for a in (ax_f, ax_m)]

    def draw(i: int) -> None:
        pose = poses[i]
        for name, line in bones.items():
            pts = pose.segments[name]
            line.set_data(pts[:, 0], pts[:, 1])
        for m in pose.muscles:
            line = muscles[m.name]
            line.set_data(m.points[:, 0], m.points[:, 1])
            line.set_color(m.color)
            line.set_linewidth(float(muscle_width_m(np.nan_to_num(m.fraction))) * pt_per_m)
        pts = np.array(list(pose.joints.values()))
        joints.set_data(pts[:, 0], pts[:, 1])
        com.set_data([pose.com[0]], [pose.com[1]])
        if pose.cop is None:
            arrow.set_visible(False)
        else:
            arrow.set_visible(True)
            arrow.set_positions(tuple(pose.cop), tuple(pose.grf_tip))
        clock.set_text(f't = {data.t_s[i]:6.2f} s')
        for c in cursors:
            c.set_xdata([data.t_s[i], data.t_s[i]])

    out.parent.mkdir(parents=True, exist_ok=True)
    with writer.saving(fig, str(out), dpi):
        for i in range(len(poses)):
            draw(i)
            writer.grab_frame()
    plt.close(fig)
    return out


def render_bag(bag: str | os.PathLike, out: str | os.PathLike, *, fps: float = 30.0,
               start_s: float = 0.0, duration_s: float | None = None, source: str = 'auto',
               dpi: int = 80, subject: str | os.PathLike | None = None) -> Path:
    """``nmt render``: the movie of a bag with its subject's model (``subject``: a bag folder
    or subject YAML; default the bag's own ``subject.yaml``, else the shipped jumper)."""
    data = load_movie_data(bag, fps=fps, start_s=start_s, duration_s=duration_s, source=source)
    body = BodyDescription(load_subject_model(bag if subject is None else subject))
    return render_movie(data, out, body=body, fps=fps, dpi=dpi,
                        title=f'{Path(bag).name}: {data.source}')
