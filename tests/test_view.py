"""fusegraph view: every file is written, the 3D render is a real picture, estimate CSVs view with TUM truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fusegraph.cli import main
from fusegraph.report.tum import read_tum
from fusegraph.scenarios import simulate_head
from fusegraph.session import save_session


@pytest.fixture(scope="module")
def head_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return save_session(simulate_head(0, profile="ideal", duration_s=3.0), tmp_path_factory.mktemp("s") / "head")


def _image(path: Path) -> np.ndarray:
    import matplotlib.image

    return np.asarray(matplotlib.image.imread(path))


def test_view_of_a_session_writes_every_file(head_session: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "view"
    assert main(["view", str(head_session), "--out", str(out)]) == 0
    names = {p.name for p in out.iterdir()}
    assert {"estimate_batch.csv", "estimate_batch.tum", "truth.tum", "attitude_batch.png", "scene_head.png"} <= names
    image = _image(out / "scene_head.png")
    # a real picture: mostly white background, plus many distinct colours (frames, error colours)
    assert image.shape[0] > 400 and image.shape[1] > 800
    assert len(np.unique((image[..., :3] * 255).astype(int).reshape(-1, 3), axis=0)) > 200
    t, _, quat = read_tum(out / "estimate_batch.tum")
    assert len(t) > 250 and np.all(np.isfinite(quat))


def test_open3d_renders_headless_when_installed(head_session: Path, tmp_path: Path) -> None:
    pytest.importorskip("open3d", exc_type=ImportError)
    from fusegraph import load_session
    from fusegraph.report.scene import head_scene, write_head_scene
    from fusegraph.systems.head import run_batch

    session = load_session(head_session)
    assert session.truth is not None
    scene = head_scene(run_batch(session), session.truth.t, session.truth.values)
    written = write_head_scene(scene, tmp_path)
    assert {p.name for p in written} == {"scene_head_points.ply", "scene_head_frames.ply", "scene_head_frames.glb", "scene_head.png"}
    assert not scene.notes, scene.notes  # no fallback was needed


def test_view_of_an_estimate_csv_with_tum_truth(head_session: Path, tmp_path: Path) -> None:
    first = tmp_path / "first"
    assert main(["view", str(head_session), "--out", str(first), "--solver", "ekf"]) == 0
    second = tmp_path / "second"
    assert main(["view", str(first / "estimate_ekf.csv"), "--out", str(second), "--truth", str(first / "truth.tum")]) == 0
    assert (second / "scene_head.png").is_file() and (second / "attitude_estimate_ekf.png").is_file()


def test_view_of_something_else_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["view", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    assert "neither a session directory" in capsys.readouterr().err


def test_an_estimate_far_off_is_drawn_and_no_band_is_drawn_without_a_covariance(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An estimate 90 deg off in azimuth widens the error axis to show it (the +-4 deg axis was an empty panel); NaN
    covariances draw no band and the axis does not promise one."""
    from fusegraph.estimate import Estimate
    from fusegraph.geometry import quat_from_rotvec, quat_multiply
    from fusegraph.report import plots

    t = np.linspace(0.0, 10.0, 200)
    truth = quat_from_rotvec(np.stack([0.1 * t, 0 * t, 0 * t], axis=1))
    off = quat_multiply(quat_from_rotvec(np.array([0.0, 0.0, np.pi / 2])), truth)
    figures = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path, dpi=110: figures.append(fig) or Path(path))
    plots.plot_attitude_axes(t, truth, [Estimate("online", t, off, np.full((len(t), 3, 3), np.nan), 0.0)], tmp_path / "a.png")
    bottom = figures[0].axes[3]  # azimuth's error axis
    assert bottom.get_ylim()[1] >= 90.0
    assert not bottom.collections and "sigma" not in bottom.get_ylabel()
