"""The public datasets the importers read: where a user gets each, under which licence, the folder layout the importer
expects and the command that imports it (``fusegraph datasets``); and what a folder holds of one (``datasets check``).

Nothing is downloaded: the user fetches a dataset from its source and points the importer at the folder as published.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class LayoutPart:
    """One kind of file an importer reads in a dataset's folder."""

    pattern: str
    """A glob relative to the folder (``*.mat``, ``*/accelerometer.csv``)."""
    meaning: str
    """What the file holds."""
    required: bool = True
    """Whether the importer needs it (an optional part adds truth or metadata)."""


@dataclass(frozen=True)
class Dataset:
    """A public dataset an importer reads."""

    name: str
    """The importer's name (``fusegraph import <name>``)."""
    title: str
    """What it is, in a line."""
    citation: str
    """The paper or source to cite."""
    source: str
    """Where a user gets it: a URL or DOI."""
    licence: str
    """Its licence, as the source states it."""
    system: str
    """The system its sessions belong to (``attitude9``, ``walking``, ...)."""
    layout: tuple[LayoutPart, ...]
    """The files the importer reads, relative to the folder a user downloads."""
    example: str
    """The import command."""
    notes: str = ""
    """What else a user should know (units, axes, a folder or one recording)."""


DATASETS: tuple[Dataset, ...] = (
    Dataset("broad", "BROAD: IMU orientation with optical ground truth, 39 trials (rotation, translation, disturbances)",
            "D. Laidig, M. Caruso, A. Cereatti, T. Seel, \"BROAD - A Benchmark for Robust Inertial Orientation Estimation\", Data 6(7):72, 2021",
            "https://github.com/dlaidig/broad (folder data_mat/)", "CC BY 4.0 (data)", "attitude9",
            (LayoutPart("*.mat", "one trial per file: imu_gyr (rad/s), imu_acc (m/s^2), imu_mag (uT), opt_quat (w, x, y, z, sensor to ENU), movement"),),
            "fusegraph import broad data_mat --out sessions/broad   (--system head: the motion as head sessions; --system gaze: "
            "the head of a simulated eye, scored against the eye's world ray)",
            "a folder of trials or one .mat file"),
    Dataset("uwb", "LIAS UWB: three tags on a rigid trolley, eight anchors, motion capture (fast, medium, slow runs)",
            "H. Jiang et al., \"Efficient Planar Pose Estimation via UWB Measurements\", ICRA 2023",
            "https://github.com/LIAS-CUHKSZ/Efficient-Pose-Estimation-via-UWB-measurements (Planar_Dataset/)", "MIT", "ultrasonic",
            (LayoutPart("UWB_*.csv", "no header: wall-clock time, 24 ranges (m) ordered a0-t0, a0-t1, a0-t2, a1-t0, ..."),
             LayoutPart("README.md|SOURCE_README.md", "anchor coordinates and tag offsets (Markdown tables)"),
             LayoutPart("motion_capture_*.csv", "time, x, y, z, quaternion (truth)", required=False),
             LayoutPart("calibration.csv", "per anchor and tag: bias_m, slope, sigma_m (--calibration)", required=False)),
            "fusegraph import uwb Planar_Dataset/fast --out sessions/uwb",
            "one run per folder, the dataset's README.md beside it"),
    Dataset("oxford", "Oxford step counter: phone accelerometer walking recordings with counted steps",
            "Salvi et al., \"An optimised algorithm for accurate steps counting from smart-phone accelerometry\", EMBC 2018",
            "https://github.com/Oxford-step-counter/DataSet", "CC BY 4.0", "walking",
            (LayoutPart("*/accelerometer.csv", "no header: timestamp (ns), sensor type, ax, ay, az (m/s^2)"),
             LayoutPart("stats.csv", "the hand-counted steps per recording", required=False),
             LayoutPart("*/stepcounter.csv", "foot-switch insoles' contacts (a reference)", required=False)),
            "fusegraph import oxford DataSet --out sessions/oxford",
            "the dataset folder (with stats.csv) or one recording's folder"),
    Dataset("hapt", "UCI HAPT: a waist-worn phone's accelerometer and gyro with activity labels (30 users)",
            "J.-L. Reyes-Ortiz, L. Oneto, A. Sama, X. Parra, D. Anguita, \"Transition-Aware Human Activity Recognition Using "
            "Smartphones\", Neurocomputing 171:754-767, 2016",
            "https://archive.ics.uci.edu (\"Smartphone-Based Recognition of Human Activities and Postural Transitions\", v2.1)",
            "CC BY 4.0", "walking",
            (LayoutPart("acc_exp*_user*.txt", "acceleration in g, 50 Hz"), LayoutPart("gyro_exp*_user*.txt", "rate in rad/s, 50 Hz"),
             LayoutPart("labels.txt", "experiment, user, activity, first and last sample"),
             LayoutPart("activity_labels.txt", "activity names", required=False)),
            "fusegraph import hapt RawData --out sessions/hapt",
            "the RawData folder of the download"),
    Dataset("mobgap", "Mobilise-D lab recordings: a lower-back IMU with the INDIP reference's walking bouts, steps and strides",
            "Mico-Amigo et al., J NeuroEngineering Rehabil 2023; Kirk et al., Sci Rep 2024 (mobgap example data)",
            "https://github.com/mobilise-d/mobgap (example_data/data/lab)", "Apache-2.0", "walking",
            (LayoutPart("**/data.mat", "SU.LowerBack Acc (g), Gyr (deg/s), and Standards.INDIP (the reference)"),
             LayoutPart("**/infoForAlgo.mat", "participant and sensor height", required=False)),
            "fusegraph import mobgap lab --out sessions/mobgap",
            "the lab folder (cohorts and participants below it) or one participant's folder"),
    Dataset("tobii", "Tobii Pro Glasses 3 export: head IMU (gyro, accelerometer, magnetometer) and gaze in the scene camera",
            "EyeDentify3d example data (E. Charbonneau et al.)", "https://github.com/EveCharbie/EyeDentify3d (examples/data/)", "MIT", "gaze",
            (LayoutPart("imudata.gz", "gyroscope (deg/s), accelerometer (m/s^2), magnetometer (uT), JSON lines"),
             LayoutPart("gazedata.gz", "gaze in scene-camera pixels (normalised) and 3D, JSON lines"),
             LayoutPart("eventdata.gz", "sync events", required=False)),
            "fusegraph import tobii recording --out sessions/tobii",
            "one export folder"),
    Dataset("pupil", "Pupil Labs Pupil Invisible or Neon export: IMU and gaze with the Cloud's fixations and blinks",
            "EyeDentify3d example data (E. Charbonneau et al.)", "https://github.com/EveCharbie/EyeDentify3d (examples/data/)", "MIT", "gaze",
            (LayoutPart("imu.csv", "timestamp [ns], gyro (deg/s), acceleration (g), the device's roll/pitch (or quaternion: Neon)"),
             LayoutPart("gaze.csv", "timestamp [ns], gaze x/y [px], worn, fixation id, blink id"),
             LayoutPart("blinks.csv", "blinks", required=False), LayoutPart("info.json", "the device", required=False)),
            "fusegraph import pupil recording --out sessions/pupil   (a folder of exports: one session each)",
            "one export folder, or a folder of them"),
    Dataset("plaza", "Plaza1/Plaza2: a vehicle with wheel odometry and range-only radio beacons, with ground truth (shipped with gtsam)",
            "Djugash, Hamner, Roth, \"Navigating with Ranging Radios: Five Data Sets with Ground Truth\", 2009",
            "gtsam.findExampleDataFile('Plaza1_.mat') (in the gtsam wheel)", "BSD (gtsam)", "walking",
            (), "fusegraph import plaza Plaza2 --out sessions/plaza", "no folder: the name of the file gtsam ships"),
)
"""Every dataset an importer reads."""


def dataset(name: str) -> Dataset:
    """The catalogue entry of an importer."""
    for entry in DATASETS:
        if entry.name == name:
            return entry
    raise KeyError(f"no dataset {name!r} (known: {', '.join(d.name for d in DATASETS)})")


def _matches(folder: Path, pattern: str) -> list[Path]:
    return sorted({p for alternative in pattern.split("|") for p in folder.glob(alternative)})


def check_folder(folder: Path) -> list[dict[str, object]]:
    """What a folder holds of each dataset it looks like: per dataset with a required part present, every part's files
    found (a count) and the parts missing. Best match first; empty when it holds none of them."""
    found = []
    for entry in DATASETS:
        parts = [(part, _matches(folder, part.pattern)) for part in entry.layout]
        if not parts or not any(files for part, files in parts if part.required):
            continue
        missing = [part.pattern for part, files in parts if part.required and not files]
        found.append({"dataset": entry.name, "complete": not missing, "missing": missing,
                      "parts": {part.pattern: len(files) for part, files in parts}, "import": entry.example})
    found.sort(key=lambda row: (not row["complete"], len(row["missing"])))  # type: ignore[arg-type]
    return found
