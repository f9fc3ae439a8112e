"""Range to a beacon at a known position, read with an unknown constant bias.

Radio and ultrasonic ranges read long by a bias that depends on the beacon (antenna delay,
multipath): ``range = |world_t_body - world_t_beacon| + bias + noise``. The bias is a graph
variable (a 1-vector per beacon and time window, a random-walk chain: one variable shared by the
whole session would tie every pose together and make each iSAM2 relinearisation re-eliminate the
whole tree, measured 5x slower on Plaza1's first 400 s) with a prior; the factor is unary in the pose, so a known beacon
is not a shared variable (which would tie every pose to it in iSAM2's tree). gtsam has no C++
factor for a range to a fixed point plus a bias, hence one small ``CustomFactor`` per range, with
analytic Jacobians (checked against numerical derivatives in the tests).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np

from ..catalogue import KeySpec, SensorKind
from ..geometry import FloatArray
from .odometry import robust


@dataclass(frozen=True)
class RangeNoise:
    """Trust in one range and the prior on a beacon's bias."""

    sigma_m: float = 1.0
    """Range noise sigma, metres."""
    kernel: str = "huber"
    """Robust kernel against multipath outliers: 'cauchy', 'huber' or 'none'."""
    kernel_width: float = 1.5
    """Kernel width in sigmas."""
    bias_prior_m: float = 0.0
    """Prior mean of a beacon's bias, metres."""
    bias_sigma_m: float = 5.0
    """Prior sigma of a beacon's bias, metres."""
    bias_walk_m: float = 0.05
    """Sigma of a bias's change from one window to the next, metres (it is a chain, not one variable)."""
    reacquire_sigma_m: float = 0.5
    """Online: sigma around the last estimate for a beacon heard again after its bias was marginalised."""


@dataclass(frozen=True)
class BeaconRanges:
    """Ranges to known, identified beacons (a ``beacon_ranges`` stream) as an estimator reads them."""

    t: FloatArray
    """Time of each range, seconds (rows of one epoch may share it)."""
    beacon: np.ndarray
    """Index of the beacon each range is to (row of ``beacons_m``)."""
    range_m: FloatArray
    """Measured distance, metres."""
    beacons_m: FloatArray
    """Beacon positions in the world frame, (B, 3) metres."""
    noise: RangeNoise
    """Trust in a range and the prior on each beacon's bias."""


def beacon_ranges_from(stream: Any, where: str) -> BeaconRanges:
    """A ``beacon_ranges`` stream (a ``session.Stream``) as ``BeaconRanges``; beacon indices are checked."""
    meta = stream.meta
    if "beacons_m" not in meta:
        raise ValueError(f"{where}: stream '{stream.name}' needs beacons_m = [[x, y, z], ...] (beacon positions, m)")
    beacons = np.atleast_2d(np.asarray(meta["beacons_m"], dtype=float))
    if beacons.shape[1] == 2:
        beacons = np.column_stack([beacons, np.zeros(len(beacons))])
    index = stream.values[:, 0]
    bad = np.flatnonzero((index != np.round(index)) | (index < 0) | (index >= len(beacons)))
    if len(bad):
        raise ValueError(f"{where}: stream '{stream.name}' row {bad[0] + 1}: beacon {index[bad[0]]:g} is not an index of beacons_m (0..{len(beacons) - 1})")
    noise = RangeNoise(sigma_m=float(meta.get("sigma_m", 1.0)), bias_sigma_m=float(meta.get("bias_sigma_m", 5.0)),
                       kernel_width=float(meta.get("kernel_width", 1.5)))
    return BeaconRanges(stream.t, index.astype(int), stream.values[:, 1], beacons, noise)


def range_factor(pose_key: int, bias_key: int, world_t_beacon: FloatArray, range_m: float, noise: RangeNoise) -> gtsam.CustomFactor:
    """Unary-in-pose biased range: error = |t - beacon| + bias - range."""
    beacon = np.asarray(world_t_beacon, dtype=float).copy()

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians: list[Any] | None) -> FloatArray:
        pose = values.atPose3(this.keys()[0])
        bias = float(values.atVector(this.keys()[1])[0])
        offset = pose.translation() - beacon
        distance = float(np.linalg.norm(offset))
        if jacobians is not None:
            unit = offset / max(distance, 1e-9)
            # Pose3 retracts translation in the body frame: d t = R dv
            jacobians[0] = np.hstack([np.zeros(3), unit @ pose.rotation().matrix()]).reshape(1, 6)
            jacobians[1] = np.ones((1, 1))
        return np.array([distance + bias - range_m])

    model = robust(gtsam.noiseModel.Isotropic.Sigma(1, noise.sigma_m), noise.kernel, noise.kernel_width)
    return gtsam.CustomFactor(model, [pose_key, bias_key], error)


def bias_prior(bias_key: int, noise: RangeNoise) -> gtsam.PriorFactorVector:
    """What is known of a beacon's bias before the run."""
    return gtsam.PriorFactorVector(bias_key, np.array([noise.bias_prior_m]), gtsam.noiseModel.Isotropic.Sigma(1, noise.bias_sigma_m))


def bias_walk(prev_key: int, next_key: int, windows: int, noise: RangeNoise) -> gtsam.BetweenFactorVector:
    """A beacon's bias in one window is its bias ``windows`` windows earlier, give or take a random walk."""
    sigma = noise.bias_walk_m * np.sqrt(max(windows, 1))
    return gtsam.BetweenFactorVector(prev_key, next_key, np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(1, sigma))

CATALOGUE = (
    SensorKind(
        kind="ranges",
        summary="ultrasonic/UWB distances heard by known receivers, transmitter unknown: one row per distance, rows of one epoch share t",
        columns=("receiver", "range_m"),
        units=("index", "m"),
        frame="receiver positions in the world frame (receivers_m)",
        factors="ultrasonic: associated online (chi-square gate, assignment, multiple-model tracks); range rows of each track's point; "
        "with tag_offsets_m: one rigid body's planar pose and a range bias per receiver",
        keys=(
            KeySpec("receivers_m", None, "receiver positions [[x, y, z], ...], m (required)"),
            KeySpec("transmitters", None, "how many transmitters emit each epoch (required)"),
            KeySpec("sigma_m", 0.005, "range noise, m"),
            KeySpec("tag_offsets_m", None, "the transmitters are tags on one rigid body: their positions in its frame [[x, y, z], ...], m "
                    "(then tracked as one body, either handedness)"),
            KeySpec("planar", False, "the tags move in a horizontal plane at the receivers' mean height: tracked and scored in x, y"),
            KeySpec("range_bias_m", None, "a range calibration per receiver and tag (measured = range_scale x true + range_bias_m): "
                    "[[bias of tag 0, tag 1, ...] per receiver], m; with tag_offsets_m, the prior of a constant bias the tracker refines"),
            KeySpec("range_scale", None, "the calibration's scale (1 + slope) per receiver and tag, same layout"),
            KeySpec("range_sigma_m", None, "the calibration's residual sigma per receiver and tag, m: the bias prior's sigma"),
        ),
        repeated_times=True,
    ),
    SensorKind(
        kind="tag_position",
        summary="positions of several tags per epoch (a motion-capture truth of ultrasonic/UWB tags): one row per tag",
        columns=("tag", "x", "y", "z"),
        units=("index", "m", "m", "m"),
        frame="world (room) frame",
        factors="none: truth for scoring",
        repeated_times=True,
    ),
    SensorKind(
        kind="beacon_ranges",
        summary="ranges to known, identified beacons (Plaza; a walker's UWB tag): one row per range, rows of one epoch share t",
        columns=("beacon", "range_m"),
        units=("index", "m"),
        frame="beacon positions in the world frame (beacons_m)",
        factors="range from the state nearest in time to the beacon plus the beacon's bias (CustomFactor, Huber); walking: the "
        "motion between the range and its state widens sigma",
        keys=(KeySpec("beacons_m", None, "beacon positions [[x, y], ...] or [[x, y, z], ...], m (required)"),
              KeySpec("sigma_m", 1.0, "range noise, m"),
              KeySpec("bias_sigma_m", 5.0, "prior sigma of each beacon's range bias (a slowly walking variable), m"),
              KeySpec("kernel_width", 1.5, "Huber kernel width in sigmas (multipath / non-line-of-sight ranges)")),
        repeated_times=True,
    ),
)
