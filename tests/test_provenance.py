"""A report says which of its sessions are recordings (or simulated seeds) that settings on main were chosen on."""

from __future__ import annotations

from fusegraph.provenance import choices_that_saw
from fusegraph.report.tables import provenance_line
from fusegraph.tuned import tuned


def test_a_recording_a_setting_was_chosen_on_is_named_and_another_is_not() -> None:
    trial = tuned("broad_mag")["trials"][0]
    assert "tuned.toml [broad_mag]" in choices_that_saw("attitude9", {"dataset": "BROAD", "trial": trial})
    # the gaze system's head runs the 9-axis settings: BROAD's gaze sessions of the same trial are in-sample for them
    assert "tuned.toml [broad_mag]" in choices_that_saw("gaze", {"dataset": "BROAD's recorded head with a SIMULATED eye", "trial": trial})
    assert choices_that_saw("attitude9", {"dataset": "BROAD", "trial": "99_a_trial_of_another_lab"}) == []
    assert choices_that_saw("attitude9", {"dataset": "my lab", "trial": trial}) == []  # the same name in another dataset
    assert choices_that_saw("head", {"dataset": "BROAD", "trial": trial}) == []  # the head's settings come from simulations


def test_simulated_tuning_seeds_are_in_sample_where_a_setting_was_chosen_on_them() -> None:
    first, last = tuned("head_ekf")["seeds"]
    assert "tuned.toml [head_ekf]" in choices_that_saw("head", {"seed": str(first)})
    assert choices_that_saw("head", {"seed": str(last + 1)}) == [] and choices_that_saw("head", {"seed": "3"}) == []
    assert choices_that_saw("attitude9", {"seed": str(first)}) == []  # every 9-axis setting was chosen on BROAD


def test_walking_names_the_activity_model_the_gait_defaults_and_the_phone_threshold() -> None:
    assert choices_that_saw("walking", {"dataset": "UCI HAPT", "trial": "exp01_user01"}) == ["the activity model (models/activity_waist.json)"]
    assert choices_that_saw("walking", {"dataset": "UCI HAPT", "trial": "exp45_user22"}) == []  # users 11-30 are held out
    assert choices_that_saw("walking", {"dataset": "Mobilise-D (mobgap example data)", "subject": "HA/002"}) == [
        "the step thresholds (frontends.pdr)"]
    assert choices_that_saw("walking", {"dataset": "Mobilise-D (mobgap example data)", "subject": "MS/001"}) == []


def test_the_report_line_says_in_sample_for_which_sessions() -> None:
    assert provenance_line({}, 3).startswith("what these figures are: held out")
    line = provenance_line({"a": ["tuned.toml [broad_mag]", "tuned.toml [broad_bias]"], "b": ["tuned.toml [broad_mag]"]}, 3)
    assert "IN-SAMPLE for 2 of the 3 sessions" in line and "(tuned.toml [broad_bias, broad_mag]): a, b; the others held out" in line


def test_a_simulated_report_says_whether_its_seeds_are_held_out() -> None:
    from fusegraph.evaluation.tuning import seeds_label

    assert seeds_label(range(10)) == ("what these figures are: simulated seeds 0-9, held out (the simulated settings were chosen on tuning "
                                      "seeds 100-119)")
    assert seeds_label([3]).startswith("what these figures are: simulated seed 3, held out")
    assert seeds_label([7, 104, 105]).endswith("simulated seeds 7, 104, 105, IN-SAMPLE on 104-105 (the tuning seeds settings were chosen on)")


def test_the_page_marks_an_in_sample_session_where_it_is_drawn(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from fusegraph.report.html import write_html

    report = {"system": "attitude9", "sessions": {"a": {}, "b": {}}, "in_sample": {"a": ["tuned.toml [broad_mag]"]}}
    text = write_html(report, "table", {"a": [], "b": []}, tmp_path / "r.html").read_text()
    a, b = text.index("<h2 id='a'>"), text.index("<h2 id='b'>")
    assert text.count("IN-SAMPLE") == 1 and a < text.index("IN-SAMPLE: settings on main were chosen on this recording (tuned.toml [broad_mag])") < b
