"""9-axis attitude graph: IMU preintegration between keyframes, bounded-motion priors, magnetometer heading.

Variables per keyframe k (one every ``keyframe_period_s``, on a sample): ``x(k)`` world_T_body
(Pose3, ENU; the position is a nuisance that lets the accelerometer's specific force be explained),
``v(k)`` velocity (world), ``b(k)`` accelerometer + gyro bias (ConstantBias). Factors per keyframe:
``ImuFactor`` from k-1, the bias walk, the zero-mean position/velocity priors, a zero-velocity
update when the sensor rests, the magnetometer's heading-only factor, and optionally the
accelerometer's gravity direction. All are C++ factors.

Samples are pushed in time order (``add_samples``, any block size, a single sample for a live
feed). Online, the heading factor levels the field with the prediction from the newest posterior;
batch smoothing defers the heading factors (``deferred_mag``) so they can be levelled with a solved
attitude (``heading_factors``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import gtsam
import numpy as np

from ..consistency import clipped_samples
from ..factors.accel import GravityNoise, gravity_factor
from ..factors.attitude import AttitudeTrack
from ..factors.gyro import GAP_MIN_S, GAP_PERIODS, GAP_RATE_RAD_S, GyroCalibrationPrior, calibration_prior_factor, scale_rate_map
from ..factors.imu import (
    ImuNoise,
    MotionPriors,
    bias_prior_factor,
    bias_walk_factor,
    position_prior_factor,
    preintegration_params,
    rest_reading,
    steady_rest,
    still_samples,
    velocity_prior_factor,
    zero_rate_factor,
)
from ..factors.linear import linear_factor, robust
from ..factors.mag import (
    CarriedReadings,
    FieldReference,
    FieldTracker,
    HardIron,
    MagCalibration,
    MagNoise,
    field_norm_dip,
    heading_factor,
    heading_sigma_rad,
    interval_mean_reading,
)
from ..geometry import FloatArray, quat_conjugate, quat_from_rotvec, quat_multiply, quat_wxyz_from_rot3, rot3_from_quat_wxyz, rotvec_from_quat
from ..tuned import tuned, tuned_studies
from .increment import GraphIncrement
from .ordering import SYMBOL_INDEX_BITS, SYMBOL_INDEX_MASK


def X(k: int) -> int:
    """Key of keyframe k's world_T_body (Pose3)."""
    return int(gtsam.symbol("x", k))


def V(k: int) -> int:
    """Key of keyframe k's world velocity (Vector3)."""
    return int(gtsam.symbol("v", k))


def B(k: int) -> int:
    """Key of keyframe k's IMU bias (ConstantBias: accelerometer, gyro)."""
    return int(gtsam.symbol("b", k))


#: Key of the gyro's calibration c (9: its scale factors and misalignment K, row by row; ``Attitude9Model.gyro_calibration``),
#: one session-wide variable that enters only linear factors on the gyro's effective biases (a builder with a key prefix
#: takes index 1 + the prefix's code, so two bodies in one graph keep their own).
GYRO_CALIBRATION = int(gtsam.symbol("k", 0))

#: Key of world_T_tracker (Pose3; only its rotation is observed): the attitude tracker's own world frame
#: (an optical or magnetic tracker's room frame) relative to the graph's ENU world, one constant variable.
TRACKER_WORLD = int(gtsam.symbol("a", 0))

#: Sigma of the unobserved translation part of the tracker factors, m: large enough to carry no information.
_FREE_TRANSLATION_SIGMA_M = 1e3


#: Seconds of gyro samples an online builder keeps for a late tracker sample (``add_attitude``): older keyframes are gone
#: from the solver's window (1 s plus up to a re-anchoring period) well before.
RECENT_GYRO_S = 10.0
#: Pushed blocks joined to the kept gyro samples at the latest after this many (a block may be one sample).
_JOIN_BLOCKS = 64

_GYRO_ROWS = np.hstack([np.zeros((3, 3)), np.eye(3)])
"""The gyro part of a ConstantBias's tangent vector (accelerometer first, as gtsam orders it)."""
_NO_RATE_MAP = np.zeros((3, 9))
"""``scale_rate_map`` of no interval (the first keyframe's, a dropout's): K turns nothing."""
_SAME_READING_SIGMAS = 3.0
"""A reading after a gap is where the still body's readings were when within this many of their scatter (x sqrt 2)."""
_REST_CAUCHY_K = 2.0
"""Cauchy width (sigmas) of the rest bridge: the gravity factor's (``GravityNoise.cauchy_k``)."""
CLIPPED_ACCEL_DENSITY = 100.0
"""Accelerometer noise density of an interval with a clipped sample, m/s^2/sqrt(Hz): 45 m/s of velocity over 0.2 s, i.e.
nothing (a 2 g range clips a trampoline landing of 4-6 g); the IMU factor keeps the gyro's rotation."""
RESTART_S = 1.0
"""Online, after a dropout: seconds of specific force and field averaged in the gyro's frame before the attitude is
re-levelled from them (one reading in motion can be tens of degrees off gravity; see ``_Restart``)."""


@dataclass
class _Restart:
    """The online estimate's way back after a dropout, as the batch's ``inertial_initial`` does from the start.

    The bridge's first guess is one sample's gravity and field: in motion 25 deg off in tilt and, levelled with that
    tilt, 80 deg in heading (a simulated hand at 100-180 deg/s); the Cauchy heading factors then ignore the field, and
    the estimate was 10-24 deg off 5 s later. Over ``RESTART_S`` the specific force turned into the bridge keyframe's
    frame by the gyro averages to gravity (the velocity stays bounded) and the field to the field; their TRIAD, turned
    back to the newest keyframe, is its guess and a prior as wide as the start's."""

    bridge_R_body: gtsam.Rot3 = field(default_factory=gtsam.Rot3)
    """The newest keyframe's attitude in the bridge keyframe's frame (the gyro alone)."""
    force_sum: FloatArray = field(default_factory=lambda: np.zeros(3))
    """Integrated specific force in the bridge frame, m/s."""
    seconds: float = 0.0
    """Time integrated."""
    field_sum: FloatArray = field(default_factory=lambda: np.zeros(3))
    """Sum of the keyframes' calibrated fields in the bridge frame."""
    fields: int = 0
    """Keyframes in ``field_sum``."""

    def add(self, pim: gtsam.PreintegratedImuMeasurements, mag: FloatArray | None) -> None:
        """One keyframe interval (its ``deltaVij`` is in the interval's first frame) and the field at its end."""
        self.force_sum = self.force_sum + self.bridge_R_body.rotate(pim.deltaVij())
        self.seconds += pim.deltaTij()
        self.bridge_R_body = self.bridge_R_body.compose(pim.deltaRij())
        if mag is not None:
            self.field_sum = self.field_sum + self.bridge_R_body.rotate(np.asarray(mag, dtype=float))
            self.fields += 1

    def world_R_body(self) -> gtsam.Rot3:
        """The newest keyframe's re-levelled attitude."""
        world_R_bridge = initial_attitude(self.force_sum / self.seconds, self.field_sum / self.fields if self.fields else None)
        return world_R_bridge.compose(self.bridge_R_body)


def mag_noise_from(settings: Mapping[str, float], base: MagNoise | None = None) -> MagNoise:
    """The magnetometer model of a ``broad_mag`` setting (a grid point, or the chosen one): heading sigma, gains, Cauchy width,
    and whether a keyframe reads its interval's mean (``interval_mean``; a setting without it: the keyframe's own reading)
    (the rest, e.g. the hard-iron model, as in ``base``)."""
    return replace(base or MagNoise(), heading_sigma_deg=float(settings["heading_sigma_deg"]), norm_gain=float(settings["gains"]),
                   dip_gain=float(settings["gains"]), cauchy_k=float(settings["cauchy_k"]), interval_mean=bool(settings.get("interval_mean", 0.0)))


def with_hard_iron(noise: MagNoise, settings: Mapping[str, float]) -> MagNoise:
    """``noise`` with a ``broad_hard_iron`` setting (a grid point, or the chosen one): the carried magnet's memory, fit
    tolerance and least size (``factors.mag.HardIron``)."""
    return replace(noise, hard_iron_s=float(settings["hard_iron_s"]), hard_iron_fit=float(settings["hard_iron_fit"]),
                   hard_iron_min=float(settings["hard_iron_min"]))


def with_field(noise: MagNoise, settings: Mapping[str, float]) -> MagNoise:
    """``noise`` with a ``broad_field`` setting (a grid point, or the chosen one): how the undisturbed field is followed
    (``factors.mag.FieldTracker``)."""
    return replace(noise, reference_tau_s=float(settings["reference_tau_s"]), new_field_s=float(settings["new_field_s"]))


def with_rest(model: Attitude9Model, settings: Mapping[str, float]) -> Attitude9Model:
    """``model`` with a ``broad_rest`` setting (a grid point, or the chosen one): the zero-rate update's rest rate."""
    return replace(model, motion=replace(model.motion, rest_rate_sigma_rad_s=float(settings["rest_rate_sigma_rad_s"])))


def with_motion(model: Attitude9Model, settings: Mapping[str, float]) -> Attitude9Model:
    """``model`` with a ``broad_motion`` setting (a grid point, or the chosen one): the velocity prior, the gyro and
    accelerometer densities, the gravity direction's sigma and inflation."""
    imu = replace(model.imu, gyro_noise_rad_s_sqrt_hz=float(settings["gyro_noise_rad_s_sqrt_hz"]),
                  accel_noise_m_s2_sqrt_hz=float(settings["accel_noise_m_s2_sqrt_hz"]))
    gravity = replace(model.gravity or GravityNoise(), sigma_deg=float(settings["gravity_sigma_deg"]),
                      inflation_deg_per_m_s2=float(settings["gravity_inflation_deg_per_m_s2"]))
    motion = replace(model.motion, velocity_sigma_m_s=float(settings["velocity_sigma_m_s"]))
    return replace(model, imu=imu, gravity=gravity, motion=motion)


def with_bias(model: Attitude9Model, settings: Mapping[str, float]) -> Attitude9Model:
    """``model`` with a ``broad_bias`` setting (a grid point, or the chosen one): the accelerometer bias's start-up sigma
    and random walk, the gyro bias's random walk."""
    imu = replace(model.imu, accel_bias_prior_m_s2=float(settings["accel_bias_prior_m_s2"]),
                  accel_bias_walk_m_s2_sqrt_s=float(settings["accel_bias_walk_m_s2_sqrt_s"]),
                  gyro_bias_walk_rad_s_sqrt_s=float(settings["gyro_bias_walk_rad_s_sqrt_s"]))
    return replace(model, imu=imu)


MODEL_STUDIES: tuple[str, ...] = ("broad_mag", "broad_motion", "broad_bias", "broad_hard_iron", "broad_field", "broad_rest")
"""The BROAD studies that set the 9-axis model, in the order they are chosen (``_batch`` appended for the batch's)."""


def model_from_settings(settings: Mapping[str, Mapping[str, float]]) -> Attitude9Model:
    """The 9-axis model from each study's setting (``MODEL_STUDIES`` name, without ``_batch`` -> its setting); a study not
    given keeps the code's default (``MagNoise()``, ``ImuNoise()``, ...: none of them read ``tuned.toml``)."""
    noise = mag_noise_from(settings["broad_mag"]) if "broad_mag" in settings else MagNoise()
    for layer, apply in MAG_LAYERS:
        noise = apply(noise, settings[layer]) if layer in settings else noise
    model = Attitude9Model(mag=noise)
    model = with_motion(model, settings["broad_motion"]) if "broad_motion" in settings else model
    model = with_bias(model, settings["broad_bias"]) if "broad_bias" in settings else model
    return with_rest(model, settings["broad_rest"]) if "broad_rest" in settings else model


def default_settings() -> dict[str, dict[str, float]]:
    """Each of ``MODEL_STUDIES``' settings as the code's defaults have it (what ``model_from_settings`` assumes of a study not
    given): where a choice of them starts from."""
    model = model_from_settings({})
    mag, imu, gravity = model.mag, model.imu, model.gravity or GravityNoise()
    return {"broad_mag": {"heading_sigma_deg": mag.heading_sigma_deg, "gains": mag.norm_gain, "cauchy_k": mag.cauchy_k,
                          "interval_mean": float(mag.interval_mean)},
            "broad_motion": {"velocity_sigma_m_s": model.motion.velocity_sigma_m_s, "gyro_noise_rad_s_sqrt_hz": imu.gyro_noise_rad_s_sqrt_hz,
                             "accel_noise_m_s2_sqrt_hz": imu.accel_noise_m_s2_sqrt_hz, "gravity_sigma_deg": gravity.sigma_deg,
                             "gravity_inflation_deg_per_m_s2": gravity.inflation_deg_per_m_s2},
            "broad_bias": {"accel_bias_prior_m_s2": imu.accel_bias_prior_m_s2, "accel_bias_walk_m_s2_sqrt_s": imu.accel_bias_walk_m_s2_sqrt_s,
                           "gyro_bias_walk_rad_s_sqrt_s": imu.gyro_bias_walk_rad_s_sqrt_s},
            "broad_hard_iron": {"hard_iron_s": mag.hard_iron_s, "hard_iron_fit": mag.hard_iron_fit, "hard_iron_min": mag.hard_iron_min},
            "broad_field": {"reference_tau_s": mag.reference_tau_s, "new_field_s": mag.new_field_s},
            "broad_rest": {"rest_rate_sigma_rad_s": model.motion.rest_rate_sigma_rad_s}}


def mag_noise_tuned(study: str) -> MagNoise:
    """The magnetometer settings a BROAD study chose (``broad_mag`` for the online estimate, ``broad_mag_batch``), with the
    hard-iron model its ``broad_hard_iron`` study chose (``broad_hard_iron_batch``) and the field tracking its
    ``broad_field`` study chose (``broad_field_batch``), once those studies have run."""
    noise = mag_noise_from(tuned(study))
    estimate = study.removeprefix("broad_mag")  # "" (online) or "_batch": the layers' studies of the same estimate
    for layer, apply in MAG_LAYERS:
        if layer + estimate in tuned_studies():
            noise = apply(noise, tuned(layer + estimate))
    return noise


MAG_LAYERS: tuple[tuple[str, Callable[[MagNoise, Mapping[str, float]], MagNoise]], ...] = (("broad_hard_iron", with_hard_iron),
                                                                                          ("broad_field", with_field))
"""The studies layered on a magnetometer study's choice, in order, with how each applies its setting (``_batch`` appended for
the batch's)."""


@dataclass(frozen=True)
class Attitude9Model:
    """Everything the 9-axis graph assumes; one set serves every recording."""

    keyframe_period_s: float = 0.2
    """Time between keyframes; preintegration is exact in between (BROAD: 0.1 s and 0.2 s scored alike,
    0.2 s is 2.4x faster)."""
    imu: ImuNoise = field(default_factory=ImuNoise)
    """Gyro and accelerometer noise and bias walks."""
    motion: MotionPriors = field(default_factory=MotionPriors)
    """Zero-mean position/velocity pseudo-measurements, the rest detector and its zero-rate update."""
    mag: MagNoise = field(default_factory=lambda: mag_noise_tuned("broad_mag"))
    """Magnetometer heading noise and disturbance rejection, chosen for the online estimate by leave-one-trial-out over
    the thirteen BROAD trials (``fusegraph tune broad_mag``; the values and their scores are in ``tuned.toml`` [broad_mag])."""
    mag_calibration: MagCalibration = field(default_factory=MagCalibration)
    """M = G m + B applied to every reading."""
    use_mag: bool = True
    """Use the magnetometer (without it the heading is the gyro's alone)."""
    gravity: GravityNoise | None = field(default_factory=GravityNoise)
    """Accelerometer gravity-direction factor on top of the IMU factor (None = off: the IMU factor and
    the motion priors alone carry the tilt)."""
    initial_attitude_sigma_deg: float = 5.0
    """Sigma of the start-up attitude from the first accelerometer and magnetometer samples."""
    gyro_calibration: GyroCalibrationPrior | None = None
    """Estimate the gyro's scale factors and misalignment as one session-wide variable (batch; None: a perfect gyro). The
    bias variable of keyframe k is then the gyro's EFFECTIVE bias over the interval after it, b - M_k c (M_k: how K turns
    that interval, ``factors.gyro.scale_rate_map``), and the bias walk and start-up prior hold b (as the head graph does)."""
    accel_range_m_s2: float = math.inf
    """The accelerometer's range (``consistency.saturation_level`` of the stream): a sample at it is clipped, a bound and not
    a measurement. An interval holding one gets ``CLIPPED_ACCEL_DENSITY`` (its velocity change unknown, the gyro's rotation
    kept) and a clipped keyframe sample no gravity factor."""
    unmodelled_acceleration: bool = False
    """Take the accelerometer's departure from gravity as acceleration the motion priors do not model: an interval whose
    readings' norms differ from g by an RMS of e (m/s^2) over T seconds gets the accelerometer density sqrt(d^2 + e^2 T)
    in its IMU factor (d declared): a velocity change of e T left unexplained, the least acceleration such readings imply,
    so zero-mean position and velocity priors cannot tilt the body to explain it. No constant to choose; where it applies
    is each system's: on for the gaze head (``systems.gaze``), off for the 9-axis system (``broad_model``; see there)."""

    def with_noise_scaled(self, factor: float) -> Attitude9Model:
        """The model told every sensor sigma ``factor`` times what it declares (gyro and accelerometer densities and
        bias walks, gravity direction, magnetometer heading): what a wrong declaration costs, for the reports."""
        imu = replace(self.imu, gyro_noise_rad_s_sqrt_hz=factor * self.imu.gyro_noise_rad_s_sqrt_hz,
                      accel_noise_m_s2_sqrt_hz=factor * self.imu.accel_noise_m_s2_sqrt_hz,
                      gyro_bias_walk_rad_s_sqrt_s=factor * self.imu.gyro_bias_walk_rad_s_sqrt_s,
                      accel_bias_walk_m_s2_sqrt_s=factor * self.imu.accel_bias_walk_m_s2_sqrt_s)
        gravity = None if self.gravity is None else replace(self.gravity, sigma_deg=factor * self.gravity.sigma_deg)
        return replace(self, imu=imu, gravity=gravity, mag=replace(self.mag, heading_sigma_deg=factor * self.mag.heading_sigma_deg))


def _mean_direction(vectors: FloatArray) -> tuple[FloatArray, float]:
    """Mean unit direction of readings and their RMS angle from it, rad."""
    unit = vectors / np.linalg.norm(vectors, axis=1, keepdims=True)
    mean = unit.mean(axis=0)
    mean /= np.linalg.norm(mean)
    return mean, float(np.sqrt(np.mean(np.arccos(np.clip(unit @ mean, -1.0, 1.0)) ** 2)))


def _angle_rad(direction: FloatArray, reading: FloatArray) -> float:
    return float(np.arccos(np.clip(direction @ (reading / np.linalg.norm(reading)), -1.0, 1.0)))


def initial_attitude(accel_body: FloatArray, mag_body: FloatArray | None) -> gtsam.Rot3:
    """world_R_body (ENU) from one gravity and one field reading (TRIAD); heading 0 without a field."""
    accel = np.asarray(accel_body, dtype=float)[None, :]
    return gtsam.Rot3(triad(accel, None if mag_body is None else np.asarray(mag_body, dtype=float)[None, :])[0])


def triad(accel_body: FloatArray, mag_body: FloatArray | None) -> FloatArray:
    """world_R_body matrices (N, 3, 3), ENU, from gravity and field readings (N, 3) each (TRIAD); heading 0 without a
    field, and about any horizontal axis where the field (or that default) lies along gravity."""
    up = np.asarray(accel_body, dtype=float)
    up = up / np.sqrt(np.einsum("ij,ij->i", up, up))[:, None]
    reference = np.asarray(mag_body, dtype=float) if mag_body is not None else np.broadcast_to([0.0, 1.0, 0.0], up.shape)
    east = np.cross(reference, up)
    degenerate = np.sqrt(np.einsum("ij,ij->i", east, east)) < 1e-9
    if degenerate.any():
        axis = np.where((np.abs(up[degenerate, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        east[degenerate] = np.cross(axis, up[degenerate])
    east /= np.sqrt(np.einsum("ij,ij->i", east, east))[:, None]
    north = np.cross(up, east)
    return np.stack([east, north, up], axis=1)  # rows: world axes in the body frame


class Attitude9Builder:
    """Measurements -> GraphIncrements for the online and the batch solver."""

    linear_keys: tuple[int, ...] = ()

    def __init__(self, model: Attitude9Model | None = None, deferred_mag: bool = False, prefix: str = "",
                 start_reference: FieldReference | None = None, start_attitude: tuple[gtsam.Rot3, float] | None = None):
        """``start_reference``: the undisturbed field at the first sample when it is known (a window of a long recording
        takes the one the window before it followed there: its own start may be in a disturbance); else the mean of the
        first ``MagNoise.reference_s``. ``start_attitude``: (world_R_body, sigma rad) at the first sample when it is
        known (the window before's estimate there), else gravity and the field's with ``initial_attitude_sigma_deg``."""
        self._start_attitude = start_attitude
        self.model = model or Attitude9Model()
        self.prefix = prefix
        """Key prefix: '' gives x/v/b keys; another letter ('t' -> 'T'...) lets two bodies share a graph."""
        letters = (prefix.upper(), prefix.lower(), chr(ord(prefix.upper()) + 1)) if prefix else ()
        self._key0 = tuple(int(gtsam.symbol(c, 0)) for c in letters) if prefix else (X(0), V(0), B(0))
        self._keyframe_letters = {key0 >> SYMBOL_INDEX_BITS for key0 in self._key0}  # gtsam Symbols: letter << 56 | keyframe
        self.deferred_mag = deferred_mag
        self._pending = GraphIncrement()
        self.keyframe_t: list[float] = []
        self.keyframe_index: list[int] = []
        """Sample index (counted over everything pushed) of every keyframe."""
        self.oldest_allowed_keyframe = 0
        self.mag_readings: list[tuple[int, FloatArray]] = []
        """(keyframe, calibrated body-frame field) for every heading factor made or deferred."""
        self.reference: FieldReference | None = None
        """The undisturbed field now (the start's, then as ``FieldTracker`` follows it)."""
        self._start_reference: FieldReference | None = start_reference  # the start's: where a batch pass's tracker begins
        self._reference_given = start_reference is not None
        self.followed: list[FieldReference] = []
        """The reference each of ``mag_readings`` was levelled against in the last batch pass (``reference_at``)."""
        self._field: FieldTracker | None = None
        self.new_fields: list[tuple[float, FieldReference]] = []
        """New fields taken as the reference (``FieldTracker.adopted``): online as they come; a batch, its last pass's."""
        self._keyframe_rate: list[float] = []  # RMS gyro rate over the interval before each keyframe, rad/s
        self._rest_reading: tuple[FloatArray, float] | None = None  # the last interval's at rest (``rest_reading``), if it was one
        # the gyro calibration (batch): keyframe k -> how K turns the preintegrated interval before it (``scale_rate_map``;
        # none before the first keyframe and across a dropout)
        self._calibrated = self.model.gyro_calibration is not None and deferred_mag
        self.calibration_key = int(gtsam.symbol("k", 1 + ord(prefix))) if prefix else GYRO_CALIBRATION
        """This body's gyro calibration key."""
        self._rate_map: dict[int, FloatArray] = {}
        self.gyro_calibration_estimate: FloatArray | None = None
        """The batch's estimate of the gyro's K (scale factors on the diagonal, misalignment off it)."""
        self.posterior_quat: list[FloatArray] = []
        """Online: keyframe k's attitude right after the update that added it (causal)."""
        self.posterior_gyro_bias: list[FloatArray] = []
        self._reference_samples: list[tuple[float, float]] = []
        self._hard_iron: HardIron | None = None
        self._nav = gtsam.NavState()
        self._bias = gtsam.imuBias.ConstantBias()
        self._interval: list[tuple[FloatArray, FloatArray, FloatArray]] = []  # blocks of (accel, gyro, dt) rows since the last keyframe
        self._interval_mag: list[FloatArray] = []  # and their magnetometer rows (MagNoise.interval_mean)
        self._last_t = np.nan
        self._count = 0
        # without a rate-dependent gyro term one set of preintegration parameters serves every interval
        self._params = preintegration_params(self.model.imu) if self.model.imu.gyro_scale_sigma == 0 else None
        self._still_run = 0  # consecutive still samples
        self._nominal_dt: float | None = None  # the sample period (median of the first block's steps)
        self._still_tail: tuple[FloatArray, FloatArray, FloatArray] | None = None  # gyro, accel, field: the newest still samples
        self.gaps: list[tuple[float, float]] = []
        """Dropouts bridged: (time of the last sample before, length), seconds."""
        self._bridges: set[int] = set()  # keyframes that follow a dropout
        self._restart: _Restart | None = None  # online, after a dropout (see ``_Restart``)
        self._solved = False
        self._keyframe_guess: list[gtsam.Rot3] = []  # each keyframe's attitude as first predicted
        # mean specific force over the interval before each keyframe, in the previous keyframe's frame (batch initial values)
        self._keyframe_accel: list[FloatArray] = []
        # the gyro samples a late tracker sample may need: one joined pair of arrays (times, readings), and the blocks
        # pushed since it was joined (joined when a tracker sample comes, or every _JOIN_BLOCKS blocks)
        self._recent_flat: tuple[FloatArray, FloatArray] = (np.empty(0), np.empty((0, 3)))
        self._recent: list[tuple[FloatArray, FloatArray]] = []
        self.tracker_factors = 0
        """How many attitude-tracker samples became factors."""
        self.tracker_readings: dict[int, gtsam.Rot3] = {}
        """Keyframe -> tracker_R_world * world_R_body(k) of its latest tracker sample (batch initial values)."""
        self._tracker_fed = 0
        self.tracker_dropped = 0
        """Tracker samples older than the online window or before the first keyframe (not used)."""

    # ------------------------------------------------------------------ keys
    # gtsam's Symbol is (letter << 56) | index: keyframe k's key is its letter's key 0 plus k, integer arithmetic
    # instead of a call into gtsam (a dozen keys per keyframe)
    def X(self, k: int) -> int:
        """This body's pose key at keyframe k."""
        return self._key0[0] + k

    def V(self, k: int) -> int:
        """This body's velocity key at keyframe k."""
        return self._key0[1] + k

    def B(self, k: int) -> int:
        """This body's bias key at keyframe k."""
        return self._key0[2] + k

    # ------------------------------------------------------------------ protocol of the online solver

    @property
    def started(self) -> bool:
        return bool(self.keyframe_t)

    @property
    def latest_keyframe(self) -> int:
        return len(self.keyframe_t) - 1

    def state_keys(self, k: int) -> tuple[int, int | None]:
        return self.X(k), self.B(k)

    def keyframe_of(self, key: int) -> int | None:
        """The keyframe of a variable: this body's pose, velocity and bias, and another sensor's per-keyframe variables
        (``add_variable(..., per_keyframe=True)``); None for one that spans many (the tracker's frame, the gyro
        calibration). With it the online solver eliminates in time order and marginalises old keyframes inside iSAM2
        (``OnlineSmoother._time_order``, ``_marginalize_in_place``)."""
        return key & SYMBOL_INDEX_MASK if key >> SYMBOL_INDEX_BITS in self._keyframe_letters else None

    def read_latest(self, isam: gtsam.ISAM2, k: int) -> tuple[gtsam.Rot3, FloatArray]:
        """Read keyframe k's posterior (pose, velocity, bias): the next prediction starts from it."""
        pose = isam.calculateEstimatePose3(self.X(k))
        self._nav = gtsam.NavState(pose, isam.calculateEstimateVector(self.V(k)))
        self._bias = isam.calculateEstimateConstantBias(self.B(k))
        self._solved = True
        gyro_bias = np.asarray(self._bias.gyroscope())
        rotation = pose.rotation()
        quat = quat_wxyz_from_rot3(rotation)
        if len(self.posterior_quat) == k:  # the usual case: one update per new keyframe
            self.posterior_quat.append(quat)
            self.posterior_gyro_bias.append(gyro_bias)
            return rotation, gyro_bias
        while len(self.posterior_quat) <= k:
            self.posterior_quat.append(np.full(4, np.nan))
            self.posterior_gyro_bias.append(np.zeros(3))
        self.posterior_quat[k] = quat
        self.posterior_gyro_bias[k] = gyro_bias
        return rotation, gyro_bias

    def solved_keyframes(self) -> tuple[np.ndarray, FloatArray, FloatArray]:
        """The keyframes an update solved as it came: (sample index, attitude (w, x, y, z), gyro bias) of each, what a
        causal estimate carries on by the gyro (``fill_samples``). An online solver that updates every few keyframes
        (``OnlineConfig.update_every``) solves only those; the samples after another come from the last solved one, as
        they did live."""
        quat = np.array(self.posterior_quat, dtype=float).reshape(-1, 4)
        solved = np.isfinite(quat[:, 0])
        index = np.array(self.keyframe_index[: len(quat)], dtype=int)
        return index[solved], quat[solved], np.array(self.posterior_gyro_bias, dtype=float).reshape(-1, 3)[solved]

    def set_latest(self, world_R_body: gtsam.Rot3, bias: FloatArray) -> None:
        """Part of the solver protocol; ``read_latest`` already took the full state."""

    def take(self) -> GraphIncrement:
        out, self._pending = self._pending, GraphIncrement()
        return out

    def add_factor(self, oldest_keyframe: int, factor: gtsam.NonlinearFactor) -> None:
        """A factor another sensor makes on this graph's keyframes (it goes out with the next ``take``)."""
        self._pending.add(oldest_keyframe, factor)

    def add_variable(self, key: int, value: FloatArray, per_keyframe: bool = False) -> None:
        """The initial guess of a point or vector variable another sensor adds (goes out with the next ``take``).
        ``per_keyframe``: the key is a gtsam Symbol whose index is its keyframe (the online solver then eliminates and
        marginalises it with that keyframe's states, ``keyframe_of``)."""
        if per_keyframe:
            self._keyframe_letters.add(key >> SYMBOL_INDEX_BITS)
        self._pending.insert(key, np.asarray(value, dtype=float))

    @property
    def predicted_attitude(self) -> gtsam.Rot3:
        """The newest keyframe's attitude as predicted (dead reckoning from the last posterior)."""
        return self._nav.attitude()

    # ------------------------------------------------------------------ measurements

    def add_samples(self, t: FloatArray, gyro_rad_s: FloatArray, accel_m_s2: FloatArray, mag_raw: FloatArray | None,
                    on_keyframe: Callable[[float], None] | None = None) -> None:
        """Push synchronous samples (rows) in time order; keyframes close as their time comes.

        The block is handled in numpy (times, rests, where keyframes close); Python runs once per keyframe. A time
        that does not increase raises before any sample of the block is taken. ``on_keyframe(t_s)`` is called as each
        keyframe is made (the first on the first sample), with its factors pending: a replay pushes a whole session
        at once and updates its solver there, which is the same as pushing it keyframe by keyframe without the
        numpy work per block."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        gyro = np.atleast_2d(np.asarray(gyro_rad_s, dtype=float))
        accel = np.atleast_2d(np.asarray(accel_m_s2, dtype=float))
        mag = None if mag_raw is None or not self.model.use_mag else self.model.mag_calibration.apply(np.atleast_2d(mag_raw))
        if len(t) == 0:
            return
        still = still_samples(gyro, accel, self.model.motion, self.model.imu.gravity_m_s2)
        first = 0
        if not self.started:
            self._still_run = self._still_run + 1 if still[0] else 0
            self._start(float(t[0]), accel[0], None if mag is None else mag[0])
            first = 1
            if on_keyframe is not None:
                on_keyframe(float(t[0]))
        if first >= len(t):
            return
        t, gyro, accel, still = t[first:], gyro[first:], accel[first:], still[first:]
        mag = None if mag is None else mag[first:]
        if self._nominal_dt is None and len(t) > 1:
            self._nominal_dt = float(np.median(np.diff(t)))
        gap = self._gap_after(t)
        if gap is not None:  # the samples before the gap, the bridge, then the rest (a gap in them is found in turn)
            if gap > 0:
                self._push(t[:gap], gyro[:gap], accel[:gap], None if mag is None else mag[:gap], still[:gap], on_keyframe)
            self._bridge(float(t[gap]), accel[gap], None if mag is None else mag[gap], bool(still[gap]))
            if on_keyframe is not None:
                on_keyframe(float(t[gap]))
            rest = slice(gap + 1, None)
            if gap + 1 < len(t):
                self.add_samples(t[rest], gyro[rest], accel[rest], None if mag_raw is None else np.atleast_2d(mag_raw)[first:][rest], on_keyframe)
            return
        self._push(t, gyro, accel, mag, still, on_keyframe)

    def _gap_after(self, t: FloatArray) -> int | None:
        """Index of the first sample that follows a dropout (``GAP_PERIODS`` nominal periods without a sample), or None."""
        if self._nominal_dt is None:
            return None
        limit = max(GAP_PERIODS * self._nominal_dt, GAP_MIN_S)
        if t[0] - self._last_t > limit:
            return 0
        jumps = np.flatnonzero(np.diff(t) > limit)
        return int(jumps[0]) + 1 if len(jumps) else None

    def _bridge(self, t: float, accel: FloatArray, mag: FloatArray | None, still: bool) -> None:
        """A keyframe at the first sample after a dropout: the motion in the gap is unknown, so the previous keyframe
        (closed at the last sample before it) is tied to it by a random-walk factor as wide as the gap allows (the
        attitude within ``GAP_RATE_RAD_S`` x the gap, at most pi; velocity and bias by their own walks over the gap),
        not by preintegrated motion; gravity and the magnetometer then fix the new keyframe."""
        if self._interval:  # close a keyframe at the last sample before the gap (its index: one before the count)
            self._count -= 1
            self._close_keyframe(self._interval[-1][0][-1], None)
            self._count += 1
        k = len(self.keyframe_t)
        model = self.model
        gap_s = t - self._last_t
        self.gaps.append((self._last_t, gap_s))
        tail = self._still_tail if self._still_run * (self._nominal_dt or 0.0) >= model.motion.rest_window_s else None
        at_rest = still and tail is not None and mag is not None and all(
            _angle_rad(direction, reading) <= _SAME_READING_SIGMAS * math.sqrt(2.0) * max(scatter, 1e-4)
            for (direction, scatter), reading in zip((_mean_direction(tail[1]), _mean_direction(tail[2])), (accel, mag), strict=True))
        if at_rest:
            # at rest before (the model's rest detector), still after, and gravity and the field where they were within
            # their scatter (a body moved and put down changes one of them): it did not turn. As fast as the gyro turned
            # (less its bias) while it was still, over the gap; a Cauchy kernel lets the evidence overturn it
            assert tail is not None
            rate_rad_s = float(np.sqrt(np.mean(np.sum((tail[0] - np.asarray(self._bias.gyroscope())) ** 2, axis=1))))
            sigma_rot = max(rate_rad_s, 1e-4) * gap_s
            attitude = self._nav.attitude()
        else:
            sigma_rot = min(math.pi, GAP_RATE_RAD_S * gap_s)
            # the first guess after the gap: gravity and the field where there is a magnetometer (what the body is now),
            # else the attitude before it
            attitude = initial_attitude(accel, mag) if mag is not None else self._nav.attitude()
            self._bridges.add(k)
        noise = robust(gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma_rot] * 3 + [1e3] * 3)), _REST_CAUCHY_K if at_rest else 0.0)
        self._rest_reading = None  # a rest's readings are compared across one interval, not across a gap
        add = self._pending.add
        add(k - 1, gtsam.BetweenFactorPose3(self.X(k - 1), self.X(k), gtsam.Pose3(), noise))
        add(k - 1, bias_walk_factor(self.B(k - 1), self.B(k), gap_s, model.imu, gyro=not self._calibrated))
        add(k, velocity_prior_factor(self.V(k), model.motion.velocity_sigma_m_s if math.isfinite(model.motion.velocity_sigma_m_s) else 50.0))
        if math.isfinite(model.motion.position_sigma_m):
            add(k, position_prior_factor(self.X(k), model.motion.position_sigma_m))
        if model.gravity is not None and not self._clipped(accel):
            add(k, gravity_factor(self.X(k), accel, model.gravity, model.imu.gravity_m_s2))
        guess = gtsam.NavState(attitude, self._nav.position(), np.zeros(3))
        self._pending.insert(self.X(k), guess.pose())
        self._pending.insert(self.V(k), guess.velocity())
        self._pending.insert(self.B(k), self._bias)
        self._still_run = self._still_run + 1 if still else 0
        self.keyframe_t.append(t)
        self.keyframe_index.append(self._count)
        self._last_t, self._count = t, self._count + 1
        self._keyframe_guess.append(guess.attitude())
        self._keyframe_accel.append(np.asarray(accel, dtype=float))
        self._keyframe_rate.append(0.0)  # a keyframe after a dropout: no interval before it
        self._nav = guess
        self._restart = _Restart() if self._solved and not at_rest else None  # the batch starts again in ``inertial_initial``
        self._after_keyframe(k, guess.attitude(), mag)

    def _push(self, t: FloatArray, gyro: FloatArray, accel: FloatArray, mag: FloatArray | None, still: FloatArray,
              on_keyframe: Callable[[float], None] | None) -> None:
        """Samples without a dropout among them or before them."""
        dt = np.empty_like(t)  # np.diff(prepend=) costs ~30 us per call: a keyframe's worth of samples is pushed at a time online
        dt[0] = t[0] - self._last_t
        np.subtract(t[1:], t[:-1], out=dt[1:])
        if not (dt > 0).all():
            i = int(np.argmin(dt > 0))
            previous = self._last_t if i == 0 else t[i - 1]
            raise ValueError(f"sample {self._count + i}: time {t[i]:.6f} s does not increase (previous {previous:.6f} s)")
        # consecutive still samples up to each sample (the run carried in from the previous block)
        position = np.arange(len(t))
        last_moving = np.maximum.accumulate(np.where(still, -1, position))
        still_run = np.where(last_moving < 0, position + 1 + self._still_run, position - last_moving)
        count0 = self._count
        self._recent.append((t, gyro))
        if len(self._recent) >= _JOIN_BLOCKS:  # bounded work and memory when no tracker sample comes (a live feed pushes single samples)
            self._join_recent()
        period = self.model.keyframe_period_s
        due_s = None
        if len(t) > _DUE_CHUNK:  # a long push (a replay, the batch): one binary search per keyframe
            due_s = t + 0.5 * dt
            if not (due_s[1:] > due_s[:-1]).all():  # very uneven steps: the look-ahead
                due_s = None
        interval_mean = self.model.mag.interval_mean
        carried = None
        if mag is not None and interval_mean and not self._solved and len(t) >= 256:  # a long push before any solve (the batch): every
            carried = CarriedReadings(mag, gyro, dt, np.asarray(self._bias.gyroscope()))  # interval's mean from one numpy pass
        start = 0
        while start < len(t):
            j = _first_due(t, dt, start, self.keyframe_t[-1], period, due_s)
            if j < 0:
                break
            self._interval.append((accel[start : j + 1], gyro[start : j + 1], dt[start : j + 1]))
            reading = None if mag is None else mag[j]
            if carried is not None and not self._interval_mag:  # the interval lies within this push
                reading = carried.mean(start, j)
            elif mag is not None and interval_mean:
                self._interval_mag.append(mag[start : j + 1])
            self._last_t, self._count, self._still_run = float(t[j]), count0 + j, int(still_run[j])
            self._close_keyframe(accel[j], reading)
            if on_keyframe is not None:
                on_keyframe(self._last_t)
            start = j + 1
        if start < len(t):
            self._interval.append((accel[start:], gyro[start:], dt[start:]))
            if mag is not None and interval_mean:
                self._interval_mag.append(mag[start:])
        self._last_t, self._count, self._still_run = float(t[-1]), count0 + len(t), int(still_run[-1])
        if still[-1] and mag is not None:  # the block's last still samples (views: a rest bridge reads them, rarely)
            tail = slice(len(t) - min(int(still_run[-1]), len(t)), None)
            self._still_tail = (gyro[tail], accel[tail], mag[tail])
        elif not still[-1]:
            self._still_tail = None

    def _start(self, t: float, accel: FloatArray, mag: FloatArray | None) -> None:
        model = self.model
        rot, sigma = self._start_attitude or (initial_attitude(accel, mag), float(np.deg2rad(model.initial_attitude_sigma_deg)))
        self._nav = gtsam.NavState(rot, np.zeros(3), np.zeros(3))
        pose_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma] * 3 + [0.01] * 3))
        self._pending.add(0, gtsam.PriorFactorPose3(self.X(0), self._nav.pose(), pose_noise))
        self._pending.add(0, velocity_prior_factor(self.V(0), model.motion.velocity_sigma_m_s if np.isfinite(model.motion.velocity_sigma_m_s) else 50.0))
        self._pending.add(0, bias_prior_factor(self.B(0), model.imu, gyro=not self._calibrated))
        self._pending.insert(self.X(0), self._nav.pose())
        self._pending.insert(self.V(0), np.zeros(3))
        self._pending.insert(self.B(0), self._bias)
        self.keyframe_t.append(t)
        self.keyframe_index.append(self._count)
        self._keyframe_guess.append(rot)
        self._keyframe_accel.append(np.asarray(accel, dtype=float))
        self._keyframe_rate.append(0.0)
        self._after_keyframe(0, rot, mag)
        self._last_t = t
        self._count += 1

    def _clipped(self, accel: FloatArray) -> bool:
        """Whether a sample (or a block of them) reached the accelerometer's range (``Attitude9Model.accel_range_m_s2``)."""
        return math.isfinite(self.model.accel_range_m_s2) and bool(clipped_samples(np.atleast_2d(accel), self.model.accel_range_m_s2).any())

    def _preintegrate(self, accel: FloatArray, gyro: FloatArray, dt: FloatArray, rate_rad_s: float) -> gtsam.PreintegratedImuMeasurements:
        """The interval's samples, with a gyro noise that grows with the rotation rate (``rate_rad_s``, the interval's RMS:
        scale errors)."""
        params = self._params
        density = CLIPPED_ACCEL_DENSITY if self._clipped(accel) else self._unmodelled_density(accel, float(dt.sum()))
        if params is None or density is not None:
            params = preintegration_params(self.model.imu, rate_rad_s, float(dt.sum()))
        if density is not None:
            params.setAccelerometerCovariance(density**2 * np.eye(3))
        pim = gtsam.PreintegratedImuMeasurements(params, self._bias)
        integrate = pim.integrateMeasurement
        for a, w, d in zip(accel, gyro, dt.tolist(), strict=True):
            integrate(a, w, d)
        return pim

    def _unmodelled_density(self, accel: FloatArray, interval_s: float) -> float | None:
        """The accelerometer density of an interval under ``Attitude9Model.unmodelled_acceleration``; None: the declared one."""
        if not self.model.unmodelled_acceleration:
            return None
        excess_sq = float(np.mean((np.linalg.norm(accel, axis=1) - self.model.imu.gravity_m_s2) ** 2))
        return math.sqrt(self.model.imu.accel_noise_m_s2_sqrt_hz**2 + excess_sq * interval_s)

    def _close_keyframe(self, accel: FloatArray, mag: FloatArray | None) -> None:
        k = len(self.keyframe_t)
        model = self.model
        if len(self._interval) == 1:  # the interval came in one block (online pushes a keyframe's worth at a time)
            interval_accel, interval_gyro, interval_dt = self._interval[0]
        else:
            interval_accel, interval_gyro, interval_dt = (np.concatenate(blocks) for blocks in zip(*self._interval, strict=True))
        self._interval = []
        if self._interval_mag:
            readings = np.concatenate(self._interval_mag)
            if mag is not None and len(readings) == len(interval_gyro):
                mag = interval_mean_reading(readings, interval_gyro, interval_dt, np.asarray(self._bias.gyroscope()))
            self._interval_mag = []
        self._keyframe_rate.append(float(np.sqrt(np.mean(np.einsum("ij,ij->i", interval_gyro, interval_gyro)))))
        pim = self._preintegrate(interval_accel, interval_gyro, interval_dt, self._keyframe_rate[-1])
        if self._calibrated:
            self._rate_map[k] = scale_rate_map(interval_gyro, interval_dt, np.asarray(self._bias.gyroscope()))
        self._keyframe_accel.append(pim.deltaVij() / pim.deltaTij())  # rotated sample by sample: the body may turn a lot in 0.2 s
        predicted = pim.predict(self._nav, self._bias)
        if not self._solved:
            # no posterior yet (batch): keep the attitude, not the accelerometer's drifting double integral
            predicted = gtsam.NavState(predicted.attitude(), np.zeros(3), np.zeros(3))
        add = self._pending.add
        if self._restart is not None:
            self._restart.add(pim, mag)
            if self._restart.seconds >= RESTART_S - 1e-9:
                predicted = gtsam.NavState(self._restart.world_R_body(), predicted.position(), predicted.velocity())
                sigma = np.deg2rad(model.initial_attitude_sigma_deg)
                noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma] * 3 + [_FREE_TRANSLATION_SIGMA_M] * 3))
                add(k, gtsam.PriorFactorPose3(self.X(k), predicted.pose(), noise))
                self._restart = None
        add(k - 1, gtsam.ImuFactor(self.X(k - 1), self.V(k - 1), self.X(k), self.V(k), self.B(k - 1), pim))
        add(k - 1, bias_walk_factor(self.B(k - 1), self.B(k), pim.deltaTij(), model.imu, gyro=not self._calibrated))
        # an infinite sigma drops the pseudo-measurement (a vehicle travels; the start pose fixes the gauge)
        if math.isfinite(model.motion.position_sigma_m):
            add(k, position_prior_factor(self.X(k), model.motion.position_sigma_m))
        if math.isfinite(model.motion.velocity_sigma_m_s):
            add(k, velocity_prior_factor(self.V(k), model.motion.velocity_sigma_m_s))
        rest_samples = int(round(model.motion.rest_window_s / max(pim.deltaTij(), 1e-9) * (self._count - self.keyframe_index[-1])))
        if self._still_run >= max(rest_samples, 1):
            add(k, velocity_prior_factor(self.V(k), model.motion.rest_velocity_sigma_m_s))
        # the interval and the rest window before it still, and it reads what the interval before read: its readings are
        # the bias (the interval's bias variable is the keyframe's before it)
        resting = math.isfinite(model.motion.rest_rate_sigma_rad_s) and self._still_run >= len(interval_gyro) + rest_samples
        previous, self._rest_reading = self._rest_reading, rest_reading(interval_gyro, interval_dt) if resting else None
        if previous is not None and self._rest_reading is not None and steady_rest(previous, self._rest_reading):
            add(k - 1, zero_rate_factor(self.B(k - 1), self._rest_reading, model.motion.rest_rate_sigma_rad_s))
        if model.gravity is not None and not self._clipped(accel):
            add(k, gravity_factor(self.X(k), accel, model.gravity, model.imu.gravity_m_s2))
        self._pending.insert(self.X(k), predicted.pose())
        self._pending.insert(self.V(k), predicted.velocity())
        self._pending.insert(self.B(k), self._bias)
        self.keyframe_t.append(self._last_t)
        self.keyframe_index.append(self._count)
        self._keyframe_guess.append(predicted.attitude())
        self._nav = predicted
        self._after_keyframe(k, predicted.attitude(), mag)

    def _after_keyframe(self, k: int, world_R_body: gtsam.Rot3, mag: FloatArray | None) -> None:
        if mag is None:
            return
        if self._hard_iron is not None:
            mag = self._hard_iron.correct(self.keyframe_t[-1], world_R_body, mag)
        self.mag_readings.append((k, mag))
        norm, dip = field_norm_dip(world_R_body, mag)
        if self._reference_given and self.reference is None:
            self.reference = self._start_reference
        if self.reference is None or (not self._reference_given and self.keyframe_t[-1] - self.keyframe_t[0] <= self.model.mag.reference_s):
            self._reference_samples.append((norm, dip))
            self.reference = self._start_reference = FieldReference(*np.mean(self._reference_samples, axis=0))
        else:
            if self._hard_iron is None and self.model.mag.hard_iron_s > 0:  # a carried magnet's offset, from the reference on
                self._hard_iron = HardIron(self.model.mag, self.reference)
            if self._field is None and not self.deferred_mag:  # a batch follows it in each pass, with that pass's attitudes
                self._field = self.field_tracker()
                if self._field is not None:
                    self.new_fields = self._field.adopted  # the tracker's own list: it grows there
            if self._field is not None:
                self.reference = self._followed(self._field, k, norm, dip)
                if self._hard_iron is not None:
                    self._hard_iron.reference = self.reference
        if not self.deferred_mag:
            self._pending.add(k, self._heading(k, world_R_body, mag, norm, dip, robust=True))

    def notes(self) -> list[str]:
        """What a user is told about the run: each dropout bridged, each new field taken as the reference (a user sees where
        the estimate changed its mind about the room)."""
        after = "gravity and the field after it" if self.model.use_mag else "gravity after it (no magnetometer: the heading across it is not observed)"
        gaps = [f"no gyro/accel/mag sample for {length_s:.2f} s after t = {after_s:.2f} s: the gap is bridged (the attitude across it "
                f"comes from {after}, not from the gyro)" for after_s, length_s in self.gaps]
        fields = [f"from t = {t_s:.1f} s the magnetometer's reference field is one of norm {field.norm:.1f} (the readings' unit) and dip "
                  f"{math.degrees(field.dip_rad):.1f} deg: a field off the start's that held steady while the sensor turned (another "
                  "place's Earth field, or a disturbance that did not change; MagNoise.new_field_s)" for t_s, field in self.new_fields]
        return gaps + fields

    def extras(self) -> dict[str, Any]:
        """The run's counts for an estimate's extras: the tracker's samples used and dropped, the new fields' times (s), the
        gyro calibration estimated (batch)."""
        out: dict[str, Any] = {}
        if self.tracker_factors or self.tracker_dropped:
            out.update(tracker_factors=self.tracker_factors, tracker_dropped=self.tracker_dropped)
        if self.new_fields:
            out["new_field_s"] = [t for t, _ in self.new_fields]
        if self.gyro_calibration_estimate is not None:  # K: the reading is scaled by I + K
            out["gyro_calibration"] = self.gyro_calibration_estimate.round(5).tolist()
        return out

    def field_tracker(self) -> FieldTracker | None:
        """A tracker of the undisturbed field from the start's reference, or None when the model keeps that reference
        (``MagNoise.reference_tau_s`` and ``new_field_s`` both 0)."""
        mag = self.model.mag
        if self._start_reference is None or (mag.reference_tau_s <= 0 and mag.new_field_s <= 0):
            return None
        return FieldTracker(mag, self._start_reference)

    def _followed(self, field: FieldTracker | None, k: int, norm: float, dip: float) -> FieldReference:
        """The reference at keyframe k: ``field`` fed keyframe k's levelled reading, or the start's when it is None."""
        if field is None:
            assert self.reference is not None
            return self.reference
        return field.update(self.keyframe_t[k], norm, dip, self._keyframe_rate[k])

    def _heading(self, k: int, world_R_body: gtsam.Rot3, mag: FloatArray, norm: float, dip: float, robust: bool,
                 reference: FieldReference | None = None) -> gtsam.AttitudeFactorPose3:
        reference = reference or self.reference
        assert reference is not None
        sigma = heading_sigma_rad(self.model.mag, reference, norm, dip)
        return heading_factor(self.X(k), world_R_body, mag, sigma, self.model.mag.cauchy_k if robust else 0.0)

    def add_attitude(self, t_s: float, tracker_R_body: gtsam.Rot3, sigma_rad: float) -> bool:
        """An attitude tracker's sample (its SAMPLE time; it may arrive late) as a factor on the keyframe before it.

        The tracker reads tracker_R_body = tracker_R_world * world_R_body(k) * Delta, Delta the gyro's rotation
        from keyframe k to ``t_s`` (bias-corrected, at most one keyframe period). tracker_R_world is the constant
        ``TRACKER_WORLD`` variable, so the tracker's room frame need not be aligned with ENU: gravity and the
        magnetometer align it, and the tracker then holds heading through magnetic disturbances. The factor is
        a ``BetweenFactorPose3`` (C++) whose translation part is left free. False when the sample is not used.
        """
        k = int(np.searchsorted(self.keyframe_t, t_s + 1e-9, side="right")) - 1
        if k < 0 or k < self.oldest_allowed_keyframe or t_s > self._last_t + 1e-9:
            self.tracker_dropped += 1
            return False
        delta = self._gyro_rotation(self.keyframe_t[k], t_s)
        measured = tracker_R_body.compose(delta.inverse())  # tracker_R_world * world_R_body(k)
        if self.tracker_factors == 0:
            solved = k < len(self.posterior_quat) and np.isfinite(self.posterior_quat[k][0])
            guess = rot3_from_quat_wxyz(self.posterior_quat[k]) if solved else self._keyframe_guess[k]
            world_R_tracker = guess.compose(measured.inverse())
            self._pending.insert(TRACKER_WORLD, gtsam.Pose3(world_R_tracker, np.zeros(3)))
            # the rotation is free (10 rad); the translation, which no factor sees, is pinned at zero
            loose = gtsam.noiseModel.Diagonal.Sigmas(np.r_[[10.0] * 3, [1.0] * 3])
            self._pending.add(k, gtsam.PriorFactorPose3(TRACKER_WORLD, gtsam.Pose3(world_R_tracker, np.zeros(3)), loose))
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma_rad] * 3 + [_FREE_TRANSLATION_SIGMA_M] * 3))
        self._pending.add(k, gtsam.BetweenFactorPose3(TRACKER_WORLD, self.X(k), gtsam.Pose3(measured, np.zeros(3)), noise))
        self.tracker_readings[k] = measured
        self.tracker_factors += 1
        return True

    def feed_tracker(self, track: AttitudeTrack, now_s: float = np.inf) -> None:
        """Every sample of ``track`` that has arrived by ``now_s`` (sample time + latency) and was not fed yet."""
        stop = int(np.searchsorted(track.t, now_s - track.latency_s + 1e-9, side="right"))  # one latency: arrival order = time order
        for n in range(self._tracker_fed, stop):
            self.add_attitude(float(track.t[n]), rot3_from_quat_wxyz(track.tracker_R_body_wxyz[n]), track.sigma_rad)
        self._tracker_fed = max(self._tracker_fed, stop)

    def heading_passes(self) -> tuple[bool, ...]:
        """Robust flags of the batch's heading passes (each levels the field with the previous attitude).

        Without a tracker: Gaussian then Cauchy (the first levels with ``inertial_initial``'s attitude). With a tracker, a
        Gaussian pass would let a disturbed stretch pull the one alignment every keyframe shares, so both
        are robust (the second levels with the first's tilt: a tilt error e becomes ~e*tan(dip) of heading).
        """
        if not self.mag_readings:
            return (True,)
        return (True, True) if self.tracker_readings else (False, True)

    def tracker_seeded(self, values: gtsam.Values) -> gtsam.Values:
        """Batch initial values with every keyframe the tracker saw set from its reading (through the first
        alignment guess): dead reckoning from a zero bias drifts tens of degrees over minutes."""
        if not self.tracker_readings:
            return values
        world_R_tracker = values.atPose3(TRACKER_WORLD).rotation()
        for k, measured in self.tracker_readings.items():
            values.update(self.X(k), gtsam.Pose3(world_R_tracker.compose(measured), values.atPose3(self.X(k)).translation()))
        return values

    def inertial_initial(self, values: gtsam.Values) -> gtsam.Values:
        """Batch initial attitudes from a filter in the gyro's own frame (the idea of VQF, Laidig & Seel 2023, Sec. 3):
        each keyframe's specific force, turned into the frame the gyro alone integrates from the start, is low-passed
        there with a 3 s time constant (VQF's published default ``tauAcc``) and the tilt is corrected so that the mean
        points up; the heading is pulled to the levelled field with a Kalman gain, the field's sigma from the heading
        factor's own model (disturbances count less) against the drift of an unknown gyro bias (its prior sigma).

        Why: a translating hand's acceleration over one 0.2 s interval can be as large as gravity (BROAD trial 15: the
        interval's mean specific force 13 deg off vertical at the median, 100 deg at the 95th percentile); in the inertial
        frame the velocity stays bounded, so over seconds the mean specific force is gravity. The complementary filter
        this replaced (keyframe TRIAD targets at gain 0.1) started 30-67 deg off on BROAD's fast and disturbed trials and
        Levenberg-Marquardt needed up to 19 iterations to get back; the batch optimum does not depend on the start.
        """
        if self.tracker_readings or not self.keyframe_t:
            return values
        model = self.model
        gyro_frame = [values.atPose3(self.X(k)).rotation() for k in range(len(self.keyframe_t))]  # the gyro alone, zero bias
        fields = dict(self.mag_readings)
        world_R_gyro = gtsam.Rot3()  # the start's TRIAD is keyframe 0's attitude already
        mean_force = gyro_frame[0].rotate(self._keyframe_accel[0])
        heading_var = np.deg2rad(model.initial_attitude_sigma_deg) ** 2
        drift_var = model.imu.gyro_bias_prior_rad_s**2
        field = self.field_tracker()
        for k in range(1, len(self.keyframe_t)):
            if k in self._bridges:  # after a dropout the gyro's frame starts again from gravity and the field, as at the start
                world_R_gyro = gtsam.Rot3()
                mean_force = gyro_frame[k].rotate(self._keyframe_accel[k])
                heading_var = np.deg2rad(model.initial_attitude_sigma_deg) ** 2
                continue
            dt = self.keyframe_t[k] - self.keyframe_t[k - 1]
            force = gyro_frame[k - 1].rotate(self._keyframe_accel[k])
            mean_force = mean_force + min(1.0, dt / _INERTIAL_TAU_S) * (force - mean_force)
            up = world_R_gyro.rotate(mean_force)
            axis = np.array([up[1], -up[0], 0.0])  # up x z: the tilt error's axis
            sin = math.hypot(up[0], up[1])
            if sin > 1e-12:
                world_R_gyro = gtsam.Rot3.Rodrigues(axis * (math.atan2(sin, up[2]) / sin)).compose(world_R_gyro)
            attitude = world_R_gyro.compose(gyro_frame[k])
            heading_var += drift_var * dt * dt
            mag = fields.get(k)
            if mag is not None and self.reference is not None:
                norm, dip = field_norm_dip(attitude, mag)
                sigma = heading_sigma_rad(model.mag, self._followed(field, k, norm, dip), norm, dip)
                gain = heading_var / (heading_var + sigma * sigma)
                heading_var *= 1.0 - gain
                x, y, _ = attitude.rotate(mag).tolist()
                world_R_gyro = gtsam.Rot3.Rz(gain * math.atan2(x, y)).compose(world_R_gyro)  # turns the field toward north
                attitude = world_R_gyro.compose(gyro_frame[k])
            pose = values.atPose3(self.X(k))
            values.update(j=self.X(k), pose3=gtsam.Pose3(attitude, pose.translation()))  # by keyword: no search of the ~46 overloads
        return values

    def _gyro_rotation(self, t0: float, t1: float) -> gtsam.Rot3:
        """body(t0)_R_body(t1) from the bias-corrected gyro samples in (t0, t1] (sample i covers (t_{i-1}, t_i])."""
        if self._recent:
            self._join_recent()
        times, gyro = self._recent_flat
        i0 = int(np.searchsorted(times, t0 + 1e-9, side="left"))
        i1 = int(np.searchsorted(times, t1 + 1e-9, side="right"))
        bias = np.asarray(self._bias.gyroscope())
        out = gtsam.Rot3()
        for i in range(i0, i1):
            prev = times[i - 1] if i > 0 else times[i]
            out = out.compose(gtsam.Rot3.Expmap((gyro[i] - bias) * (times[i] - prev)))
        return out

    def _join_recent(self) -> None:
        """Join the pushed blocks to the kept samples; online, drop those older than ``RECENT_GYRO_S`` before the newest
        sample taken (a block pushed whole may reach far beyond it; the batch keeps all)."""
        times = np.concatenate([self._recent_flat[0], *(block[0] for block in self._recent)])
        gyro = np.concatenate([self._recent_flat[1], *(block[1] for block in self._recent)])
        self._recent = []
        if not self.deferred_mag:
            keep = int(np.searchsorted(times, min(times[-1], self._last_t) - RECENT_GYRO_S, side="left"))
            times, gyro = times[keep:], gyro[keep:]
        self._recent_flat = (times, gyro)

    def with_calibration(self, graph: gtsam.NonlinearFactorGraph, order: gtsam.Ordering, values: gtsam.Values) -> gtsam.Values:
        """The batch's graph, ordering and initial values with the gyro calibration (``calibration_factors``) where the
        model estimates one: its factors added, its key eliminated last (it is in every gyro bias factor)."""
        factors, initial = self.calibration_factors()
        for factor in factors:
            graph.add(factor)
        if factors:
            order.push_back(self.calibration_key)
            values.insert(initial)
        return values

    def read_calibration(self, values: gtsam.Values) -> None:
        """Keep a batch solution's gyro calibration (``gyro_calibration_estimate``, reported in ``extras``)."""
        if values.exists(self.calibration_key):
            self.gyro_calibration_estimate = np.asarray(values.atVector(self.calibration_key)).reshape(3, 3)

    def calibration_factors(self) -> tuple[list[gtsam.NonlinearFactor], gtsam.Values]:
        """The gyro calibration's factors over the whole recording (batch, ``Attitude9Model.gyro_calibration``) and its
        initial value: its prior, and the gyro bias's start-up prior and walk through the effective biases (keyframe k's
        the interval after it: beta_k = b_k - M_k c, ``scale_rate_map``, so b_k = beta_k + M_k c). Empty without one."""
        calibration = self.model.gyro_calibration
        values = gtsam.Values()
        if calibration is None or not self._calibrated:
            return [], values
        values.insert(self.calibration_key, np.zeros(9))
        count = len(self.keyframe_t)
        # keyframe k's effective bias covers the interval after it (the last keyframe's none: its bias is b itself)
        maps = [self._rate_map.get(k + 1, _NO_RATE_MAP) for k in range(count)]
        at_zero = gtsam.Values(values)  # every bias and the calibration at zero: the linear factors' point (each copies its keys)
        for k in range(count):
            at_zero.insert(self.B(k), gtsam.imuBias.ConstantBias())
        imu, cal = self.model.imu, self.calibration_key
        out: list[gtsam.NonlinearFactor] = [calibration_prior_factor(cal, calibration),
                                            linear_factor([(self.B(0), _GYRO_ROWS), (cal, maps[0])], imu.gyro_bias_prior_rad_s, at_zero=at_zero)]
        for k, interval_s in enumerate(np.diff(self.keyframe_t), start=1):
            sigma = imu.gyro_bias_walk_rad_s_sqrt_s * math.sqrt(max(float(interval_s), 1e-9))
            out.append(linear_factor([(self.B(k - 1), -_GYRO_ROWS), (self.B(k), _GYRO_ROWS), (cal, maps[k] - maps[k - 1])], sigma, at_zero=at_zero))
        return out, values

    def heading_factors(self, attitude: list[gtsam.Rot3], robust: bool) -> list[gtsam.AttitudeFactorPose3]:
        """Heading factors of every reading, levelled with the given keyframe attitudes (batch passes)."""
        out = []
        field = self.field_tracker()  # the reference followed again with this pass's attitudes
        self.followed = []
        for k, mag in self.mag_readings:
            norm, dip = field_norm_dip(attitude[k], mag)
            self.followed.append(self._followed(field, k, norm, dip))
            out.append(self._heading(k, attitude[k], mag, norm, dip, robust, self.followed[-1]))
        self.new_fields = field.adopted if field is not None else []
        return out

    def heading_residuals_deg(self, attitude: Sequence[gtsam.Rot3]) -> FloatArray:
        """For every magnetometer reading: the angle between its horizontal field, turned into the world with its
        keyframe's attitude, and magnetic north (degrees). Unlike the factor's projected error it grows to 180."""
        out = []
        for k, mag in self.mag_readings:
            m_world = attitude[k].rotate(mag)
            out.append(abs(math.degrees(math.atan2(m_world[0], m_world[1]))))
        return np.array(out)

    def reference_at(self, t_s: float) -> FieldReference | None:
        """The undisturbed field the last batch pass followed at ``t_s`` (its last reading's at or before it), or None."""
        times = [self.keyframe_t[k] for k, _ in self.mag_readings[: len(self.followed)]]
        n = int(np.searchsorted(times, t_s, side="right")) - 1
        return self.followed[n] if n >= 0 else (self.followed[0] if self.followed else None)


def _first_due(t: FloatArray, dt: FloatArray, start: int, keyframe_s: float, period_s: float, due_s: FloatArray | None = None) -> int:
    """The first sample from ``start`` on that closes the keyframe after ``keyframe_s`` (the sample nearest ``period_s``
    later: its time is past that less half its period), or -1. ``due_s`` (t + dt/2, increasing; a long push computes
    it once): a binary search, its answer checked against the rule itself. Else, or when the check fails (rounding at
    the boundary), looks ahead a chunk at a time: a whole session pushed at once must not compare every remaining
    sample per keyframe."""
    if due_s is not None:
        j = max(start, int(due_s.searchsorted(keyframe_s + period_s)))
        if j < len(t) and t[j] - keyframe_s >= period_s - 0.5 * dt[j] and (j == start or t[j - 1] - keyframe_s < period_s - 0.5 * dt[j - 1]):
            return j
    for lo in range(start, len(t), _DUE_CHUNK):
        hi = min(len(t), lo + _DUE_CHUNK)
        due = t[lo:hi] - keyframe_s >= period_s - 0.5 * dt[lo:hi]
        if due.any():
            return lo + int(np.argmax(due))
    return -1


_DUE_CHUNK = 1024

#: Time constant of the batch initial values' low-pass of the specific force in the gyro's frame, s (VQF's ``tauAcc``).
_INERTIAL_TAU_S = 3.0


def fill_samples(
    t: FloatArray,
    gyro_rad_s: FloatArray,
    keyframe_index: FloatArray,
    keyframe_quat_wxyz: FloatArray,
    keyframe_gyro_bias: FloatArray,
    blend_to_next: bool,
) -> FloatArray:
    """Attitude at every sample: each keyframe's attitude carried on by its bias-corrected gyro.

    Causal (``blend_to_next=False``): samples after keyframe k use k's attitude only. Smoothed: the
    mismatch with keyframe k+1 is spread linearly in time over the interval.
    """
    n = len(t)
    kf = np.asarray(keyframe_index, dtype=int)
    out = np.full((n, 4), np.nan)
    segment = np.searchsorted(kf, np.arange(n), side="right") - 1
    valid = segment >= 0
    dt = np.diff(t, prepend=t[0])
    rates = gyro_rad_s - keyframe_gyro_bias[np.clip(segment, 0, None)]
    increments = quat_from_rotvec(rates * dt[:, None])  # sample i covers (t_{i-1}, t_i]
    out[kf] = keyframe_quat_wxyz
    lengths = np.diff(np.r_[kf, n])
    for offset in range(1, int(lengths.max(initial=1))):
        rows = kf[lengths > offset] + offset
        out[rows] = quat_multiply(out[rows - 1], increments[rows])
    if blend_to_next and len(kf) > 1:
        ends = kf[1:]
        # sample ends-1 forward one more step gives the forward estimate at the next keyframe
        forward_end = quat_multiply(out[ends - 1], increments[ends])
        mismatch = rotvec_from_quat(quat_multiply(quat_conjugate(forward_end), keyframe_quat_wxyz[1:]))
        inner = valid & (segment < len(kf) - 1) & ~np.isin(np.arange(n), kf)
        seg = segment[inner]
        frac = (t[inner] - t[kf[seg]]) / (t[kf[seg + 1]] - t[kf[seg]])
        out[inner] = quat_multiply(out[inner], quat_from_rotvec(frac[:, None] * mismatch[seg]))
    return out
