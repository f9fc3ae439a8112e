"""Shared test helpers: the factor contract (SymForce-style, written once), and where real data lives."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(autouse=True)
def _work_in_a_temporary_folder(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """`fusegraph run` writes its estimate into the current folder: every test works in a folder of its own."""
    monkeypatch.chdir(tmp_path_factory.mktemp("cwd"))


def _kind(values: gtsam.Values, key: int) -> str:
    for kind, getter in (("rot3", values.atRot3), ("pose3", values.atPose3)):
        try:
            getter(key)
            return kind
        except RuntimeError:
            pass
    return "vector"


def _dim(values: gtsam.Values, key: int) -> int:
    return {"rot3": 3, "pose3": 6}.get(_kind(values, key)) or len(values.atVector(key))


def _retracted(values: gtsam.Values, key: int, delta: np.ndarray) -> gtsam.Values:
    out = gtsam.Values(values)
    kind = _kind(values, key)
    if kind == "vector":
        out.update(key, values.atVector(key) + delta)
    elif kind == "rot3":
        out.update(key, values.atRot3(key).retract(delta))
    else:
        out.update(key, values.atPose3(key).retract(delta))
    return out


def numerical_jacobian(factor: gtsam.NoiseModelFactor, values: gtsam.Values, step: float = 1e-6) -> np.ndarray:
    """Central differences of the whitened error along every variable's tangent space, stacked by key."""
    blocks = []
    for key in factor.keys():
        columns = []
        for j in range(_dim(values, key)):
            delta = np.zeros(_dim(values, key))
            delta[j] = step
            plus = factor.whitenedError(_retracted(values, key, delta))
            minus = factor.whitenedError(_retracted(values, key, -delta))
            columns.append((plus - minus) / (2 * step))
        blocks.append(np.array(columns).T)
    return np.hstack(blocks)


def assert_jacobians_match(factor: gtsam.NoiseModelFactor, values: gtsam.Values, rtol: float = 1e-5, atol: float = 1e-4) -> None:
    """The contract every factor meets: its linearisation equals numerical derivatives.

    Tolerance: central differences with a 1e-6 step are good to ~1e-8 relative; whitening by sigmas
    of 1e-4 rad scales absolute values up by 1e4, hence the relative tolerance.
    """
    analytic = factor.linearize(values).jacobian()[0]
    numeric = numerical_jacobian(factor, values)
    np.testing.assert_allclose(analytic, numeric, rtol=rtol, atol=atol * max(1.0, float(np.abs(numeric).max())) * 1e-3)


def random_rot3(rng: np.random.Generator, scale: float = np.pi) -> gtsam.Rot3:
    return gtsam.Rot3.Expmap(rng.uniform(-1, 1, 3) * scale / np.sqrt(3))


def requires_shared_data(subdir: str) -> pytest.MarkDecorator:
    """Skip (with the reason) when the real recordings are not beside the repository."""
    path = SHARED_DATA / subdir
    return pytest.mark.skipif(not path.is_dir(), reason=f"real recordings not found at {path} (CI has them beside the repo)")


def cut_streams(session, names: tuple[str, ...], start_s: float, end_s: float):  # type: ignore[no-untyped-def]
    """The session without the named streams' samples in [start_s, end_s) (a dropout)."""
    from dataclasses import replace

    streams = dict(session.streams)
    for name in names:
        stream = session.stream(name)
        kept = (stream.t < start_s) | (stream.t >= end_s)
        streams[name] = replace(stream, t=stream.t[kept], values=stream.values[kept])
    return replace(session, streams=streams)


def solve_saying(session, solver: str, about: str):  # type: ignore[no-untyped-def]
    """``solve_session`` with every warning recorded: (its outcome, the messages that contain ``about``)."""
    import warnings

    from fusegraph.evaluation.runner import solve_session

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outcome = solve_session(session, solver)
    return outcome, [str(w.message) for w in caught if about in str(w.message)]
