"""Headless open3d render of saved geometry, run in a child process: ``python -m fusegraph.report.render3d``.

open3d's offscreen renderer (Filament) hangs when a process creates it more than once or twice, so
every render gets a fresh process that exits without running the renderer's destructor.
Usage: ``python -m fusegraph.report.render3d POINTS.ply MESH.glb OUT.png``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np


def render(points_path: str, mesh_path: str, out_path: str, width: int = 1400, height: int = 700) -> None:
    import open3d as o3d
    from open3d.visualization import rendering

    points = o3d.io.read_point_cloud(Path(points_path))
    mesh = o3d.io.read_triangle_mesh(Path(mesh_path))
    renderer = rendering.OffscreenRenderer(width, height)
    point_material = rendering.MaterialRecord()
    point_material.shader = "defaultUnlit"
    point_material.point_size = 6.0
    mesh_material = rendering.MaterialRecord()
    mesh_material.shader = "defaultUnlit"  # flat axis colours read better than lit ones without a light rig
    renderer.scene.set_background([1.0, 1.0, 1.0, 1.0])
    renderer.scene.view.set_post_processing(False)  # no tone mapping: colours as given, white background
    renderer.scene.add_geometry("points", points, point_material)
    renderer.scene.add_geometry("mesh", mesh, mesh_material)
    box = points.get_axis_aligned_bounding_box()
    center = box.get_center()
    extent = float(np.max(box.get_extent()))
    eye = center + np.array([0.1 * extent, -0.75 * extent, 0.3 * extent])
    renderer.setup_camera(45.0, center, eye, [0.0, 0.0, 1.0])
    o3d.io.write_image(Path(out_path), renderer.render_to_image())


if __name__ == "__main__":
    if len(sys.argv) != 4:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    render(sys.argv[1], sys.argv[2], sys.argv[3])
    sys.stdout.flush()
    os._exit(0)  # skip the renderer's teardown, which is where it can hang
