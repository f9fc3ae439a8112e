"""Metrics: attitude error per Euler axis, RMS, NEES — as result objects that merge across runs."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .estimate import Estimate
from .geometry import FloatArray, euler_zyx_from_quat, quat_conjugate, quat_multiply, quat_normalize, rotvec_from_quat, wrap_angle
from .records import GazeSession, RangeEpochs

AXES = ("azimuth", "elevation", "roll")


def euler_errors(estimate_quat: FloatArray, truth_quat: FloatArray) -> FloatArray:
    """Per-axis error: difference of ZYX Euler angles (estimate - truth), wrapped to [-pi, pi)."""
    return wrap_angle(euler_zyx_from_quat(estimate_quat) - euler_zyx_from_quat(truth_quat))


def body_errors(estimate_quat: FloatArray, truth_quat: FloatArray) -> FloatArray:
    """Rotation-vector error Log(est^-1 * truth) in the body frame, rad (gtsam's right perturbation)."""
    return rotvec_from_quat(quat_multiply(quat_conjugate(estimate_quat), truth_quat))


def nees(estimate_quat: FloatArray, cov: FloatArray, truth_quat: FloatArray) -> FloatArray:
    """Normalised estimation error squared per sample (3 dof: about 3 when the covariance is honest); NaN where ``cov``
    or the estimate is not finite, or ``cov`` is not positive definite (to rounding), which is no covariance (Method II's EKF on BROAD
    trial 04 at one of bench head-recorded's grid points: 1e10 rad^2 and indefinite 132 s in; numpy's solve then
    stopped the whole bench)."""
    delta = body_errors(estimate_quat, truth_quat)
    out = np.full(len(delta), np.nan)
    positive = np.all(np.isfinite(cov.reshape(len(cov), -1)), axis=1) & np.all(np.isfinite(delta), axis=1)
    eigenvalues = np.linalg.eigvalsh(cov[positive])
    # positive beyond rounding: a smallest eigenvalue within 1e-12 of the largest left numpy's solve a zero pivot (Method II
    # on BROAD trial 21 at a grid point of bench head-recorded)
    positive[positive] = eigenvalues[:, 0] > 1e-12 * eigenvalues[:, -1]
    out[positive] = np.einsum("ni,ni->n", delta[positive], np.linalg.solve(cov[positive], delta[positive][..., None])[..., 0])
    return out


@dataclass(frozen=True)
class AttitudeScore:
    """Scores of one estimate against the truth over the scored samples."""

    rms_rad: FloatArray
    """RMS of the Euler-angle errors (azimuth, elevation, roll), rad."""
    nees: float | None
    """Mean NEES of the attitude, None when the method has no covariance."""
    samples: int
    """Number of scored samples."""
    missing: int
    """Scored instants where the method had no estimate (counted, not hidden)."""
    missing_t: FloatArray = field(default_factory=lambda: np.empty(0))
    """Their truth times, s (``why_missing`` says why)."""

    def as_dict(self) -> dict[str, object]:
        return {"rms_rad": dict(zip(AXES, (float(v) for v in self.rms_rad), strict=True)), "nees": self.nees, "samples": self.samples, "missing": self.missing}


def nearest_samples(t: FloatArray, times: FloatArray) -> np.ndarray:
    """Index of the sample of ``t`` (sorted) nearest each of ``times``."""
    if len(t) < 2:
        return np.zeros(len(times), dtype=int)
    right = np.clip(np.searchsorted(t, times), 1, len(t) - 1)
    return np.where(np.abs(t[right] - times) < np.abs(times - t[right - 1]), right, right - 1)


def estimate_gaps(t: FloatArray) -> list[tuple[float, float]]:
    """(start, end) of the steps of an estimate's times that are dropouts (``factors.gyro.gap_limit_s`` at its median
    rate): the sensor was silent there and an online estimate has nothing to say."""
    from .factors.gyro import gap_limit_s

    if len(t) < 3:
        return []
    steps = np.diff(t)
    limit = gap_limit_s(1.0 / max(float(np.median(steps)), 1e-12))
    return [(float(t[i]), float(t[i + 1])) for i in np.flatnonzero(steps > limit)]


def inside_gaps(gaps: Sequence[tuple[float, float]], t: FloatArray) -> np.ndarray:
    """Times strictly inside any of the (start, end) spans."""
    inside = np.zeros(len(t), dtype=bool)
    for start, end in gaps:
        inside |= (t > start + 1e-6) & (t < end - 1e-6)
    return inside


def why_missing(estimate_t: FloatArray, truth_t: FloatArray) -> str | None:
    """Why the truth samples at ``truth_t`` (scored, but without a finite estimate) were not scored; None when none."""
    if not len(truth_t):
        return None
    gaps = estimate_gaps(estimate_t)
    counts = {
        "before the estimate starts": int((truth_t < estimate_t[0] - 1e-6).sum()) if len(estimate_t) else len(truth_t),
        "after it ends": int((truth_t > estimate_t[-1] + 1e-6).sum()) if len(estimate_t) else 0,
        "inside its dropouts (" + ", ".join(f"{a:.2f}-{b:.2f} s" for a, b in gaps[:3]) + (", ..." if len(gaps) > 3 else "")
        + ": no sensor sample there)": int(inside_gaps(gaps, truth_t).sum()),
    }
    said = sum(counts.values())
    counts["where the method gave no finite attitude"] = len(truth_t) - said
    return "; ".join(f"{n} {what}" for what, n in counts.items() if n > 0)


def on_truth_times(estimate: Estimate, truth_t: FloatArray) -> Estimate:
    """The estimate at the truth's times (the truth may be on any grid: an optical system's own rate, occluded rows
    dropped): a truth time that matches an estimate time (to 1 us) takes that sample unchanged, any other the slerp
    between its two neighbours and the nearer one's covariance; NaN outside the estimate's span. Equal grids are returned
    as they are."""
    from .geometry import quat_from_rotvec, quat_normalize

    if estimate.t.shape == truth_t.shape and np.allclose(estimate.t, truth_t, rtol=0.0, atol=1e-6):
        return estimate
    t, q = estimate.t, estimate.quat_wxyz
    right = np.clip(np.searchsorted(t, truth_t), 1, max(len(t) - 1, 1))
    left = right - 1
    span = np.maximum(t[right] - t[left], 1e-12)
    fraction = np.clip((truth_t - t[left]) / span, 0.0, 1.0)
    step = quat_multiply(quat_conjugate(q[left]), q[right])
    step = np.where(step[:, :1] < 0, -step, step)  # the short way round
    quat = quat_normalize(quat_multiply(q[left], quat_from_rotvec(fraction[:, None] * rotvec_from_quat(step))))
    exact = np.isclose(t[left], truth_t, rtol=0.0, atol=1e-6) | np.isclose(t[right], truth_t, rtol=0.0, atol=1e-6)
    nearest = nearest_samples(t, truth_t)
    quat[exact] = q[nearest[exact]]
    quat[(truth_t < t[0] - 1e-6) | (truth_t > t[-1] + 1e-6)] = np.nan
    # nor inside a dropout of the estimate (an online solver has nothing to say while its gyro is silent)
    quat[inside_gaps(estimate_gaps(t), truth_t) & ~exact] = np.nan
    cov = None if estimate.cov is None else estimate.cov[nearest]
    return Estimate(estimate.method, np.asarray(truth_t, dtype=float).copy(), quat, cov, estimate.runtime_s, estimate.extras)


EULER_DOMAIN_DEG = 80.0
"""Elevation bound of the Euler-angle domain, degrees: near +-90 deg azimuth and roll are not separate angles, and an
Euler-angle filter's rate matrix (1/cos(elevation): 5.8 at 80 deg) amplifies a rate error that much."""


def in_euler_domain(quat_wxyz: FloatArray) -> np.ndarray:
    """Attitudes whose ZYX elevation is inside ``EULER_DOMAIN_DEG`` (a NaN attitude is not)."""
    finite = np.all(np.isfinite(quat_wxyz), axis=1)
    inside = np.zeros(len(quat_wxyz), dtype=bool)
    inside[finite] = np.abs(euler_zyx_from_quat(quat_wxyz[finite])[:, 1]) < np.deg2rad(EULER_DOMAIN_DEG)
    return inside


def score_attitude(estimate: Estimate, truth_t: FloatArray, truth_quat: FloatArray, start_s: float = 1.0,
                   mask: np.ndarray | None = None) -> AttitudeScore:
    """Score an estimate sampled at the truth's times, from ``start_s`` after the first truth sample, where the truth is
    finite and (``mask``) where the caller scores (a movement flag, the Euler-angle domain)."""
    if estimate.t.shape != truth_t.shape or not np.allclose(estimate.t, truth_t):
        raise ValueError(f"estimate '{estimate.method}' is not sampled at the truth times")
    scored = (truth_t >= truth_t[0] + start_s) & np.all(np.isfinite(truth_quat), axis=1)
    if mask is not None:
        scored &= mask
    have = scored & np.all(np.isfinite(estimate.quat_wxyz), axis=1)
    errors = euler_errors(estimate.quat_wxyz[have], truth_quat[have])
    rms = np.sqrt(np.mean(errors**2, axis=0)) if have.any() else np.full(3, np.nan)
    mean_nees = None
    if estimate.cov is not None:
        usable = have & np.all(np.isfinite(estimate.cov.reshape(len(truth_t), -1)), axis=1)
        if usable.any():
            mean_nees = float(np.mean(nees(estimate.quat_wxyz[usable], estimate.cov[usable], truth_quat[usable])))
    return AttitudeScore(rms, mean_nees, int(have.sum()), int((scored & ~have).sum()), truth_t[scored & ~have])


def mean_scores(scores: Sequence[AttitudeScore]) -> AttitudeScore:
    """Mean over runs (seeds) of each RMS and NEES: what ratios between methods compare."""
    rms = np.mean([s.rms_rad for s in scores], axis=0)
    nees_values = [s.nees for s in scores if s.nees is not None]
    return AttitudeScore(rms, float(np.mean(nees_values)) if nees_values else None, sum(s.samples for s in scores), sum(s.missing for s in scores))


@dataclass(frozen=True)
class BroadErrors:
    """The benchmark's RMSE, degrees."""

    total: float
    heading: float
    inclination: float
    samples: int
    """Samples scored (movement set, truth finite)."""
    failed: int = 0
    """Of those, samples where the estimate was not finite (scored as 180 deg)."""


def broad_errors(estimate_quat_wxyz: FloatArray, truth_quat_wxyz: FloatArray, movement: FloatArray) -> BroadErrors:
    """Total, heading and inclination RMSE (deg) as the benchmark defines them.

    Samples are those in movement with a finite truth. A sample where the ESTIMATE is not finite is not
    dropped (a method must not escape its hard samples): it is scored as failing, 180 deg in all three.
    """
    scored = (np.asarray(movement) > 0) & np.all(np.isfinite(truth_quat_wxyz), axis=1)
    if not scored.any():
        raise ValueError("no sample to score (no movement with a finite truth)")
    estimate = np.asarray(estimate_quat_wxyz, dtype=float)[scored]
    failed = ~np.all(np.isfinite(estimate), axis=1) | (np.linalg.norm(np.nan_to_num(estimate), axis=1) < 1e-9)
    estimate = np.where(failed[:, None], np.array([1.0, 0.0, 0.0, 0.0]), estimate)
    q_err = quat_multiply(quat_normalize(estimate), quat_conjugate(quat_normalize(truth_quat_wxyz[scored])))
    w = np.clip(np.abs(q_err[:, 0]), 0.0, 1.0)
    z = q_err[:, 3]
    total = np.where(failed, np.pi, 2.0 * np.arccos(w))
    heading = np.where(failed, np.pi, 2.0 * np.arctan(np.abs(z) / np.maximum(w, 1e-12)))
    inclination = np.where(failed, np.pi, 2.0 * np.arccos(np.clip(np.sqrt(w**2 + z**2), 0.0, 1.0)))

    def rmse(x: FloatArray) -> float:
        return float(np.rad2deg(np.sqrt(np.mean(x**2))))

    return BroadErrors(rmse(total), rmse(heading), rmse(inclination), int(scored.sum()), int(failed.sum()))


def gap_scores(estimate: Estimate, truth_t: np.ndarray, truth_quat: np.ndarray, gaps: list[tuple[float, float]],
               estimate_t: FloatArray | None = None) -> dict[str, Any]:
    """Scores over the truth samples strictly inside the tracker's gaps: ``gap_rms_deg`` per axis, ``gap_max_deg``
    (largest attitude error angle) and ``gap_nees`` (mean NEES there; None without covariances), so a long dropout
    shows whether the error stays bounded and the covariance grows with it. With the estimate's own times
    (``estimate_t``), ``gap_why`` says why samples there had no estimate."""
    inside = inside_gaps(gaps, truth_t)
    if not inside.any():
        return {"gap_rms_deg": dict.fromkeys(AXES, float("nan")), "gap_max_deg": float("nan"), "gap_nees": None}
    errors = np.rad2deg(euler_errors(estimate.quat_wxyz[inside], truth_quat[inside]))
    # a method with no estimate inside the gap fails there (NaN), it does not escape it
    rms = np.sqrt(np.mean(errors**2, axis=0))
    angle = np.rad2deg(np.linalg.norm(body_errors(estimate.quat_wxyz[inside], truth_quat[inside]), axis=1))
    gap_nees = None
    if estimate.cov is not None:
        gap_nees = float(np.nanmean(nees(estimate.quat_wxyz[inside], estimate.cov[inside], truth_quat[inside])))
    out: dict[str, Any] = {"gap_rms_deg": dict(zip(AXES, (float(v) for v in rms), strict=True)), "gap_max_deg": float(np.max(angle)), "gap_nees": gap_nees}
    unscored = inside & ~np.isfinite(estimate.quat_wxyz).all(axis=1)
    if estimate_t is not None and unscored.any():
        out["gap_why"] = why_missing(estimate_t, truth_t[unscored])
    return out


def identity_map(estimate: FloatArray, truth: FloatArray) -> np.ndarray:
    """Method's transmitter index -> truth index by an optimal matching of positions (one epoch)."""
    from scipy.optimize import linear_sum_assignment

    cost = np.linalg.norm(estimate[:, None, :] - truth[None, :, :], axis=2)
    rows, cols = linear_sum_assignment(np.nan_to_num(cost, nan=1e6))
    mapping = np.full(len(estimate), -1)
    mapping[rows] = cols
    return mapping


@dataclass(frozen=True)
class AssociationScore:
    """Association accuracy (fractions) and position accuracy of one run."""

    assoc_acc: float
    """Over all distances: direct ones given their transmitter, echoes left out."""
    assoc_acc_unambiguous: float
    """Over echoes and the direct distances more than 2 cm from every other transmitter's at that receiver."""
    rmse_m: float
    """Position RMSE over the transmitter-epochs that are tracked (within ``lost_beyond_m``), metres."""
    rmse_all_m: float
    """Position RMSE over every transmitter-epoch with an estimate, lost ones included, metres."""
    lost_frac: float
    """Transmitter-epochs with no estimate within ``lost_beyond_m`` (track loss)."""
    identity_swaps: int
    """Times the matching of the method's transmitters to the truth changed from one epoch to the next."""


def lost_beyond_m(epochs: RangeEpochs) -> float:
    """A track is lost when its error exceeds what the range noise explains: 3 declared range sigmas, at least 5 cm
    (the ultrasonic simulations' 5 mm ranges: 5 cm; UWB's 10 cm ranges: 30 cm). Set before any run was scored."""
    return max(0.05, 3.0 * epochs.range_sigma_m)


def oracle_labels(epochs: RangeEpochs, gate_chi2: float = 16.0) -> list[list[np.ndarray]]:
    """The limit: each receiver's distances assigned against the TRUE positions (same assignment and gate), through the
    range calibration where the session declares one (measured = scale x true + bias, its sigma per receiver and tag)."""
    from .frontends.association import assign_ranges

    assert epochs.positions is not None
    out = []
    receivers = len(epochs.receivers)
    bias, scale, sigma = (np.zeros((receivers, epochs.transmitters)), np.ones((receivers, epochs.transmitters)),
                          np.full((receivers, epochs.transmitters), epochs.range_sigma_m)) if epochs.calibration is None else epochs.calibration
    for k in range(len(epochs.t)):
        predicted = scale * np.linalg.norm(epochs.positions[k][None, :, :] - epochs.receivers[:, None, :], axis=2) + bias
        out.append([assign_ranges(epochs.ranges[k][r], predicted[r], sigma[r], gate_chi2) for r in range(receivers)])
    return out


SCORE_CHUNK_EPOCHS = 20_000
"""``score_run`` counts this many epochs' distances at once: a LIAS run's 13,481 in one pass, an hour's at 100 Hz in 18
passes of ~60 MB each."""


def _association_counts(epochs: RangeEpochs, labels: list[list[np.ndarray]], mappings: np.ndarray | None, span: range) -> tuple[int, int, int, int]:
    """(correct, total, correct unambiguous, total unambiguous) over the distances of the epochs in ``span``, every receiver's
    at once (the same integers as a loop over them); ``mappings``: per epoch, the method's transmitter -> truth index."""
    assert epochs.labels is not None and epochs.positions is not None
    receivers = len(epochs.receivers)  # a chunk's distances, flat, epoch by epoch and receiver by receiver
    truth = np.concatenate([np.zeros(0, dtype=int)] + [np.asarray(epochs.labels[k][r]) for k in span for r in range(receivers)]).astype(int)
    guess = np.concatenate([np.zeros(0, dtype=int)] + [np.asarray(labels[k][r]) for k in span for r in range(receivers)]).astype(int)
    counts = [len(epochs.labels[k][r]) for k in span for r in range(receivers)]
    epoch_of = np.repeat(np.repeat(np.asarray(span), receivers), counts)
    receiver_of = np.repeat(np.tile(np.arange(receivers), len(span)), counts)
    if mappings is not None:
        guess = np.where(guess >= 0, mappings[epoch_of, np.clip(guess, 0, None)], -1)
    hit = guess == np.where(truth >= 0, truth, -1)
    # unambiguous: echoes, and direct distances > 2 cm from every OTHER transmitter's direct distance at that receiver
    direct = np.linalg.norm(epochs.positions[epoch_of] - epochs.receivers[receiver_of][:, None, :], axis=2)  # (n, transmitters)
    own = np.clip(truth, 0, None)
    others = np.abs(direct - direct[np.arange(len(own)), own][:, None])
    others[np.arange(len(own)), own] = np.inf
    clear = (truth < 0) | (others.min(axis=1, initial=np.inf) > 0.02)
    return int(hit.sum()), len(truth), int(hit[clear].sum()), int(clear.sum())


def score_run(epochs: RangeEpochs, labels: list[list[np.ndarray]], positions: FloatArray | None) -> AssociationScore:
    """Score a run. Each epoch, the method's transmitters are matched to the truth by position (the
    association question is which distance belongs to which transmitter; keeping identities over time
    is counted apart, as swaps). ``positions`` None: the labels are truth indices already (oracle). A planar session
    is scored in x, y. A track is lost beyond ``lost_beyond_m(epochs)``."""
    assert epochs.labels is not None and epochs.positions is not None
    dims = 2 if epochs.planar else 3
    errors, swaps, previous = [], 0, None
    mappings = np.tile(np.arange(epochs.transmitters), (len(epochs.t), 1))  # a method's transmitter -> truth index, per epoch
    for k in range(len(epochs.t)):
        truth_k = epochs.positions[k]
        if positions is not None:
            mapping = identity_map(positions[k][:, :dims], truth_k[:, :dims])
            if previous is not None:
                swaps += int(np.sum(mapping != previous)) // 2
            previous = mappings[k] = mapping
            matched = np.full((epochs.transmitters, dims), np.nan)
            matched[mapping[mapping >= 0]] = positions[k][mapping >= 0, :dims]
            errors.append(np.linalg.norm(matched - truth_k[:, :dims], axis=1))
    correct = total = correct_u = total_u = 0
    for first in range(0, len(epochs.t), SCORE_CHUNK_EPOCHS):
        counts = _association_counts(epochs, labels, mappings if positions is not None else None, range(first, min(first + SCORE_CHUNK_EPOCHS, len(epochs.t))))
        correct, total, correct_u, total_u = correct + counts[0], total + counts[1], correct_u + counts[2], total_u + counts[3]
    rmse = rmse_all = lost = float("nan")
    if errors:
        err = np.nan_to_num(np.array(errors), nan=np.inf)
        finite = np.isfinite(err)
        tracked = err <= lost_beyond_m(epochs)
        rmse = float(np.sqrt(np.mean(err[tracked] ** 2))) if tracked.any() else float("nan")
        rmse_all = float(np.sqrt(np.mean(err[finite] ** 2))) if finite.any() else float("nan")
        lost = float(np.mean(~tracked))
    return AssociationScore(correct / max(total, 1), correct_u / max(total_u, 1), rmse, rmse_all, lost, swaps)


# ------------------------------------------------------------------------------ walking on real recordings

WALKING_LABELS = {1: "flat", 2: "stairs_up", 3: "stairs_down"}
"""Activity label ids that score walking cycles (UCI HAPT's: walking, upstairs, downstairs)."""

STATIC_LABELS = (4, 5, 6)
"""Label ids of static segments (sitting, standing, lying)."""

NOT_WALKING_LABELS = tuple(range(4, 13))
"""Label ids of not walking: the static segments and HAPT's postural transitions (7-12: stand to sit, sit to stand, sit to
lie, lie to sit, stand to lie, lie to stand)."""

CLASSES = (*WALKING_LABELS.values(), "not_walking")
"""The classes a cycle is scored in (the classifier's, ``frontends.activity.ACTIVITIES``)."""


def class_of_label(label: int) -> str | None:
    """The class a label id scores in (None: unlabelled, 0)."""
    return WALKING_LABELS.get(int(label)) or ("not_walking" if int(label) in NOT_WALKING_LABELS else None)


def activity_counts(cycle_labels: Sequence[int] | np.ndarray, calls: Sequence[str], labels: np.ndarray, label_dt_s: float) -> dict[str, Any]:
    """One recording's raw activity counts: per labelled class (``CLASSES``; every HAPT label scores) how many of its cycles
    were called each class, the cycles inside static segments, the calls of cycles where no label is (reported apart:
    nobody said what happened there), and the seconds labelled with each class (what ``activity_scores`` pools)."""
    called = {name: dict.fromkeys(CLASSES, 0) for name in CLASSES}
    unlabelled = dict.fromkeys(CLASSES, 0)
    static = 0
    for label, call in zip(cycle_labels, calls, strict=True):
        name = class_of_label(int(label))
        if name is None:
            unlabelled[call] += 1
        else:
            called[name][call] += 1
        static += int(label) in STATIC_LABELS
    ids = np.asarray(labels, dtype=int)
    seconds = {name: float((ids == i).sum() * label_dt_s) for i, name in WALKING_LABELS.items()}
    seconds["not_walking"] = float(np.isin(ids, NOT_WALKING_LABELS).sum() * label_dt_s)
    seconds["static"] = float(np.isin(ids, STATIC_LABELS).sum() * label_dt_s)
    return {"called": called, "unlabelled": unlabelled, "static_cycles": static, "labelled_s": seconds}


def activity_scores(counts: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Pooled over recordings (``activity_counts`` each): per class the fraction of its cycles called right, the
    confusion (label -> fraction called each class), the cycles, cycles per labelled second, cycles per minute static,
    the fraction of walking cycles called any walking class, and the calls of unlabelled cycles."""
    walking = list(WALKING_LABELS.values())
    called = {name: {other: sum(c["called"][name][other] for c in counts) for other in CLASSES} for name in CLASSES}
    seconds = {name: sum(c["labelled_s"][name] for c in counts) for name in [*CLASSES, "static"]}
    total = {name: sum(row.values()) for name, row in called.items()}
    static = sum(c["static_cycles"] for c in counts)
    walked = sum(total[name] for name in walking)
    return {
        "correct": {name: called[name][name] / total[name] if total[name] else None for name in CLASSES},
        "walking_called_walking": sum(called[name][other] for name in walking for other in walking) / walked if walked else None,
        "confusion": {name: {other: n / total[name] if total[name] else None for other, n in row.items()} for name, row in called.items()},
        "cycles": total,
        "cycles_per_s": {name: total[name] / seconds[name] if seconds[name] else None for name in CLASSES},
        "static_cycles_per_min": 60.0 * static / seconds["static"] if seconds["static"] else None,
        "unlabelled_calls": {name: sum(c["unlabelled"][name] for c in counts) for name in CLASSES},
    }


GAIT_MATCH_S = 0.25
"""A detected step matches a reference initial contact within this, seconds."""


@dataclass(frozen=True)
class GaitReference:
    """A reference system's walking bouts, as a session's ``[truth_extra]`` carries them (``import mobgap``)."""

    bouts_s: np.ndarray
    """(start, end) per bout, s."""
    stride_length_m: np.ndarray
    """Each bout's mean stride length, m."""
    walking_speed_m_s: np.ndarray
    """Each bout's mean walking speed, m/s."""
    contacts_s: np.ndarray
    """Every reference initial contact, s."""

    @classmethod
    def from_truth_extra(cls, extra: dict[str, Any]) -> GaitReference | None:
        """The reference in ``[truth_extra]`` (``bouts_s``, ``bout_stride_length_m``, ``bout_walking_speed_m_s``,
        ``initial_contacts_s``), None without bouts."""
        if "bouts_s" not in extra:
            return None
        return cls(np.array(extra["bouts_s"], dtype=float).reshape(-1, 2), np.array(extra.get("bout_stride_length_m", []), dtype=float),
                   np.array(extra.get("bout_walking_speed_m_s", []), dtype=float), np.array(extra.get("initial_contacts_s", []), dtype=float))


def gait_counts(steps_s: np.ndarray, stride_t_s: np.ndarray, stride_length_m: np.ndarray, walking_speed_m_s: np.ndarray,
                reference: GaitReference) -> dict[str, Any]:
    """One recording's step matches and per-bout errors against a reference system's bouts: the steps inside each bout's
    span (widened by ``GAIT_MATCH_S``) matched one-to-one to its contacts within ``GAIT_MATCH_S`` (least total time
    difference); stride length and speed: the mean of the strides inside the bout against the bout's mean
    (``stride_length_bouts`` / ``walking_speed_bouts``: the index of the bout each error belongs to; ``stride_length_m`` /
    ``walking_speed_m_s``: the method's mean in those bouts; strides without a finite value are left out of it;
    ``bout_steps``: (matched, extra, missed) steps per bout, in the reference's order)."""
    from scipy.optimize import linear_sum_assignment

    bouts_s, contacts_s = reference.bouts_s, reference.contacts_s
    bout_length_m, bout_speed_m_s = reference.stride_length_m, reference.walking_speed_m_s
    tp = fp = fn = 0
    length_errors: list[float] = []
    speed_errors: list[float] = []
    length_bouts: list[int] = []
    speed_bouts: list[int] = []
    length_values: list[float] = []
    speed_values: list[float] = []
    bout_steps: list[tuple[int, int, int]] = []
    for n, (start, end) in enumerate(bouts_s):
        truth = contacts_s[(contacts_s >= start - 1e-6) & (contacts_s <= end + 1e-6)]
        found = steps_s[(steps_s >= start - GAIT_MATCH_S) & (steps_s <= end + GAIT_MATCH_S)]
        matched = 0
        if len(truth) and len(found):
            cost = np.abs(found[:, None] - truth[None, :])
            rows, cols = linear_sum_assignment(np.where(cost <= GAIT_MATCH_S, cost, 1e6))
            matched = int(np.sum(cost[rows, cols] <= GAIT_MATCH_S))
        bout_steps.append((matched, len(found) - matched, len(truth) - matched))
        tp, fp, fn = tp + matched, fp + len(found) - matched, fn + len(truth) - matched
        # a stride without a value (a peer's NaN) is not one of the bout's values: it neither counts nor poisons the mean
        inside = (stride_t_s >= start) & (stride_t_s <= end)
        for method, bout_mean, values, errors, bouts in ((stride_length_m, bout_length_m, length_values, length_errors, length_bouts),
                                                         (walking_speed_m_s, bout_speed_m_s, speed_values, speed_errors, speed_bouts)):
            has = inside & np.isfinite(method)
            if has.any() and n < len(bout_mean) and np.isfinite(bout_mean[n]):
                values.append(float(np.mean(method[has])))
                errors.append(abs(values[-1] - float(bout_mean[n])))
                bouts.append(n)
    return {"tp": tp, "fp": fp, "fn": fn, "stride_length_errors_m": length_errors, "walking_speed_errors_m_s": speed_errors,
            "stride_length_bouts": length_bouts, "walking_speed_bouts": speed_bouts, "stride_length_m": length_values,
            "walking_speed_m_s": speed_values, "bouts": len(bouts_s), "bout_steps": bout_steps}


def gait_scores(counts: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Pooled over recordings (``gait_counts`` each): step F1, precision, recall, stride-length and walking-speed MAE over
    the bouts that got a value, and how many bouts those were."""
    tp, fp, fn = (sum(r[k] for r in counts) for k in ("tp", "fp", "fn"))
    lengths = [e for r in counts for e in r["stride_length_errors_m"]]
    speeds = [e for r in counts for e in r["walking_speed_errors_m_s"]]
    return {"step_f1": 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else None,
            "step_precision": tp / (tp + fp) if tp + fp else None, "step_recall": tp / (tp + fn) if tp + fn else None,
            "stride_length_mae_m": float(np.mean(lengths)) if lengths else None, "walking_speed_mae_m_s": float(np.mean(speeds)) if speeds else None,
            "bouts_scored": len(lengths), "bouts": sum(r["bouts"] for r in counts)}


def gaze_rms_mm(estimate: FloatArray, session: GazeSession, skip_s: float = 1.0) -> dict[str, float]:
    """RMS of the gaze point error on the wall, X and Z, millimetres (after the first ``skip_s``)."""
    keep = (session.tracker_t >= skip_s) & np.all(np.isfinite(estimate), axis=1) & np.all(np.isfinite(session.truth_gaze_xz_m), axis=1)
    err = (estimate[keep] - session.truth_gaze_xz_m[keep]) * 1000.0
    return {"x_mm": float(np.sqrt(np.mean(err[:, 0] ** 2))), "z_mm": float(np.sqrt(np.mean(err[:, 1] ** 2)))}


def gaze_ray_errors(world_R_head: FloatArray | None, session: GazeSession, true_world_ray: FloatArray,
                    fixations: Sequence[np.ndarray]) -> dict[str, Any]:
    """The angle between a method's world gaze ray (its head attitude at each gaze sample turning the tracker's ray) and
    the true one, over ``fixations`` (each the rows of its gaze samples: ``frontends.gaze_timing.device_fixations`` of the
    labels): ``gaze_error_deg`` (RMS over those samples), ``gaze_error_fixation_median_deg`` (median over the fixations
    of each one's RMS), the fixations and samples scored. A sample without an attitude scores as failing (180 deg): a
    method must not escape its hard samples. ``world_R_head`` None (no attitude at all): the head frame taken as the world."""
    from .geometry import rotate_by_quat

    rays = session.config.camera.ray(session.gaze_px)
    world = rays if world_R_head is None else rotate_by_quat(np.asarray(world_R_head, dtype=float), rays)
    angle = np.degrees(np.arccos(np.clip(np.sum(world * true_world_ray, axis=1), -1.0, 1.0)))
    angle = np.where(np.isfinite(angle), angle, 180.0)
    per = [float(np.sqrt(np.mean(angle[rows] ** 2))) for rows in fixations]
    scored = np.concatenate(list(fixations)) if len(fixations) else np.zeros(0, dtype=int)
    return {"gaze_error_deg": float(np.sqrt(np.mean(angle[scored] ** 2))) if len(scored) else float("nan"),
            "gaze_error_fixation_median_deg": float(np.median(per)) if per else float("nan"), "fixations": len(per),
            "fixation_samples": int(len(scored))}


def track_errors(t: FloatArray, xyz: FloatArray, truth_t: FloatArray, truth_xyz_m: FloatArray) -> dict[str, float]:
    """A trajectory's 3D position RMSE over its states (the truth interpolated to their times) and its error at the end
    (its last state against the truth's last sample), metres."""
    truth = np.stack([np.interp(t, truth_t, truth_xyz_m[:, j]) for j in range(3)], axis=1)
    err = np.linalg.norm(xyz - truth, axis=1)
    return {"rmse_m": float(np.sqrt(np.mean(err**2))), "final_error_m": float(np.linalg.norm(xyz[-1] - truth_xyz_m[-1]))}
