"""Gait against a reference system (``bench gait``): the inverted pendulum on a constructed walk, the scoring's
one-to-one matching on constructed steps, and the Mobilise-D importer and bench on the shared files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import requires_shared_data

from fusegraph.evaluation.gait import SLOW_GAIT_M_S, GaitEstimate, score_recording, steps_by_speed
from fusegraph.frontends.gait import MAX_GAP_S, StepLengthConfig, step_lengths, with_missed_steps
from fusegraph.metrics import GaitReference as Reference


def test_the_pendulum_gives_the_step_length_of_a_pure_vertical_excursion() -> None:
    """A pelvis that rises and falls 3 cm each step (a sine at the step frequency) over a leg of 0.95 m: the pendulum's
    step length is 2 sqrt(2 l h - h^2) = 0.472 m (within 3 %: the high-passes take a little of the amplitude)."""
    fs, step_s, h = 100.0, 0.55, 0.03
    t = np.arange(0.0, 30.0, 1.0 / fs)
    omega = 2 * np.pi / step_s
    vertical = (h / 2) * omega**2 * np.cos(omega * t)  # z = -(h/2) cos: its second derivative; lowest at each contact
    steps = np.arange(1.0, 29.0, step_s)
    lengths = step_lengths(t, vertical, steps, 0.95, StepLengthConfig(0.1, 0.5, 4, 1.0, "pendulum"))
    expected = 2 * np.sqrt(2 * 0.95 * h - h * h)
    assert np.nanmedian(lengths) == pytest.approx(expected, rel=0.03)
    assert np.nanmedian(step_lengths(t, vertical, steps, 0.95, StepLengthConfig(0.1, 0.5, 4, 1.25, "pendulum"))) == pytest.approx(1.25 * expected, rel=0.03)
    # the excursion model: the step in proportion to the rise (the same 3 % for the high-passes); the leg only bounds it
    assert np.nanmedian(step_lengths(t, vertical, steps, 0.95, StepLengthConfig(0.1, 0.5, 4, 18.0, "excursion"))) == pytest.approx(18.0 * h, rel=0.03)
    with pytest.raises(ValueError, match="step-length model"):
        StepLengthConfig(model="compass")


def test_missed_contacts_are_inferred_inside_a_bout_and_not_across_a_pause() -> None:
    """Steps every 0.6 s with one contact missed (an interval of 2 periods) and two missed (3 periods), then a pause
    longer than ``MAX_GAP_S`` and a second bout of 0.5 s steps missing one: the missing contacts come back at the
    whole-period times, flagged as inferred; the pause is not walked through."""
    steps = np.array([0.0, 0.6, 1.2, 2.4, 3.0, 3.6, 5.4, 6.0, 6.0 + MAX_GAP_S + 1.0])
    steps = np.concatenate([steps, steps[-1] + np.array([0.5, 1.0, 2.0])])
    times, inferred = with_missed_steps(steps)
    assert times[inferred] == pytest.approx([1.8, 4.2, 4.8, steps[-1] - 0.5])
    assert times[~inferred] == pytest.approx(steps) and np.all(np.diff(times) > 0)
    assert not with_missed_steps(np.array([0.0, 0.6, 1.2, 1.8]))[1].any()  # nothing missed: nothing added


def test_steps_match_one_to_one_within_the_tolerance() -> None:
    """One bout 10-15 s with 6 contacts; the method finds 5 near them (one 0.3 s off: not a match), one extra, and one
    step outside every bout (not counted)."""
    contacts = np.array([10.0, 11.0, 12.0, 13.0, 14.0, 15.0])
    reference = Reference(np.array([[10.0, 15.0]]), np.array([1.2]), np.array([1.1]), contacts)
    steps = np.array([10.1, 11.05, 11.5, 12.3, 13.0, 14.2, 30.0])
    estimate = GaitEstimate(steps, np.array([10.1, 12.3, 30.0]), np.array([1.0, 1.2, 5.0]), np.array([1.0, 1.0, 9.0]))
    row = score_recording(estimate, reference)
    assert (row["tp"], row["fp"], row["fn"]) == (4, 2, 2)  # 10.1, 11.05, 13.0, 14.2 match; 11.5 and 12.3 do not
    assert row["stride_length_errors_m"] == [pytest.approx(0.1)] and row["walking_speed_errors_m_s"] == [pytest.approx(0.1)]
    assert row["stride_length_bouts"] == [0]


def test_steps_are_scored_apart_on_slow_and_faster_bouts() -> None:
    """Each bout's steps fall in the band of the reference's own speed for it: a slow bout (0.5 m/s) with 4 of 6 contacts
    found and 2 extra steps, a faster one (1.2 m/s) found whole, and a bout without a reference speed in neither band."""
    contacts = np.r_[10.0:16.0, 20.0:26.0, 30.0, 31.0]
    reference = Reference(np.array([[10.0, 15.0], [20.0, 25.0], [30.0, 31.0]]), np.array([0.6, 1.4, 1.0]),
                          np.array([0.5, 1.2, np.nan]), contacts)
    steps = np.r_[[10.1, 11.05, 11.5, 12.3, 13.0, 14.2], 20.0:26.0, 30.0]
    row = score_recording(GaitEstimate(steps, np.zeros(0), np.zeros(0), np.zeros(0)), reference)
    assert row["bout_steps"] == [(4, 2, 2), (6, 0, 0), (1, 0, 1)]
    bands = steps_by_speed([(reference, row)])
    assert 0.5 < SLOW_GAIT_M_S < 1.2
    assert bands["slow"] == {"step_f1": pytest.approx(8 / 12), "step_precision": pytest.approx(4 / 6), "step_recall": pytest.approx(4 / 6),
                             "bouts": 1, "contacts": 6}
    assert bands["not_slow"] == {"step_f1": 1.0, "step_precision": 1.0, "step_recall": 1.0, "bouts": 1, "contacts": 6}


def test_the_slow_walking_line_says_where_a_row_scored_fewer_bouts() -> None:
    """A peer that failed on a trial is scored on fewer bouts: the table's slow-walking line says over how many."""
    from fusegraph.evaluation.gait import format_gait

    def band(f1: float, bouts: int) -> dict[str, object]:
        return {"step_f1": f1, "step_precision": f1, "step_recall": f1, "bouts": bouts, "contacts": 10 * bouts}

    row = {"step_f1": 0.8, "step_precision": 0.8, "step_recall": 0.8, "stride_length_mae_m": 0.1, "walking_speed_mae_m_s": 0.1,
           "bouts_scored": 3, "bouts": 4}
    result = {"match_s": 0.25, "methods": {"fusegraph": row, "mobgap": row}, "recordings": {}, "cross_validated": False, "notes": {},
              "by_speed": {"fusegraph": {"slow": band(0.78, 7), "not_slow": band(0.95, 4)},
                           "mobgap": {"slow": band(0.64, 5), "not_slow": band(0.86, 4)}},
              "step_length": {"chosen_per_participant": {}, "in_sample": "", "on_main": ""}}
    line = next(x for x in format_gait(result).splitlines() if x.startswith("step F1 by"))
    assert "(7 bouts, 70 contacts) fusegraph 0.780, mobgap 0.640 (over 5 bouts);" in line
    assert line.endswith("(4 bouts, 40 contacts) fusegraph 0.950, mobgap 0.860")


def test_a_stride_without_a_value_is_left_out_of_the_bout_mean() -> None:
    """A peer may give a stride no length (mobgap's NaN at a bout's edge): the bout's mean comes from the strides that
    have one, and a bout whose strides all lack one is not scored, rather than the whole figure turning NaN."""
    reference = Reference(np.array([[10.0, 15.0], [20.0, 25.0]]), np.array([1.2, 1.0]), np.array([1.1, 0.9]), np.array([10.0, 20.0]))
    estimate = GaitEstimate(np.array([10.0, 20.0]), np.array([11.0, 12.0, 21.0]), np.array([1.0, np.nan, np.nan]),
                            np.array([np.nan, 1.0, 0.8]))
    row = score_recording(estimate, reference)
    assert row["stride_length_errors_m"] == [pytest.approx(0.2)] and row["stride_length_bouts"] == [0]
    assert row["walking_speed_errors_m_s"] == [pytest.approx(0.1), pytest.approx(0.1)] and row["walking_speed_bouts"] == [0, 1]


@requires_shared_data("mobgap")
def test_a_participant_folder_that_is_a_link_is_read(tmp_path: Path) -> None:
    """A Mobilise-D layout assembled from links (a participant of another cohort linked in) is read like a copy."""
    from fusegraph.datasets.mobgap_lab import DEFAULT_DIR, data_files, mobgap_sessions

    (tmp_path / "lab" / "MS").mkdir(parents=True)
    (tmp_path / "lab" / "MS" / "001").symlink_to(DEFAULT_DIR / "lab" / "HA" / "001", target_is_directory=True)
    assert [p.relative_to(tmp_path) for p in data_files(tmp_path)] == [Path("lab/MS/001/data.mat")]
    names = [name for name, _ in mobgap_sessions(tmp_path)]
    assert names and all(name.startswith("MS_001_") for name in names)


@requires_shared_data("mobgap")
def test_import_mobgap_and_bench_gait_on_the_sessions(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from fusegraph.cli import main
    from fusegraph.datasets.mobgap_lab import DEFAULT_DIR
    from fusegraph.session import load_session

    assert main(["import", "mobgap", str(DEFAULT_DIR), "--out", str(tmp_path / "s")]) == 0
    session = load_session(tmp_path / "s" / "HA_001_Test11_Trial1")
    assert session.meta["person"]["sensor_height_m"] == pytest.approx(0.964)
    assert len(session.meta["truth_extra"]["bouts_s"]) == 6 and np.median(np.linalg.norm(session.stream("accel").values, axis=1)) == pytest.approx(9.8, abs=0.3)
    # run --solver gait writes its steps beside the strides, the inferred contacts flagged
    assert main(["run", str(tmp_path / "s" / "HA_002_Test11_Trial1"), "--solver", "gait", "--out", str(tmp_path / "g.csv")]) == 0
    steps = np.loadtxt(tmp_path / "g_steps.csv", delimiter=",", skiprows=1)
    assert np.all(np.diff(steps[:, 0]) > 0) and 0 < steps[:, 1].sum() < len(steps) / 2
    capsys.readouterr()
    assert main(["bench", "gait", str(tmp_path / "s"), "--json", "--plot", str(tmp_path / "gait.png")]) == 0
    found = json.loads(capsys.readouterr().out)
    assert (tmp_path / "gait.png").stat().st_size > 10_000
    # the picture's per-bout values are the ones the MAE is made of
    pairs = [(b["reference"]["stride_length_m"], b["fusegraph"]["stride_length_m"]) for rec in found["recordings"].values() if rec["scored"]
             for b in rec["per_bout"] if b["fusegraph"]["stride_length_m"] is not None]
    assert np.mean([abs(e - r) for r, e in pairs]) == pytest.approx(found["methods"]["fusegraph"]["stride_length_mae_m"], rel=1e-12)
    assert set(found["methods"]) == {"fusegraph", "paper_speed"}  # mobgap's row needs the raw files
    assert found["cross_validated"] is True and not found["recordings"]["HA_002_Test5_Trial1"]["scored"]
    ours = found["methods"]["fusegraph"]
    # floors a regression would break. The row re-chooses the step thresholds without each participant, the step length
    # is the cited one (the bench: F1 0.792, stride length 0.153 m); with the thresholds as set by hand, F1 0.825 and 0.155 m
    assert ours["step_f1"] > 0.77 and ours["stride_length_mae_m"] < 0.17
    assert ours["hand_set_thresholds"]["step_f1"] > 0.81 and ours["hand_set_thresholds"]["stride_length_mae_m"] < 0.17
    # the bouts split by the reference's speed: every scored bout in one band (the bench: slow 7 bouts at F1 0.741)
    bands = found["by_speed"]["fusegraph"]
    assert bands["slow"]["bouts"] + bands["not_slow"]["bouts"] == ours["bouts"] and bands["slow"]["step_f1"] > 0.72
    # over the bouts every row scored (paper_speed scores all 11, fusegraph 10): a subset of fusegraph's own
    assert ours["bouts_common"] == min(m["bouts_scored"] for m in found["methods"].values()) and ours["stride_length_mae_common_m"] is not None
    # a held-out participant's row is run --solver gait on its session declaring the setting chosen without it
    from fusegraph.evaluation.gait import declare, setting_of_text
    from fusegraph.frontends.gait import CITED, MS_PROJECT_CORRECTION
    from fusegraph.session import save_session

    setting = setting_of_text(found["step_length"]["chosen_per_participant"]["HA/002"])
    assert setting.length == CITED and CITED.correction == MS_PROJECT_CORRECTION and CITED.highpass_hz == 1.0  # Mobilise-D's settings
    save_session(declare(load_session(tmp_path / "s" / "HA_002_Test11_Trial1"), setting.length, setting.detection), tmp_path / "declared")
    assert main(["report", "walking", str(tmp_path / "declared"), "--solvers", "gait", "--json"]) == 0
    metrics = json.loads(capsys.readouterr().out)["sessions"]["declared"]["gait"]["metrics"]
    bench = found["recordings"]["HA_002_Test11_Trial1"]["methods"]["fusegraph"]
    assert (metrics["step_f1"], metrics["stride_length_mae_m"]) == (bench["step_f1"], bench["stride_length_mae_m"])


@requires_shared_data("mobgap")
def test_the_gait_solver_reads_its_declared_step_thresholds() -> None:
    """``[gait] peak_threshold_m_s2`` / ``forward_slope_m_s3`` reach the step detector (a stricter threshold finds fewer
    steps, and the walking front end's own cycles are among the default thresholds' steps); a key that is no setting is an
    error naming it, and declaring keeps the session's checks made once."""
    from fusegraph.datasets.mobgap_lab import DEFAULT_DIR, mobgap_sessions
    from fusegraph.evaluation.gait import declare
    from fusegraph.evaluation.runner import solve_session
    from fusegraph.frontends.gait import HAND_SET_DETECTION, StepDetection, StepLengthConfig
    from fusegraph.frontends.pdr import front_end
    from fusegraph.session import SessionError
    from fusegraph.systems.walking import WAIST

    session = dict(mobgap_sessions(DEFAULT_DIR))["HA_001_Test11_Trial1"]

    def steps(detection: StepDetection) -> np.ndarray:
        declared = declare(session, StepLengthConfig(), detection)
        assert declared.__dict__.get("_validation_warnings") is not None  # checked once, for the original and its copy
        return np.asarray(solve_session(declared, "gait").estimate.extras["steps_s"])

    loose, strict, hand = steps(StepDetection(0.05, 0.0)), steps(StepDetection(0.5, 3.0)), steps(HAND_SET_DETECTION)
    assert len(strict) < len(hand) < len(loose)
    # one step detector: the walking front end (the activity classifier's cycles) runs with the solver's default thresholds
    accel, gyro = session.synchronous("accel", "gyro")
    cycles = front_end(accel.t, accel.values, gyro.values, WAIST)[1]
    chosen = steps(StepDetection())
    assert set(np.round([c.t for c in cycles], 9)) <= set(np.round(chosen, 9))  # the front end's cycles, plus inferred contacts
    assert not set(np.round([c.t for c in cycles], 9)) <= set(np.round(strict, 9))
    # the settings' search computes what the solver computes, the gravity filter run once
    from fusegraph.evaluation.gait import Setting, _Searched, fusegraph_counts, reference_of

    for setting in (Setting(), Setting(StepDetection(0.5, 3.0), StepLengthConfig(0.1, 0.5, 4, 1.25, "pendulum"))):
        searched = _Searched.of(session).counts(setting, reference_of(session))
        assert searched == fusegraph_counts(declare(session, setting.length, setting.detection))
    # a value that is no number, or below its least, is an error naming the key (not a bare conversion error)
    for table, wrong in (({"peak_threshold_m_s2": "high"}, "not a number"), ({"forward_slope_m_s3": -1.0}, "must be at least 0"),
                         ({"correction": 0.0}, "must be above 0")):
        with pytest.raises(ValueError, match=wrong):
            solve_session(session.with_meta(gait=table), "gait")
    with pytest.raises(SessionError, match=r"\[gait\]: unknown key 'peak_threshold' \(did you mean 'peak_threshold_m_s2'\?\)"):
        solve_session(session.with_meta(gait={"peak_threshold": 0.2}), "gait")


@requires_shared_data("mobgap")
def test_the_peer_is_the_pipeline_mobgap_recommends_for_the_cohort() -> None:
    """mobgap's row runs its universal pipeline, which picks the healthy one for the healthy adults (HA) shared here
    (and its impaired one for PD, MS, PFF): every shared trial says which ran, and its strides are mobgap's."""
    from fusegraph.datasets.mobgap_lab import DEFAULT_DIR
    from fusegraph.evaluation.gait import mobgap_estimates

    estimates, used = mobgap_estimates(DEFAULT_DIR)
    assert set(used) == set(estimates) and len(used) == 6 and set(used.values()) == {"healthy"}
    assert sum(len(e.stride_length_m) for e in estimates.values()) > 20


@requires_shared_data("mobgap")
def test_a_trial_the_peer_fails_on_is_said_and_left_out(monkeypatch: pytest.MonkeyPatch) -> None:
    """When mobgap's pipeline raises on a trial (another cohort's recording may do that), the bench keeps going: the
    trial has no mobgap estimate and its pipeline reads ``failed: ...``, which the bench's note prints."""
    from mobgap.pipeline import MobilisedPipelineUniversal

    from fusegraph.datasets.mobgap_lab import DEFAULT_DIR
    from fusegraph.evaluation.gait import _pipelines_text, mobgap_estimates

    def fail(self: object, datapoint: object) -> None:
        raise ValueError("no lower-back sensor")

    monkeypatch.setattr(MobilisedPipelineUniversal, "safe_run", fail)
    estimates, used = mobgap_estimates(DEFAULT_DIR)
    assert not estimates and len(used) == 6 and all(v == "failed: ValueError: no lower-back sensor" for v in used.values())
    assert "HA_001_Test5_Trial1 failed: ValueError: no lower-back sensor" in _pipelines_text(used)

