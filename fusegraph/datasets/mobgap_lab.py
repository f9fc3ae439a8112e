"""Mobilise-D laboratory recordings as ``mobgap`` ships them (``fusegraph import mobgap DIR``): a lower-back IMU with the
INDIP reference system's walking bouts, initial contacts, stride lengths and speeds.

Read through ``mobgap.data.GenericMobilisedDataset`` (the package's own reader of this layout: ``lab/<cohort>/<participant>/
data.mat``, ``data.TimeMeasure1.<Test>.<Trial>``). One walking session per test and trial: ``accel`` (m/s^2) and ``gyro``
(rad/s; the file's deg/s converted) at 100 Hz in the sensor's own axes (the walking front end finds gravity and the
direction of travel from the data); ``[person]`` the participant's height and sensor height (``infoForAlgo.mat``: a
person's height may calibrate a model); ``[truth_extra]`` the reference's bouts (``bouts_s``), each bout's mean stride
length and walking speed, and its initial contacts, for scoring only. Times are seconds from the trial's first sample.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..session import KIND_COLUMNS, Session, SessionError, Stream

DEFAULT_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "mobgap"
"""Where the shared recordings are (``../shared/data/mobgap`` beside the repository)."""


def data_files(directory: str | Path) -> list[Path]:
    """Every ``data.mat`` under ``directory``, participant folders that are symbolic links included (``Path.rglob``
    does not follow them before Python 3.13)."""
    import glob

    return sorted(Path(p) for p in glob.glob(str(Path(glob.escape(str(directory))) / "**" / "data.mat"), recursive=True))


def mobgap_dataset(directory: str | Path = DEFAULT_DIR) -> Any:
    """mobgap's dataset over every ``data.mat`` under ``directory`` (laboratory, INDIP reference, bout level)."""
    with warnings.catch_warnings():  # mobgap's import and loader warn about its pickled models and its cache: not the user's concern
        warnings.simplefilter("ignore")
        from mobgap.data import GenericMobilisedDataset

    directory = Path(directory)
    paths = data_files(directory)
    if not paths:
        raise SessionError(f"{directory}: no data.mat below it (a Mobilise-D layout: lab/<cohort>/<participant>/data.mat)")
    return GenericMobilisedDataset(paths, test_level_names=["time_measure", "test", "trial"], parent_folders_as_metadata=["cohort", "participant_id"],
                                   measurement_condition="laboratory", reference_system="INDIP", reference_para_level="wb")


def trial_name(datapoint: Any) -> str:
    """``HA_001_Test5_Trial1``: cohort, participant, test, trial."""
    row = datapoint.group_label
    return f"{row.cohort}_{row.participant_id}_{row.test}_{row.trial}"


def mobgap_session(datapoint: Any) -> Session:
    """One test and trial as a walking session (see the module docstring)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # mobgap's loader warns about its cache and scikit-learn's persistence
        data = datapoint.data_ss
        fs = float(datapoint.sampling_rate_hz)
        reference = datapoint.reference_parameters_
        person = datapoint.participant_metadata
    t = np.arange(len(data)) / fs
    accel = data[["acc_x", "acc_y", "acc_z"]].to_numpy(dtype=float)
    gyro = np.deg2rad(data[["gyr_x", "gyr_y", "gyr_z"]].to_numpy(dtype=float))
    median_g = float(np.median(np.linalg.norm(accel, axis=1)))
    if not 7.0 < median_g < 13.0:
        raise SessionError(f"{trial_name(datapoint)}: median |acc| = {median_g:.3g}, not about 9.81 m/s^2 (mobgap's reader gives m/s^2)")
    bouts = reference.wb_list
    contacts = reference.ic_list
    truth_extra: dict[str, Any] = {
        "bouts_s": [[float(a) / fs, float(b) / fs] for a, b in zip(bouts["start"], bouts["end"], strict=True)],
        "bout_stride_length_m": [float(v) for v in bouts["avg_stride_length_m"]],
        "bout_walking_speed_m_s": [float(v) for v in bouts["avg_walking_speed_mps"]],
        "initial_contacts_s": [float(v) / fs for v in contacts["ic"]],
    }
    truth_extra = {k: [x for x in v if not (isinstance(x, float) and math.isnan(x))] if k == "initial_contacts_s" else v for k, v in truth_extra.items()}
    name = trial_name(datapoint)
    row = datapoint.group_label
    header = {
        "session": {"system": "walking", "dataset": "Mobilise-D (mobgap example data)", "trial": name, "subject": f"{row.cohort}/{row.participant_id}",
                    "placement": "lower back", "description": f"{row.test} {row.trial}: lower-back IMU at {fs:g} Hz; INDIP reference in [truth_extra]"},
        "person": {"height_m": float(person["height_m"]), "sensor_height_m": float(person["sensor_height_m"])},
        "truth_extra": truth_extra,
    }
    streams = {"accel": Stream("accel", "accel", t, accel, KIND_COLUMNS["accel"], 0.0, {"frame": "sensor", "rate_hz": fs}),
               "gyro": Stream("gyro", "gyro", t.copy(), gyro, KIND_COLUMNS["gyro"], 0.0, {"frame": "sensor", "rate_hz": fs})}
    return Session("walking", streams, None, header)


def mobgap_sessions(directory: str | Path = DEFAULT_DIR) -> list[tuple[str, Session]]:
    """Every test and trial under ``directory`` as a walking session, named ``cohort_participant_test_trial``."""
    dataset = mobgap_dataset(directory)
    with warnings.catch_warnings():  # the loader's cache warning, at the first datapoint
        warnings.simplefilter("ignore")
        return [(trial_name(datapoint), mobgap_session(datapoint)) for datapoint in dataset]
