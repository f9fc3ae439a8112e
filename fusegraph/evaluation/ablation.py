"""Ablation studies: system x variants (sensor subsets dropped, parameter grids) x seeds x solvers.

A study expands into runs, each keyed by its full configuration; results are appended to
``runs.csv`` as each run finishes, so an interrupted study resumes where it stopped and loses
nothing. Runs execute in a local process pool (default), or on a Dask cluster
(``scheduler="local"`` starts a LocalCluster, ``"tcp://host:port"`` joins an existing one). A
failed run (an exception, or a worker that died) becomes a row with status ``failed`` and its
error; the study goes on.

Head variants: ``drop tracker`` keeps only the tracker's first sample (the gyro alone, aligned
once at start-up); ``drop gyro`` leaves the tracker alone: the EKF row becomes the paper's
tracker-only Kalman filter, and fusegraph runs its graph as a constant-angular-velocity model
(``without_gyro``). ``vary`` names: see ``HEAD_PARAMETERS``.
"""

from __future__ import annotations

import csv
import hashlib
import itertools
import json
import time
import tomllib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..factors.gyro import GyroNoise
from ..graphs.head import HeadModel, head_model_for
from ..progress import progress
from ..results import SummaryRow
from ..session import NotApplicableError, Session
from ..tuned import value as tuned_value

#: ``--vary`` names for the head system -> fields of the head scenario.
HEAD_PARAMETERS: dict[str, str] = {
    "latency": "tracker_latency_s",
    "tracker_rate": "tracker_rate_hz",
    "tracker_drop_fraction": "tracker_drop_fraction",
    "gyro_noise": "gyro_white_sigma_rad_s",
    "gyro_bias_rw": "gyro_bias_rw_sigma",
    "tracker_markov_sigma_deg": "tracker_gm_sigma_deg",
}
SENSORS = {"head": ("tracker", "gyro", "accel")}
"""Head streams with their own drop semantics (see the module docstring); other systems drop any stream by name."""
SOLVERS = ("ekf", "online", "batch")
METRIC_COLUMNS = ("rms_azimuth_rad", "rms_elevation_rad", "rms_roll_rad", "nees")
COLUMNS = ("key", "system", "variant", "drop", "params", "seed", "session", "solver", "profile", "duration_s", "status", "error",
           *METRIC_COLUMNS, "solver_s", "run_s", "metrics")


def _baseline_solver(system: str) -> str:
    """The paper's baseline of a system as a solver name."""
    from ..systems.presets import PRESETS

    solvers = PRESETS[system].solvers
    return "ekf" if "ekf" in solvers else next(s for s in solvers if s not in ("online", "batch"))


@dataclass(frozen=True)
class Variant:
    """One sensor subset and one point of the parameter grid."""

    drop: tuple[str, ...] = ()
    """Sensors removed (empty: the full-sensor baseline)."""
    params: tuple[tuple[str, float], ...] = ()
    """Parameter values, (name, value) pairs in a fixed order."""

    @property
    def name(self) -> str:
        parts = ["full" if not self.drop else "-" + "-".join(self.drop)]
        parts += [f"{k}={v:g}" for k, v in self.params]
        return " ".join(parts)


@dataclass(frozen=True)
class Study:
    """What to run; ``runs()`` expands it."""

    system: str = "head"
    """Which system (scenario) to study."""
    drops: tuple[tuple[str, ...], ...] = ()
    """Each entry is a variant dropping those sensors; the full-sensor baseline is always included."""
    vary: tuple[tuple[str, tuple[float, ...]], ...] = ()
    """Parameter grids, crossed with each other and with every sensor variant."""
    seeds: tuple[int, ...] = (0,)
    """Seeds of the simulated sessions (unused when ``sessions`` are given)."""
    sessions: tuple[str, ...] = ()
    """Session directories (imported, recorded, hand-made): the study runs on these instead of simulating."""
    solvers: tuple[str, ...] = ()
    """Solvers (any of the system's; empty: its paper's baseline, ``online`` and ``batch``)."""
    duration_s: float | None = None
    """Seconds of data per session (None: head 10 s, others their ``simulate`` default)."""
    profile: str = "realistic"
    """Sensor error profile of the scenario."""

    def __post_init__(self) -> None:
        from ..systems.presets import PRESETS

        if self.system not in PRESETS:
            raise ValueError(f"no system {self.system!r} (available: {', '.join(PRESETS)})")
        if self.system == "head" and self.duration_s is None and not self.sessions:
            object.__setattr__(self, "duration_s", 10.0)
        if not self.solvers:
            object.__setattr__(self, "solvers", (_baseline_solver(self.system), "online", "batch"))
        for drop in self.drops:
            unknown = [s for s in drop if self.system in SENSORS and s not in SENSORS[self.system]]
            if unknown:
                raise ValueError(f"cannot drop {', '.join(unknown)}: {self.system} has sensors {', '.join(SENSORS[self.system])}")
        for name, _ in self.vary:
            stream, dot, key = name.partition(".")
            if not dot and not (self.system == "head" and name in HEAD_PARAMETERS):
                known = ", ".join(HEAD_PARAMETERS) if self.system == "head" else "none"
                raise ValueError(f"unknown parameter {name!r} to vary: use STREAM.KEY (a catalogued key, e.g. tracker.noise_sigma_deg) "
                                 f"or a scenario name (head: {known})")
        for solver in self.solvers:
            if solver not in PRESETS[self.system].solvers:
                raise ValueError(f"unknown solver {solver!r} for {self.system} (known: {', '.join(PRESETS[self.system].solvers)})")

    def variants(self) -> list[Variant]:
        names = [name for name, _ in self.vary]
        grid = list(itertools.product(*[values for _, values in self.vary])) or [()]
        drops = [()] + [d for d in self.drops if d]
        return [Variant(tuple(drop), tuple(zip(names, point, strict=True))) for drop in drops for point in grid]

    def runs(self) -> list[dict[str, Any]]:
        """Every run as a plain dict (picklable, hashable by ``run_key``)."""
        out = []
        sources: list[tuple[int | str, str]] = [("", path) for path in self.sessions] or [(seed, "") for seed in self.seeds]
        for variant in self.variants():
            for seed, session in sources:
                for solver in self.solvers:
                    spec = {"system": self.system, "drop": list(variant.drop), "params": dict(variant.params), "seed": seed,
                            "solver": solver, "profile": self.profile, "duration_s": self.duration_s}
                    if session:
                        spec.update(session=session, profile="", duration_s="")
                    spec["key"] = run_key(spec)
                    spec["variant"] = variant.name
                    out.append(spec)
        return out


def run_key(spec: Mapping[str, Any]) -> str:
    """A stable key of a run's full configuration (what it computes, not where or when)."""
    fields = {k: spec[k] for k in ("system", "drop", "params", "seed", "solver", "profile", "duration_s")}
    if spec.get("session"):
        fields["session"] = spec["session"]
    return hashlib.sha1(json.dumps(fields, sort_keys=True).encode()).hexdigest()[:16]


def load_study(path: str | Path) -> Study:
    """A study from a TOML file with a ``[study]`` table (see examples/)."""
    path = Path(path)
    try:
        table = tomllib.loads(path.read_text())["study"]
    except (OSError, tomllib.TOMLDecodeError, KeyError) as exc:
        raise ValueError(f"{path}: cannot read a [study] table ({exc})") from None
    from .runner import parse_seeds

    seeds = table.get("seeds", [0])
    return Study(
        system=table.get("system", "head"),
        drops=tuple(tuple(d.split("+")) for d in table.get("drop", [])),
        vary=tuple((k, tuple(float(x) for x in v)) for k, v in table.get("vary", {}).items()),
        seeds=tuple(parse_seeds(seeds) if isinstance(seeds, str) else seeds),
        solvers=tuple(table.get("solvers", ())),
        sessions=tuple(str(p) for p in table.get("sessions", ())),
        duration_s=float(table["duration_s"]) if "duration_s" in table else None,
        profile=table.get("profile", "realistic"),
    )


# ------------------------------------------------------------------------------------ one run


def execute(spec: Mapping[str, Any]) -> dict[str, Any]:
    """Simulate, drop, solve, score one run; never raises (a failure is a row)."""
    start = time.perf_counter()
    row = _blank_row(spec)
    generic = spec["system"] != "head" or any("." in k for k in spec["params"]) or "accel" in spec["drop"] or bool(spec.get("session"))
    try:
        if generic:
            metrics, seconds = _solve_generic(spec)
            row["metrics"] = json.dumps(metrics)
            row["solver_s"] = seconds
            row["status"] = "ok"
            row["run_s"] = time.perf_counter() - start
            return row
        estimate, truth_t, truth_q = _solve_head(spec)
        from ..estimate import Estimate
        from ..metrics import score_attitude

        assert isinstance(estimate, Estimate)
        score = score_attitude(estimate, truth_t, truth_q)
        row.update(zip(METRIC_COLUMNS[:3], (float(v) for v in score.rms_rad), strict=True))
        row["nees"] = "" if score.nees is None else score.nees
        row["solver_s"] = estimate.runtime_s
        row["status"] = "ok"
    except NotApplicableError as exc:  # the variant took away what this solver needs: not a failure
        row["status"] = "n/a"
        row["error"] = str(exc)
    except Exception as exc:  # noqa: BLE001 - recorded in the row, the study goes on
        row["status"] = "failed"
        row["error"] = f"{type(exc).__name__}: {exc}"
    row["run_s"] = time.perf_counter() - start
    return row


def _blank_row(spec: Mapping[str, Any]) -> dict[str, Any]:
    """A row with the run's configuration filled in and its results empty."""
    row: dict[str, Any] = dict.fromkeys(COLUMNS, "")
    row.update({k: spec[k] for k in ("key", "system", "variant", "seed", "solver", "profile", "duration_s")})
    row["session"] = spec.get("session", "")
    row["drop"] = "+".join(spec["drop"])
    row["params"] = ";".join(f"{k}={v:g}" for k, v in spec["params"].items())
    return row


def _solve_generic(spec: Mapping[str, Any]) -> tuple[dict[str, float], float]:
    """Any system: load the session (or simulate one: ``scenarios.SIMULATORS``), drop streams, set catalogued keys, solve,
    score (flattened metrics)."""
    from dataclasses import replace

    from ..results import flatten
    from ..scenarios import SIMULATORS
    from ..sensors import sensor_catalogue
    from .runner import solve_session

    options: dict[str, Any] = {}
    scenario = {k: v for k, v in spec["params"].items() if "." not in k}
    if spec["system"] == "head":
        options = {HEAD_PARAMETERS[k]: v for k, v in scenario.items()}
        options["profile"] = spec["profile"]
        options["sensors"] = ("gyro", "accel", "tracker")
    duration = spec["duration_s"]
    if spec.get("session"):
        from ..session import load_session

        if scenario:
            raise ValueError(f"--vary {', '.join(scenario)}: scenario settings apply to simulated sessions; a recording's are STREAM.KEY")
        session = load_session(spec["session"])
        if session.system != spec["system"]:
            raise ValueError(f"{spec['session']}: a {session.system} session, not {spec['system']}")
    else:
        session = SIMULATORS[spec["system"]].simulate(int(spec["seed"]), None if duration in ("", None) else float(duration), **options)
    drop = [d for d in spec["drop"] if d in session.streams]
    missing = [d for d in spec["drop"] if d not in session.streams]
    if missing:
        raise ValueError(f"no stream {', '.join(missing)} to drop (have: {', '.join(session.streams)})")
    session = session.without(*drop)
    streams = dict(session.streams)
    for name, value in spec["params"].items():
        stream_name, dot, key = name.partition(".")
        if not dot:
            continue
        stream = session.stream(stream_name)
        entry = sensor_catalogue()[stream.kind]
        if entry.key(key) is None:
            raise ValueError(f"{stream_name}.{key}: not a key of kind {stream.kind} (keys: {', '.join(entry.key_names)})")
        streams[stream_name] = replace(streams[stream_name], meta={**streams[stream_name].meta, key: value})
    session = replace(session, streams=streams)
    outcome = solve_session(session, spec["solver"])
    return flatten(outcome.metrics or {}), outcome.estimate.runtime_s


def _solve_head(spec: Mapping[str, Any]) -> tuple[Any, Any, Any]:
    from ..scenarios.head import simulate_head
    from ..systems import head

    overrides = {HEAD_PARAMETERS[k]: v for k, v in spec["params"].items()}
    session = simulate_head(int(spec["seed"]), profile=spec["profile"], duration_s=float(spec["duration_s"]), **overrides)
    assert session.truth is not None
    drop = set(spec["drop"])
    method = {"ekf": "method2", "online": "isam2"}.get(spec["solver"], spec["solver"])
    if "tracker" in drop:
        tracker = session.stream("tracker")
        session = session.without("tracker")
        session = type(session)(session.system, {**session.streams, "tracker": tracker.select(np.arange(len(tracker)) == 0)}, session.truth, session.meta)
    model = None
    if "gyro" in drop:
        if method == "method2":
            method = "kalman"  # the paper's tracker-only filter; the gyro's clock only sets output times
        else:
            session, model = without_gyro(session)
    truth = session.truth
    assert truth is not None
    return head.run_method(session, method, model), truth.t, truth.values


# ------------------------------------------------------------------------------------ a study


@dataclass
class StudyResult:
    """All rows of a study (in the study's order) and how its wall time was spent."""

    rows: list[dict[str, Any]]
    wall_s: float = 0.0
    workers: int = 1
    ran: int = 0
    skipped: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def solver_fraction(self) -> float:
        """Share of the workers' wall time spent inside the solvers (runs done in this call)."""
        fresh = [r for r in self.rows if r.get("_fresh") and r["status"] == "ok"]
        busy = sum(float(r["solver_s"]) for r in fresh)
        return busy / (self.wall_s * self.workers) if self.wall_s > 0 else float("nan")


def run_study(
    study: Study,
    out_dir: str | Path,
    workers: int = 1,
    scheduler: str | None = None,
    on_row: Callable[[dict[str, Any]], None] | None = None,
    retry_failed: bool = False,
    force: bool = False,
) -> StudyResult:
    """Run every run of ``study`` not yet in ``out_dir/runs.csv``; returns all rows in study order.

    A run that failed before is kept as failed (a deterministic failure would only fail again) unless
    ``retry_failed``. A folder holding another study is refused, or with ``force`` started afresh (its
    rows kept aside as ``runs.replaced.csv``, its definition as ``study.replaced.json``).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    described = json.dumps(asdict(study), indent=2)
    recorded = out / "study.json"
    table_path = out / "runs.csv"
    rows = read_rows(table_path)
    if recorded.exists() and recorded.read_text() != described and rows:
        if not force:
            raise ValueError(f"{out} holds a study with other settings ({recorded}): its rows would mix with these; "
                             "use another --out folder, or --force to start this study there (the old rows are kept aside)")
        recorded.replace(out / "study.replaced.json")
        table_path.replace(out / "runs.replaced.csv")
        rows = []
    recorded.write_text(described)
    # finished runs are kept (and failed ones unless retried); a torn or damaged row is dropped and redone
    kept = [row for row in rows if row["status"] in ("ok", "n/a") or not retry_failed]
    done = {row["key"]: row for row in kept}
    _rewrite(table_path, kept)
    specs = study.runs()
    todo = [s for s in specs if s["key"] not in done]
    new_file = not table_path.exists() or table_path.stat().st_size == 0
    start = time.perf_counter()
    with table_path.open("a", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS, extrasaction="ignore")
        if new_file:
            writer.writeheader()
        for row in progress(_execute_all(todo, workers, scheduler), len(todo), f"ablation {study.system}"):
            writer.writerow(row)
            handle.flush()  # a kill after this line loses nothing
            row["_fresh"] = True
            done[row["key"]] = row
            if on_row is not None:
                on_row(row)
    wall = time.perf_counter() - start
    rows = [done[s["key"]] for s in specs]
    # for a remote cluster its size is its own; ``workers`` then only scales the overhead figure
    return StudyResult(rows, wall, max(1, workers), len(todo), len(specs) - len(todo))


def _execute_all(specs: Sequence[dict[str, Any]], workers: int, scheduler: str | None) -> Iterable[dict[str, Any]]:
    from .cluster import completed

    for spec, future in completed(execute, specs, workers, scheduler):
        yield _result_or_failure(future, spec)


def _result_or_failure(future: Any, spec: Mapping[str, Any]) -> dict[str, Any]:
    """The run's row, or a failed row when the worker itself died."""
    try:
        return dict(future.result())
    except Exception as exc:  # noqa: BLE001 - e.g. a worker killed mid-run
        row = _blank_row(spec)
        row.update(status="failed", error=f"worker failed: {type(exc).__name__}: {exc}")
        return row


def read_rows(path: str | Path) -> list[dict[str, Any]]:
    """Complete rows of a runs.csv (empty when it does not exist yet). A row cut short (the study killed while
    writing it) or otherwise damaged is left out: its run counts as not done."""
    path = Path(path)
    if not path.exists() or path.stat().st_size == 0:
        return []
    with path.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    return [r for r in rows if None not in r and all(r.get(c) is not None for c in COLUMNS) and r["key"] and r["status"] in ("ok", "failed", "n/a")]


def _rewrite(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    """runs.csv holding exactly ``rows`` (atomic: written aside, then renamed)."""
    if not path.exists():
        return
    aside = path.with_suffix(".csv.tmp")
    with aside.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    aside.replace(path)


# ------------------------------------------------------------------------------------ summary


def _metric_values(row: Mapping[str, Any]) -> dict[str, float]:
    if row.get("metrics"):
        return {k: float(v) for k, v in json.loads(row["metrics"]).items()}
    return {name: float(row[c]) for name, c in zip(("azimuth", "elevation", "roll"), METRIC_COLUMNS[:3], strict=True) if row.get(c) not in ("", None)}


def summarize(rows: Sequence[Mapping[str, Any]]) -> list[SummaryRow]:
    """Mean and 95 % confidence interval (Student t over seeds) of each metric per variant and solver."""
    from scipy import stats

    from ..systems.presets import PRESETS

    groups: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["variant"], row["solver"]), []).append(row)
    out = []
    for (variant, solver), members in groups.items():
        ok = [m for m in members if m["status"] == "ok"]
        found = [_metric_values(m) for m in ok]
        system = members[0]["system"]
        head_axes = bool(found) and all("azimuth" in f for f in found)
        names = ("azimuth", "elevation", "roll") if head_axes or system == "head" and not found else tuple(
            k for k in PRESETS[system].metric_keys if found and all(k in f for f in found))
        values = np.array([[f.get(n, np.nan) for n in names] for f in found]) if found else np.full((0, len(names)), np.nan)
        mean = values.mean(axis=0) if len(ok) else np.full(len(names), np.nan)
        half = stats.t.ppf(0.975, len(ok) - 1) * values.std(axis=0, ddof=1) / np.sqrt(len(ok)) if len(ok) > 1 else np.full(len(names), np.nan)
        solver_s = float(np.mean([float(m["solver_s"]) for m in ok])) if ok else float("nan")
        na = [m for m in members if m["status"] == "n/a"]
        out.append(SummaryRow(variant, solver, len(members), len(members) - len(ok) - len(na), tuple(mean), tuple(half), solver_s, names,
                              not_applicable=str(na[0]["error"]) if na and not ok else ""))
    return out


def settings_without_effect(rows: Sequence[Mapping[str, Any]], study: Study) -> list[str]:
    """The ``vary`` settings whose every value gave the same metrics in every run that finished (same variant otherwise,
    same seed or session, same solver): a setting no solver honoured."""
    idle = []
    for name, values in study.vary:
        if len(values) < 2:
            continue
        groups: dict[tuple[Any, ...], set[str]] = {}
        for row in rows:
            if row.get("status") != "ok":
                continue
            params = dict(p.split("=", 1) for p in str(row["params"]).split(";") if p)
            params.pop(name, None)
            key = (row["drop"], tuple(sorted(params.items())), row["seed"], row.get("session", ""), row["solver"])
            found = _metric_values(row)
            groups.setdefault(key, set()).add(json.dumps({k: round(v, 12) for k, v in found.items()}, sort_keys=True))
        if groups and all(len(results) == 1 for results in groups.values()):
            idle.append(name)
    return idle


#: Constant-angular-velocity model used when the gyro is dropped (see ``without_gyro``). Its angular-acceleration noise
#: (rad/s/sqrt(s)) is chosen by ``fusegraph tune head_no_gyro`` on seeds 100-119 (``tuned.toml``).
NO_GYRO_MODEL = GyroNoise(white_sigma_rad_s=0.01, bias_rw_sigma=float(tuned_value("head_no_gyro", "bias_rw_sigma")), bias_prior_sigma_rad_s=2.0)


def without_gyro(session: Session) -> tuple[Session, HeadModel]:
    """The session with the gyro reduced to a clock, and the model that makes the graph tracker-only.

    With every measured rate zero, the gyro model omega = omega_measured - bias makes the "bias" minus
    the angular velocity: each AHRSFactor becomes X(k+1) = X(k) Exp(omega dt) and the bias random walk
    an angular-velocity random walk (``bias_rw_sigma`` is then the angular-acceleration noise, rad/s
    per sqrt(s)). So the same graph, solvers and latency handling run a constant-angular-velocity
    model on the tracker alone; the clock only says when to report.
    """
    gyro = session.stream("gyro")
    clock = replace(gyro, values=np.zeros_like(gyro.values), meta={**gyro.meta, "calibrated": True})
    tracker_only = replace(session, streams={**session.streams, "gyro": clock})
    model = replace(head_model_for(tracker_only), gyro=replace(NO_GYRO_MODEL, sample_rate_hz=float(gyro.meta.get("rate_hz", 100.0))), gyro_calibration=None)
    # no gyro to carry a reading between keyframes with: a keyframe per tracker sample (its period)
    stamps = session.stream("tracker").t
    if len(stamps) > 1:
        model = replace(model, keyframe_period_s=float(np.median(np.diff(stamps))))
    return tracker_only, model
