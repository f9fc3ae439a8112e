"""The end-to-end nested choice (``evaluation.nested.choose_nested``): each fold chooses every study without its held-out trial."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fusegraph.evaluation.nested import ALL, choose_nested, study_order


def _grids() -> dict[str, dict[str, dict[str, float]]]:
    return {"first": {f"x={x}": {"x": float(x)} for x in range(4)}, "second": {f"y={y}": {"y": float(y)} for y in range(2)}}


def _score(study: str, key: str, trial: str) -> float:
    """Trial d wants x = 3, the others x = 0; the second study, once chosen, wants y = 1 exactly where the first chose x >= 1."""
    settings = json.loads(key)
    x = settings["first"]["x"]
    best_x = 3.0 if trial == "d" else 0.0
    if "second" not in settings:  # before the second study is chosen
        return (x - best_x) ** 2
    return (x - best_x) ** 2 + (settings["second"]["y"] - float(x >= 1)) ** 2


def test_each_fold_chooses_without_its_trial_and_later_studies_follow_the_fold() -> None:
    asked: list[set[str]] = []
    chosen, passes, converged = choose_nested(["a", "b", "c", "d"], _grids(), _score, asked.append, passes=5, say=lambda _: None)
    # on all four trials x = 1 (mean squared error 1.75 against 2.25 at x = 0); without d, x = 0 (0 against 1); without a, b or
    # c the two remaining zeros and the 3 still choose x = 1 (2 against 3)
    assert chosen[ALL] == {"first": {"x": 1.0}, "second": {"y": 1.0}}
    assert chosen["d"] == {"first": {"x": 0.0}, "second": {"y": 0.0}}  # the second study chosen on the fold's own first choice
    for trial in "abc":
        assert chosen[trial] == chosen[ALL]
    assert passes == 2 and converged  # the second pass moved nothing, so it stopped there
    assert not choose_nested(["a", "b", "c", "d"], _grids(), _score, asked.append, passes=1, say=lambda _: None)[2]  # one pass cannot know
    assert all(asked)  # every step asked for its runs before scoring them


def test_the_online_solver_also_chooses_its_relinearisation() -> None:
    assert study_order("online")[-1] == "broad_online"
    assert "broad_online" not in study_order("batch")
    assert study_order("online")[:-1] == study_order("batch")


def test_the_bench_table_says_what_the_nested_figure_is_and_when_it_is_stale() -> None:
    from fusegraph.report.broad import format_broad_table

    row = {"total": 1.0, "heading": 0.8, "inclination": 0.5, "x_realtime": 400.0}
    nested = {"in_sample_on_main": 1.93, "cross_validated": 2.10, "cross_validated_peer_ratio": 0.69, "cross_validated_inclination_peer_ratio": 0.9,
              "in_sample": 1.90}
    result = {"trials": {"01_a": {"online": row}}, "mean": {"online": row},
              "nested": {"online": {**nested, "current": True, "rule": "one_se"}, "batch": {**nested, "current": False}}}
    lines = [line for line in format_broad_table(result).splitlines() if "every study re-chosen" in line]
    assert len(lines) == 2
    assert "1.930 deg in-sample" in lines[0] and "2.100 deg" in lines[0] and "cross-validated" in lines[0] and "STALE" not in lines[0]
    assert lines[1].startswith("batch:") and "STALE" in lines[1]
    assert "--rule one_se" in lines[0] and "--rule best" in lines[1]  # a figure filed before the rule was: the old rule


def _noisy_score(study: str, key: str, trial: str) -> float:
    """x = 1 beats the start's x = 0 by 0.1 on average, but by +0.5 on two trials and -0.3 on the others: within its spread.
    x = 2 beats x = 0 by exactly 1 on every trial: beyond it."""
    x = json.loads(key)["first"]["x"]
    if x == 1.0:
        return 0.5 if trial in "ab" else 1.3
    return {0.0: 1.0, 2.0: 0.0, 3.0: 2.0}[x]


def test_one_standard_error_keeps_a_setting_the_trials_cannot_tell_apart() -> None:
    grids = {"first": {f"x={x}": {"x": float(x)} for x in (0, 1)}}
    start = {"first": {"x": 0.0}}
    trials = ["a", "b", "c", "d"]
    kept, _, _ = choose_nested(trials, grids, _noisy_score, lambda _: None, passes=1, say=lambda _: None, rule="one_se", start=start)
    best, _, _ = choose_nested(trials, grids, _noisy_score, lambda _: None, passes=1, say=lambda _: None, rule="best", start=start)
    assert best[ALL] == {"first": {"x": 1.0}}  # mean 0.9 against 1.0 ...
    assert kept[ALL] == {"first": {"x": 0.0}}  # ... a gain of 0.1 against a standard error of 0.23: kept
    wider = {"first": {f"x={x}": {"x": float(x)} for x in (0, 1, 2)}}
    moved, _, _ = choose_nested(trials, wider, _noisy_score, lambda _: None, passes=1, say=lambda _: None, rule="one_se", start=start)
    assert all(settings == {"first": {"x": 2.0}} for settings in moved.values())  # a gain of 1 on every trial: moved on every path


def test_the_code_defaults_as_settings_give_the_default_model() -> None:
    from fusegraph.graphs.attitude9 import MODEL_STUDIES, default_settings, model_from_settings

    defaults = default_settings()
    assert sorted(defaults) == sorted(MODEL_STUDIES)
    for study in MODEL_STUDIES:  # each study's default point read back through its setter is the untouched model
        assert model_from_settings({study: defaults[study]}) == model_from_settings({}), study


def test_a_cached_nested_run_runs_only_the_settings_it_has_not_run(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """``tune broad_nested --cache``: the same call again runs nothing and gives the same figures; one more pass runs only
    settings no earlier call ran; a trial whose file changed is run again (its runs only). The runs are stand-ins (a
    function of the trial file and the settings), so the test is about what is run, not about BROAD."""
    import zlib

    import fusegraph.evaluation.nested as nested

    made: list[tuple[str, str]] = []
    killed = {"06_c.mat"}

    def trial_runs(job: tuple[str, str, list[str]]) -> dict[str, tuple[float, float]]:
        path, _, keys = job
        if Path(path).name in killed:
            raise KeyboardInterrupt  # the run killed while this trial ran
        made.extend((path, key) for key in keys)
        salt = zlib.crc32(Path(path).read_bytes())
        return {key: (1.0 + (zlib.crc32(key.encode()) ^ salt) % 997 / 997.0, 0.5) for key in keys}

    monkeypatch.setattr(nested, "_trial_runs", trial_runs)
    monkeypatch.setattr(nested, "_peer_run", lambda job: (2.0, 1.0))
    for name in ("01_a", "04_b", "06_c"):
        (tmp_path / "trials").mkdir(exist_ok=True)
        (tmp_path / "trials" / f"{name}.mat").write_bytes(name.encode())
    cache = tmp_path / "cache"

    def call(passes: int) -> dict[str, object]:
        return nested.nested_broad("batch", str(tmp_path / "trials"), passes=passes, say=lambda _: None, cache=cache)

    with pytest.raises(KeyboardInterrupt):
        call(1)
    before_kill = set(made)
    assert {Path(path).name for path, _ in before_kill} == {"01_a.mat", "04_b.mat"}
    killed.clear()
    made.clear()
    first = call(1)
    assert made and not set(made) & before_kill  # what the trials had finished before the kill is not run again
    ran_first = set(made) | before_kill
    assert len(set(made)) == len(made)  # each (trial, settings) run once
    made.clear()
    assert call(1) == first and made == []
    second_pass = call(2)
    assert not set(made) & ran_first and second_pass["passes"] == 2
    before = ran_first | set(made)
    made.clear()
    (tmp_path / "trials" / "04_b.mat").write_bytes(b"another recording")
    call(1)
    changed = [key for path, key in made if Path(path).name == "04_b.mat"]
    # the first study's grid (from the code's defaults, whatever the scores) was run on it before: now again
    assert {key for path, key in before if Path(path).name == "04_b.mat"} & set(changed)
    assert not {(path, key) for path, key in made if Path(path).name != "04_b.mat"} & before  # the others: only settings new to them
