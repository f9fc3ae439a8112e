"""Gaze sessions from BROAD trials (``fusegraph import broad DIR --system gaze``): a recorded head and a SIMULATED eye.

BROAD's IMU is the head's (gyro, accelerometer, magnetometer as recorded, ~286 Hz) and its optical attitude and position
are where the head was; an eye driven by that motion (``scenarios.eye``: fixations on world-fixed targets 1-4 m away,
saccades, imperfect counter-rotation, blinks, the tracker's offset, noise and delay) gives the gaze pixels a head-fixed
scene camera would (the Glasses 3's 1920 x 1080 at 880 px focal length, looking along the IMU's x axis). What the gaze
system reads is what an eye tracker's recording gives: the IMU, the gaze pixels, the gaze stamps' delay behind the IMU
as ``frontends.gaze_timing.find_time_offset`` finds it from those two (declared by the import, as ``import tobii`` does), and a depth to
hold each fixation point at (``TARGET_DEPTH_M``: a room's; the targets' own distances are not given). The session declares
``head_motion = "free"``: BROAD's sensor is moved by hand and translated by up to a metre (its trials' protocol, not a seated
viewer's head), so the gaze graph's head is the 9-axis system's model for that IMU (``systems.gaze.model_for``).

What only scores: the truth (stream ``truth``, kind ``position``: the eye's true world ray as a unit vector at each gaze
sample's time, in BROAD's ENU frame, which BROAD's optical attitude is given in) and the simulator's fixations (stream
``fixation``, kind ``flag``, ``role`` scoring only: its fixation id per gaze sample, 0 in a saccade).
Scored by ``report gaze``: ``gaze_error_deg``, the RMS angle between each method's world gaze ray (its head attitude turning
the tracker's ray) and the true one over the samples of the fixations (``frontends.gaze_timing.FIXATION_MIN_S`` or longer).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..factors.gaze import SceneCamera
from ..scenarios.eye import EyeConfig, simulate_eye
from ..session import KIND_COLUMNS, Session, SessionError, Stream
from .broad import load_broad
from .tobii import FOCAL_PX, HEIGHT_PX, PIXEL_SIGMA, TARGET_DEPTH_M, WIDTH_PX

EYE_SEED = 0
"""Seed of the simulated eye (fixed: every import of a trial gives the same eye), offset by the trial's number."""


def gaze_session_from_broad(path: str | Path, config: EyeConfig | None = None, seed: int = EYE_SEED) -> Session:
    """A gaze session from one BROAD trial (streams ``gyro``, ``accel``, ``mag``, ``gaze``; scoring only: ``fixation``;
    truth: the eye's world ray)."""
    import scipy.io

    cfg = config or EyeConfig()
    trial = load_broad(path)
    assert trial.truth is not None
    position = np.asarray(scipy.io.loadmat(Path(path), squeeze_me=True).get("opt_pos", np.zeros((len(trial.truth), 3))), dtype=float)
    if position.shape != (len(trial.truth), 3):
        raise SessionError(f"{path}: opt_pos is {position.shape}, not one position per sample")
    number = int(Path(path).stem.split("_")[0]) if Path(path).stem.split("_")[0].isdigit() else 0
    camera = SceneCamera(focal_px=FOCAL_PX, width_px=WIDTH_PX, height_px=HEIGHT_PX, pixel_sigma=PIXEL_SIGMA)
    half_view = (float(np.degrees(np.arctan(WIDTH_PX / 2 / FOCAL_PX))), float(np.degrees(np.arctan(HEIGHT_PX / 2 / FOCAL_PX))))
    eye = simulate_eye(trial.truth.t, trial.truth.values, position, np.random.default_rng(seed * 1000 + number), cfg, half_view)
    pixels = camera.project(eye.head_ray)
    gaze = Stream("gaze", "pixel", eye.t, pixels, KIND_COLUMNS["pixel"], 0.0,
                  {"rate_hz": cfg.rate_hz, "focal_px": FOCAL_PX, "width_px": WIDTH_PX, "height_px": HEIGHT_PX, "pixel_sigma": PIXEL_SIGMA,
                   "description": "simulated eye (scenarios.eye) driven by the trial's optical head motion"})
    streams = {name: trial.stream(name) for name in ("gyro", "accel", "mag")}
    header = {"system": "gaze", "dataset": "BROAD's recorded head with a SIMULATED eye (scenarios.eye)", "trial": Path(path).stem,
              "target_depth_m": TARGET_DEPTH_M, "gaze_truth": "world_ray", "head_motion": "free", "world_frame": "ENU (optical)",
              "description": f"gaze session from BROAD trial {Path(path).stem}: recorded head IMU, SIMULATED eye (scenarios.eye)"}
    fixation = Stream("fixation", "flag", eye.t, eye.fixation[:, None], KIND_COLUMNS["flag"], 0.0,
                      {"role": "scoring only", "description": "the simulated eye's own fixations"})
    truth = Stream("truth", "position", eye.t, eye.true_world_ray, KIND_COLUMNS["position"], 0.0,
                   {"frame": "world ray (unit vector, ENU)", "description": "the simulated eye's world gaze ray"})
    return Session("gaze", {**streams, "gaze": gaze, "fixation": fixation}, truth, {"session": header}, trial.path)
