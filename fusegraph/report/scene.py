"""The head system's 3D scene (open3d: PLY/GLB files + a headless PNG, matplotlib without open3d).

Head tracking scene: time runs along x (0.5 m per second). Every 0.5 s the estimated head
attitude is drawn as an axes frame (x red = forward, y green = left, z blue = up) with the true
one beside it in grey; at every sample the tip of the head's forward axis leaves a point, coloured
by the attitude error (viridis, 0 to the 99th percentile), the truth's tips in black. Rendered
offscreen by open3d (Debian packages ``libvulkan1 mesa-vulkan-drivers libusb-1.0-0``, installed by
``make``); without a working renderer the same scene is drawn with matplotlib and the reason is said.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..estimate import Estimate
from ..geometry import FloatArray, matrix_from_quat
from ..metrics import body_errors

METRES_PER_SECOND = 0.5
FRAME_EVERY_S = 0.5
FRAME_SIZE_M = 0.22
TIP_LENGTH_M = 0.35
TRUTH_OFFSET_M = np.array([0.0, 0.0, -0.55])
"""The truth is drawn this far below the estimate, so that neither hides the other."""


@dataclass
class HeadScene:
    """Geometry of the head scene in plain arrays (renderer-independent)."""

    tips_estimate: FloatArray
    tips_truth: FloatArray | None
    error_deg: FloatArray | None
    frame_origins: FloatArray
    frame_rotations: FloatArray
    truth_rotations: FloatArray | None
    title: str
    notes: list[str] = field(default_factory=list)


def head_scene(estimate: Estimate, truth_t: FloatArray | None = None, truth_quat: FloatArray | None = None, title: str = "") -> HeadScene:
    """Build the head scene from an estimate (and the truth at the same instants, if known)."""
    have = np.all(np.isfinite(estimate.quat_wxyz), axis=1)
    t, quat = estimate.t[have], estimate.quat_wxyz[have]
    origins = np.column_stack([(t - t[0]) * METRES_PER_SECOND, np.zeros((len(t), 2))])
    rotations = matrix_from_quat(quat)
    tips = origins + TIP_LENGTH_M * rotations[:, :, 0]
    tips_truth = error_deg = truth_rot = None
    if truth_t is not None and truth_quat is not None:
        truth_q = np.array([np.interp(t, truth_t, truth_quat[:, i]) for i in range(4)]).T
        truth_q /= np.linalg.norm(truth_q, axis=1, keepdims=True)
        truth_rot = matrix_from_quat(truth_q)
        tips_truth = origins + TRUTH_OFFSET_M + TIP_LENGTH_M * truth_rot[:, :, 0]
        error_deg = np.rad2deg(np.linalg.norm(body_errors(quat, truth_q), axis=1))
    step = max(1, int(round(FRAME_EVERY_S / max(np.median(np.diff(t)), 1e-9))))
    pick = np.arange(0, len(t), step)
    return HeadScene(
        tips, tips_truth, error_deg, origins[pick], rotations[pick], None if truth_rot is None else truth_rot[pick], title or estimate.method
    )


def _colors(error_deg: FloatArray | None, n: int) -> tuple[FloatArray, float]:
    import matplotlib

    if error_deg is None:
        return np.tile([0.1, 0.3, 0.8], (n, 1)), 0.0
    top = float(np.percentile(error_deg, 99)) or 1.0
    return np.asarray(matplotlib.colormaps["viridis"](np.clip(error_deg / top, 0, 1))[:, :3]), top


def write_head_scene(scene: HeadScene, out_dir: str | Path, stem: str = "scene_head") -> list[Path]:
    """PLY (error-coloured points), PLY + GLB (axes frames) and a PNG render; returns the files written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    try:
        import open3d as o3d
    except (ImportError, OSError) as exc:  # missing wheel or a system library it needs
        scene.notes.append(f"open3d unavailable ({exc}); PLY/GLB not written, PNG drawn with matplotlib")
        written.append(_render_matplotlib(scene, out / f"{stem}.png"))
        return written
    colors, top = _colors(scene.error_deg, len(scene.tips_estimate))
    points = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scene.tips_estimate))
    points.colors = o3d.utility.Vector3dVector(colors)
    if scene.tips_truth is not None:
        truth_points = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scene.tips_truth))
        truth_points.paint_uniform_color([0.0, 0.0, 0.0])
        points += truth_points
    ply = out / f"{stem}_points.ply"
    o3d.io.write_point_cloud(ply, points)
    written.append(ply)
    frames = o3d.geometry.TriangleMesh()
    for i, origin in enumerate(scene.frame_origins):
        frame = o3d.geometry.TriangleMesh.create_coordinate_frame(size=FRAME_SIZE_M)
        frame.rotate(scene.frame_rotations[i], center=(0, 0, 0))
        frame.translate(origin)
        frames += frame
        if scene.truth_rotations is not None:
            true_frame = o3d.geometry.TriangleMesh.create_coordinate_frame(size=0.7 * FRAME_SIZE_M)
            true_frame.paint_uniform_color([0.55, 0.55, 0.55])
            true_frame.rotate(scene.truth_rotations[i], center=(0, 0, 0))
            true_frame.translate(origin + TRUTH_OFFSET_M)
            frames += true_frame
    frames.compute_vertex_normals()
    frames_ply, glb = out / f"{stem}_frames.ply", out / f"{stem}_frames.glb"
    o3d.io.write_triangle_mesh(frames_ply, frames)  # PLY keeps the vertex colours for the renderer
    o3d.io.write_triangle_mesh(glb, frames)
    written += [frames_ply, glb]
    png = out / f"{stem}.png"
    try:
        image = _render_open3d(ply, frames_ply, out / f".{stem}_raw.png")
    except Exception as exc:  # noqa: BLE001 - any renderer failure (or a hang past the timeout) falls back, and says why
        scene.notes.append(f"open3d offscreen rendering failed ({exc}); PNG drawn with matplotlib")
        written.append(_render_matplotlib(scene, png))
        return written
    _compose_png(image, scene, top, png)
    written.append(png)
    return written


#: Longest a child render may take before the matplotlib fallback is used, seconds.
RENDER_TIMEOUT_S = 120.0


def _render_open3d(points_path: Path, mesh_path: Path, raw_png: Path) -> FloatArray:
    """Render in a child process (see ``fusegraph.report.render3d``); the image as an array."""
    import subprocess

    import matplotlib.image

    command = [sys.executable, "-m", "fusegraph.report.render3d", str(points_path), str(mesh_path), str(raw_png)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=RENDER_TIMEOUT_S)
    if done.returncode != 0 or not raw_png.is_file():
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"renderer exited with {done.returncode}: {last}")
    image = np.asarray(matplotlib.image.imread(raw_png))
    raw_png.unlink()
    return image


def _compose_png(image: FloatArray, scene: HeadScene, top: float, path: Path) -> None:
    """The render with a title, a legend of what is drawn and the error colour bar."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(14, 7.6))
    ax.imshow(image)
    ax.set_axis_off()
    ax.set_title(scene.title + "\n" + _legend_text(scene), fontsize=10)
    if scene.error_deg is not None:
        mappable = plt.cm.ScalarMappable(cmap="viridis", norm=matplotlib.colors.Normalize(0, top))
        fig.colorbar(mappable, ax=ax, fraction=0.025, pad=0.01, label="attitude error [deg]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _legend_text(scene: HeadScene) -> str:
    text = (f"time runs left to right ({METRES_PER_SECOND:g} m per s); axes frames every {FRAME_EVERY_S:g} s "
            "(x red = forward, y green, z blue)")
    if scene.truth_rotations is not None:
        text += ("\ntop row: estimate, forward-axis tip traced and coloured by its error; "
                 "bottom row: the truth (grey frames, black trace)")
    return text


def _render_matplotlib(scene: HeadScene, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors, top = _colors(scene.error_deg, len(scene.tips_estimate))
    fig = plt.figure(figsize=(14, 7))
    ax = fig.add_subplot(projection="3d")
    ax.scatter(*scene.tips_estimate.T, c=colors, s=3)
    if scene.tips_truth is not None:
        ax.scatter(*scene.tips_truth.T, c="black", s=1)
    for origin, rotation in zip(scene.frame_origins, scene.frame_rotations, strict=True):
        for axis, color in zip(rotation.T, ("red", "green", "blue"), strict=True):
            ax.plot(*np.column_stack([origin, origin + FRAME_SIZE_M * axis]), color=color)
    ax.set_title(scene.title + "\n" + _legend_text(scene) + ("\n" + "; ".join(scene.notes) if scene.notes else ""), fontsize=9)
    ax.set_box_aspect((np.ptp(scene.tips_estimate[:, 0]) + 0.5, 1.0, 1.0))
    fig.savefig(path, dpi=100)
    plt.close(fig)
    print(f"note: {'; '.join(scene.notes)}", file=sys.stderr)
    return path


