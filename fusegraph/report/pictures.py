"""Every system's picture by name: ``PICTURES[system](session, estimates, out_dir) -> [files]`` (``run --plot``,
``view``, ``report --plot``): the estimates against the truth, or against each other without truth."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..estimate import Estimate, PointEstimate, Result
from ..session import Session


def _attitude_picture(session: Session, estimates: list[Result], out: Path) -> list[Path]:
    """Attitude axes with 3-sigma bands against the truth (or the first estimate without truth)."""
    from .plots import plot_attitude_axes

    attitude = [e for e in estimates if isinstance(e, Estimate)]
    truth = session.truth
    if truth is not None and truth.kind == "attitude":
        t, q = truth.t, truth.values
    else:
        t, q = attitude[0].t, attitude[0].quat_wxyz
    name = "_".join(e.method for e in attitude)
    title = f"{session.system}: {', '.join(e.method for e in attitude)}" + ("" if truth is not None else " (no truth)")
    return [plot_attitude_axes(t, q, attitude, out / f"attitude_{name}.png", title=title)]


def _head_picture(session: Session, estimates: list[Result], out: Path) -> list[Path]:
    from .scene import head_scene, write_head_scene

    written = _attitude_picture(session, estimates, out)
    first = estimates[0]
    assert isinstance(first, Estimate)
    truth = session.truth
    scene = head_scene(first, truth.t if truth else None, truth.values if truth else None, title=f"{session.system}: {first.method}: 3D view")
    return written + write_head_scene(scene, out)


def _gaze_ray_picture(session: Session, estimates: list[Result], out: Path) -> list[Path]:
    """A session whose truth is the eye's world ray (``import broad --system gaze``): the world gaze azimuth over time, each
    estimate's (its head attitude turning the tracker's ray) against the truth, and the angle between them."""
    import matplotlib.pyplot as plt

    from ..factors.gaze import SceneCamera
    from ..geometry import rotate_by_quat
    from .plots import save_figure

    gaze, truth = session.stream("gaze"), session.truth
    assert truth is not None
    rays = SceneCamera.from_meta(gaze.meta, ("focal_px", "width_px", "height_px")).ray(gaze.values)
    fig, axes = plt.subplots(1, 2, figsize=(13, 5))
    axes[0].plot(truth.t, np.degrees(np.arctan2(truth.values[:, 1], truth.values[:, 0])), color="black", lw=1.5, label="truth (simulated eye)")
    for e in estimates:
        attitude = e.extras.get("world_R_head") if isinstance(e, PointEstimate) else None
        if attitude is None or len(attitude) != len(rays):
            continue
        world = rotate_by_quat(np.asarray(attitude, dtype=float), rays)  # NaN (nothing drawn) where no attitude yet
        axes[0].plot(e.t, np.degrees(np.arctan2(world[:, 1], world[:, 0])), lw=0.8, label=e.method)
        error = np.degrees(np.arccos(np.clip(np.sum(world * truth.values, axis=1), -1.0, 1.0)))
        axes[1].plot(e.t, np.maximum(error, 1e-3), lw=0.8, label=e.method)
    axes[0].set(xlabel="time [s]", ylabel="world gaze azimuth [deg]", title="where the eye looked in the world")
    axes[1].set(xlabel="time [s]", ylabel="angle to the true gaze ray [deg]", title="gaze error (saccades included)", yscale="log")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return [save_figure(fig, out / f"gaze_{'_'.join(e.method for e in estimates)}.png")]


def _gaze_picture(session: Session, estimates: list[Result], out: Path) -> list[Path]:
    """The gaze point on the wall (X right, Z up), each estimate against the truth."""
    import matplotlib.pyplot as plt

    from .plots import save_figure

    if session.meta.get("session", {}).get("gaze_truth") == "world_ray" and session.truth is not None:
        return _gaze_ray_picture(session, estimates, out)
    fig, axes = plt.subplots(1, 2, figsize=(13, 5))
    truth = session.truth
    if truth is not None:
        axes[0].plot(truth.values[:, 1], truth.values[:, 2], color="black", lw=2, label="truth")
    for e in estimates:
        if isinstance(e, PointEstimate):
            axes[0].plot(e.points[:, 0, 0], e.points[:, 0, 1], lw=0.8, label=e.method)
            if truth is not None and len(truth.t) == len(e.t):
                axes[1].plot(e.t, 1000 * np.linalg.norm(e.points[:, 0, :] - truth.values[:, 1:3], axis=1), lw=0.8, label=e.method)
    axes[0].set(xlabel="wall X = world y [m]", ylabel="wall Z = world z [m]", title="gaze point on the wall", aspect="equal")
    axes[1].set(xlabel="time [s]", ylabel="error [mm]", title="distance to the true gaze point", yscale="log")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return [save_figure(fig, out / f"gaze_{'_'.join(e.method for e in estimates)}.png")]


def _walking_picture(session: Session, estimates: list[Result], out: Path) -> list[Path]:
    """The walk per floor (top views), each estimate against the truth."""
    import matplotlib.pyplot as plt

    from .plots import save_figure

    height = float(session.meta.get("building", {}).get("floor_height_m", 3.5))
    truth = session.truth
    tracks = [(e.method, e.points[:, 0, :]) for e in estimates if isinstance(e, PointEstimate)]
    # the floors are the building's (where the truth walks, else the declared count): an estimate's drift in height
    # does not invent a floor, its points on none of them are drawn on the nearest
    if truth is not None:
        floors = sorted(set(np.round(truth.values[np.isfinite(truth.values[:, 2]), 2] / height).astype(int).tolist())) or [0]
    else:
        floors = list(range(int(session.meta.get("building", {}).get("floors", 1))))
    tracks = [(name, np.column_stack([xyz[:, :2], height * np.clip(np.round(xyz[:, 2] / height), floors[0], floors[-1])])) for name, xyz in tracks]
    fig, axes = plt.subplots(1, len(floors), figsize=(5 * len(floors), 5), squeeze=False)
    for ax, floor in zip(axes[0], floors, strict=True):
        if truth is not None:
            on = np.round(truth.values[:, 2] / height) == floor
            ax.plot(np.where(on, truth.values[:, 0], np.nan), np.where(on, truth.values[:, 1], np.nan), color="black", lw=2, label="truth")
        for name, xyz in tracks:
            on = np.round(xyz[:, 2] / height) == floor
            ax.plot(np.where(on, xyz[:, 0], np.nan), np.where(on, xyz[:, 1], np.nan), lw=1, marker=".", ms=2, label=name)
        ax.set(title=f"floor {floor}", xlabel="x east [m]", ylabel="y north [m]", aspect="equal")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    return [save_figure(fig, out / f"walk_{'_'.join(n for n, _ in tracks)}.png")]


def _ultrasonic_picture(session: Session, estimates: list[Result], out: Path) -> list[Path]:
    """The receivers and every tag's track in 3D, and each tag's error over time."""
    import matplotlib.pyplot as plt

    from ..metrics import identity_map
    from ..records import epochs_from_session
    from .plots import save_figure

    epochs = epochs_from_session(session)
    fig = plt.figure(figsize=(14, 6))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax3.scatter(*epochs.receivers.T, marker="s", color="grey", label="receivers")
    if epochs.positions is not None:
        for j in range(epochs.positions.shape[1]):
            ax3.plot(*epochs.positions[:, j].T, color="black", lw=1.5, label="truth" if j == 0 else None)
    ax2 = fig.add_subplot(1, 2, 2)
    for e in estimates:
        if not isinstance(e, PointEstimate):
            continue
        for j in range(e.points.shape[1]):
            (line,) = ax3.plot(*e.points[:, j].T, lw=0.8, label=f"{e.method}" if j == 0 else None)
        if epochs.positions is not None:
            errors = []
            for k in range(len(e.t)):
                mapping = identity_map(e.points[k], epochs.positions[k])
                matched = np.full_like(epochs.positions[k], np.nan)
                matched[mapping[mapping >= 0]] = e.points[k][mapping >= 0]
                errors.append(np.linalg.norm(matched - epochs.positions[k], axis=1))
            ax2.plot(e.t, 1000 * np.array(errors), lw=0.6, color=line.get_color())
    ax3.set(xlabel="x [m]", ylabel="y [m]", zlabel="z [m]", title="tags and receivers")
    ax3.legend(fontsize=8)
    ax2.set(xlabel="time [s]", ylabel="error per tag [mm]", yscale="log", title="position error (each tag matched to the truth)")
    ax2.grid(alpha=0.3)
    return [save_figure(fig, out / f"tags_{'_'.join(e.method for e in estimates)}.png")]


Picture = Callable[[Session, list[Result], Path], list[Path]]
"""Figures of estimates of one session, written into a folder."""

PICTURES: dict[str, Picture] = {"head": _head_picture, "attitude9": _attitude_picture, "gaze": _gaze_picture, "bicycle": _attitude_picture,
                                "walking": _walking_picture, "ultrasonic": _ultrasonic_picture}
"""Every system's picture by name."""
