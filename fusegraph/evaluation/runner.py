"""Running presets: one session, many sessions (local processes or Dask, resumable), a report over seeds.

Library functions that ``fusegraph run`` and ``fusegraph report`` wrap; generic over ``PRESETS``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..estimate import Estimate, PointEstimate, Result
from ..geometry import FloatArray
from ..provenance import choices_that_saw
from ..results import flatten
from ..session import NotApplicableError, Session, SessionError, Stream, load_session
from ..solvers.windowed import Windows
from ..systems.presets import PRESETS, Preset, preset_for


@dataclass
class Outcome:
    """One solver's run on one session: the estimate, its metrics (None without truth) and files written."""

    session: Session
    preset: Preset
    solver: str
    estimate: Result
    metrics: dict[str, Any] | None
    files: list[Path] = field(default_factory=list)
    suspect: list[str] = field(default_factory=list)
    """Why the run may be unreliable though it ran (``consistency.suspect_reasons``): reports leave it out of their means."""

    def as_json(self) -> dict[str, Any]:
        """``{"system": s, "solver": s, "metrics": {...}}`` (metrics empty without truth), ``suspect: [reasons]`` when the
        run's own diagnostics say it may be unreliable, and the estimated calibrations a solver reports (``ESTIMATED``)."""
        found = {key: self.estimate.extras[key] for key in ESTIMATED if key in self.estimate.extras}
        marked = {"suspect": self.suspect} if self.suspect else {}
        return {"system": self.preset.name, "solver": self.solver, "metrics": self.metrics or {}, **marked, **found}


ESTIMATED = ("gyro_calibration",)
"""Estimate extras that ``run`` prints: what a solver learnt about the sensors (the 9-axis batch's gyro K, when the
recording declares ``scale_sigma``)."""


def solve_session(session: Session, solver: str) -> Outcome:
    """Run one solver of the session's preset and score it when the session has truth."""
    from ..consistency import suspect_reasons

    preset = preset_for(session)
    estimate = preset.solve(session, solver)
    return Outcome(session, preset, solver, estimate, preset.score(session, estimate), suspect=suspect_reasons(session.streams, estimate.extras))


def run_session(path: str | Path, solver: str, out: str | Path | None = None, plot: str | Path | None = None) -> Outcome:
    """Load, solve, score; write the estimate CSV (default ``./<session folder>_<stem>_<solver>.csv``: in the current
    folder, never into the recording) and, if asked, the picture."""
    session = load_session(path)
    outcome = solve_session(session, solver)
    target = Path(out) if out is not None else Path.cwd() / f"{Path(path).resolve().name}_{outcome.preset.estimate_name}_{solver}.csv"
    if target.is_dir():
        raise SessionError(f"--out {target}: is a folder; give a file name (e.g. {target / (outcome.preset.estimate_name + '_' + solver + '.csv')})")
    target.parent.mkdir(parents=True, exist_ok=True)
    outcome.files.append(outcome.estimate.save_csv(target))
    steps = outcome.estimate.extras.get("steps_s")
    if steps is not None:  # --solver gait: its steps beside the strides, the inferred contacts said as such
        inferred = outcome.estimate.extras.get("steps_inferred", np.zeros(len(steps), dtype=bool))
        steps_path = _steps_path(target)
        with steps_path.open("w") as handle:
            _write_steps(handle, steps, inferred, header=True)
        outcome.files.append(steps_path)
    if plot is not None:
        from ..report.pictures import PICTURES

        picture = PICTURES[outcome.preset.name]
        plot_path = Path(plot)
        written = picture(session, [outcome.estimate], plot_path.parent if plot_path.suffix else plot_path)
        if plot_path.suffix and written:
            written[0].replace(plot_path)
            written[0] = plot_path
        outcome.files += written
    return outcome


STREAMED = {"attitude9": "batch", "walking": "gait"}
"""The solver ``run --stream`` runs, by system: the 9-axis batch smoothed in overlapping windows, the waist's steps and
strides found window by window. Not the waist's activity: its cycles' features are taken against
the recording's own reference (``evaluation.activity.with_reference``), so a window's calls are not the whole run's (180
of 4,287 cycles differed on a Mobilise-D walk repeated for 2 h, in 10-minute windows with two minutes either side)."""

GAIT_WINDOWS = Windows(window_s=600.0, margin_s=120.0)
"""``run --stream --solver gait``'s windows: two minutes solved on each side of the ten kept. Measured on a Mobilise-D walk
repeated for 2 h (seams every ten minutes, in bouts and between them): the windows' 5,121 steps are the whole run's and
their strides within 1.2e-5 m (the pelvis's rise is high-passed at 0.1 Hz with zero phase, and a window's ends cut the
filter); with one minute 2 steps were not found, as the front end accepts a step by the walking direction of the cycles
before it (a median over recent cycles, carried across pauses) and a window starts without those more than its margin
back; with three minutes the strides were within 2e-7 m."""


def run_streamed(path: str | Path, out: str | Path | None = None, block_s: float = 60.0,
                 progress: Callable[[str], None] | None = None, solver: str | None = None) -> str:
    """A session read a block at a time, its estimate written as each window is solved: a recording of any length in
    memory that does not grow with it (``solvers.windowed``): the 9-axis batch (attitude9) or the waist's steps and strides
    (walking, ``--solver gait``; the steps in ``<out>_steps.csv`` beside, as ``run`` writes them). Each window gets every
    check a session gets before it is solved (``Session.validate``: a frame, unit or dead-stream mistake is an error naming
    the stream and the window, as ``check`` names it). Nothing is scored (the truth is not read: run the session whole to
    score it). Returns what a terminal is told."""
    from ..estimate import save_csv_pieces
    from ..session import iter_session_blocks, read_session_spec
    from ..systems.attitude9 import windowed_batch

    system = read_session_spec(Path(path))[2]
    solver = solver or STREAMED.get(system)
    if STREAMED.get(system) != solver:
        runs = ", ".join(f"the {s} {v}" for s, v in STREAMED.items())
        raise NotApplicableError(f"{Path(path) / 'session.toml'}: --stream runs {runs}; this is a {system!r} session and --solver {solver} "
                                 "(run it without --stream)")
    name = f"{PRESETS[system].estimate_name}_{solver}"
    target = Path(out) if out is not None else Path.cwd() / f"{Path(path).resolve().name}_{name}.csv"
    if target.is_dir():
        raise SessionError(f"--out {target}: is a folder; give a file name (e.g. {target / (name + '.csv')})")
    target.parent.mkdir(parents=True, exist_ok=True)
    say = progress or (lambda _line: None)
    rows, start = 0, time.perf_counter()
    blocks = iter_session_blocks(path, block_s)
    if system == "attitude9":

        def counted(piece: Estimate) -> None:
            nonlocal rows
            rows += len(piece.t)
            if len(piece.t):
                say(f"smoothed to t = {piece.t[-1]:.0f} s ({rows} rows written)")

        save_csv_pieces(windowed_batch(blocks, check=checked_window), target, counted)
        seconds = time.perf_counter() - start
        return f"wrote {target} ({rows} rows, smoothed window by window in {seconds:.1f} s; not scored: the truth is not read when streaming)"
    steps, pieces = 0, 0
    with _steps_path(target).open("w") as handle:

        def written(piece: PointEstimate) -> None:
            nonlocal rows, steps, pieces
            _write_steps(handle, piece.extras["steps_s"], piece.extras["steps_inferred"], header=pieces == 0)
            rows, steps, pieces = rows + len(piece.t), steps + len(piece.extras["steps_s"]), pieces + 1
            say(f"walked to t = {piece.extras['until_s']:.0f} s ({steps} steps, {rows} strides written)")

        save_csv_pieces(gait_in_windows(blocks), target, written)
    seconds = time.perf_counter() - start
    return (f"wrote {target} ({rows} strides) and {_steps_path(target)} ({steps} steps), found window by window in {seconds:.1f} s; "
            "not scored: the truth is not read when streaming")


def gait_in_windows(blocks: Iterable[Session], windows: Windows | None = None) -> Iterator[PointEstimate]:
    """``--solver gait`` over a walking recording given as ``blocks`` (Sessions in time order), window by window
    (``solvers.windowed.events_in_windows``; ``windows`` default ``GAIT_WINDOWS``): each window checked (``checked_window``)
    and solved by the walking preset, its strides and steps in its kept part as a PointEstimate (``extras``: ``steps_s``,
    ``steps_inferred`` and ``until_s``, the time its kept part ends)."""
    from ..solvers.windowed import events_in_windows

    runtimes: list[float] = []  # each window's, and where its kept part ends: for the piece it gives
    ends: list[float] = []

    def detect(window: Session) -> list[tuple[FloatArray, FloatArray]]:
        estimate = PRESETS["walking"].run(checked_window(window), "gait")  # checked here: Preset.solve would check it again
        assert isinstance(estimate, PointEstimate)
        runtimes.append(estimate.runtime_s)
        return [(estimate.t, estimate.points), (estimate.extras["steps_s"], np.asarray(estimate.extras["steps_inferred"], dtype=bool))]

    for (stride_t, points), (steps_s, inferred) in events_in_windows(blocks, detect, windows or GAIT_WINDOWS, ends.append):
        yield PointEstimate("gait", stride_t, points, ("stride_length_m", "walking_speed_m_s"), runtimes[-1],
                            {"steps_s": steps_s, "steps_inferred": inferred, "until_s": ends[-1]})


def _steps_path(strides: Path) -> Path:
    """Where ``--solver gait``'s steps go beside its strides' CSV."""
    return strides.with_name(f"{strides.stem}_steps.csv")


def _write_steps(handle: Any, steps_s: FloatArray, inferred: np.ndarray, header: bool) -> None:
    """``--solver gait``'s steps as CSV rows (the inferred contacts said as such)."""
    np.savetxt(handle, np.column_stack([steps_s, np.asarray(inferred, dtype=int)]).reshape(-1, 2), fmt=["%.4f", "%d"], delimiter=",",
               header="t_s,inferred" if header else "", comments="")


CHECK_WINDOW_S = 600.0
"""``check`` reads a session of one and a half of these or more a window of this many seconds at a time (the 9-axis batch's window,
``attitude9.BATCH_WINDOWS``: the memory a long run holds anyway)."""


def check_session(path: str | Path, window_s: float = CHECK_WINDOW_S) -> dict[str, Any]:
    """``fusegraph check``'s findings on one session directory: every check of ``load_session`` and ``Session.validate`` (an
    error raises, naming the stream), the accelerometer's and magnetometer's frames against the gyro
    (``consistency.frames_found``) and what makes a run on it suspect. A session of 1.5 ``window_s`` or more (``session.recording_times_s``) is read
    and checked a window at a time, in memory that does not grow with it: each window gets every check, its truth's
    among them (an error names its span), a truth that overlaps no window is the error a whole read gives, a frame is the
    one of the window that tells it best (the smallest largest 1-sigma), and the suspect reasons are every window's.
    Returns {"frames", "suspect", "windows"}."""
    from ..consistency import frames_found, suspect_reasons, truth_clock_error
    from ..session import csv_time_span, iter_session_blocks, read_session_spec, recording_times_s

    times = recording_times_s(path)
    if times is None or times[1] - times[0] < 1.5 * window_s:  # one window holds it (a short last one is joined): read it whole, with its truth
        session = load_session(path)
        session.validate()
        return {"frames": frames_found(session.streams), "suspect": suspect_reasons(session.streams), "windows": 1}
    frames: dict[str, dict[str, Any]] = {}
    suspect: list[str] = []
    count, truth_heard = 0, False
    for window in _tail_joined(iter_session_blocks(path, window_s, truth=True), window_s):
        count += 1
        checked_window(window)
        truth_heard |= window.truth is not None
        for frame in frames_found(window.streams):
            held = frames.get(frame["stream"])
            if held is None or (frame["told"] and (not held["told"] or max(frame["turn_sigma_deg"]) < max(held["turn_sigma_deg"]))):
                frames[frame["stream"]] = frame
        suspect += [reason for reason in suspect_reasons(window.streams) if reason not in suspect]
    _, spec, _ = read_session_spec(Path(path))
    if "truth" in spec and not truth_heard:  # on another clock: no window held a sample of it
        truth_s = csv_time_span(Path(path) / spec["truth"].get("file", "truth.csv"))
        if truth_s is not None:
            raise SessionError(f"{Path(path) / 'session.toml'}: {truth_clock_error(truth_s, times)}")  # as a whole read names it
    return {"frames": list(frames.values()), "suspect": suspect, "windows": count}


def _tail_joined(windows: Iterable[Session], window_s: float) -> Iterator[Session]:
    """The windows in order, one that spans less than half a window (the recording's last samples, or a stretch with a
    dropout) joined to the one before: a few samples cannot be checked on their own."""
    held: Session | None = None
    for window in windows:
        if held is not None:
            gyro = next((s for s in window.streams.values() if s.kind == "gyro"), None)
            short = gyro is not None and (len(gyro) < 2 or float(gyro.t[-1] - gyro.t[0]) < 0.5 * window_s)
            if not short:
                yield held
            else:
                joined = {name: s if s.own_recording else _joined(s, window.streams[name]) for name, s in held.streams.items()}
                truth = window.truth if held.truth is None else held.truth if window.truth is None else _joined(held.truth, window.truth)
                window = replace(held, streams=joined, truth=truth)
        held = window
    if held is not None:
        yield held


def _joined(first: Stream, then: Stream) -> Stream:
    """A stream's samples of two windows in one."""
    return replace(first, t=np.concatenate([first.t, then.t]), values=np.concatenate([first.values, then.values]))


def checked_window(window: Session) -> Session:
    """``window.validate()``, an error saying which span of the recording it is in; the window as a solver takes it
    (``Session.usable``: a dead magnetometer left out, as a session read whole)."""
    gyro = next((s for s in window.streams.values() if s.kind == "gyro" and len(s)), None)
    try:
        window.validate()
    except SessionError as err:
        span = f" (in the window {gyro.t[0]:.0f}-{gyro.t[-1]:.0f} s)" if gyro is not None else ""
        raise type(err)(f"{err}{span}") from None
    return window.usable()


def describe(outcome: Outcome) -> str:
    """One or two lines for a terminal: what was written, how long it took, the headline metrics."""
    e = outcome.estimate
    lines = [f"wrote {outcome.files[0]} ({len(e.t)} rows, {outcome.session.duration_s:.1f} s of data in {e.runtime_s:.2f} s)" if outcome.files else ""]
    latency = e.extras.get("latency_s")
    if latency is not None:
        sigma = e.extras.get("latency_sigma_s")
        lines.append(f"tracker latency estimated: {1000 * latency:.1f} ms" + (f" (sigma {1000 * sigma:.1f} ms)" if sigma else ""))
    gyro = e.extras.get("gyro_calibration")
    if gyro is not None:
        K = np.asarray(gyro)
        lines.append("gyro calibration estimated (each reading corrected to (I + K) times it): K's scale terms "
                     + " / ".join(f"{100 * v:+.2f} %" for v in np.diag(K)) + f", largest cross-axis term {np.abs(K - np.diag(np.diag(K))).max():.4f} rad")
    if outcome.metrics:
        flat = flatten(outcome.metrics)
        keys = [k for k in outcome.preset.metric_keys if k in flat] + [k for k in flat if k.startswith("gap_")]
        lines.append("; ".join(f"{k} {flat[k]:.4g}" for k in keys))
    if outcome.suspect:
        lines.append("suspect: " + "; ".join(outcome.suspect) + " (reports leave this run out of their means)")
    return "\n".join(line for line in lines if line)


# --------------------------------------------------------------------------------- many sessions


def session_dirs(paths: Iterable[str | Path]) -> list[Path]:
    """Session directories from arguments: each is a session, or a folder with sessions below it (at any depth)."""
    found: list[Path] = []
    for item in paths:
        path = Path(item)
        if (path / "session.toml").is_file():
            found.append(path)
        elif path.is_dir():
            inner = sorted(p.parent for p in path.rglob("session.toml"))  # at any depth: nothing below the folder is skipped
            if not inner:
                raise SessionError(f"{path / 'session.toml'}: not found (a session is a directory with session.toml; a study, a folder of them)")
            found += inner
        else:
            raise SessionError(f"{path}: not found")
    return found


def unique_names(paths: Sequence[Path]) -> list[str]:
    """A name per session that no other of them has: its folder's name, or where two share one, its path below the folder
    they share with ``__`` between the parts (``A/trial`` and ``B/trial`` -> ``A__trial``, ``B__trial``)."""
    names = [p.name for p in paths]
    if len(set(names)) == len(names):
        return names
    resolved = [p.resolve() for p in paths]
    common = Path(*[parts[0] for parts in zip(*(r.parts for r in resolved), strict=False) if len(set(parts)) == 1]) if len(resolved) > 1 else resolved[0].parent
    return ["__".join(r.relative_to(common).parts) or r.name for r in resolved]


def settings_digest() -> str:
    """What every solver's settings are made of, hashed: the package version, the chosen settings (``tuned.toml``) and the
    fitted models (``models/``). A change to any of them makes a study's finished runs stale."""
    package = Path(__file__).resolve().parent.parent
    return _digest(_release(), [(path.name, path) for path in [package / "tuned.toml", *sorted((package / "models").glob("*"))]])


def code_digest() -> str:
    """The code every solver runs, hashed: the package version and every module's source (and the fitted models), so a
    result made by other code is not taken for this code's."""
    package = Path(__file__).resolve().parent.parent
    files = [*sorted(package.rglob("*.py")), *sorted((package / "models").glob("*"))]
    return _digest(_release(), [(str(path.relative_to(package)), path) for path in files])


def _release() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("fusegraph")
    except PackageNotFoundError:  # run from a source tree that was not installed
        return "source"


def _digest(release: str, files: Sequence[tuple[str, Path]]) -> str:
    """``release`` and each (name, file)'s name and bytes, hashed (16 hex digits)."""
    import hashlib

    digest = hashlib.sha256(release.encode())
    for name, path in files:
        digest.update(name.encode() + path.read_bytes())
    return digest.hexdigest()[:16]


def session_digest(path: str | Path) -> str:
    """A session directory's content hashed (every file in it, by name and bytes), or a recording file's, so a run is
    known to be of this data."""
    import hashlib

    digest = hashlib.sha256()
    for file in sorted(p for p in Path(path).rglob("*") if p.is_file()) if Path(path).is_dir() else [Path(path)]:
        digest.update(str(file.relative_to(path) if file != Path(path) else file.name).encode())
        with file.open("rb") as handle:
            for chunk in iter(lambda: handle.read(1 << 20), b""):
                digest.update(chunk)
    return digest.hexdigest()[:16]


def run_key(content: str, solver: str, settings: str) -> str:
    """The key a row is kept under: the session's content (``session_digest``), the solver and the settings
    (``settings_digest``)."""
    return f"{content}-{solver}-{settings}"


def read_rows(log: Path) -> list[dict[str, Any]]:
    """The rows of a JSON-lines log (none when it does not exist); a line a kill tore, or any other that does not parse,
    is left out (its run is made again)."""
    rows = []
    for line in log.read_text().splitlines() if log.exists() else []:
        with contextlib.suppress(json.JSONDecodeError):
            rows.append(json.loads(line))
    return rows


def append_rows(log: Path, rows: Iterable[dict[str, Any]]) -> None:
    """Append ``rows`` to a JSON-lines log, each flushed as it is written (a kill loses at most the one being written); a
    last line a kill tore is ended first, so the next row starts a line of its own."""
    log.parent.mkdir(parents=True, exist_ok=True)
    torn = False
    if log.exists() and log.stat().st_size:
        with log.open("rb") as handle:
            handle.seek(-1, 2)
            torn = handle.read(1) != b"\n"
    with log.open("a") as handle:
        handle.write("\n" if torn else "")
        for row in rows:
            handle.write(json.dumps(row) + "\n")
            handle.flush()


def _run_one_to_folder(args: tuple[str, str, str, str, str]) -> dict[str, Any]:
    """Worker: one session into the study folder; a failure is a row, not an exception."""
    path, solver, out_dir, name, key = args
    try:
        outcome = run_session(path, solver, Path(out_dir) / f"{name}_{solver}.csv")
        row = {"session": name, "path": path, "status": "ok", **outcome.as_json(), "runtime_s": outcome.estimate.runtime_s, "key": key}
    except Exception as exc:  # noqa: BLE001 - recorded, the study goes on
        row = {"session": name, "path": path, "status": "failed", "solver": solver, "error": f"{type(exc).__name__}: {exc}", "key": key}
    return row


def run_many(paths: Sequence[Path], solver: str, out_dir: str | Path, workers: int = 1, scheduler: str | None = None) -> list[dict[str, Any]]:
    """Run every session into ``out_dir`` (estimate CSVs and ``results.jsonl``); a session already done there with the same
    content, solver and settings (``run_key``) is skipped, one whose data or settings changed since is run again.

    ``scheduler``: None = local processes, ``local`` = a Dask LocalCluster, ``tcp://host:port`` = an existing cluster.
    """
    from ..progress import progress

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    log = out / "results.jsonl"
    done = {row["path"]: row for row in read_rows(log) if row.get("status") == "ok" and row.get("solver") == solver}
    names = unique_names(paths)
    settings = settings_digest()
    keys = {str(p): run_key(session_digest(p), solver, settings) for p in paths}
    done = {path: row for path, row in done.items() if row.get("key") == keys.get(path)}  # data or settings changed: run again
    todo = [(str(p), solver, str(out), name, keys[str(p)]) for p, name in zip(paths, names, strict=True) if str(p) not in done]

    def kept(rows: Iterable[dict[str, Any]]) -> Iterator[dict[str, Any]]:
        for row in rows:
            done[row["path"]] = row
            yield row

    append_rows(log, kept(progress(_map(todo, workers, scheduler), len(todo), f"run {solver}")))
    return [done.get(str(p), {"session": p.name, "path": str(p), "status": "failed", "error": "not run"}) for p in paths]


def _map(todo: list[tuple[str, str, str, str, str]], workers: int, scheduler: str | None) -> Iterable[dict[str, Any]]:
    from .cluster import completed

    for _, future in completed(_run_one_to_folder, todo, workers, scheduler):
        yield future.result()


def format_many(rows: Sequence[dict[str, Any]]) -> str:
    """One line per session (status and the metrics its preset summarises), then the mean over the sessions scored, as
    ``report`` prints it: a NaN figure or a suspect run is not averaged, and said."""
    width = max([len(str(r.get("session", ""))) for r in rows] + [7]) + 2
    lines = []
    scored: list[dict[str, float]] = []
    keys: list[str] = []
    for row in rows:
        if row.get("status") != "ok":
            lines.append(f"{row['session']:<{width}}FAILED {row.get('error', '')}")
            continue
        preset = PRESETS[row["system"]]
        flat = flatten(row.get("metrics", {}))
        shown = [k for k in preset.metric_keys if k in flat] or list(flat)  # a solver with metrics of its own (walking: steps)
        cells = "  ".join(f"{k} {flat[k]:.4g}" for k in shown) or "(no truth)"
        mark = "  suspect: " + "; ".join(row["suspect"]) if row.get("suspect") else ""
        lines.append(f"{row['session']:<{width}}{row['system']:<11}{row['solver']:<9}{cells}{mark}")
        if flat and not row.get("suspect") and all(np.isfinite(flat[k]) for k in shown):
            scored.append(flat)
            keys = keys or shown
    failed = sum(r.get("status") != "ok" for r in rows)
    if scored:
        means = "  ".join(f"{k} {np.mean([s[k] for s in scored if k in s]):.4g}" for k in keys)
        lines.append(f"{'mean':<{width}}{'':<20}{means}   (over {len(scored)} scored; a NaN figure or a suspect run is left out)")
    lines.append(f"{len(rows)} sessions, {failed} failed, {len(rows) - failed - len(scored)} not scored")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------- report


def generic_report(system: str, seeds: Sequence[int], duration_s: float | None = None, solvers: Sequence[str] | None = None,
                   **options: Any) -> dict[str, Any]:
    """Simulate each seed, run every solver, score: the mean of each metric over seeds per solver, and speed.

    JSON: ``{"system", "seeds", "duration_s", "methods": {solver: {"metrics": {...}, "x_realtime": x}}, "per_seed": ...}``.
    """
    from ..progress import progress
    from ..scenarios import SIMULATORS

    preset = PRESETS[system]
    names = list(solvers or preset.solvers)
    per_seed: dict[str, list[dict[str, float]]] = {m: [] for m in names}
    seconds: dict[str, float] = dict.fromkeys(names, 0.0)
    data_s = 0.0
    for seed in progress(seeds, len(seeds), f"{system} report (seeds)"):
        session = SIMULATORS[system].simulate(seed, duration_s, **options)
        data_s += session.duration_s
        for name in names:
            outcome = solve_session(session, name)
            per_seed[name].append(flatten(outcome.metrics or {}))
            seconds[name] += outcome.estimate.runtime_s
    methods = {}
    for name in names:
        keys = sorted(set().union(*[set(r) for r in per_seed[name]]))
        means = {k: float(np.mean([r.get(k, np.nan) for r in per_seed[name]])) for k in keys}
        methods[name] = {"metrics": means, "x_realtime": data_s / seconds[name] if seconds[name] > 0 else float("inf")}
    return {"system": system, "seeds": list(seeds), "duration_s": duration_s, "methods": methods, "per_seed": per_seed}


def format_generic_report(report: dict[str, Any]) -> str:
    """A text table: one row per solver, the preset's metrics (means over seeds) and speed."""
    preset = PRESETS[report["system"]]
    keys = [k for k in preset.metric_keys if any(k in m["metrics"] for m in report["methods"].values())]
    width = max(len(n) for n in report["methods"]) + 2
    lines = [f"{report['system']}: seeds {','.join(str(s) for s in report['seeds'])}, means over seeds",
             f"{'method':<{width}}" + "".join(f"{k:>24}" for k in keys) + f"{'x real time':>14}"]
    for name, row in report["methods"].items():
        cells = "".join(f"{row['metrics'].get(k, float('nan')):24.4f}" for k in keys)
        lines.append(f"{name:<{width}}{cells}{row['x_realtime']:14.1f}")
    return "\n".join(lines)


# --------------------------------------------------------------------------- report over sessions


def unflatten(flat: dict[str, float]) -> dict[str, Any]:
    """``a.b`` -> number back into nested dicts (the shape ``run --json`` prints)."""
    out: dict[str, Any] = {}
    for key, value in flat.items():
        *parents, leaf = key.split(".")
        node = out
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return out


def _without_truth(outcome: Outcome) -> dict[str, float]:
    """What can be said of an estimate without truth: its own sigma (median over samples, the attitude's largest axis in
    degrees) and how much of the session it covers."""
    estimate = outcome.estimate
    out: dict[str, float] = {}
    if isinstance(estimate, Estimate):
        covered = np.isfinite(estimate.quat_wxyz).all(axis=1)
        if estimate.cov is not None:
            variances = np.diagonal(estimate.cov, axis1=1, axis2=2)
            known = np.isfinite(variances).all(axis=1)  # NaN before the first fix
            if known.any():
                out["sigma_deg_median"] = float(np.degrees(np.median(np.sqrt(variances[known].max(axis=1)))))
    elif isinstance(estimate, PointEstimate):
        covered = np.isfinite(estimate.points).all(axis=(1, 2))
    else:
        return out
    out["covered_frac"] = float(np.mean(covered)) if np.size(covered) else 0.0
    return out


def report_sessions(system: str, sessions: Sequence[tuple[str, Session | Path]], solvers: Sequence[str] | None = None,
                    show_progress: bool = True, include_suspect: bool = False, traces: dict[str, list[Any]] | None = None,
                    workers: int = 1, scheduler: str | None = None, cache: str | Path | None = None) -> dict[str, Any]:
    """Every solver of ``system`` on every session (imported, hand-made or simulated), each through ``solve_session``
    exactly as ``fusegraph run`` runs it.

    JSON: ``{"system", "solvers", "sessions": {name: {solver: {"status", "metrics", "runtime_s", "x_realtime",
    "warnings", "no_truth"}}}, "methods": {solver: {"metrics": mean over the sessions it scored (the keys ``run --json``
    prints), "x_realtime", "sessions_scored", "sessions_failed", "sessions_not_scored", "sessions_suspect"}}}``. A session
    without truth gets ``metrics: {}`` and ``no_truth`` (the estimate's own sigma, the fraction of samples it covers); a
    solver that fails is a row with its error; a run whose headline metric is NaN is ``not_scored`` with the reason, and a
    ``suspect`` run (its own diagnostics) stays out of the means unless ``include_suspect``: neither is averaged silently.
    ``in_sample``: the sessions that are recordings (or simulated seeds) a setting on main was chosen on, with the choices
    (``provenance.choices_that_saw``): their figures are in-sample.
    ``traces``: a dict to fill with each session's ``results.Trace`` per solver that ran (what ``report --html`` draws).
    ``workers``/``scheduler``: sessions in parallel (processes, or Dask: ``local`` or ``tcp://host:port``), gathered in
    the order of the sessions. A session given as its folder (``named_session_dirs``) is read by the worker that runs it, so
    reading runs in parallel too and this process holds no recording; one that cannot be read is a failed row per solver
    with the reader's error (its file and line), and the report goes on.
    ``cache``: a folder where each session folder's rows are kept by its content, the solver and the settings
    (``run_key``), so that a report run again (killed, or over a folder that grew) runs only what it does not hold: a
    session whose files or settings changed, a solver not run on it yet, a run that failed.
    """

    from ..progress import progress

    preset = PRESETS[system]
    names = list(solvers or preset.solvers)
    unknown = [s for s in names if s not in preset.solvers]
    if unknown:
        raise SessionError(f"--solvers {','.join(unknown)}: {system} has {', '.join(preset.solvers)}")
    for name, session in sessions:
        kind = session.system if isinstance(session, Session) else _declared_system(session)
        if kind is not None and kind != system:
            raise SessionError(f"{name}: a {kind} session, not {system} (report one system at a time)")
    from .cluster import completed, costliest_first

    store = ReportCache(Path(cache), sessions, names, traces is not None) if cache is not None else None
    jobs = [(name, session, store.missing(name) if store else tuple(names), traces is not None) for name, session in sessions]
    jobs = list(costliest_first([job for job in jobs if job[2]], lambda job: _size(job[1]), workers, scheduler))
    finished: dict[str, tuple[dict[str, dict[str, Any]], list[Any], float, dict[str, str]]] = {}
    for (name, _, _, _), future in progress(completed(_report_one_session, jobs, workers, scheduler), len(jobs), f"report {system}",
                                            enabled=None if show_progress else False):
        finished[name] = future.result()
        if store:
            store.keep(name, *finished[name])
    if store:
        finished = {name: store.merged(name, finished.get(name)) for name, _ in sessions}
    rows = {name: finished[name][0] for name, _ in sessions}  # in the order of the sessions, however they finished
    if traces is not None:
        traces.update({name: finished[name][1] for name, _ in sessions})
    methods: dict[str, dict[str, Any]] = {}
    for solver in names:
        done = [rows[name][solver] for name, _ in sessions if rows[name][solver]["status"] == "ok"]
        counted = [r for r in done if r["metrics"] and "not_scored" not in r and (include_suspect or "suspect" not in r)]
        scored = [flatten(r["metrics"]) for r in counted]
        keys = sorted(set().union(*[set(r) for r in scored])) if scored else []
        means = {k: float(np.mean([r[k] for r in scored if k in r])) for k in keys}
        data_s = sum(finished[name][2] for name, _ in sessions if rows[name][solver]["status"] == "ok")
        seconds = sum(r["runtime_s"] for r in done)
        methods[solver] = {"metrics": unflatten(means), "x_realtime": data_s / seconds if seconds > 0 else float("nan"),
                           "sessions_scored": len(scored),
                           "sessions_failed": sum(rows[name][solver]["status"] == "failed" for name, _ in sessions),
                           "sessions_not_applicable": sum(rows[name][solver]["status"] == "n/a" for name, _ in sessions),
                           "sessions_not_scored": sum("not_scored" in r for r in done),
                           "sessions_suspect": sum("suspect" in r for r in done), "suspect_in_means": include_suspect}
    datasets = sorted({finished[name][3].get("dataset", "") for name, _ in sessions} - {""})
    saw = {name: choices_that_saw(system, finished[name][3]) for name, _ in sessions}
    return {"system": system, "solvers": names, "metric_keys": list(preset.metric_keys), "sessions": rows, "methods": methods,
            "datasets": datasets, "in_sample": {name: what for name, what in saw.items() if what}}


class ReportCache:
    """``report_sessions``' rows kept in a folder (``report.jsonl``, a row per line; each trace a page draws beside it in
    ``traces/``), each under its session folder's content, solver and settings (``run_key``). A row that failed is not
    kept (it runs again); a line torn by a kill is skipped (that run is made again)."""

    def __init__(self, folder: Path, sessions: Sequence[tuple[str, Session | Path]], solvers: Sequence[str], want_traces: bool):
        self.folder, self.solvers, self.want_traces = folder, tuple(solvers), want_traces
        self.log = folder / "report.jsonl"
        settings = settings_digest()
        contents = {name: session_digest(session) for name, session in sessions if isinstance(session, Path)}
        self.keys = {(name, solver): run_key(content, solver, settings) for name, content in contents.items() for solver in solvers}
        """The key of each (session, solver) that can be kept: in-memory sessions (simulated) have none."""
        self.held = {entry["key"]: entry for entry in read_rows(self.log)
                     if not want_traces or entry["row"]["status"] != "ok" or self._trace_path(entry["key"]).exists()}

    def _trace_path(self, key: str) -> Path:
        return self.folder / "traces" / f"{key}.pkl"

    def missing(self, name: str) -> tuple[str, ...]:
        """The solvers to run on session ``name``: those whose row is not held."""
        return tuple(solver for solver in self.solvers if self.keys.get((name, solver)) not in self.held)

    def keep(self, name: str, rows: dict[str, dict[str, Any]], traces: list[Any], duration_s: float, meta: dict[str, str]) -> None:
        """Append the rows a worker made (the failed ones left out) and their traces."""
        import pickle

        by_solver = {trace.solver: trace for trace in traces}
        entries = []
        for solver, row in rows.items():
            key = self.keys.get((name, solver))
            if key is None or row["status"] == "failed":
                continue
            if solver in by_solver:
                self._trace_path(key).parent.mkdir(parents=True, exist_ok=True)
                self._trace_path(key).write_bytes(pickle.dumps(by_solver[solver]))
            entries.append({"key": key, "row": row, "duration_s": duration_s, "meta": meta})
            self.held[key] = entries[-1]
        append_rows(self.log, entries)

    def merged(self, name: str, ran: tuple[dict[str, dict[str, Any]], list[Any], float, dict[str, str]] | None
               ) -> tuple[dict[str, dict[str, Any]], list[Any], float, dict[str, str]]:
        """Session ``name``'s result as ``_report_one_session`` gives it: the rows just made (``ran``) and the held ones, in
        the solvers' order."""
        import pickle

        rows, traces = dict(ran[0]) if ran else {}, {trace.solver: trace for trace in ran[1]} if ran else {}
        duration_s, meta = (ran[2], ran[3]) if ran else (0.0, {})
        for solver in self.solvers:
            entry = self.held.get(self.keys.get((name, solver), ""))
            if solver not in rows and entry is not None:
                rows[solver] = entry["row"]
                duration_s, meta = entry["duration_s"], entry["meta"]
                if self.want_traces and entry["row"]["status"] == "ok":
                    traces[solver] = pickle.loads(self._trace_path(entry["key"]).read_bytes())
        return ({solver: rows[solver] for solver in self.solvers}, [traces[s] for s in self.solvers if s in traces], duration_s, meta)


def _declared_system(directory: Path) -> str | None:
    """The system a session folder declares (its session.toml alone), or None when that cannot be read (the worker that
    reads the session says why)."""
    from ..session import read_session_spec

    try:
        return read_session_spec(directory)[2]
    except SessionError:
        return None


def _size(session: Session | Path) -> float:
    """How long a session takes to run, for ordering: its duration, or its files' bytes when not read yet."""
    if isinstance(session, Session):
        return session.duration_s
    from .cluster import path_bytes

    return path_bytes(session)


def _report_one_session(job: tuple[str, Session | Path, tuple[str, ...], bool]) -> tuple[dict[str, dict[str, Any]], list[Any], float, dict[str, str]]:
    """Worker: every solver on one session (read here when given as a folder), each through ``solve_session`` with its
    warnings; a solver that fails or cannot take the session is a row saying why, and so is every solver of a session that
    cannot be read. Returns the rows by solver, when asked the traces a page draws, the session's duration (s) and its
    ``[session]`` dataset, trial, subject and simulated seed (those it declares)."""
    import warnings

    from ..results import trace_of

    name, source, names, want_traces = job
    try:
        session = source if isinstance(source, Session) else load_session(source)
    except (SessionError, OSError, ValueError) as exc:  # one unreadable session is a row per solver, the report goes on
        return {solver: {"status": "failed", "error": f"{type(exc).__name__}: {exc}", "metrics": {}} for solver in names}, [], 0.0, {}
    preset = PRESETS[session.system]
    rows: dict[str, dict[str, Any]] = {}
    traces: list[Any] = []
    for solver in names:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                outcome = solve_session(session, solver)
            except NotApplicableError as exc:  # the session lacks what this solver needs: said, not a failure
                rows[solver] = {"status": "n/a", "error": str(exc).split(": ", 1)[-1], "metrics": {}}
                continue
            except Exception as exc:  # noqa: BLE001 - one solver failing on one session is a row, the report goes on
                rows[solver] = {"status": "failed", "error": f"{type(exc).__name__}: {exc}", "metrics": {}}
                continue
        runtime = float(outcome.estimate.runtime_s)
        said = sorted({str(w.message) for w in caught})
        row = {
            "status": "ok", "metrics": outcome.metrics or {}, "runtime_s": runtime,
            "x_realtime": session.duration_s / runtime if runtime > 0 else float("inf"),
            "warnings": said,
            **({} if outcome.metrics else {"no_truth": _without_truth(outcome)}),
            **({"suspect": outcome.suspect} if outcome.suspect else {}),
        }
        if want_traces:
            traces.append(trace_of(solver, outcome.estimate, session.truth))
        unscored = not_scored_reason(preset, outcome.metrics, said)
        if unscored:
            row["not_scored"] = unscored
        rows[solver] = row
    return rows, traces, session.duration_s, {k: str(v) for k, v in session.meta.get("session", {}).items() if k in ("dataset", "trial", "subject", "seed")}


def not_scored_reason(preset: Preset, metrics: dict[str, Any] | None, said: Sequence[str]) -> str | None:
    """Why a run with truth has no figure to average: a headline metric that is NaN (with the run's first warning, which
    usually says why: truth that does not overlap, an Euler filter out of its domain). None when every one is a number."""
    if not metrics:
        return None
    flat = flatten(metrics)
    missing = [k for k in preset.metric_keys if k in flat and not np.isfinite(flat[k])]
    if not missing:
        return None
    why = str(metrics.get("excluded", "") or metrics.get("truth_samples_missing_why", "")) or (said[0] if said else "")
    return f"{', '.join(missing)} not a number" + (f": {why}" if why else "")


def load_sessions(paths: Iterable[str | Path]) -> list[tuple[str, Session]]:
    """Sessions from directories (each a session, or a folder of them at any depth), named by their folder (where two
    share a name: by their path below the folder they share, ``unique_names``)."""
    return [(name, load_session(p)) for name, p in named_session_dirs(paths)]


def named_session_dirs(paths: Iterable[str | Path]) -> list[tuple[str, Path]]:
    """The session directories ``load_sessions`` would read, with the same names, unread (``report_sessions`` has its
    workers read them)."""
    dirs = session_dirs(paths)
    return list(zip(unique_names(dirs), dirs, strict=True))


def simulated_sessions(system: str, seeds: Sequence[int], duration_s: float | None = None, **options: Any) -> list[tuple[str, Session]]:
    """The system's simulator at each seed, named ``seed<N>``."""
    from ..scenarios import SIMULATORS

    return [(f"seed{seed}", SIMULATORS[system].simulate(seed, duration_s, **options)) for seed in seeds]


def parse_seeds(text: str) -> list[int]:
    """``0-9`` or ``0,3,5`` or ``0-4,8`` -> list of seeds."""
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        if "-" in part[1:]:
            lo, hi = part.split("-", 1) if not part.startswith("-") else (part, part)
            seeds.extend(range(int(lo), int(hi) + 1))
        else:
            seeds.append(int(part))
    if not seeds:
        raise argparse.ArgumentTypeError(f"no seeds in {text!r} (use e.g. 0-9 or 0,2,5)")
    return seeds
