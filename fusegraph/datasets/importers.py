"""``fusegraph import FORMAT SOURCE --out DIR``: real recordings written as session directories.

A session written here runs through ``run``, ``view`` and ``ablate`` like a simulated one. Formats:

* ``broad``: a BROAD trial (.mat) or a folder of them -> one attitude9 session per trial (gyro,
  accel, mag at the IMU rate, the movement flag; the optical attitude as truth); with ``system="head"`` one
  head session per trial instead (the recorded gyro, the optical attitude as a late 50 Hz tracker with the
  realistic profile's errors: ``datasets.broad_head``).
* ``oxford``: an Oxford step recording folder (``accelerometer.csv``) or the dataset folder (with
  ``stats.csv``) -> walking sessions with the phone's accelerometer only and the hand-counted steps in
  ``[truth_extra] steps``: ``run --solver steps`` counts them (there is no gyro for a trajectory).
* ``plaza``: ``Plaza1`` or ``Plaza2`` (the range + odometry runs that ship with gtsam; SOURCE is the name)
  -> a walking session driven by wheel odometry: ``odometry`` (kind wheel_odometry), ``ranges`` (kind
  beacon_ranges: Huber, a bias per beacon), the ground truth (x, y, 0) as truth. No start pose is
  written: it is found from the first minute of odometry and ranges.
* ``uwb``: a UWB run's folder (``UWB_<run>.csv`` and ``motion_capture_<run>.csv``) -> one ultrasonic
  session: the anchors as receivers, every tag's range per epoch UNLABELLED (the tag labels become
  the scoring-only ``truth_label`` column; ``labelled`` keeps them as a ``tag`` column), the tags as one
  rigid planar body (``tag_offsets_m``, ``planar``), the tags' motion-capture positions on the UWB clock as
  truth (a folder without ``motion_capture_<run>.csv``: no truth, the run is tracked and not scored). Times are
  seconds from the first UWB epoch.
* ``hapt``: UCI HAPT's raw folder (``acc_expXX_userYY.txt``, ``gyro_...``, ``labels.txt``) -> one walking session per
  experiment (waist accel and gyro, the hand labels as the scoring-only ``activity`` stream; ``datasets.hapt``).
* ``mobgap``: Mobilise-D laboratory recordings in mobgap's layout (``lab/<cohort>/<participant>/data.mat``) -> one walking
  session per test and trial (lower-back accel and gyro; the INDIP reference's bouts, steps, stride lengths and speeds in
  ``[truth_extra]``; ``datasets.mobgap_lab``).
* ``tobii``: a Tobii Pro Glasses 3 export folder (``imudata.gz``, ``gazedata.gz``) -> one gaze session
  (gyro in rad/s and head axes, accel, mag on the IMU times, gaze pixels; no wall: ``target_depth_m``);
  no truth (``bench gaze-recorded`` scores fixations). See ``datasets.tobii``.
* ``pupil``: a Pupil Labs Pupil Invisible or Neon export folder (``imu.csv``, ``gaze.csv``) -> one gaze session (gyro
  in rad/s and head axes, accel in m/s^2, no magnetometer, the gaze rays as pinhole pixels, the device's fixations as
  the scoring-only ``fixation`` stream, a Neon's own attitude as the scoring-only ``device_attitude``). See
  ``datasets.pupil``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..session import KIND_COLUMNS, Session, SessionError, Stream, save_session


def import_recording(fmt: str, source: str | Path, out: str | Path, labelled: bool = False, calibration: Path | None = None,
                     system: str | None = None, device: str | None = None) -> list[Path]:
    """Write the recording at ``source`` as session directories under ``out``; returns them. ``system``: whose sessions
    a dataset that serves two systems becomes (BROAD: ``attitude9``, the default, or ``head``). ``device``: pupil only,
    which Pupil Labs device made the export (``invisible``/``neon``; default: what the export says)."""
    if device is not None and fmt != "pupil":
        raise SessionError(f"--device {device}: for import pupil only")
    if system is not None and not (fmt == "broad" and system in ("head", "attitude9", "gaze")):
        raise SessionError(f"--system {system}: import {fmt} writes {'head, gaze or attitude9' if fmt == 'broad' else 'its own system'}'s sessions")
    if fmt == "plaza":
        return [save_session(plaza_session(str(source)), Path(out))]
    source, out = Path(source), Path(out)
    if not source.exists():
        raise SessionError(f"{source}: not found")
    if fmt == "broad":
        found = broad_sessions(source, system=system or "attitude9")
        if source.is_file():
            return [save_session(found[0][1], out)]
        return [save_session(session, out / name) for name, session in found]
    if fmt == "uwb":
        runs = recordings_below(source, "UWB_*.csv")
        return [save_session(uwb_session(run, labelled, calibration), out if run == source else out / run.name) for run in runs]
    if fmt == "oxford":
        found = oxford_sessions(source)
        if (source / "stats.csv").is_file():
            return [save_session(session, out / name) for name, session in found]
        return [save_session(found[0][1], out)]
    if fmt == "pupil":
        exports = recordings_below(source, "imu.csv")
        return [save_session(pupil_session(export, device), out if export == source else out / export.name) for export in exports]
    if fmt == "tobii":
        exports = recordings_below(source, "imudata.gz")
        return [save_session(tobii_session(export), out if export == source else out / export.name) for export in exports]
    if fmt == "hapt":
        from .hapt import hapt_sessions

        return [save_session(session, out / name) for name, session in hapt_sessions(source)]
    if fmt == "mobgap":
        from .mobgap_lab import mobgap_sessions

        return [save_session(session, out / name) for name, session in mobgap_sessions(source)]
    raise SessionError(f"unknown format {fmt!r} (known: broad, hapt, mobgap, oxford, plaza, pupil, tobii, uwb)")


def recordings_below(source: Path, marker: str) -> list[Path]:
    """One recording's folder (it holds ``marker``) as itself, or a dataset folder's recordings: every folder below it that
    holds one (at any depth), each imported into a folder of its own name."""
    if not source.is_dir() or any(source.glob(marker)):
        return [source]
    found = sorted({p.parent for p in source.rglob(marker)})
    if not found:
        raise SessionError(f"{source}: no {marker} here or below (one recording's folder, or a folder of them)")
    return found


def broad_sessions(source: Path, trials: Sequence[str] = (), system: str = "attitude9") -> list[tuple[str, Session]]:
    """BROAD trials as ``import broad`` writes them (a trial file, or every ``*.mat`` of a folder whose name starts with one
    of ``trials``), in memory, named by trial: attitude9 sessions, with ``system="head"`` head sessions
    (``datasets.broad_head``), with ``system="gaze"`` gaze sessions of a simulated eye (``datasets.broad_gaze``)."""
    from .broad import load_broad, trial_paths
    from .broad_head import head_session_from_broad

    paths = [source] if source.is_file() else [p for p in trial_paths(source) if not trials or any(p.stem.startswith(x) for x in trials)]
    if not paths:
        raise SessionError(f"{source}: no BROAD trial (*.mat)" + (f" starting with {', '.join(trials)}" if trials else ""))
    if system == "gaze":
        from .broad_gaze import gaze_session_from_broad

        return [(p.stem, _with_gaze_offset(_portable(gaze_session_from_broad(p)))) for p in paths]
    load = head_session_from_broad if system == "head" else load_broad
    return [(p.stem, _portable(load(p))) for p in paths]


def plaza_session(name: str) -> Session:
    """A Plaza run as a wheel-odometry walking session (see the module docstring)."""
    from .plaza import BEACON_RANGES, RECORDINGS, WHEEL_ODOMETRY, beacon_table, load_plaza

    if name not in RECORDINGS:
        raise SessionError(f"plaza: SOURCE is the recording's name, one of {', '.join(RECORDINGS)} (got {name!r})")
    rec = load_plaza(name)
    t = rec.truth_t
    odometry = np.column_stack([np.r_[0.0, rec.distance_m], np.r_[0.0, rec.dyaw_rad]])
    meta = dict(WHEEL_ODOMETRY)
    beacons, rows = beacon_table(rec)
    order = np.argsort(rec.range_t, kind="stable")
    ranges = Stream("ranges", "beacon_ranges", rec.range_t[order], np.column_stack([rows[order], rec.range_m[order]]), KIND_COLUMNS["beacon_ranges"], 0.0,
                    {"beacons_m": beacons.tolist(), **BEACON_RANGES})
    truth = Stream("truth", "position", t, np.column_stack([rec.truth_xy, np.zeros(len(t))]), KIND_COLUMNS["position"])
    header = {"session": {"system": "walking", "dataset": "Plaza", "trial": name, "world_frame": "the dataset's local frame (m)",
                          "description": "vehicle: wheel odometry and ranges to identified beacons; the start is found from the ranges"}}
    return Session("walking", {"odometry": Stream("odometry", "wheel_odometry", t, odometry, KIND_COLUMNS["wheel_odometry"], 0.0, meta),
                               "ranges": ranges}, truth, header)


def oxford_sessions(source: Path) -> list[tuple[str, Session]]:
    """Oxford recordings as ``import oxford`` writes them (the dataset folder, with ``stats.csv``, or one recording's),
    in memory, named by recording."""
    from .steps_oxford import recordings

    if (source / "stats.csv").is_file():
        return [(name, oxford_session(source, name)) for name in recordings(source)]
    return [(source.name, oxford_session(source.parent, source.name))]


def oxford_session(directory: Path, name: str) -> Session:
    """One Oxford step recording as an accelerometer-only walking session (see the module docstring)."""
    from .steps_oxford import load_recording

    try:
        rec = load_recording(directory, name)
    except (OSError, ValueError) as err:
        raise SessionError(f"{directory / name}: {err}") from None
    rate = float(1.0 / np.median(np.diff(rec.t)))
    accel = Stream("accel", "accel", rec.t, rec.accel_m_s2, KIND_COLUMNS["accel"], 0.0, {"frame": "phone", "rate_hz": round(rate, 1)})
    truth_extra: dict[str, object] = {"steps": rec.true_steps}
    if rec.foot_switch_steps is not None:
        truth_extra["foot_switch_steps"] = rec.foot_switch_steps
    header = {"session": {"system": "walking", "dataset": "Oxford step counting", "trial": name, "placement": rec.position,
                          "description": f"phone carried in the {rec.position}; accelerometer only"},
              "truth_extra": truth_extra}
    return Session("walking", {"accel": accel}, None, header)


EARTH_FIELD_UT = (25.0, 65.0)
"""The Earth's field strength anywhere on its surface, uT (the World Magnetic Model's range)."""


def tobii_session(directory: Path) -> Session:
    """A Tobii Pro Glasses 3 export as a gaze session, with what the data alone tells declared for every method:

    * the gaze stream's delay behind the IMU (``time_offset_s``, ``frontends.gaze_timing.gaze_time_offset``: the gaze
      and the gyro, no method's estimate), which every solver applies;
    * whether the magnetometer can serve: a median field strength outside the Earth's (25-65 uT) with no calibration
      recording is a field of the glasses themselves that the recording cannot calibrate: ``use_mag = false``, the
      reason in the description (the shipped recording reads 110-131 uT).
    """
    from dataclasses import replace

    from .tobii import load_tobii

    session = _with_gaze_offset(_portable(load_tobii(directory)))
    header = dict(session.meta["session"])
    field = float(np.median(np.linalg.norm(session.stream("mag").values, axis=1)))
    if not EARTH_FIELD_UT[0] <= field <= EARTH_FIELD_UT[1] and "mag_cal" not in session.streams:
        header["use_mag"] = False
        header["description"] = (f"{header.get('description', '')}; the magnetometer reads {field:.0f} uT (the Earth's field is "
                                 f"{EARTH_FIELD_UT[0]:g}-{EARTH_FIELD_UT[1]:g}) with no calibration recording: not used (use_mag = false)")
    return replace(session, meta={**session.meta, "session": header})


def pupil_session(directory: Path, device: str | None = None) -> Session:
    """A Pupil Invisible or Neon export as a gaze session (``datasets.pupil``; ``device`` overrides what the export says
    of itself), the gaze stream's delay behind the IMU declared as for the Tobii (``time_offset_s``, from the gaze and the
    gyro alone). It has no magnetometer (``use_mag = false``)."""
    from .pupil import load_pupil

    return _with_gaze_offset(_portable(load_pupil(directory, device)))


def _with_gaze_offset(session: Session) -> Session:
    """The gaze stream with its delay behind the IMU declared (``frontends.gaze_timing.gaze_time_offset``), which every
    gaze solver applies."""
    import warnings
    from dataclasses import replace

    from ..frontends.gaze_timing import HEAD_MIN_DEG_S, OFFSET_MIN_SAMPLES, find_time_offset
    from ..session import SessionWarning
    from ..systems.gaze import from_session

    found = find_time_offset(from_session(session))
    offset, sigma = found.offset_s, found.sigma_s
    if not found.told:
        warnings.warn(f"gaze: the head turned faster than {HEAD_MIN_DEG_S:g} deg/s in fewer than {OFFSET_MIN_SAMPLES} gaze samples: the gaze-to-IMU "
                      "delay cannot be told from this recording; none is applied (declare time_offset_s on the gaze stream if the "
                      "device's documentation gives one)", SessionWarning, stacklevel=3)
    elif found.at_edge:
        warnings.warn(f"gaze: the gaze-to-IMU delay found, {offset:.3f} s, lies at the search's edge (+-{found.search_s:g} s): the gaze and "
                      "IMU stamps may not share a clock; check the export's timestamps", SessionWarning, stacklevel=3)
    gaze = session.stream("gaze")
    return replace(session, streams={**session.streams, "gaze": replace(gaze, meta={**gaze.meta, "time_offset_s": offset, "time_offset_sigma_s": sigma})})


def _portable(session: Session) -> Session:
    """Without the loader's path (the session is written elsewhere)."""
    from dataclasses import replace

    return replace(session, path=None)


def uwb_session(directory: Path, labelled: bool = False, calibration: Path | None = None) -> Session:
    """A UWB run as an ultrasonic session (see the module docstring).

    The tags ride one trolley: the stream declares their offsets (``tag_offsets_m``) and that they move in a plane
    (``planar``). The motion capture is moved onto the UWB clock by the offset the raw ranges give against it
    (``clock_offset_from_ranges``: no estimate enters) and written at the UWB epochs it covers. ``labelled``: the
    ranges keep the tag each was measured to (a ``tag`` column), as a UWB system that knows its tags reports them.
    A range calibration per anchor and tag (``calibration``, else the folder's ``calibration.csv`` when there is one) is
    declared on the stream (``range_bias_m``, ``range_scale``, ``range_sigma_m``).
    """
    from .uwb_lias import clock_offset_from_ranges, load_uwb_lias, read_calibration

    rec = load_uwb_lias(directory)
    calibration = calibration or (directory / "calibration.csv" if (directory / "calibration.csv").is_file() else None)
    t0 = float(rec.t[0])
    k, a, tag = np.nonzero(np.isfinite(rec.ranges))
    table = np.column_stack([rec.t[k] - t0, a, rec.ranges[k, a, tag], tag])
    order = np.lexsort((table[:, 2], table[:, 1], table[:, 0]))
    table = table[order]
    meta = {"receivers_m": rec.anchors.tolist(), "transmitters": int(rec.ranges.shape[2]), "sigma_m": 0.1,
            "tag_offsets_m": rec.tag_offsets.tolist(), "planar": True,
            **({} if calibration is None else dict(zip(("range_bias_m", "range_scale", "range_sigma_m"),
                                                       (v.tolist() for v in read_calibration(calibration, *rec.ranges.shape[1:])), strict=True))),
            "description": "UWB anchors as receivers; " + ("each range's tag in the tag column" if labelled else "tag labels kept only as truth_label")}
    columns = (*KIND_COLUMNS["ranges"], "truth_label", "tag") if labelled else (*KIND_COLUMNS["ranges"], "truth_label")
    values = np.column_stack([table[:, 1:4], table[:, 3]]) if labelled else table[:, 1:4]
    ranges = Stream("ranges", "ranges", table[:, 0], values, columns, 0.0, meta)
    header: dict[str, dict[str, Any]] = {"session": {"system": "ultrasonic", "dataset": "UWB", "trial": Path(directory).name,
                                                     "world_frame": "motion-capture room frame"}}
    if not len(rec.mocap_t):  # a run without motion capture: tracks, nothing to score them against
        header["session"]["description"] = "no motion capture in the folder: no truth (run gives the tracks; report and bench need the truth)"
        return Session("ultrasonic", {"ranges": ranges}, None, header)
    offset = clock_offset_from_ranges(rec)
    covered = (rec.t + offset >= rec.mocap_t[0]) & (rec.t + offset <= rec.mocap_t[-1])
    positions = rec.tags_truth(rec.t[covered] + offset)
    n = positions.shape[1]
    truth = Stream("truth", "tag_position", np.repeat(rec.t[covered] - t0, n),
                   np.column_stack([np.tile(np.arange(n, dtype=float), int(covered.sum())), positions.reshape(-1, 3)]), KIND_COLUMNS["tag_position"])
    header["session"].update({"truth_clock_offset_s": offset,
                              "description": "truth: the motion capture moved onto the UWB clock by truth_clock_offset_s (found from the raw ranges)"})
    return Session("ultrasonic", {"ranges": ranges}, truth, header)
