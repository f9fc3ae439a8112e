"""Damaged sessions, generated: a clear error (exit 2) or a valid estimate (exit 0), never a traceback or an
internal error (exit 1), never a silently wrong one for the faults the loader can see."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fusegraph.cli import main

FAULTS = ("gyro_deg_s", "stamps_ms", "quat_x3", "nan_value", "time_backwards", "key_typo", "sigma_zero", "drop_column", "tracker_shifted", "truncated")


def _damage(root: Path, fault: str, rng: np.random.Generator) -> None:
    def rows(name: str) -> tuple[str, list[list[str]]]:
        lines = (root / name).read_text().splitlines()
        return lines[0], [line.split(",") for line in lines[1:]]

    def write(name: str, header: str, table: list[list[str]]) -> None:
        (root / name).write_text("\n".join([header, *(",".join(r) for r in table)]) + "\n")

    toml = root / "session.toml"
    if fault == "gyro_deg_s":
        header, table = rows("gyro.csv")
        write("gyro.csv", header, [[r[0], *(repr(float(v) * 57.3) for v in r[1:])] for r in table])
    elif fault == "stamps_ms":
        for name in ("gyro.csv", "tracker.csv"):
            header, table = rows(name)
            write(name, header, [[repr(float(r[0]) * 1000.0), *r[1:]] for r in table])
    elif fault == "quat_x3":
        header, table = rows("tracker.csv")
        write("tracker.csv", header, [[r[0], *(repr(float(v) * 3.0) for v in r[1:])] for r in table])
    elif fault == "nan_value":
        header, table = rows("gyro.csv")
        table[int(rng.integers(len(table)))][1] = "nan"
        write("gyro.csv", header, table)
    elif fault == "time_backwards":
        header, table = rows("gyro.csv")
        i = int(rng.integers(1, len(table)))
        table[i][0] = repr(float(table[i - 1][0]) - 0.5)
        write("gyro.csv", header, table)
    elif fault == "key_typo":
        toml.write_text(toml.read_text().replace("noise_sigma_deg", "noise_sigma_degs"))
    elif fault == "sigma_zero":
        toml.write_text(toml.read_text().replace("noise_sigma_rad_s = 0.015", "noise_sigma_rad_s = 0"))
    elif fault == "drop_column":
        header, table = rows("tracker.csv")
        write("tracker.csv", ",".join(header.split(",")[:-1]), [r[:-1] for r in table])
    elif fault == "tracker_shifted":
        header, table = rows("tracker.csv")
        write("tracker.csv", header, [[repr(float(r[0]) + 1000.0), *r[1:]] for r in table])
    elif fault == "truncated":
        text = (root / "gyro.csv").read_text()
        (root / "gyro.csv").write_text(text[: int(len(text) * 0.7)])


@pytest.fixture(scope="module")
def pristine(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("fuzz") / "ok"
    assert main(["simulate", "head", "--seed", "1", "--duration", "2", "--out", str(root)]) == 0
    return root


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(faults=st.lists(st.sampled_from(FAULTS), min_size=1, max_size=3, unique=True), seed=st.integers(0, 1000),
       solver=st.sampled_from(["online", "batch", "ekf"]))
def test_damaged_sessions_are_a_clear_error_or_a_result(pristine: Path, tmp_path_factory: pytest.TempPathFactory, faults: list[str], seed: int,
                                                         solver: str, capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path_factory.mktemp("case") / "s"
    shutil.copytree(pristine, root)
    rng = np.random.default_rng(seed)
    for fault in faults:
        _damage(root, fault, rng)
    code = main(["run", str(root), "--solver", solver, "--json"])
    err = capsys.readouterr().err
    assert code in (0, 2), (faults, solver, err)
    assert "Traceback" not in err and "internal error" not in err, (faults, err)
    if code == 2:
        assert err.startswith("fusegraph run: error:") and err.count("\n") == 1, err
    else:  # the loader saw nothing wrong: only faults it cannot see may pass (none of these can)
        pytest.fail(f"{faults} passed as a valid session")


GENERIC_FAULTS = ("nan_value", "time_backwards", "truncated", "drop_block", "scale_57", "duplicate_row", "swap_columns", "empty_stream",
                  "extra_stream", "key_typo")
SYSTEMS = {"head": "online", "attitude9": "online", "gaze": "online", "bicycle": "online", "walking": "online", "ultrasonic": "online"}


@pytest.fixture(scope="module")
def every_system(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = {}
    for system in SYSTEMS:
        root = tmp_path_factory.mktemp("fuzz_all") / system
        duration = {"walking": "20"}.get(system, "10")  # the shortest each simulator makes
        assert main(["simulate", system, "--seed", "2", "--duration", duration, "--out", str(root)]) == 0
        out[system] = root
    return out


def _damage_largest(root: Path, fault: str, rng: np.random.Generator) -> None:
    """A fault in the session's largest stream file (never the truth): what a recording of any system can suffer."""
    path = max((p for p in root.glob("*.csv") if p.name != "truth.csv"), key=lambda p: p.stat().st_size)
    lines = path.read_text().splitlines()
    header, table = lines[0], [line.split(",") for line in lines[1:]]
    if fault == "nan_value":
        table[int(rng.integers(len(table)))][1] = "nan"
    elif fault == "time_backwards":
        i = int(rng.integers(1, len(table)))
        table[i][0] = repr(float(table[i - 1][0]) - 0.5)
    elif fault == "truncated":
        text = "\n".join(lines)
        path.write_text(text[: int(len(text) * 0.7)])
        return
    elif fault == "drop_block":  # a dropout: a fifth of the rows gone from the middle
        n = len(table)
        del table[int(0.4 * n) : int(0.6 * n)]
    elif fault == "scale_57":
        table = [[r[0], *(repr(float(v) * 57.3) if v not in ("", "nan") else v for v in r[1:])] for r in table]
    elif fault == "duplicate_row":
        i = int(rng.integers(len(table)))
        table.insert(i, list(table[i]))
    elif fault == "swap_columns":  # the first two value columns in each other's place
        table = [[r[0], r[2], r[1], *r[3:]] if len(r) > 2 else r for r in table]
    elif fault == "empty_stream":
        table = []
    elif fault == "extra_stream":  # a file and a stream of a kind nobody declared
        (root / "extra.csv").write_text("t,a\n0.0,1.0\n1.0,2.0\n")
        toml = root / "session.toml"
        toml.write_text(toml.read_text() + '\n[streams.extra]\nkind = "thermometer"\nfile = "extra.csv"\n')
        return
    elif fault == "key_typo":  # a misspelled key in the stream's entry
        toml = root / "session.toml"
        text = toml.read_text()
        toml.write_text(text.replace(f'file = "{path.name}"', f'fiel = "{path.name}"', 1))
        return
    path.write_text("\n".join([header, *(",".join(r) for r in table)]) + "\n")


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(system=st.sampled_from(sorted(SYSTEMS)), fault=st.sampled_from(GENERIC_FAULTS), seed=st.integers(0, 1000))
def test_every_system_gives_a_clear_error_or_a_result_on_a_damaged_recording(every_system: dict[str, Path], tmp_path_factory: pytest.TempPathFactory,
                                                                             system: str, fault: str, seed: int, capsys: pytest.CaptureFixture[str]) -> None:
    """Any system, any of these faults: exit 0 (a dropout is bridged and said; a scaled stream or swapped columns a
    loader cannot always tell) or exit 2 with a one-line error naming the file or stream, never a traceback or an
    internal error; faults the loader can see are an error or a one-line warning."""
    root = tmp_path_factory.mktemp("case_all") / system
    shutil.copytree(every_system[system], root)
    _damage_largest(root, fault, np.random.default_rng(seed))
    code = main(["run", str(root), "--solver", SYSTEMS[system], "--json", "--out", str(tmp_path_factory.mktemp("out"))])
    err = capsys.readouterr().err
    assert code in (0, 2), (system, fault, err)
    assert "Traceback" not in err and "internal error" not in err, (system, fault, err)
    lines = err.strip().splitlines()
    assert all(line.startswith(("warning: ", "fusegraph run: error: ")) for line in lines), err  # one line each
    if code == 2:
        assert lines[-1].startswith("fusegraph run: error:") and (".csv" in lines[-1] or "session.toml" in lines[-1]), err
    if fault in ("nan_value", "time_backwards", "truncated", "empty_stream", "extra_stream", "key_typo"):
        assert code == 2, (system, fault, "a fault the loader sees passed")
    # a repeated range row is two transmitters at one range (LIAS UWB has 3,908 such at its 1 cm resolution): not a fault
    if (fault == "drop_block" or (fault == "duplicate_row" and system != "ultrasonic")) and code == 0:
        assert any(line.startswith("warning: ") for line in lines), (system, fault, "passed unsaid")


# ------------------------------------------------------------------------------------------------ frames, dead streams, truth

FRAME_DAMAGE = {
    "x-y-swapped": np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
    "x-negated": np.diag([-1.0, 1.0, 1.0]),
    "turned-90-about-z": np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
    "turned-30-about-x": np.array([[1.0, 0.0, 0.0], [0.0, np.cos(0.52), -np.sin(0.52)], [0.0, np.sin(0.52), np.cos(0.52)]]),
    "constant": np.zeros((3, 3)),
}
SCORED_BY = {"head": ("rms_deg.azimuth", 1.0), "attitude9": ("total_deg", 1.0), "gaze": ("rms.x_mm", 5.0), "bicycle": ("rms.pitch_deg", 1.0),
             "walking": ("rmse_m", 0.05), "ultrasonic": ("rmse_m", 0.02)}
"""The figure a damage must not worsen unsaid, and a floor under the 1.5x the issue allows (a figure near zero doubles by noise)."""


def _frame_cases() -> list[tuple[str, str, str]]:
    from fusegraph.evaluation.runner import simulated_sessions

    cases = []
    for system in SYSTEMS:
        _, session = simulated_sessions(system, [2], duration_s=20.0 if system == "walking" else 10.0)[0]
        for name, stream in session.streams.items():
            if stream.kind in ("gyro", "accel", "mag") and stream.meta.get("role") != "calibration recording":
                cases += [(system, name, damage) for damage in FRAME_DAMAGE]
            if stream.kind == "ranges":
                cases.append((system, name, "rows-twice"))
        if session.truth is not None:
            cases.append((system, "truth", "clock+1000s"))
            if session.truth.kind == "attitude":
                cases.append((system, "truth", "conjugated"))
    return cases


UNTOLD = {
    **{("bicycle", s, d): "the thigh turns about one axis (pedalling) and the frame hardly turns: gravity cannot tell its axes"
       for s in ("thigh_accel", "frame_accel") for d in ("x-y-swapped", "x-negated", "turned-90-about-z")},
    **{("walking", s, d): "a waist turns about the vertical and tilts a few degrees at the step rate: gravity cannot tell its axes"
       for s, d in (("gyro", "x-negated"), ("gyro", "turned-90-about-z"), ("accel", "x-y-swapped"), ("accel", "x-negated"),
                    ("accel", "turned-90-about-z"))},
    ("attitude9", "gyro", "turned-30-about-x"): "10 s of simulated motion: the axes as written are off by 5-10 deg, too little to fit an odd turn",
    ("attitude9", "mag", "turned-30-about-x"): "10 s of simulated motion: the axes as written are off by 5-6 deg, too little to fit an odd turn",
    ("gaze", "gyro", "turned-30-about-x"): "a head that turns about one axis: a turn about another cannot be told",
    ("gaze", "accel", "turned-30-about-x"): "a head that turns about one axis: a turn about another cannot be told",
}
"""Damages the checks do not tell on these short simulations, measured (a strict xfail: a check that learns one fails here)."""


_UNDAMAGED: dict[str, tuple[object, float]] = {}
"""Each system's simulated session and its undamaged figure, made once for every damage."""


def _frame_params() -> list[object]:
    return [pytest.param(*case, marks=pytest.mark.xfail(strict=True, reason=UNTOLD[case])) if case in UNTOLD else case for case in _frame_cases()]


@pytest.mark.parametrize(("system", "stream", "damage"), _frame_params())
def test_frames_dead_streams_and_truth_are_named_or_harmless_in_every_system(system: str, stream: str, damage: str) -> None:
    """Every system, each IMU stream in another frame (signed permutations, a 30 deg turn) or dead, the truth conjugated or
    on another clock, range rows written twice: an error naming the stream (or truth), or the answer within 1.5x of the
    undamaged one (with a warning naming the stream where something was left out): never a wrong answer without a word."""
    import warnings
    from dataclasses import replace

    from fusegraph.evaluation.runner import simulated_sessions
    from fusegraph.results import flatten
    from fusegraph.session import SessionError
    from fusegraph.systems.presets import PRESETS

    preset, (metric, floor) = PRESETS[system], SCORED_BY[system]
    if system not in _UNDAMAGED:
        _, simulated = simulated_sessions(system, [2], duration_s=20.0 if system == "walking" else 10.0)[0]
        _UNDAMAGED[system] = (simulated, flatten(preset.score(simulated, preset.solve(simulated, "online")) or {})[metric])
    session, undamaged = _UNDAMAGED[system]
    if stream == "truth":
        truth = session.truth
        assert truth is not None
        conjugate = damage == "conjugated"
        damaged = replace(session, truth=replace(truth, values=truth.values * [1.0, -1.0, -1.0, -1.0]) if conjugate else replace(truth, t=truth.t + 1000.0))
    else:
        original = session.stream(stream)
        if damage == "rows-twice":
            twice = np.repeat(np.arange(len(original)), 2)
            changed = replace(original, t=original.t[twice], values=original.values[twice])
        elif damage == "constant":
            changed = replace(original, values=np.tile(original.values[len(original) // 2], (len(original), 1)))
        else:
            changed = replace(original, values=original.values @ FRAME_DAMAGE[damage].T)
        damaged = replace(session, streams={**session.streams, stream: changed})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            estimate = preset.solve(damaged, "online")
        except SessionError as err:
            assert f"'{stream}'" in str(err) or (stream == "truth" and "truth" in str(err)), str(err)
            return
    said = [str(w.message) for w in caught if f"'{stream}'" in str(w.message)]
    if any("solved without it" in line for line in said):  # left out, said: the answer is the one without the stream
        undamaged = flatten(preset.score(session, preset.solve(session.without(stream), "online")) or {})[metric]
    figure = flatten(preset.score(damaged, estimate) or {}).get(metric, float("nan"))
    assert figure <= max(1.5 * undamaged, undamaged + floor), f"{system} {stream} {damage}: {metric} {figure:.4g} against {undamaged:.4g} unsaid ({said})"
