"""BROAD: every trial imported as an attitude9 session (in memory, exactly as ``fusegraph import broad`` writes it) and
reported by ``report_sessions``: every attitude9 solver and the peers, scored by the preset's scorer (the benchmark's
own metric), then laid out per trial with the means."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..systems.attitude9 import METHODS
from ..systems.presets import PRESETS
from .runner import report_sessions


def bench_broad(
    directory: str | Path | None = None,
    methods: Sequence[str] = (),
    trials: Sequence[str] = (),
    show_progress: bool = True,
) -> dict[str, Any]:
    """Every BROAD trial in ``directory``, every method, in one run: RMSE (deg) and speed per trial and mean.

    ``trials`` keeps the files whose name starts with one of these prefixes (e.g. ``"01"``); all by default.
    ``methods``: attitude9 solvers (default: all of them, the peers first). One parameter set serves every trial; the truth only scores.
    JSON: ``trials.<trial>.<method>`` and ``mean.<method>`` with ``total``, ``heading``, ``inclination`` (deg) and
    ``x_realtime`` (the mean of the trials' ratios), ``ratios`` (``peer_ratios``: ours against each peer, with the worst
    trial), plus the report it was laid out from (``methods``, ``sessions``:
    what ``report attitude9 DIR --json`` prints for the imported trials).
    """
    from ..datasets.broad import DEFAULT_DIR
    from ..datasets.importers import broad_sessions

    names = list(methods) or list(METHODS)
    unknown = [m for m in names if m not in PRESETS["attitude9"].solvers]
    if unknown:
        raise ValueError(f"unknown method(s) {', '.join(unknown)} (have: {', '.join(PRESETS['attitude9'].solvers)})")
    sessions = broad_sessions(Path(directory or DEFAULT_DIR), trials)
    report = report_sessions("attitude9", sessions, names, show_progress=show_progress)
    out: dict[str, Any] = {"trials": {}, "mean": {}}
    for trial, per_method in report["sessions"].items():
        for method in names:
            row = per_method[method]
            if row["status"] != "ok":
                raise RuntimeError(f"{trial}: {method} failed: {row['error']}")
            metrics = row["metrics"]
            out["trials"].setdefault(trial, {})[method] = {"total": metrics["total_deg"], "heading": metrics["heading_deg"],
                                                           "inclination": metrics["inclination_deg"], "x_realtime": row["x_realtime"]}
    for method in names:
        rows = [trial[method] for trial in out["trials"].values()]
        out["mean"][method] = {key: float(np.mean([r[key] for r in rows])) for key in ("total", "heading", "inclination", "x_realtime")}
    out["ratios"] = peer_ratios(out)
    out.update(methods=report["methods"], sessions=report["sessions"])
    out["published"] = published_baselines(Path(directory or DEFAULT_DIR))
    out["settings"] = tuning_provenance()
    out["figures_are"] = figures_are(list(out["trials"]))
    out["nested"] = nested_figures(list(out["trials"]))
    return out


def nested_figures(trials: Sequence[str]) -> dict[str, dict[str, Any]]:
    """Per solver, the end-to-end nested leave-one-trial-out figure ``tune broad_nested --write`` filed (every study re-chosen
    without the held-out trial), where it was measured on these trials: its ``cross_validated`` and ``in_sample`` mean totals
    (deg), ``in_sample_on_main`` (the settings on main on the same trials) and ``current``: whether the settings on main are
    still those it was measured against (a stale figure is reported as stale, not dropped)."""
    from ..tuned import CHECK_STUDIES, tuned, tuned_studies
    from .nested import settings_key
    from .tuning import tuned_compare

    out = {}
    for study in CHECK_STUDIES["attitude9"]:
        solver = "batch" if study.endswith("_batch") else "online"
        if study not in tuned_studies():
            continue
        table = tuned(study)
        if sorted(table.get("trials", [])) != sorted(trials):
            continue
        out[solver] = {key: value for key, value in table.items() if key not in ("trials", "settings_on_main")}
        out[solver]["current"] = table.get("settings_on_main") == settings_key(tuned_compare(solver))
    return out


def figures_are(trials: Sequence[str]) -> str:
    """What a table of these trials' figures is: in-sample where the settings on main were chosen on some of them (every
    BROAD study's trials in ``tuned.toml``), held out where on none."""
    from ..tuned import SYSTEM_STUDIES, tuned

    chosen_on: set[str] = set()
    for study in SYSTEM_STUDIES["attitude9"]:
        listed = tuned(study).get("trials", [])
        chosen_on |= set(listed) if isinstance(listed, list) else set()
    inside = [t for t in trials if t in chosen_on]
    if not inside:
        return f"held out: no setting on main was chosen on any of these {len(trials)} trials"
    return (f"in-sample: the settings on main were chosen on {len(inside)} of these {len(trials)} trials (tuned.toml); "
            "the settings table's leave-one-trial-out figures are cross-validated within each study only, the lines 'every study "
            "re-chosen' end to end")


PEERS = (("online", "vqf"), ("batch", "vqf_offline"), ("online", "imufusion"))
"""Each of our estimates beside the peer a user would pick for the same information (causal, or the whole recording)."""


def peer_ratios(bench: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """``ours/peer`` for every pair of ``PEERS`` the bench ran: the means' ratios (total, inclination, speed) and the trial
    where ours does worst against the peer (``worst_trial``, its total's ratio ``worst_trial_ratio``)."""
    mean, trials = bench["mean"], bench["trials"]
    out = {}
    for ours, peer in PEERS:
        if ours in mean and peer in mean:
            per_trial = {stem: row[ours]["total"] / row[peer]["total"] for stem, row in trials.items()}
            worst = max(per_trial, key=lambda stem: per_trial[stem])
            out[f"{ours}/{peer}"] = {"total": mean[ours]["total"] / mean[peer]["total"],
                                     "inclination": mean[ours]["inclination"] / mean[peer]["inclination"],
                                     "speed": mean[ours]["x_realtime"] / mean[peer]["x_realtime"],
                                     "worst_trial": worst, "worst_trial_ratio": per_trial[worst]}
    return out


def tuning_provenance() -> dict[str, dict[str, Any]]:
    """How the settings on main were chosen (``tuned.toml``): per BROAD study, the trials, the in-sample and the
    leave-one-trial-out (cross-validated) mean total RMSE, deg (``in_sample``, ``cross_validated``); a study chosen by
    another score (``tuning.BROAD_OBJECTIVES``) gives that score as ``score_in_sample`` / ``score_cross_validated`` with its
    ``unit``. On a folder of other trials the bench runs these settings unchanged: its figures are out of sample."""
    from ..tuned import SYSTEM_STUDIES, tuned

    out = {}
    for study in SYSTEM_STUDIES["attitude9"]:
        table = tuned(study)
        trials = table.get("trials", [])
        row = {"in_sample": table.get("in_sample"), "cross_validated": table.get("cross_validated"),
               "trials": len(trials) if isinstance(trials, list) else trials}
        if "total_in_sample" in table:  # chosen by another score: the total is filed beside it
            row.update(score_in_sample=row["in_sample"], score_cross_validated=row["cross_validated"], unit=table.get("unit"),
                       in_sample=table["total_in_sample"], cross_validated=table.get("total_cross_validated"))
        out[study] = row
    return out


def published_baselines(directory: Path) -> dict[str, dict[str, float]]:
    """The BROAD authors' published Madgwick and Mahony RMSE (all 39 trials of the benchmark, their tuned parameter), from
    ``baseline_<name>_rmse.json`` in the trials' folder when it is there (deg: total, heading, inclination)."""
    import json

    out = {}
    for name in ("madgwick", "mahony"):
        path = directory / f"baseline_{name}_rmse.json"
        if path.is_file():
            figures = json.loads(path.read_text())["groups"]["all_trials"]["tagp_parameters"]
            out[name] = {key.removesuffix("_rmse_deg"): float(value) for key, value in figures.items()}
    return out
