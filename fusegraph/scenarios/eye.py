"""An eye driven by a recorded head motion: what a head-worn eye tracker would report while its wearer looks at
world-fixed targets (``import broad --system gaze``).

The head's attitude and position are a recording's reference (BROAD's optical ones); the eye is simulated:

* fixations on targets fixed in the world, each drawn where the head points at its start turned by an eye-in-head
  direction, 1-4 m away; their durations, the eye-in-head spread, the blinks' length and the tracker's precision were
  measured on the shipped Pupil Invisible export (its own fixation and blink detectors; ``measure_pupil``); the rest is
  from the literature (each field says which);
* during a fixation the eye turns against the head with ``vor_gain`` < 1, so the gaze slips in the world by the rest of
  the head's turn (and the head's translation changes the target's direction: parallax);
* saccades between fixations follow the main sequence, with a minimum-jerk profile; an eye that would turn beyond
  ``eye_range_deg`` or out of the scene camera's view ends its fixation early (a new target is taken, as a person does);
* blinks hide the eye; the tracker adds a calibration offset and white noise, reports at ``rate_hz`` and stamps its
  samples ``delay_s`` late.

A simulator, not a recording: every table that shows it says so, and its truth (the eye's world ray, the fixations)
only scores.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry import FloatArray, matrix_from_quat, quat_conjugate, quat_from_rotvec, quat_multiply, rotvec_from_quat


@dataclass(frozen=True)
class EyeConfig:
    """The simulated eye and eye tracker (every value fixed before any score)."""

    rate_hz: float = 50.0
    """Gaze samples per second: the Tobii Pro Glasses 3's lower setting (its data sheet: 50 or 100 Hz)."""
    delay_s: float = 0.0095
    """The gaze stamps' delay behind the IMU: what ``import tobii`` finds on the shipped Glasses 3 recording (9.5 ms,
    ``frontends.gaze_timing.gaze_time_offset``)."""
    fixation_median_s: float = 0.216
    """Median fixation duration: 63 fixations of the shipped Pupil Invisible export (``measure_pupil``); the scene-viewing
    literature's mean of ~0.3 s (Rayner 1998, Psychol. Bull. 124:372) is this distribution's mean (0.32 s there)."""
    fixation_log_sigma: float = 1.05
    """Spread of the log-normal fixation durations: ln(Q3 / Q1) / 1.349 of the same fixations (Q1 0.092 s, Q3 0.378 s)."""
    fixation_min_s: float = 0.06
    """Shortest fixation drawn (the detectors' least; the shortest measured lasted 0.07 s)."""
    fixation_max_s: float = 2.0
    """Longest fixation drawn (the longest measured: 1.9 s)."""
    eye_sigma_deg: tuple[float, float] = (4.1, 16.0)
    """Spread of the eye-in-head direction at a fixation's start (azimuth, elevation), degrees: the standard deviation of the
    measured fixations' mean directions (about the image centre)."""
    eye_range_deg: float = 40.0
    """An eye turned further from straight ahead ends its fixation (the oculomotor range is ~50 deg; gaze shifts beyond
    ~40 deg recruit the head: Freedman 2008, Biol. Cybern. 98:461)."""
    distance_m: tuple[float, float] = (1.0, 4.0)
    """Targets' distance from the eye, uniform, metres (a room; the issue's "a metre or more away")."""
    vor_gain: float = 0.95
    """Counter-rotation of the eye against the head's turn in a fixation on a distant target (the VOR's gain in the light,
    close to but below 1: Leigh & Zee, The Neurology of Eye Movements, 5th ed., 2015, ch. 2)."""
    saccade_ms: tuple[float, float] = (21.0, 2.2)
    """Saccade duration = a + b x amplitude (ms, ms/deg): the main sequence (Carpenter, Movements of the Eyes, 1988)."""
    blink_per_min: float = 17.0
    """Blinks per minute at rest (Bentivoglio et al. 1997, Mov. Disord. 12:1028; the shipped Pupil recording, on a
    trampoline, had 53)."""
    blink_s: float = 0.278
    """Blink duration: the median of the shipped Pupil recording's 38 blinks."""
    precision_deg: float = 0.11
    """The tracker's white noise per axis, degrees: the RMS of successive differences over sqrt 2 in the measured fixations
    (0.09 in azimuth, 0.13 in elevation)."""
    accuracy_deg: float = 0.6
    """The tracker's calibration offset (one per recording, in a random direction), degrees: the Glasses 3 data sheet's
    accuracy (``datasets.tobii``)."""


@dataclass(frozen=True)
class EyeTrace:
    """What the simulated eye did and what its tracker reported."""

    t: FloatArray
    """Gaze sample times (the tracker's stamps: ``delay_s`` after the eye was there), seconds, shape (M,)."""
    head_ray: FloatArray
    """The tracker's gaze ray in the head frame (noise and offset included), unit, shape (M, 3)."""
    true_world_ray: FloatArray
    """Where the eye looked, in the world, at the sample's true time (the truth that scores), unit, shape (M, 3)."""
    fixation: FloatArray
    """The simulator's fixation id per sample (1, 2, ...; 0 in a saccade), the labels that pick the scored samples."""
    targets_m: FloatArray
    """Each fixation's target in the world, metres, shape (fixations, 3)."""


def _unit(v: FloatArray) -> FloatArray:
    return np.asarray(v / np.linalg.norm(v, axis=-1, keepdims=True))


def _direction(azimuth_deg: float, elevation_deg: float) -> FloatArray:
    """Head-frame direction (x forward, y left, z up) at an azimuth (to the left) and elevation (up)."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def _angle_deg(a: FloatArray, b: FloatArray) -> FloatArray:
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)))


def simulate_eye(t: FloatArray, world_R_head: FloatArray, head_position_m: FloatArray, rng: np.random.Generator,
                 config: EyeConfig | None = None, half_view_deg: tuple[float, float] = (90.0, 90.0)) -> EyeTrace:
    """The eye over a head motion sampled at ``t`` (world_R_head quaternions, head positions; NaN where the reference lost
    the head: no gaze sample there). ``half_view_deg``: the scene camera's half field of view (horizontal, vertical): a
    gaze outside its image is no pixel, so a target is drawn inside it and a fixation ends where the eye would leave it."""
    cfg = config or EyeConfig()
    tan_view = np.tan(np.radians(np.minimum(half_view_deg, cfg.eye_range_deg)))

    def seen_by_camera(ray: FloatArray) -> bool:  # in the image and within the eye's range
        return bool(ray[0] > 0 and abs(ray[1]) <= tan_view[0] * ray[0] and abs(ray[2]) <= tan_view[1] * ray[0]
                    and _angle_deg(ray, np.array([1.0, 0.0, 0.0])) <= cfg.eye_range_deg)

    period = 1.0 / cfg.rate_hz
    sample_t = np.arange(t[0], t[-1] - cfg.delay_s, period)
    index = np.clip(np.searchsorted(t, sample_t), 0, len(t) - 1)  # the head at each gaze sample (285 Hz: within 1.8 ms)
    quat = world_R_head[index]
    known = np.all(np.isfinite(quat), axis=1) & np.all(np.isfinite(head_position_m[index]), axis=1)
    rotation = matrix_from_quat(np.where(known[:, None], quat, [1.0, 0.0, 0.0, 0.0]))
    position = np.where(known[:, None], head_position_m[index], 0.0)
    n = len(sample_t)
    world_ray = np.full((n, 3), np.nan)
    fixation = np.zeros(n)
    targets: list[FloatArray] = []
    k = 0
    last_head_ray: FloatArray | None = None
    while k < n:
        if not known[k]:
            k += 1
            last_head_ray = None
            continue
        # the next target: where the head points turned by an eye-in-head direction, at a drawn distance
        eye = _direction(*(rng.normal(0.0, 1.0, 2) * np.array(cfg.eye_sigma_deg)))
        while not seen_by_camera(eye):  # the measured spread, truncated to what the camera sees
            eye = _direction(*(rng.normal(0.0, 1.0, 2) * np.array(cfg.eye_sigma_deg)))
        start_ray = rotation[k] @ eye
        target = position[k] + rng.uniform(*cfg.distance_m) * start_ray
        duration = float(np.clip(cfg.fixation_median_s * np.exp(cfg.fixation_log_sigma * rng.normal()), cfg.fixation_min_s, cfg.fixation_max_s))
        # the saccade to it from where the eye was (in the head: minimum jerk along the arc), then the fixation
        if last_head_ray is not None:
            amplitude = float(_angle_deg(last_head_ray, eye))
            steps = max(1, int(round((cfg.saccade_ms[0] + cfg.saccade_ms[1] * amplitude) / 1000.0 / period)))
            for s in range(min(steps, n - k)):
                if not known[k]:
                    break
                tau = (s + 1) / (steps + 1)
                blend = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
                world_ray[k] = rotation[k] @ _unit(last_head_ray + blend * (eye - last_head_ray))
                k += 1
        targets.append(target)
        start = k
        while k < n and known[k] and sample_t[k] - sample_t[start] < duration:
            ideal = _unit(target - position[k])  # parallax: the head's translation moves the target's direction
            turn = rotvec_from_quat(quat_multiply(quat[k], quat_conjugate(quat[start])))  # the head's turn since the fixation began (world)
            slip = matrix_from_quat(quat_from_rotvec((1.0 - cfg.vor_gain) * turn))
            ray = slip @ ideal
            in_head = rotation[k].T @ ray
            if not seen_by_camera(in_head):  # the eye would leave the camera's view or its range: a new target
                break
            world_ray[k] = ray
            fixation[k] = len(targets)
            last_head_ray = in_head
            k += 1
        if k == start:  # could not hold even one sample: a new target next
            k += 1
    true_head = np.einsum("nji,nj->ni", rotation, np.nan_to_num(world_ray))
    # blinks: a Poisson process hides the eye; the tracker reports nothing there
    seen = known & np.all(np.isfinite(world_ray), axis=1)
    blink_t = t[0] + np.cumsum(rng.exponential(60.0 / cfg.blink_per_min, int(3 * (t[-1] - t[0]) * cfg.blink_per_min / 60.0) + 3))
    for b in blink_t[blink_t < t[-1]]:
        seen &= ~((sample_t >= b) & (sample_t < b + cfg.blink_s))
    # the tracker: one calibration offset, white noise per sample
    axis = _unit(rng.normal(size=3))
    offset = matrix_from_quat(quat_from_rotvec(np.radians(cfg.accuracy_deg) * axis))
    noise = matrix_from_quat(quat_from_rotvec(np.radians(cfg.precision_deg) * rng.normal(size=(n, 3))))
    measured = np.einsum("nij,nj->ni", noise, np.einsum("ij,nj->ni", offset, true_head))[seen]
    return EyeTrace(sample_t[seen] + cfg.delay_s, _unit(measured), world_ray[seen], fixation[seen], np.array(targets).reshape(-1, 3))


def measure_pupil(directory: str | Path) -> dict[str, float]:
    """The eye's measured parameters from a Pupil Cloud export (``gaze.csv`` with ``fixation id``, ``azimuth [deg]``,
    ``elevation [deg]``; ``blinks.csv``): fixation duration median and log spread, eye-in-head spread, blink median,
    precision: what ``EyeConfig`` holds for the shipped recording."""
    import pandas as pd

    folder = Path(directory)
    gaze = pd.read_csv(folder / "gaze.csv")
    blinks = pd.read_csv(folder / "blinks.csv")
    fixations = gaze.dropna(subset=["fixation id"])
    spans = fixations.groupby("fixation id")["timestamp [ns]"].agg(["min", "max"])
    duration = (spans["max"] - spans["min"]).to_numpy() / 1e9
    q1, q3 = np.quantile(duration, [0.25, 0.75])
    means = fixations.groupby("fixation id")[["azimuth [deg]", "elevation [deg]"]].mean().to_numpy()
    steps = [np.diff(group[["azimuth [deg]", "elevation [deg]"]].to_numpy(), axis=0) for _, group in fixations.groupby("fixation id")]
    step = np.vstack(steps)
    return {"fixation_median_s": float(np.median(duration)), "fixation_log_sigma": float(np.log(q3 / q1) / 1.349),
            "eye_sigma_azimuth_deg": float(np.std(means[:, 0], ddof=1)), "eye_sigma_elevation_deg": float(np.std(means[:, 1], ddof=1)),
            "blink_s": float(np.median(blinks["duration [ms]"])) / 1000.0, "precision_deg": float(np.sqrt(np.mean(step**2)) / np.sqrt(2.0)),
            "fixations": float(len(duration))}
