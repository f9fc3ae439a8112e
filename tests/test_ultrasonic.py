"""Ultrasonic tags with unknown association: assignment, prior-free location, tracker, the paper's search."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import requires_shared_data

from fusegraph.baselines.combinatorial import combinatorial_epoch
from fusegraph.evaluation.ultrasonic import crossing_epochs
from fusegraph.frontends.association import assign_ranges, locate, trilaterate
from fusegraph.metrics import identity_map, score_run
from fusegraph.scenarios.ultrasonic import ceiling_board, simulate_ultrasonic
from fusegraph.systems.ultrasonic import RangeEpochs, UltrasonicTracker, run_fusegraph

RECEIVERS = ceiling_board()
# a UWB-like layout: three tags 10-30 cm apart on one planar body, six anchors around it at its height
TROLLEY_TAGS_M = ((0.2, 0.0, 0.0), (-0.1, 0.17, 0.0), (-0.1, -0.17, 0.0))
TROLLEY_ANCHORS_M = np.array([[-1.0, -1.0, 0.9], [3.0, -1.0, 0.9], [3.0, 2.5, 0.9], [-1.0, 2.5, 0.9], [1.0, -1.2, 0.9], [1.0, 2.7, 0.9]])


def _heard(positions: np.ndarray) -> list[np.ndarray]:
    return [np.sort(np.linalg.norm(positions - r, axis=1)) for r in RECEIVERS]


def test_assignment_on_a_hand_built_receiver() -> None:
    # predicted 1.00, 1.20, 1.50 m; heard: an echo at 1.35, the first two, and the third missed
    labels = assign_ranges(np.array([1.001, 1.198, 1.35]), np.array([1.0, 1.2, 1.5]), np.full(3, 0.01))
    assert labels.tolist() == [0, 1, -1]
    # the optimal assignment is global: nearest-neighbour would give both to track 1
    labels = assign_ranges(np.array([1.195, 1.215]), np.array([1.21, 1.23]), np.full(2, 0.01))
    assert labels.tolist() == [0, 1]
    assert assign_ranges(np.zeros(0), np.array([1.0]), np.ones(1)).size == 0
    assert assign_ranges(np.array([1.0]), np.zeros(0), np.ones(0)).tolist() == [-1]


def test_trilaterate_picks_the_point_below_the_board() -> None:
    point = np.array([[0.8, 0.6, 1.0]])
    centres = RECEIVERS[[0, 5, 12]]
    radii = np.linalg.norm(point - centres, axis=1)[None, :]
    found, valid = trilaterate(centres, radii)
    assert valid.all()
    np.testing.assert_allclose(found, point, atol=1e-9)


def test_locate_without_prior_finds_every_transmitter_despite_echoes_and_misses() -> None:
    truth = np.array([[0.3, 0.3, 0.8], [1.2, 1.1, 1.0], [1.7, 0.4, 0.6]])
    ranges = _heard(truth)
    ranges[2] = np.sort(np.r_[ranges[2][1:], 2.9])  # receiver 2 missed one and heard an echo
    ranges[7] = np.sort(np.r_[ranges[7], ranges[7][0] + 0.4])  # an echo
    found = locate(RECEIVERS, ranges, 3)
    assert len(found) == 3
    positions = np.array([f.position_m for f in found])
    error = np.linalg.norm(positions[identity_map(positions, truth).argsort()] - truth, axis=1)
    assert error.max() < 1e-6  # noise-free distances: exact


def test_combinatorial_search_recovers_a_noise_free_epoch() -> None:
    truth = np.array([[0.3, 0.3, 0.8], [1.2, 1.1, 1.0], [1.7, 0.4, 0.6]])
    positions, labels, exhaustive = combinatorial_epoch(RECEIVERS, _heard(truth), 3, 0.005)
    assert exhaustive
    mapping = identity_map(positions, truth)
    np.testing.assert_allclose(positions[mapping.argsort()], truth, atol=1e-6)
    for r, lab in enumerate(labels):
        expected = np.argsort(np.linalg.norm(truth - RECEIVERS[r], axis=1))  # sorted distances -> transmitter
        assert mapping[lab].tolist() == expected.tolist()


def test_tracker_meets_the_accuracy_figures_on_a_short_scenario() -> None:
    epochs = simulate_ultrasonic(4, transmitters=3, duration_s=6.0)
    run = run_fusegraph(epochs, 3)
    score = score_run(epochs, run.labels, run.positions)
    # 5 mm ranges from a 0.6 x 1.5 m board 1.2-2 m above: ~8 mm position RMSE (mostly height)
    assert score.rmse_m < 0.015
    assert score.assoc_acc_unambiguous > 0.998 and score.lost_frac == 0.0


def test_the_association_score_counts_as_a_loop_over_epochs_and_receivers(monkeypatch: pytest.MonkeyPatch) -> None:
    """``score_run`` counts every epoch's and receiver's distances at once; written out here epoch by epoch and receiver by
    receiver, with each epoch's matching of the method's transmitters to the truth (a run with wrong assignments: its
    transmitters given to the wrong distances half the time, so that the counts are not all hits)."""
    epochs = simulate_ultrasonic(6, transmitters=3, duration_s=4.0)
    run = run_fusegraph(epochs, 3)
    rng = np.random.default_rng(2)
    labels = [[np.where(rng.random(len(g)) < 0.5, rng.integers(-1, 3, len(g)), g) for g in epoch] for epoch in run.labels]
    score = score_run(epochs, labels, run.positions)
    assert epochs.labels is not None and epochs.positions is not None
    counts = np.zeros(4, dtype=int)  # correct, total, correct unambiguous, total unambiguous
    for k in range(len(epochs.t)):
        mapping = identity_map(run.positions[k], epochs.positions[k])
        direct = np.linalg.norm(epochs.positions[k][None, :, :] - epochs.receivers[:, None, :], axis=2)
        for r in range(len(epochs.receivers)):
            truth, guess = epochs.labels[k][r], np.where(labels[k][r] >= 0, mapping[np.clip(labels[k][r], 0, None)], -1)
            hit = guess == np.where(truth >= 0, truth, -1)
            others = np.abs(direct[r][None, :] - direct[r][np.clip(truth, 0, None)][:, None])
            others[np.arange(len(truth)), np.clip(truth, 0, None)] = np.inf
            clear = (truth < 0) | (others.min(axis=1, initial=np.inf) > 0.02)
            counts += [hit.sum(), len(truth), hit[clear].sum(), clear.sum()]
    assert (score.assoc_acc, score.assoc_acc_unambiguous) == (counts[0] / counts[1], counts[2] / counts[3])
    assert 0.3 < score.assoc_acc < 0.9  # the wrong labels count as misses
    import fusegraph.metrics

    monkeypatch.setattr(fusegraph.metrics, "SCORE_CHUNK_EPOCHS", 7)  # many passes, one of fewer epochs: the same counts
    assert score_run(epochs, labels, run.positions) == score


def test_a_transmitter_that_disappears_comes_back() -> None:
    epochs = simulate_ultrasonic(5, transmitters=3, duration_s=6.0)
    assert epochs.labels is not None
    # transmitter 1 is silent (every reception missed) from 2 s to 3 s
    silent = (epochs.t >= 2.0) & (epochs.t < 3.0)
    ranges = [[r.copy() for r in row] for row in epochs.ranges]
    labels = [[lab.copy() for lab in row] for row in epochs.labels]
    for k in np.nonzero(silent)[0]:
        for r in range(len(RECEIVERS)):
            keep = labels[k][r] != 1
            ranges[k][r], labels[k][r] = ranges[k][r][keep], labels[k][r][keep]
    gone = RangeEpochs(epochs.t, epochs.receivers, ranges, labels, epochs.positions, epochs.range_sigma_m)
    tracker = UltrasonicTracker(gone.receivers, 3)
    positions = np.array([tracker.step(float(t), gone.ranges[k]).positions for k, t in enumerate(gone.t)])
    assert epochs.positions is not None
    assert tracker.reinitialisations >= 1  # it was declared lost, then found again from unassigned distances
    back = gone.t >= 3.5
    error = np.linalg.norm(positions[back][:, :, None] - epochs.positions[back][:, None, :], axis=3).min(axis=1)
    assert error.max() < 0.05  # every transmitter has a track within 5 cm again half a second later


@pytest.mark.parametrize("head_on", [True, False])
def test_no_identity_swap_when_passing_at_5_cm(head_on: bool) -> None:
    epochs = crossing_epochs(0.05, 1.0, head_on, seed=11)
    run = run_fusegraph(epochs, 2)
    assert epochs.positions is not None
    start = identity_map(run.positions[0], epochs.positions[0])
    end = identity_map(run.positions[-1], epochs.positions[-1])
    assert start.tolist() == end.tolist()


def test_scenario_is_seeded_and_checks_its_size() -> None:
    a, b = simulate_ultrasonic(7, duration_s=1.0), simulate_ultrasonic(7, duration_s=1.0)
    assert all(np.array_equal(x, y) for x, y in zip(a.ranges[10], b.ranges[10], strict=True))
    with pytest.raises(ValueError, match="1..16"):
        simulate_ultrasonic(0, transmitters=17)


def test_uwb_loader_names_a_missing_file(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from fusegraph import SessionError
    from fusegraph.datasets.uwb_lias import load_uwb_lias

    with pytest.raises(SessionError, match="one UWB run per folder .* found none"):
        load_uwb_lias(tmp_path)
    (tmp_path / "UWB_dynamic_exp_mid.csv").write_text("")
    with pytest.raises(SessionError, match=r"no README.md \(or SOURCE_README.md\) with the anchors"):
        load_uwb_lias(tmp_path)


@requires_shared_data("uwb_lias")
def test_a_uwb_run_without_motion_capture_tracks_and_has_nothing_to_score(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A user's run has ranges but no motion capture: `import uwb` writes a session without truth, `run` tracks it
    (the same tracks as with the truth beside; the first 5 s, to stay fast), and the bench, which needs the truth, says
    so instead of failing."""
    from dataclasses import replace

    from fusegraph import SessionError
    from fusegraph.datasets.importers import uwb_session
    from fusegraph.datasets.uwb_lias import DEFAULT_DIR
    from fusegraph.evaluation.runner import solve_session
    from fusegraph.evaluation.uwb import bench_uwb

    def first_seconds(session, seconds: float = 5.0):  # type: ignore[no-untyped-def]
        ranges = session.stream("ranges")
        keep = ranges.t < seconds
        return replace(session, streams={"ranges": replace(ranges, t=ranges.t[keep], values=ranges.values[keep])})

    for name in ("UWB_dynamic_exp_fast.csv", "calibration.csv", "SOURCE_README.md"):
        (tmp_path / name).symlink_to(DEFAULT_DIR / name)
    session = uwb_session(tmp_path)
    assert session.truth is None and "no motion capture" in session.meta["session"]["description"]
    alone, beside = solve_session(first_seconds(session), "online"), solve_session(first_seconds(uwb_session(DEFAULT_DIR)), "online")
    assert alone.metrics is None and beside.metrics is not None
    np.testing.assert_array_equal(alone.estimate.points, beside.estimate.points)
    with pytest.raises(SessionError, match="no motion_capture_<run>.csv"):
        bench_uwb(tmp_path)


@requires_shared_data("uwb_lias")
def test_uwb_recording_reads_the_documented_quaternion_and_tracks_labelled_tags() -> None:
    import dataclasses

    from fusegraph.datasets.uwb_lias import load_uwb_lias
    from fusegraph.systems.uwb import UwbTracker

    rec = load_uwb_lias()
    assert rec.ranges.shape[1:] == (8, 3) and rec.anchors.shape == (8, 3)

    def spread(recording) -> float:  # type: ignore[no-untyped-def]
        truth = recording.tags_truth(recording.t)
        residual = rec.ranges - np.linalg.norm(truth[:, None, :, :] - rec.anchors[None, :, None, :], axis=3)
        return float(np.nanpercentile(residual, 75) - np.nanpercentile(residual, 25))

    # IQR of the labelled range residuals (biases included), metres: the documented scalar-first order
    # with the rigid body's half turn 0.13; without the half turn 0.40; the old scalar-last reading 0.22
    no_turn = dataclasses.replace(rec, local_R_offsets=np.eye(3))
    scalar_last = dataclasses.replace(no_turn, mocap_quat_wxyz=rec.mocap_quat_wxyz[:, [3, 0, 1, 2]])
    assert spread(rec) < 0.7 * min(spread(no_turn), spread(scalar_last))
    tracker = UwbTracker(rec.anchors, rec.tag_offsets)
    xy = np.array([tracker.step(float(t), rec.ranges[k], labelled=True)[0] for k, t in enumerate(rec.t[:1500])])
    truth = rec.tags_truth(rec.t[:1500] + 0.03)[:, :, :2]
    centroid = np.linalg.norm(xy.mean(axis=1) - truth.mean(axis=1), axis=1)
    assert np.sqrt(np.mean(centroid[500:] ** 2)) < 0.15  # m; ranges ~0.1 m noisy, biases learnt on the way


@requires_shared_data("uwb_lias")
def test_uwb_figures_do_not_depend_on_where_the_run_starts() -> None:
    """Started at 0, 30 or 60 s (handedness and start found again from the ranges each time), the labelled
    rigid-body tracker of the imported session scores the same on the common stretch 70-90 s; the clock offset
    comes from the raw ranges and is the same for every start."""
    import dataclasses

    from fusegraph.datasets.importers import uwb_session
    from fusegraph.datasets.uwb_lias import DEFAULT_DIR, clock_offset_from_ranges, load_uwb_lias
    from fusegraph.records import epochs_from_session
    from fusegraph.systems.uwb import track_rigid

    rec = load_uwb_lias().between(0.0, 90.0)
    epochs = epochs_from_session(uwb_session(DEFAULT_DIR, labelled=True))
    assert epochs.labelled and epochs.planar and epochs.tag_offsets_m is not None and epochs.positions is not None
    offsets, scores = [], []
    for start in (0.0, 30.0, 60.0):
        offsets.append(clock_offset_from_ranges(rec.between(start), search_s=0.1, step_s=0.01))
        keep = np.nonzero((epochs.t >= start) & (epochs.t <= 90.0))[0]
        part = dataclasses.replace(epochs, t=epochs.t[keep], ranges=[epochs.ranges[k] for k in keep], labels=None, positions=epochs.positions[keep])
        run = track_rigid(part, epochs.tag_offsets_m, labelled=True)
        common = part.t >= 70.0
        error = run.positions[common, :, :2] - part.positions[common, :, :2]  # labelled: the tags in the truth's order
        scores.append(float(np.sqrt(np.nanmean(np.sum(error**2, axis=2)))))
    assert max(offsets) - min(offsets) <= 0.011, offsets  # one grid step
    assert max(scores) - min(scores) < 0.02, scores  # m (the run's RMSE is ~0.09 m)


@requires_shared_data("uwb_lias")
def test_uwb_clock_offset_is_found_beyond_the_first_search_range() -> None:
    """Another run's clocks may differ by seconds: the UWB stamps moved 2.7 s back, the search widens past its first
    +-1 s and finds the run's own offset (5 ms) plus the shift, to one fine grid step."""
    import dataclasses

    from fusegraph.datasets.uwb_lias import clock_offset_from_ranges, load_uwb_lias

    rec = load_uwb_lias().between(0.0, 60.0)
    own = clock_offset_from_ranges(rec)
    shifted = clock_offset_from_ranges(dataclasses.replace(rec, t=rec.t - 2.7))
    assert abs(own - 0.005) <= 0.0051, own  # the fast run's offset (README), one grid step
    assert abs(shifted - (own + 2.7)) <= 0.0051, (own, shifted)


@requires_shared_data("uwb_lias")
def test_uwb_import_and_run_online_give_the_bench_figures(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The user's path: ``import uwb`` then ``run --solver online --json`` tracks the unlabelled tags of the fast run
    (targets: every estimate within 0.09 m RMS, association >= 0.75, under 5 % lost; measured with the folder's range
    calibration 0.043 m, 0.81, 0.000; without it 0.077, 0.80, 0.017).
    ``bench ultrasonic --uwb`` runs the same ``solve_session`` on the same import."""
    import contextlib
    import io
    import json

    from fusegraph.cli import main
    from fusegraph.datasets.uwb_lias import DEFAULT_DIR

    assert main(["import", "uwb", str(DEFAULT_DIR), "--out", str(tmp_path / "s")]) == 0
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        assert main(["run", str(tmp_path / "s"), "--solver", "online", "--json", "--out", str(tmp_path / "est.csv")]) == 0
    metrics = json.loads(buffer.getvalue())["metrics"]
    assert metrics["rmse_all_m"] <= 0.09 and metrics["assoc_acc"] >= 0.75 and metrics["lost_frac"] <= 0.05, metrics
    assert not (tmp_path / "s" / "tags_online.csv").exists()  # --out given: nothing written into the recording
    assert metrics["rmse_all_m"] <= 0.06  # m: the calibration's per-anchor-and-tag biases (0.084 without them)


def test_a_uwb_range_calibration_is_read_and_checked(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from fusegraph import SessionError
    from fusegraph.datasets.uwb_lias import read_calibration

    rows = [f"{a},{t},{0.01 * (a + t)},{0.001 * t},0.02" for a in range(2) for t in range(3)]
    (tmp_path / "c.csv").write_text("anchor,tag,bias_m,slope,sigma_m\n" + "\n".join(rows) + "\n")
    bias, scale, sigma = read_calibration(tmp_path / "c.csv", 2, 3)
    assert bias[1, 2] == pytest.approx(0.03) and scale[0, 2] == pytest.approx(1.002) and sigma.shape == (2, 3)
    (tmp_path / "d.csv").write_text("anchor,tag,bias_m,slope,sigma_m\n" + "\n".join(rows[:-1]) + "\n")
    with pytest.raises(SessionError, match="no calibration for anchor 1, tag 2"):
        read_calibration(tmp_path / "d.csv", 2, 3)
    with pytest.raises(SessionError, match="anchor 0 / tag 0 outside"):
        read_calibration(tmp_path / "c.csv", 2, 0)


def test_batched_update_equals_gtsam_eliminating_the_same_graph() -> None:
    """One model, no mixing: the bank's update is the marginal of [prior, motion law, range rows], which
    gtsam eliminates (``MarginalStep``) from the same linearisation; both re-linearise once."""
    from fusegraph.solvers.multiple_model import MotionModes, PointBank
    from fusegraph.solvers.sequential import MarginalStep, constant_velocity, covariance, whitening

    rng = np.random.default_rng(3)
    truth = np.array([0.7, 0.9, 1.1])
    ranges = np.linalg.norm(truth - RECEIVERS, axis=1) + rng.normal(0.0, 0.005, len(RECEIVERS))
    ranges[[2, 9]] = np.nan  # two receptions missed
    x_old, cov_old = np.r_[truth + [0.01, -0.02, 0.005], [0.3, 0.0, -0.1]], np.diag([4e-4] * 3 + [0.04] * 3)
    dt, psd, sigma = 0.025, 2.0, 0.005
    bank = PointBank(1, MotionModes(accel_psd=(psd,), mean_stay_s=1e9))  # REST and one constant velocity, never switching
    bank.x[0, :], bank.P[0, :], bank.mu[0] = x_old, cov_old, [0.0, 1.0]
    prediction = bank.predict(dt)
    bank.update(prediction, RECEIVERS, ranges[None, :], sigma, cauchy_k=1e9)  # no reweighting: plain least squares

    F, Q = constant_velocity(dt, [psd] * 3)
    sqrt_info = np.linalg.cholesky(np.linalg.inv(cov_old)).T
    step = MarginalStep(sqrt_info, x_old, F, whitening(Q))
    seen = np.isfinite(ranges)
    x_lin = F @ x_old
    for _ in range(2):
        diff = x_lin[:3] - RECEIVERS[seen]
        rho = np.linalg.norm(diff, axis=1)
        A = np.zeros((seen.sum(), 6))
        A[:, :3] = diff / rho[:, None] / sigma
        R, x_lin = step.solve(A, (ranges[seen] - rho + A[:, :3] @ x_lin[:3] * sigma) / sigma)
    np.testing.assert_allclose(bank.x[0, 1], x_lin, atol=1e-9)  # metres, m/s: both are exact Gaussian elimination
    np.testing.assert_allclose(bank.P[0, 1], covariance(R), rtol=1e-6, atol=1e-12)
    assert np.linalg.norm(bank.x[0, 1, :3] - truth) < 0.01


def test_multiple_models_choose_rest_for_a_resting_target_and_move_for_a_moving_one() -> None:
    """Noise-free ranges: a resting target ends with REST most likely and its position exact; a target at
    0.5 m/s with a constant-velocity model most likely and tracked to a millimetre."""
    from fusegraph.solvers.multiple_model import REST, PointBank

    bank = PointBank(2)
    start = np.array([[0.5, 0.5, 1.0], [1.5, 0.5, 0.8]])
    velocity = np.array([[0.0, 0.0, 0.0], [0.0, 0.5, 0.0]])
    for i in range(2):
        bank.reset(i, start[i])
    dt = 0.025
    for k in range(1, 80):
        here = start + velocity * k * dt
        ranges = np.linalg.norm(here[:, None, :] - RECEIVERS[None], axis=2)
        bank.update(bank.predict(dt), RECEIVERS, ranges, 0.005, cauchy_k=3.0)
    mean, _ = bank.combined()
    assert bank.mu[0].argmax() == REST and bank.mu[1].argmax() != REST
    np.testing.assert_allclose(mean[:, :3], here, atol=1e-3)  # metres: exact data; the moving target's start was unknown in speed
    np.testing.assert_allclose(mean[1, 3:], velocity[1], atol=0.02)  # m/s


@pytest.mark.parametrize(("settle_s", "held_off"), [(0.5, False), (0.0, True)])
def test_a_start_on_borrowed_distances_settles_before_rest_averages_it(settle_s: float, held_off: bool) -> None:
    """Seed 5, N = 12: the prior-free start puts two resting transmitters 4-5 cm off, each on the other's
    distances at one receiver column. Carried by the moving models for 0.5 s the tracks re-read their
    positions from the ranges; with REST at once they stay held off (the reason for ``settle_s``)."""
    from fusegraph.evaluation.ultrasonic import _head
    from fusegraph.systems.ultrasonic import TrackerConfig

    epochs = _head(simulate_ultrasonic(5, transmitters=12, duration_s=20.0), 1.5)
    run = run_fusegraph(epochs, 12, TrackerConfig(settle_s=settle_s))
    assert epochs.positions is not None
    late = slice(40, None)  # after the first second
    error = np.linalg.norm(run.positions[late][:, :, None] - epochs.positions[late][:, None], axis=3)
    worst = float(np.nanmin(error, axis=1).max())  # every transmitter's nearest track, worst epoch
    assert (worst > 0.03) == held_off, worst  # metres: settled tracks are within 2 cm, held ones 4-5 cm off


def test_an_epoch_whose_complete_receivers_are_collinear_gives_no_estimate_not_an_error() -> None:
    truth = np.array([[0.3, 0.3, 0.8], [1.2, 1.1, 1.0], [1.7, 0.4, 0.6]])
    ranges = _heard(truth)
    for r in range(len(RECEIVERS)):
        if RECEIVERS[r, 0] != RECEIVERS[0, 0]:  # only the first column (one line of receivers) heard all three
            ranges[r] = ranges[r][:2]
    positions, labels, _ = combinatorial_epoch(RECEIVERS, ranges, 3, 0.005)
    assert np.isnan(positions).all() and all((lab == -1).all() for lab in labels)
    # a NaN prediction is outside every gate
    assert assign_ranges(np.array([1.0, 2.0]), np.array([np.nan, 2.001]), np.full(2, 0.01)).tolist() == [-1, 1]


def test_the_range_calibration_model_recovers_a_simulated_trolley_with_biased_receivers() -> None:
    """Three tags on one planar body among six anchors at its height (the UWB layout), every anchor-tag range biased by
    its own constant (sigma 0.1 m, the size the recordings carry): declared as the session's calibration, the tracker
    stays within 3 cm and never loses the body (measured 0.010 m); not declared, the biases break it (0.166 m, 56 % of
    the estimates lost), as they broke the real slow run before the calibration."""
    from fusegraph.evaluation.runner import simulated_sessions, solve_session

    found = {}
    for declare in (True, False):
        _, session = simulated_sessions("ultrasonic", [0], duration_s=20.0, rigid_tag_offsets_m=TROLLEY_TAGS_M, range_bias_sigma_m=0.1,
                                        declare_calibration=declare, receivers=TROLLEY_ANCHORS_M, range_sigma_m=0.03)[0]
        assert ("range_bias_m" in session.stream("ranges").meta) is declare
        metrics = solve_session(session, "online").metrics
        assert metrics is not None
        found[declare] = metrics
    assert found[True]["rmse_all_m"] < 0.03 and found[True]["lost_frac"] == 0.0
    assert found[False]["rmse_all_m"] > 3 * found[True]["rmse_all_m"]


def test_the_association_ceiling_assigns_through_the_declared_calibration() -> None:
    """``metrics.oracle_labels`` (the bench's ceiling for a UWB run): the ranges assigned against the true positions
    through the declared calibration (measured 0.937); without it the 0.1 m biases lower the ceiling (0.873); the
    unlabelled tracker reaches it and cannot pass it by more than near-ties taken the other way (0.933)."""
    from dataclasses import replace

    from fusegraph.evaluation.runner import simulated_sessions, solve_session
    from fusegraph.metrics import oracle_labels
    from fusegraph.records import epochs_from_session

    _, session = simulated_sessions("ultrasonic", [0], duration_s=10.0, rigid_tag_offsets_m=TROLLEY_TAGS_M, range_bias_sigma_m=0.1,
                                    receivers=TROLLEY_ANCHORS_M, range_sigma_m=0.03)[0]
    epochs = epochs_from_session(session)
    with_calibration = score_run(epochs, oracle_labels(epochs, gate_chi2=1e12), None).assoc_acc
    without = score_run(replace(epochs, calibration=None), oracle_labels(replace(epochs, calibration=None), gate_chi2=1e12), None).assoc_acc
    tracked = solve_session(session, "online").metrics
    assert tracked is not None
    assert without < with_calibration - 0.05, (without, with_calibration)
    assert tracked["assoc_acc"] <= with_calibration + 0.02, (tracked["assoc_acc"], with_calibration)  # 2 %: near-ties either way


def test_uwb_soft_pairs_share_only_ranges_that_could_have_swapped() -> None:
    """``frontends.association.share_swaps`` (the rigid UWB tracker's soft pairs): two tags whose predicted ranges at an
    anchor differ by 1 cm (within the assignment's 5 cm sigma) each take nearly half of the other's range; a third 40 cm
    away keeps its own (a swap there is 8 sigmas off). The weights of each tag's rows sum to one (the EM weights of a
    two-way mixture)."""
    from fusegraph.frontends.association import share_swaps

    predicted = np.array([[5.0], [5.01], [5.4]])  # (tags, anchors)
    receiver, tag, z, weight = share_swaps(np.zeros(3, dtype=int), np.array([2, 0, 1]), np.array([5.4, 5.0, 5.01]), predicted, 0.05)
    np.testing.assert_allclose(np.bincount(tag, weights=weight, minlength=3), 1.0, atol=1e-12)
    assert weight[(tag == 2) & (z == 5.4)].item() > 1 - 1e-6
    shared = weight[(tag == 0) & (z == 5.01)]
    assert len(shared) == 1 and 0.45 < shared.item() < 0.5  # 1 / (1 + e^0.04): nearly a coin toss
    assert np.all(receiver == 0) and len(z) == 5  # the three given rows and the two shared ones; 2 <-> 1 carries nothing


@pytest.mark.parametrize("seed", [0, 2, 3])
def test_a_short_biased_run_starts_on_the_calibrated_layout(seed: int) -> None:
    """The start compares an anchor's unlabelled range differences with what each tag would MEASURE (the calibration's
    bias on the prediction). Before, it compared them with the bare geometry: with 0.1 m biases per anchor and tag
    beside a 10-30 cm layout, 6 of 10 ten-second runs (seeds 0-9) started turned and lost 55-84 % of the estimates
    (seeds 0, 2, 3: 0.15-0.27 m); now none (0.008-0.024 m)."""
    from fusegraph.evaluation.runner import simulated_sessions, solve_session

    _, session = simulated_sessions("ultrasonic", [seed], duration_s=10.0, rigid_tag_offsets_m=TROLLEY_TAGS_M, range_bias_sigma_m=0.1,
                                    receivers=TROLLEY_ANCHORS_M, range_sigma_m=0.03)[0]
    metrics = solve_session(session, "online").metrics
    assert metrics is not None
    assert metrics["lost_frac"] == 0.0 and metrics["rmse_all_m"] < 0.04, metrics  # 4 cm: above the worst of seeds 0-9 (0.024)


@requires_shared_data("uwb_lias")
def test_a_silent_anchor_is_said_and_the_others_track_without_numpy_noise(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The fast run with anchor 3's three columns emptied: the import's clock offset and the tracker's start take the
    other anchors without numpy's empty-slice warnings (they leaked to the user before), validation names the silent
    receiver, and the tracks hold (the whole run: 0.0436 m unlabelled against 0.0432 with every anchor)."""
    import warnings
    from dataclasses import replace

    from fusegraph.consistency import check_streams
    from fusegraph.datasets.importers import uwb_session
    from fusegraph.datasets.uwb_lias import DEFAULT_DIR
    from fusegraph.evaluation.runner import solve_session
    from fusegraph.session import SessionWarning

    lines = (DEFAULT_DIR / "UWB_dynamic_exp_fast.csv").read_text().splitlines()
    silent = []
    for line in lines:
        cells = line.split(",")
        cells[10:13] = ["", "", ""]  # a3-t0, a3-t1, a3-t2 (after the time column)
        silent.append(",".join(cells))
    (tmp_path / "UWB_dynamic_exp_fast.csv").write_text("\n".join(silent) + "\n")
    for name in ("motion_capture_dynamic_exp_fast.csv", "calibration.csv", "SOURCE_README.md"):
        (tmp_path / name).symlink_to(DEFAULT_DIR / name)
    with pytest.warns(SessionWarning, match=r"receiver\(s\) 3 of receivers_m never heard"), warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        session = uwb_session(tmp_path)
        ranges = session.stream("ranges")
        first = ranges.t < 5.0
        short = replace(session, streams={"ranges": replace(ranges, t=ranges.t[first], values=ranges.values[first])})
        outcome = solve_session(short, "online")
    assert any("receiver(s) 3 of receivers_m never heard" in line for line in check_streams(short.streams))
    assert outcome.metrics is not None and outcome.metrics["lost_frac"] == 0.0 and outcome.metrics["rmse_all_m"] < 0.1


def test_the_uwb_bench_says_what_its_figures_are() -> None:
    from pathlib import Path

    from fusegraph.evaluation.ultrasonic import uwb_figures_are

    assert "in-sample: the calibrated tracker's settings were chosen on this run" in uwb_figures_are(Path("data/uwb_lias"))
    assert uwb_figures_are(Path("data/uwb_lias_medium")) == "ran; held out: no setting was chosen on this run"


@requires_shared_data("uwb_lias")
def test_the_uwb_start_searches_the_heading_as_its_per_range_form() -> None:
    """``UwbTracker.start`` on unlabelled ranges (the first second of the LIAS run, both handednesses) scores every heading
    at once: its cost, heading and handedness are those of the per-anchor loop it replaced (written out here), the cost
    to the bit."""
    from fusegraph.datasets.uwb_lias import load_uwb_lias
    from fusegraph.systems.uwb import UwbTracker

    rec = load_uwb_lias()
    first = rec.ranges[: int(np.searchsorted(rec.t, rec.t[0] + 1.0))]
    for shift in (0, 400):  # the run's start and a moment 400 epochs on
        epochs = rec.ranges[shift : shift + len(first)]
        tracker = UwbTracker(rec.anchors, rec.tag_offsets)
        tracker.start(epochs, labelled=False)
        chosen = (tracker.start_cost, float(tracker.x[2]), tracker.mirror)
        c, bias = tracker.x[:2], np.zeros((len(rec.anchors), 3))
        best = (np.inf, 0.0, 1.0)
        for handed in (1.0, -1.0):
            tracker.mirror = handed
            for heading in np.deg2rad(np.arange(0, 360, 5)):
                predicted = tracker._scale.T * tracker._predicted_ranges(tracker.tag_xy(np.r_[c, heading])) + bias.T
                rel_p = predicted - predicted.mean(axis=0)
                cost = 0.0
                for epoch in epochs:
                    for a in range(len(rec.anchors)):
                        heard = np.isfinite(epoch[a])
                        if heard.sum() >= 2:
                            rel_h = epoch[a][heard] - epoch[a][heard].mean()
                            cost += float(np.min(np.abs(rel_h[:, None] - rel_p[None, :, a]), axis=1).sum())
                if cost < best[0]:
                    best = (cost, float(heading), handed)
        assert chosen == best  # the cost to the bit
