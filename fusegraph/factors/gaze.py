"""Eye-tracker gaze pixel: the projection of the fixated world point into the head-fixed scene camera.

The scene camera looks along the head's +x axis (head frame x forward, y left, z up); a gaze pixel
is ``(u, v)`` with the origin at the image centre, u to the right and v UP (the image's X and Z).
``SceneCamera`` is a pinhole (``focal_px``); the paper's "239.5 px per maximum head angle" mapping is
one calibration of it. The factor is gtsam's C++ ``GenericProjectionFactorCal3_S2`` on the head
keyframe's pose and the fixation point: the sample's time offset from the keyframe enters as the
``body_P_sensor`` transform (the gyro's rotation from the keyframe to the sample, then the
head-to-camera rotation), so one keyframe carries every 60 Hz sample exactly without a variable
per sample.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import gtsam
import numpy as np

from ..catalogue import KeySpec, SensorKind
from ..geometry import FloatArray
from ..tuned import tuned, value
from .linear import robust
from .mag import MagNoise

# gtsam's camera frame: z forward, x right, y down; ours (head): x forward, y left, z up
HEAD_R_CAMERA = gtsam.Rot3(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]))


@dataclass(frozen=True)
class SceneCamera:
    """The head-fixed scene camera of the eye tracker."""

    focal_px: float = 500.0
    """Pinhole focal length, pixels."""
    width_px: int = 640
    """Image width, pixels (the origin is at the centre)."""
    height_px: int = 480
    """Image height, pixels."""
    pixel_sigma: float = 5.0
    """Gaze pixel noise (tracker noise + fixational jitter), pixels."""
    cauchy_k: float = 3.0
    """Cauchy kernel width in sigmas (blinks, tracker glitches)."""

    @classmethod
    def from_meta(cls, meta: Mapping[str, Any], keys: tuple[str, ...] = ("focal_px", "width_px", "height_px", "pixel_sigma")) -> SceneCamera:
        """The camera a gaze stream's metadata declares (``keys`` of it; the rest this class's defaults)."""
        return cls(**{k: type(getattr(cls(), k))(meta[k]) for k in keys if k in meta})

    def calibration(self) -> gtsam.Cal3_S2:
        return gtsam.Cal3_S2(self.focal_px, self.focal_px, 0.0, 0.0, 0.0)

    def project(self, head_t_point: FloatArray) -> FloatArray:
        """Pixels (u right, v up) of points given in the head frame, shape (N, 3) -> (N, 2)."""
        p = np.atleast_2d(head_t_point)
        return np.stack([-self.focal_px * p[:, 1] / p[:, 0], self.focal_px * p[:, 2] / p[:, 0]], axis=1)

    def ray(self, uv: FloatArray) -> FloatArray:
        """Unit direction in the head frame through pixel(s) (u right, v up), shape (N, 3)."""
        uv = np.atleast_2d(uv)
        d = np.stack([np.full(len(uv), self.focal_px), -uv[:, 0], uv[:, 1]], axis=1)
        return d / np.linalg.norm(d, axis=1, keepdims=True)


def gaze_factor(pose_key: int, point_key: int, uv: FloatArray, keyframe_R_sample: gtsam.Rot3, camera: SceneCamera) -> gtsam.GenericProjectionFactorCal3_S2:
    """The gaze pixel of a sample taken ``keyframe_R_sample`` (gyro rotation) after the keyframe."""
    measured = np.array([float(uv[0]), -float(uv[1])])  # gtsam's v points down
    model = robust(gtsam.noiseModel.Isotropic.Sigma(2, camera.pixel_sigma), camera.cauchy_k)
    body_P_sensor = gtsam.Pose3(keyframe_R_sample.compose(HEAD_R_CAMERA), np.zeros(3))
    return gtsam.GenericProjectionFactorCal3_S2(measured, model, pose_key, point_key, camera.calibration(), body_P_sensor)


@dataclass(frozen=True)
class FixationNoise:
    """How the fixated world point moves: slowly, with saccades the robust kernel absorbs."""

    drift_m_per_sqrt_s: float = value("gaze_fixation", "drift_m_per_sqrt_s")
    """Random walk of the point during a fixation, metres per sqrt(second) (``tune gaze_fixation``, seeds 100-119)."""
    cauchy_k: float = value("gaze_fixation", "cauchy_k")
    """Cauchy kernel width in sigmas: a saccade (a jump of centimetres to metres) is absorbed (``tune gaze_fixation``)."""
    plane_sigma_m: float = 0.002
    """How well the point is known to lie on the wall plane, metres."""
    sample_gate_sigmas: float = field(default_factory=lambda: float(value("gaze_points", "gate_sigmas")))
    """A gaze sample whose own ray misses its keyframe's fixation point by more than this many pixel sigmas takes its
    own ray's point, not the keyframe's (``sample_points``; ``tune gaze_points`` / ``gaze_points_batch``, seeds 100-119 of
    both gaze scenarios)."""


def fixation_tuned(study: str = "gaze_fixation") -> FixationNoise:
    """The fixation model chosen by ``fusegraph tune`` for one solver (``gaze_fixation``: online,
    ``gaze_fixation_batch``: batch; each solver's RMS on seeds 100-119), with that solver's sample gate (``gaze_points``,
    ``gaze_points_batch``)."""
    gate = value(study.replace("fixation", "points"), "gate_sigmas")
    return FixationNoise(drift_m_per_sqrt_s=value(study, "drift_m_per_sqrt_s"), cauchy_k=value(study, "cauchy_k"), sample_gate_sigmas=gate)


def head_mag_tuned() -> MagNoise:
    """The seated head's magnetometer heading (``tune gaze_head_mag``, seeds 100-119): each keyframe reads the mean of its
    interval's readings carried by the gyro (one reading's noise over ~20 at 100 Hz; it was the start's heading error that
    took ~20 s to average away) with the chosen sigma."""
    chosen = tuned("gaze_head_mag")
    return MagNoise(heading_sigma_deg=float(chosen["heading_sigma_deg"]), interval_mean=bool(chosen["interval_mean"]))


def fixation_walk(prev_key: int, next_key: int, dt_s: float, noise: FixationNoise) -> gtsam.BetweenFactorPoint3:
    sigma = noise.drift_m_per_sqrt_s * np.sqrt(max(dt_s, 1e-6))
    model = robust(gtsam.noiseModel.Isotropic.Sigma(3, sigma), noise.cauchy_k)
    return gtsam.BetweenFactorPoint3(prev_key, next_key, np.zeros(3), model)


def sample_points(points_m: FloatArray, world_R_head: FloatArray, rays: FloatArray, camera: SceneCamera, on_wall: bool,
                  gate_sigmas: float) -> FloatArray:
    """Each gaze sample's point (M, 3) from its keyframe's fixation point ``points_m`` (M, 3) and its own ray (``rays`` in
    the head frame, turned by ``world_R_head``, quaternions w, x, y, z): the fixation point where the ray sees it within
    ``gate_sigmas`` pixel sigmas, else where the ray meets the point's plane (``on_wall``:
    the wall x = const through it; else the plane through it facing the eye at the origin). One point holds per 0.2 s
    keyframe; a saccade inside it leaves the samples on its other side looking elsewhere, and the keyframe's point put
    them up to the saccade's size away (`report gaze --viewing`, a saccade every 0.33 s, seeds 0-9: X / Z RMS online
    119.7 / 120.8 mm, batch 116.2 / 117.8; with this 20.4 / 11.8 and 8.7 / 7.0). NaN rows stay NaN; a sample without an
    attitude keeps its keyframe's point."""
    from ..geometry import matrix_from_quat

    out = np.array(points_m, dtype=float, copy=True)
    has = np.all(np.isfinite(out), axis=1) & np.all(np.isfinite(world_R_head), axis=1)
    if not has.any():
        return out
    world = np.einsum("nij,nj->ni", matrix_from_quat(world_R_head[has]), rays[has])
    point = out[has]
    along = point / np.linalg.norm(point, axis=1, keepdims=True)
    outlier = np.einsum("ni,ni->n", world, along) < np.cos(gate_sigmas * camera.pixel_sigma / camera.focal_px)
    normal = np.tile([1.0, 0.0, 0.0], (len(point), 1)) if on_wall else along
    with np.errstate(divide="ignore", invalid="ignore"):
        reach = np.einsum("ni,ni->n", normal, point) / np.einsum("ni,ni->n", normal, world)
    moved = outlier & np.isfinite(reach) & (reach > 0)
    rows = np.flatnonzero(has)[moved]
    out[rows] = world[moved] * reach[moved, None]
    return out


def wall_plane_prior(point_key: int, wall_x_m: float, noise: FixationNoise) -> gtsam.PriorFactorPoint3:
    """The point lies on the wall x = wall_x_m (its other coordinates are free)."""
    sigmas = np.array([noise.plane_sigma_m, 100.0, 100.0])
    return gtsam.PriorFactorPoint3(point_key, np.array([wall_x_m, 0.0, 0.0]), gtsam.noiseModel.Diagonal.Sigmas(sigmas))


def depth_prior(point_key: int, world_t_point: FloatArray, noise: FixationNoise) -> gtsam.PriorFactorPoint3:
    """No wall known (targets anywhere in a room): the point stays at its initial depth along its initial
    direction from the head (sigma ``plane_sigma_m``), free across it: a small wall facing the head."""
    point = np.asarray(world_t_point, dtype=float)
    normal = point / np.linalg.norm(point)
    across = 10.0**2 * (np.eye(3) - np.outer(normal, normal))  # 10 m is free at room depths; 100 m left it near-indeterminate
    cov = noise.plane_sigma_m**2 * np.outer(normal, normal) + across
    return gtsam.PriorFactorPoint3(point_key, point, gtsam.noiseModel.Gaussian.Covariance(cov))


def _pixels_in_view(values: FloatArray, keys: Mapping[str, Any]) -> str | None:
    """Pixels (centred on the principal point) within two image sizes of the image."""
    width, height = float(keys.get("width_px", 640)), float(keys.get("height_px", 480))
    worst_u, worst_v = float(np.max(np.abs(values[:, 0]))), float(np.max(np.abs(values[:, 1])))
    if worst_u > 2 * width or worst_v > 2 * height:
        return (f"|u| up to {worst_u:.0f}, |v| up to {worst_v:.0f} px for a {width:.0f} x {height:.0f} image: pixels measured from the "
                f"image centre (u right, v UP) are expected; normalised or top-left coordinates, or another camera size?")
    return None


CATALOGUE = (
    SensorKind(
        kind="pixel",
        summary="eye tracker: gaze point in the head-fixed scene camera image",
        columns=("u", "v"),
        units=("px", "px"),
        frame="scene image, measured from the principal point (u right, v UP: image rows counted downwards are negated)",
        factors="GenericProjectionFactorCal3_S2 of the fixated world point into the scene camera at the sample's head pose",
        keys=(
            KeySpec("focal_px", 500.0, "focal length, px"),
            KeySpec("width_px", 640, "image width, px"),
            KeySpec("height_px", 480, "image height, px"),
            KeySpec("pixel_sigma", 5.0, "gaze noise, px"),
            KeySpec("time_offset_s", 0.0, "the gaze stamps' delay behind the IMU's clock, s: every method takes a sample at stamp - "
                    "time_offset_s (import tobii finds it from the gaze and the gyro alone)"),
            KeySpec("time_offset_sigma_s", None, "the offset's uncertainty, s (documentation)"),
        ),
        check=_pixels_in_view,
    ),
)
