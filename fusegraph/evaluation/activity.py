"""``fusegraph bench activity``: each cycle the waist front end detects, scored against the hand label of the segment it
falls in (UCI HAPT: walking, up, down; every other label, standing, sitting, lying and the postural transitions between
them, is "not walking"; cycles where no label is are counted apart), for fusegraph's classifier (``frontends.activity``) and the walking paper's rules
(``frontends.pdr.detect_cycles``' own activity); and ``fusegraph tune activity``, which fits the classifier on main.

The cycles are the walking preset's own (``pdr.gravity_filter`` + ``pdr.detect_cycles`` with ``systems.walking.WAIST``) on
each imported session (``import hapt``). On the folder whose subjects fitted the model on main the ``fusegraph`` figures are
leave-one-subject-out (nested: the held-out subject's model and its settings are chosen without it), the model on main's
in-sample figures beside; on any other folder the model on main scores as it is (``cross_validated: false``).

Settings the fit chooses (the rest are scikit-learn's usual boosting values, stated in ``FIXED``): the features from
``FEATURE_SETS``, the number of boosting stages and the context (cycles either side) from ``STAGES`` x ``CONTEXTS``, by
grouped 3-fold cross-validation over the training subjects, scored by the mean of the three classes' fractions correct;
with simulated walks (``simulated_cycles``: the pendulum gait's tuning seeds 100-119, never the scored seeds 0-9) by the
lower of that and the same mean on the walks, as each fold's model calls them. The walks are there because HAPT's users
each walk at one pace: a model can learn "amplitude above the person's median = stairs down" there, which a walker who
speeds up meets on level ground (the pelvis's vertical acceleration grows about as speed squared), and only walks with
changing pace can tell the feature sets apart on that.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from itertools import repeat
from pathlib import Path
from typing import Any

import numpy as np

from ..frontends.activity import (
    ACTIVITIES,
    BASE_FEATURES,
    FEATURES,
    GATE_CLASSES,
    ActivityModel,
    Tree,
    cycle_features,
    feature_columns,
    in_context,
    load_model,
    with_reference,
)
from ..frontends.pdr import Cycle
from ..metrics import WALKING_LABELS, activity_counts, activity_scores, class_of_label
from ..session import Session, SessionError

STAGES = (100, 200, 300)
"""Boosting stages the fit chooses from."""

CONTEXTS = (0, 2, 4, 6, 8)
"""Cycles either side (within a bout) the fit chooses from."""

NOT_WALKING_CONTEXTS = (0, 1, 2, 4, 8)
"""Cycles either side that decide walking or not (``frontends.activity.decide``) the fit chooses from."""

FIXED = {"max_depth": 3, "learning_rate": 0.1, "subsample": 0.8, "random_state": 0}
"""Boosting settings not searched (scikit-learn's default depth and rate; subsampling as its documentation's examples)."""

WORST_LEAST_CYCLES = 20
"""``bench activity`` names the worst user and recording per class among those with at least this many of its cycles
(a recording with five cycles of a class says little about it)."""

INNER_FOLDS = 3
"""Folds over the training subjects that choose the stages and the context."""

PACE_AMPLITUDES = ("vertical_rms", "forward_rms", "lateral_rms", "vertical_pp", "forward_pp", "vertical_max", "vertical_min",
                   "vertical_above_3hz_rms")
"""Acceleration amplitudes: they grow with the walking pace (about as speed squared vertically)."""
PACE_RATES = ("roll_rate_rms", "pitch_rate_rms", "yaw_rate_rms")
"""Rotation rates: the pelvis's rotation amplitudes times the cadence, both growing with the pace."""


def _without(names: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(f for f in FEATURES if f not in names)


FEATURE_SETS: dict[str, tuple[str, ...]] = {
    "all": FEATURES,
    "amplitudes_absolute_only": _without(tuple(f"{a}_vs_median" for a in PACE_AMPLITUDES)),
    "amplitudes_and_rates_absolute_only": _without(tuple(f"{a}_vs_median" for a in PACE_AMPLITUDES + PACE_RATES)),
    "no_amplitudes": _without(PACE_AMPLITUDES + tuple(f"{a}_vs_median" for a in PACE_AMPLITUDES)),
}
"""Feature sets the fit chooses from: all, or without the pace-dependent ones relative to the person's median (a pace
change then cannot pass for a change of activity), or without acceleration amplitudes at all."""

SIMULATED_SEEDS = tuple(range(100, 120))
"""The pendulum gait's tuning seeds whose walks the fit reads (``simulated_cycles``); the benches score seeds 0-9."""


@dataclass(frozen=True)
class SimulatedCycles:
    """A simulated walk's detected cycles with the true activity of each (the walking preset's front end)."""

    cycle_t: np.ndarray
    """Time of each detected cycle, s."""
    base: np.ndarray
    """``frontends.activity.BASE_FEATURES`` per cycle."""
    label: np.ndarray
    """The label id of the true step within a quarter second of each cycle (``metrics.WALKING_LABELS``; 0: none)."""


def simulated_cycles(seeds: Sequence[int] = SIMULATED_SEEDS) -> list[SimulatedCycles]:
    """The pendulum gait's walks (``scenarios.walking``, ``gait="pendulum"``) of ``seeds`` through the walking preset's
    front end: each cycle's features and true activity."""
    from ..frontends.pdr import front_end
    from ..scenarios.walking import WalkingScenarioConfig, simulate_walking
    from ..systems.walking import WAIST

    ids = {name: i for i, name in WALKING_LABELS.items()}
    out = []
    for seed in seeds:
        walk = simulate_walking(seed, WalkingScenarioConfig(gait="pendulum"))
        gravity, cycles = front_end(walk.t, walk.accel_m_s2, walk.gyro_rad_s, WAIST)
        cycle_t = np.array([c.t for c in cycles])
        label = np.array([ids.get(walk.activity_at(t) or "", 0) for t in cycle_t], dtype=int)
        out.append(SimulatedCycles(cycle_t, cycle_features(walk.t, walk.accel_m_s2, walk.gyro_rad_s, gravity, cycles), label))
    return out


@dataclass(frozen=True)
class Recording:
    """One session's detected cycles, their features and labels."""

    name: str
    """Session name."""
    subject: str
    """Whose recording (``[session] subject``; the session name without one)."""
    cycle_t: np.ndarray
    """Time of each detected cycle, s."""
    base: np.ndarray
    """``frontends.activity.BASE_FEATURES`` per cycle."""
    label: np.ndarray
    """The label id of the segment each cycle falls in (0: none)."""
    paper: tuple[str, ...]
    """The paper's rules' activity per cycle."""
    labels: np.ndarray
    """The label id of every sample of the ``activity`` stream (what the labelled seconds are counted from)."""
    label_dt_s: float
    """The ``activity`` stream's sample period, s."""
    on_main: tuple[str, ...] = ()
    """The model on main's call per cycle (``run --solver activity``)."""


def recording(name: str, session: Session) -> Recording:
    """One session with an ``activity`` label stream through ``run --solver activity`` (``runner.solve_session``): its
    cycles, their features, the model on main's and the rules' calls, and the labels."""
    from ..estimate import PointEstimate
    from ..metrics import nearest_samples
    from .runner import solve_session

    if "activity" not in session.streams:
        raise SessionError(f"{session.where}: no 'activity' stream (bench activity needs the activity labels: fusegraph import hapt DIR)")
    estimate = solve_session(session, "activity").estimate
    assert isinstance(estimate, PointEstimate)
    labels = session.stream("activity")
    cycle_t = estimate.t
    label = labels.values[nearest_samples(labels.t, cycle_t), 0].astype(int) if len(cycle_t) else np.zeros(0, dtype=int)
    subject = str(session.meta.get("session", {}).get("subject", name))
    return Recording(name, subject, cycle_t, estimate.extras["features"], label, tuple(estimate.extras["rules_activity"]),
                     labels.values[:, 0].astype(int), float(np.median(np.diff(labels.t))), tuple(estimate.extras["activity"]))


# ------------------------------------------------------------------------------------ fitting


def _export(model: Any, context: int, provenance: dict[str, Any], features: tuple[str, ...], classes: tuple[str, ...]) -> ActivityModel:
    """A fitted ``GradientBoostingClassifier`` (on the columns ``features`` of ``FEATURES``) as plain trees (its start score
    read back from its own decision function; a two-class one has one tree per stage, its score the log-odds of the
    second class)."""
    trees = tuple(tuple(Tree(e.tree_.children_left.copy(), e.tree_.children_right.copy(), e.tree_.feature.copy(), e.tree_.threshold.copy(),
                             e.tree_.value[:, 0, 0].copy()) for e in stage) for stage in model.estimators_)
    probe = np.zeros((1, len(features)))
    raw = np.atleast_1d(model.decision_function(probe)[0])
    from_trees = np.array([sum(model.learning_rate * stage[k].predict(probe)[0] for stage in trees) for k in range(len(trees[0]))])
    return ActivityModel(classes, features, raw - from_trees, float(model.learning_rate), trees, context, provenance)


def _fit(x: np.ndarray, y: np.ndarray, stages: int, balanced: bool = False) -> Any:
    """Boosted trees; ``balanced``: every class weighing alike (scikit-learn's "balanced" sample weights, n / (classes x
    n_class)), as the gate's settings are chosen by the mean of its two classes' fractions correct and not walking has
    ~200 cycles against ~3,900 walking on HAPT's users 1-10."""
    from sklearn.ensemble import GradientBoostingClassifier
    from sklearn.utils.class_weight import compute_sample_weight

    weights = compute_sample_weight("balanced", y) if balanced else None
    return GradientBoostingClassifier(n_estimators=stages, **FIXED).fit(x, y, sample_weight=weights)  # type: ignore[arg-type]


NOT_WALKING_ID = 1 + ACTIVITIES.index("not_walking")
"""The class id of not walking (``class_ids``)."""


def _design(recordings: Sequence[Recording]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Features (with each recording's own reference), class ids (``class_ids``; 0: unlabelled), recording index and time
    of EVERY cycle. A model is fitted and scored on some of them (``_walking``: the labelled walking cycles; ``y > 0``:
    every labelled one); the others stay in as context: ``ActivityModel.classify`` averages over every cycle of a bout,
    labelled or not, so a choice of context is scored the same way."""
    rows, labels, which, times = [], [], [], []
    for n, rec in enumerate(recordings):
        y = class_ids(rec.label)
        rows.append(with_reference(rec.base))
        labels.append(y)
        which.append(np.full(len(y), n))
        times.append(rec.cycle_t)
    return np.vstack(rows), np.concatenate(labels), np.concatenate(which), np.concatenate(times)


def _walking(y: np.ndarray) -> np.ndarray:
    """The labelled walking cycles among class ids ``y``: what the walking classes' model is fitted and scored on."""
    return (y > 0) & (y != NOT_WALKING_ID)


def class_ids(label: np.ndarray) -> np.ndarray:
    """Each cycle's class as the model's id (1 + its index in ``ACTIVITIES``; 0: unlabelled) from HAPT's label ids."""
    names = [class_of_label(int(v)) for v in label]
    return np.array([0 if name is None else 1 + ACTIVITIES.index(name) for name in names], dtype=int)


def _balanced_correct(predicted: np.ndarray, label: np.ndarray) -> float:
    return float(np.mean([np.mean(predicted[label == i] == i) for i in np.unique(label)]))


def _calls(model: Any, log_p: np.ndarray, times: np.ndarray, groups: np.ndarray, context: int) -> np.ndarray:
    """The class ids of cycles whose log-probabilities are ``log_p``, each recording (``groups``) in its own context."""
    predicted = np.empty(len(log_p), dtype=int)
    for group in np.unique(groups):
        rows = groups == group
        predicted[rows] = model.classes_[in_context(log_p[rows], times[rows], context).argmax(axis=1)]
    return predicted


def _simulated_design(simulated: Sequence[SimulatedCycles]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The walks' cycles (features, class ids, cycle times, walk index: each walk its own group) and which are labelled
    (scored; the rest are context, as in ``_design``)."""
    return (np.vstack([with_reference(w.base) for w in simulated]), np.concatenate([w.label for w in simulated]),
            np.concatenate([w.cycle_t for w in simulated]), np.concatenate([np.full(len(w.label), n) for n, w in enumerate(simulated)]),
            np.concatenate([w.label > 0 for w in simulated]))


def _grid_scores(x: np.ndarray, y: np.ndarray, which: np.ndarray, times: np.ndarray, kept: np.ndarray, subjects: np.ndarray,
                 feature_sets: Sequence[str], contexts: Sequence[int], simulated: Sequence[SimulatedCycles], balanced: bool,
                 sim_target: Callable[[np.ndarray], np.ndarray]) -> dict[tuple[str, int, int], float]:
    """Every (feature set, stages, context)'s grouped ``INNER_FOLDS``-fold score over the subjects: fitted on the training
    subjects' ``kept`` cycles, the held-out subjects' every cycle called (each recording's log-probabilities smoothed
    within its bouts, as ``ActivityModel.classify`` does) and the mean of the classes' fractions correct taken over their
    ``kept`` cycles; with ``simulated`` walks the lower of that and the same mean on the walks' labelled cycles (their ids
    mapped by ``sim_target``), as each fold's model calls them."""
    from sklearn.model_selection import GroupKFold

    folds = min(INNER_FOLDS, len(set(subjects)))
    if simulated:
        sim_x, sim_label, sim_t, sim_walk, sim_kept = _simulated_design(simulated)
        sim_label = sim_target(sim_label)
    points = [(f, s, c) for f in feature_sets for s in STAGES for c in contexts]
    scores: dict[tuple[str, int, int], list[float]] = {p: [] for p in points}
    on_walks: dict[tuple[str, int, int], list[float]] = {p: [] for p in points}
    for name in feature_sets:
        cols = feature_columns(FEATURE_SETS[name])
        for train, test in GroupKFold(n_splits=folds).split(x, y, subjects):
            train = train[kept[train]]
            model = _fit(x[train][:, cols], y[train], max(STAGES), balanced)
            scored = kept[test]
            on_test = model.staged_predict_proba(x[test][:, cols])
            on_sim = model.staged_predict_proba(sim_x[:, cols]) if simulated else repeat(None)
            for stage_n, (proba, sim_proba) in enumerate(zip(on_test, on_sim, strict=False), start=1):
                if stage_n not in STAGES:
                    continue
                log_p = np.log(np.maximum(proba, 1e-12))
                sim_log_p = np.log(np.maximum(sim_proba, 1e-12)) if sim_proba is not None else None
                for context in contexts:
                    calls = _calls(model, log_p, times[test], which[test], context)
                    scores[(name, stage_n, context)].append(_balanced_correct(calls[scored], y[test][scored]))
                    if sim_log_p is not None:
                        sim_calls = _calls(model, sim_log_p, sim_t, sim_walk, context)
                        on_walks[(name, stage_n, context)].append(_balanced_correct(sim_calls[sim_kept], sim_label[sim_kept]))
    return {p: min(float(np.mean(scores[p])), float(np.mean(on_walks[p]))) if simulated else float(np.mean(scores[p])) for p in points}


def _best(values: dict[tuple[str, int, int], float], feature_sets: Sequence[str]) -> tuple[str, int, int]:
    """The best point; ties: the earlier feature set, the smaller model, the shorter context."""
    return max(values, key=lambda p: (values[p], -list(feature_sets).index(p[0]), -p[1], -p[2]))


def choose_settings(recordings: Sequence[Recording], simulated: Sequence[SimulatedCycles] = (),
                    feature_sets: Sequence[str] = tuple(FEATURE_SETS)) -> tuple[str, int, int, dict[str, float]]:
    """The walking classes' model: features, stages and context by grouped ``INNER_FOLDS``-fold cross-validation over the
    recordings' subjects on their walking cycles (``_grid_scores``). Returns (feature set, stages, context, every point's
    score)."""
    x, y, which, times = _design(recordings)
    subjects = np.array([recordings[i].subject for i in which])
    values = _grid_scores(x, y, which, times, _walking(y), subjects, feature_sets, CONTEXTS, simulated, False, lambda label: label)
    best = _best(values, feature_sets)
    return best[0], best[1], best[2], {f"features={f} stages={s} context={c}": v for (f, s, c), v in values.items()}


def choose_gate(recordings: Sequence[Recording], features: str, simulated: Sequence[SimulatedCycles] = ()) -> tuple[int, int, dict[str, float]]:
    """The walking-or-not gate on every labelled cycle (walking 0, not walking 1; balanced weights): its stages and context
    by the same rule on the walking model's features (a simulated walk's every cycle is walking). Returns (stages,
    context, every point's score)."""
    x, y, which, times = _design(recordings)
    subjects = np.array([recordings[i].subject for i in which])
    gate = (y == NOT_WALKING_ID).astype(int)
    values = _grid_scores(x, gate, which, times, y > 0, subjects, [features], NOT_WALKING_CONTEXTS, simulated, True,
                          lambda label: np.zeros_like(label))
    best = _best(values, [features])
    return best[1], best[2], {f"gate stages={s} context={c}": v for (_, s, c), v in values.items()}


def fit_model(recordings: Sequence[Recording], dataset: str = "", simulated: Sequence[SimulatedCycles] = (),
              feature_sets: Sequence[str] = tuple(FEATURE_SETS)) -> ActivityModel:
    """The classifier on these recordings: the walking classes' model (``choose_settings``) and the walking-or-not gate
    on its features (``choose_gate``)."""
    features, stages, context, grid = choose_settings(recordings, simulated, feature_sets)
    x, y, _, _ = _design(recordings)
    labelled, walking = y > 0, _walking(y)
    gate_y = (y[labelled] == NOT_WALKING_ID).astype(int)
    # recordings without a not-walking cycle (no such label) make no gate: every cycle is then a walking class
    gate_stages, gate_context, gate_grid = choose_gate(recordings, features, simulated) if gate_y.any() else (None, None, {})
    cols = feature_columns(FEATURE_SETS[features])
    walks = f"; the lower of it and the same mean on the simulated walks of seeds {min(SIMULATED_SEEDS)}-{max(SIMULATED_SEEDS)})"
    rule = (f"features x stages x context chosen by grouped {INNER_FOLDS}-fold cross-validation over the subjects (mean of the "
            "classes' fractions correct, every cycle of a held-out recording called in its bout's context as classify does"
            + (walks if simulated else ")") + "; the gate's stages x context by the same rule on its two classes, on the walking model's features")
    provenance = {"dataset": dataset, "subjects": sorted({r.subject for r in recordings}), "recordings": [r.name for r in recordings],
                  "cycles": int(walking.sum()), "feature_set": features, "stages": stages, "context_cycles": context, "gate_stages": gate_stages,
                  "not_walking_context": gate_context, "fixed": FIXED, "rule": rule, "grid_scores": {**grid, **gate_grid}}
    walking_model = _export(_fit(x[walking][:, cols], y[walking], stages), context, provenance, FEATURE_SETS[features], ACTIVITIES[:3])
    if gate_stages is None or gate_context is None:
        return walking_model
    gate = _export(_fit(x[labelled][:, cols], gate_y, gate_stages, balanced=True), gate_context, {}, FEATURE_SETS[features], GATE_CLASSES)
    return replace(walking_model, gate=gate)


# ------------------------------------------------------------------------------------ scoring


def score(recordings: Sequence[Recording], predicted: Sequence[Sequence[str]]) -> dict[str, Any]:
    """``metrics.activity_scores`` pooled over the recordings, each with its calls; with ``by_recording`` and ``by_user``,
    each recording's and each user's fraction correct and cycles per class (how far the pooled figure holds across
    people: a class can be right on most users and wrong on one)."""
    counts = [activity_counts(r.label, calls, r.labels, r.label_dt_s) for r, calls in zip(recordings, predicted, strict=True)]
    out = activity_scores(counts)

    def each(scored: dict[str, Any]) -> dict[str, Any]:
        return {"correct": scored["correct"], "confusion": scored["confusion"], "cycles": scored["cycles"]}

    out["by_recording"] = {r.name: each(activity_scores([c])) for r, c in zip(recordings, counts, strict=True)}
    out["by_user"] = {user: each(activity_scores([c for r, c in zip(recordings, counts, strict=True) if r.subject == user]))
                      for user in sorted({r.subject for r in recordings})}
    return out


def worst(by: dict[str, Any], least_cycles: int = WORST_LEAST_CYCLES) -> dict[str, tuple[str, float, int] | None]:
    """Per class, the recording or user (a ``score`` result's ``by_recording`` or ``by_user``) with the lowest fraction
    correct among those with at least ``least_cycles`` of the class: (name, fraction, cycles); None where none has."""
    out: dict[str, tuple[str, float, int] | None] = {}
    for name in next(iter(by.values()))["correct"] if by else ():
        scored = [(who, v["correct"][name], v["cycles"][name]) for who, v in by.items()
                  if v["correct"][name] is not None and v["cycles"][name] >= least_cycles]
        out[name] = min(scored, key=lambda x: x[1]) if scored else None
    return out


def _worst_line(by: dict[str, Any], what: str, method: str) -> str:
    """``worst`` as the table prints it: each class's worst user or recording and what its cycles were called instead."""

    def called_instead(who: str, label: str) -> str:
        row = by[who].get("confusion", {}).get(label, {})
        wrong = [f"{other} {100 * v:.0f}%" for other, v in row.items() if other != label and v]
        return f"; called {', '.join(wrong)}" if wrong else ""

    found = worst(by)
    return (f"worst {what}, {method} (of those with {WORST_LEAST_CYCLES} cycles of the class or more): "
            + "; ".join(f"{label} {100 * w[1]:.1f}% ({w[0]}, {w[2]} cycles{called_instead(w[0], label)})" if w else f"{label} -"
                        for label, w in found.items()))


def _load(directory: str | Path | None, sessions: Sequence[str | Path]) -> list[tuple[str, Session]]:
    from ..datasets.hapt import DEFAULT_DIR, hapt_sessions
    from .runner import load_sessions

    if sessions:
        return load_sessions(sessions)
    folder = Path(directory or DEFAULT_DIR)
    if list(folder.glob("acc_exp*_user*.txt")):
        return hapt_sessions(folder)
    return load_sessions([folder])


def _held_out_fold(job: tuple[Sequence[Recording], str, Sequence[SimulatedCycles], Sequence[str]]) -> tuple[dict[str, Any], dict[int, list[str]]]:
    """One leave-one-user-out fold (the recordings, the subject held out, the simulated walks, the feature sets chosen from):
    the model fitted (settings chosen) without the subject, its choices and its calls on each of the subject's recordings
    (by index)."""
    recordings, subject, simulated, feature_sets = job
    fitted = fit_model([r for r in recordings if r.subject != subject], simulated=simulated, feature_sets=feature_sets)
    calls = {i: fitted.classify(rec.base, rec.cycle_t) for i, rec in enumerate(recordings) if rec.subject == subject}
    return {"feature_set": fitted.provenance["feature_set"], "stages": fitted.provenance["stages"], "context_cycles": fitted.context_cycles,
            "not_walking_context": fitted.gate.context_cycles if fitted.gate else None}, calls


def leave_one_user_out(recordings: Sequence[Recording], simulated: Sequence[SimulatedCycles] = (), workers: int = 1,
                       progress: Callable[[str], None] | None = None, scheduler: str | None = None,
                       feature_sets: Sequence[str] = tuple(FEATURE_SETS)) -> tuple[list[list[str]], dict[str, dict[str, Any]]]:
    """Each subject's recordings called by a model fitted (its settings chosen, the features among ``feature_sets``) without
    the subject (``_held_out_fold``), the folds side by side in ``workers`` processes: the calls per recording, and each
    subject's fold's choices."""
    from .cluster import completed

    subjects = sorted({r.subject for r in recordings})
    held_out: list[list[str]] = [[] for _ in recordings]
    choices = {}
    jobs = [(recordings, subject, simulated, tuple(feature_sets)) for subject in subjects]
    for n, ((_, subject, _, _), future) in enumerate(completed(_held_out_fold, jobs, workers, scheduler)):
        choices[subject], calls = future.result()
        for i, called in calls.items():
            held_out[i] = called
        if progress is not None:
            progress(f"held out {subject} ({n + 1}/{len(subjects)})")
    return held_out, {subject: choices[subject] for subject in subjects}  # in the users' order, whatever order the folds ended in


def bench_activity(directory: str | Path | None = None, sessions: Sequence[str | Path] = (),
                   progress: Callable[[str], None] | None = None, workers: int = 1, scheduler: str | None = None) -> dict[str, Any]:
    """The JSON of ``fusegraph bench activity`` (see the module docstring): ``directory`` is HAPT's raw folder or a folder
    of imported sessions (``sessions``: session directories instead). The model on main scores through ``run --solver
    activity`` (``runner.solve_session``): its figures are ``report walking DIR --solvers activity``'s counts pooled.
    ``workers``: leave-one-user-out folds fitted side by side in processes (the same figures: the fits are seeded). Each
    method's figures carry ``by_user`` and ``by_recording`` (``score``), and the table names the worst of each per class."""
    model = load_model()
    loaded = _load(directory, sessions)
    recordings = []
    for n, (name, session) in enumerate(loaded):
        recordings.append(recording(name, session))
        if progress is not None:
            progress(f"cycles of {name} ({n + 1}/{len(loaded)})")
    subjects = sorted({r.subject for r in recordings})
    on_main = [list(r.on_main) for r in recordings]
    cross_validated = set(subjects) <= set(model.provenance.get("subjects", ())) and len(subjects) > 1
    result: dict[str, Any] = {"users": subjects, "recordings": [r.name for r in recordings], "cross_validated": cross_validated,
                              "model": {k: model.provenance.get(k) for k in ("dataset", "subjects", "feature_set", "stages", "context_cycles",
                                                                          "not_walking_context", "rule")}}
    if cross_validated:
        if progress is not None:
            progress(f"simulated walks of seeds {min(SIMULATED_SEEDS)}-{max(SIMULATED_SEEDS)} (the fit's pace check)")
        held_out, choices = leave_one_user_out(recordings, simulated_cycles(), workers, progress, scheduler)
        fusegraph = score(recordings, held_out)
        in_sample = score(recordings, on_main)
        fusegraph["correct_in_sample"] = in_sample["correct"]
        fusegraph["walking_called_walking_in_sample"] = in_sample["walking_called_walking"]
        result["chosen_per_user"] = choices
    else:
        fusegraph = score(recordings, on_main)
    result["methods"] = {"fusegraph": fusegraph, "paper_rules": score(recordings, [list(r.paper) for r in recordings])}
    return result


def format_activity(result: dict[str, Any]) -> str:
    """The bench as a table: per method and class the fraction correct and cycles per labelled second, static cycles/min."""
    rule = "leave-one-user-out (nested)" if result["cross_validated"] else "the model on main, unchanged"
    lines = [f"activity per detected cycle against the hand labels: {len(result['recordings'])} recordings, users {', '.join(result['users'])}",
             f"fusegraph: {rule}; paper_rules: the walking paper's rules as detect_cycles applies them",
             f"{'method':<22} {'flat':>7} {'up':>7} {'down':>7} {'not walk':>8}   walking as walking   {'cycles/s flat/up/down/not':>26}   static cycles/min"]

    def pct(v: float | None) -> str:
        return f"{100 * v:6.1f}%" if v is not None else f"{'-':>7}"

    for name, m in result["methods"].items():
        rates = "/".join(f"{v:.2f}" if v is not None else "-" for v in m["cycles_per_s"].values())
        correct = " ".join(pct(v) for v in m["correct"].values())
        lines.append(f"{name:<22} {correct}  {pct(m['walking_called_walking']):>19}   {rates:>26}   {m['static_cycles_per_min']:.2f}")
        if "correct_in_sample" in m:
            lines.append(f"{'  in-sample (on main)':<22} {' '.join(pct(v) for v in m['correct_in_sample'].values())}  "
                         f"{pct(m['walking_called_walking_in_sample']):>19}")
    if "chosen_per_user" in result:
        from collections import Counter

        sets = Counter(c.get("feature_set", "all") for c in result["chosen_per_user"].values())
        lines.append("feature sets the held-out users' folds chose: " + ", ".join(f"{name} ({n})" for name, n in sets.most_common())
                     + f"; on main: {result['model'].get('feature_set') or 'all'}")
    for name, m in result["methods"].items():
        lines += [_worst_line(m[by], what, name) for by, what in (("by_user", "user"), ("by_recording", "recording")) if by in m]
    for name, m in result["methods"].items():
        lines.append(f"confusion, {name} (row: label, columns: called flat / up / down / not walking):")
        for label, row in m["confusion"].items():
            lines.append(f"    {label:<12} " + " ".join(pct(v) for v in row.values()) + f"   ({m['cycles'][label]} cycles)")
        unlabelled = m["unlabelled_calls"]
        lines.append(f"    {'unlabelled':<12} {sum(unlabelled.values())} cycles where HAPT has no label (not scored), called "
                     + ", ".join(f"{k} {v}" for k, v in unlabelled.items()))
    return "\n".join(lines)


STEP_STATISTICS = ("excursion_m", "vertical_rms_m_s2", "vertical_to_horizontal", "duration_s", "vertical_pitch_corr")
"""Per-step signal statistics (``step_statistics``): the pelvis's vertical excursion (the vertical acceleration integrated
twice, ``frontends.gait.pelvis_excursion`` with 0.5 Hz drift removal), the RMS of the vertical acceleration about its
step mean, its ratio to the horizontal one's, the step's duration, and how the sagittal rotation goes with the vertical
acceleration (the classifier's ``corr_vertical_pitch_rate`` of the step's first cycle, over ``WINDOW_S``)."""


def step_statistics(t: np.ndarray, accel_m_s2: np.ndarray, gyro_rad_s: np.ndarray, activity_of: Callable[[float, float], str | None],
                    analysed: tuple[np.ndarray, Sequence[Cycle]] | None = None) -> dict[str, np.ndarray]:
    """Per walking class, the ``STEP_STATISTICS`` of every step between two consecutive cycles of the walking preset's
    front end (at most 1.2 s apart), a row per step (shape (n, len(STEP_STATISTICS))); ``activity_of(start, end)`` names a
    step's class (None: not scored); ``analysed``: the front end's gravity and cycles when the caller has them (the
    gravity filter is a per-sample loop). The same code reads a real recording and a simulated one, so the two are
    compared like for like."""
    from ..frontends.gait import pelvis_excursion
    from ..frontends.pdr import front_end, vertical_horizontal
    from ..systems.walking import WAIST

    fs = 1.0 / float(np.median(np.diff(t)))
    gravity, cycles = analysed or front_end(t, accel_m_s2, gyro_rad_s, WAIST)
    cycle_t = np.array([c.t for c in cycles])
    pitch_corr = cycle_features(t, accel_m_s2, gyro_rad_s, gravity, cycles)[:, BASE_FEATURES.index("corr_vertical_pitch_rate")]
    vertical, horizontal = vertical_horizontal(accel_m_s2, gravity)
    height = pelvis_excursion(vertical, fs, 0.5, None, 2)
    rows: dict[str, list[tuple[float, ...]]] = {a: [] for a in ACTIVITIES}
    for n, (start, end) in enumerate(zip(cycle_t[:-1], cycle_t[1:], strict=True)):
        activity = activity_of(float(start), float(end))
        if end - start > 1.2 or activity not in rows:
            continue
        k = (t >= start) & (t < end)
        v = vertical[k] - vertical[k].mean()
        h = np.linalg.norm(horizontal[k] - horizontal[k].mean(axis=0), axis=1)
        v_rms = float(np.sqrt(np.mean(v**2)))
        rows[activity].append((float(np.ptp(height[k])), v_rms, v_rms / float(np.sqrt(np.mean(h**2))), float(end - start), float(pitch_corr[n])))
    return {a: np.array(r).reshape(-1, len(STEP_STATISTICS)) for a, r in rows.items()}


def labelled_step_statistics(session: Session) -> dict[str, np.ndarray]:
    """``step_statistics`` of a session with an ``activity`` label stream (``import hapt``): a step scores when one
    walking label covers it."""
    accel, gyro = session.synchronous("accel", "gyro")
    labels = session.stream("activity")

    def activity_of(start: float, end: float) -> str | None:
        inside = labels.values[(labels.t >= start) & (labels.t < end), 0]
        if not len(inside) or not np.all(inside == inside[0]):
            return None
        return WALKING_LABELS.get(int(inside[0]))

    return step_statistics(accel.t, accel.values, gyro.values, activity_of)
