"""Magnetometer: heading only, from the tilt-compensated field, with calibration, a carried magnet's offset (``HardIron``)
and disturbance rejection.

Calibration (the founding papers'): M = G m + B, per-axis gain G and offset B, from a calibration
recording (``fit_mag_calibration``: an axis-aligned ellipsoid fit) or given.

Heading only: the field is levelled with the attitude known when the factor is made (the online
prediction, or the previous batch pass), its horizontal direction expressed back in the body frame,
and a C++ ``AttitudeFactorPose3`` asks it to point to magnetic north (+y of ENU). Its error has two
components on the sphere around north; the vertical one gets zero precision, so the factor carries
no tilt information: a disturbed field can turn the heading but never tilt the estimate (the field
dips ~70 deg, so a 3-D residual converts field errors into tilt errors).

Disturbances (steel, magnets) change the field's norm and dip: the heading sigma grows with their
departure from the reference, and a Cauchy kernel takes what slips through. The reference is the field where the
recording starts; a room's field is not the same everywhere (steel in floors and tables), so ``FieldTracker`` lets it
follow a field that agrees with it and take a new one that stays steady while the sensor turns (VQF's rule).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from ..catalogue import KeySpec, SensorKind
from ..geometry import FloatArray, matrix_from_quat, quat_from_rotvec, quat_running_product
from .linear import robust

#: Magnetic north in the ENU world frame.
NORTH_ENU = np.array([0.0, 1.0, 0.0])
_NORTH = gtsam.Unit3(NORTH_ENU)
# which tangent component of the error around north is vertical (zero precision)
_VERTICAL_COMPONENT = int(np.argmax(np.abs(_NORTH.basis()[2])))


@dataclass(frozen=True)
class MagCalibration:
    """M = G m + B (founding papers' calibration): calibrated field from the raw reading."""

    gain: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Per-axis gain G."""
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Offset B, in the reading's unit (uT)."""

    def apply(self, raw: FloatArray) -> FloatArray:
        if self.gain == (1.0, 1.0, 1.0) and self.offset == (0.0, 0.0, 0.0):
            return np.asarray(raw, dtype=float)  # identity (already calibrated): no copy per pushed block
        return np.asarray(raw, dtype=float) * np.asarray(self.gain) + np.asarray(self.offset)


def fit_mag_calibration(raw: FloatArray) -> MagCalibration:
    """Axis-aligned ellipsoid fit of readings taken in many orientations (a calibration recording).

    Solves a x^2 + b y^2 + c z^2 + d x + e y + f z = 1 by least squares; the gains make the ellipsoid a
    sphere (their geometric mean is 1, since heading needs only the shape) and the offset centres it.
    """
    m = np.asarray(raw, dtype=float)
    if m.ndim != 2 or m.shape[1] != 3 or len(m) < 9:
        raise ValueError(f"calibration needs at least 9 readings of 3 axes, got shape {m.shape}")
    design = np.column_stack([m**2, m])
    coef, *_ = np.linalg.lstsq(design, np.ones(len(m)), rcond=None)
    quad, lin = coef[:3], coef[3:]
    if np.any(quad <= 0):
        raise ValueError("calibration readings do not span enough orientations (ellipsoid fit is not closed)")
    centre = -lin / (2 * quad)
    gain = np.sqrt(quad)
    gain /= np.prod(gain) ** (1 / 3)
    return MagCalibration(tuple(float(g) for g in gain), tuple(float(b) for b in -gain * centre))  # type: ignore[arg-type]


@dataclass(frozen=True)
class MagNoise:
    """Heading noise of the magnetometer and its disturbance rejection."""

    heading_sigma_deg: float = 5.0
    """Heading sigma per keyframe in an undisturbed field, degrees."""
    norm_gain: float = 20.0
    """Sigma multiplier per unit relative departure of |m| from the reference norm."""
    dip_gain: float = 20.0
    """Sigma multiplier per radian of departure of the dip angle from the reference dip."""
    cauchy_k: float = 1.0
    """Cauchy kernel width in sigmas; 0 = Gaussian."""
    reference_s: float = 0.5
    """The reference norm and dip are the mean over the first this many seconds."""
    hard_iron_s: float = 0.0
    """Memory of the hard-iron estimate (``HardIron``), seconds; 0: no hard-iron state (the readings as calibrated)."""
    hard_iron_fit: float = 0.05
    """The hard-iron estimate corrects the readings while the model explains them: its residual RMS and its field's norm
    departure under this fraction of the reference norm, its field's dip within this many radians of the reference dip."""
    hard_iron_min: float = 0.1
    """...and while the offset is a magnet's, not what attitude errors in fast motion fit: larger than this fraction of the
    reference norm."""
    reference_tau_s: float = 0.0
    """Time constant with which the reference norm and dip follow a field that agrees with them (``FieldTracker``), s;
    0: the reference stays the start's (VQF's ``magRefTau``: 20 s)."""
    new_field_s: float = 0.0
    """A field off the reference that stays steady this long while the sensor turns becomes the reference
    (``FieldTracker``), s; 0: never (VQF's ``magNewTime``: 20 s)."""
    interval_mean: bool = False
    """The keyframe's heading reads the mean of every reading since the keyframe before, each carried by the gyro to the
    keyframe (``interval_mean_reading``); False: the keyframe's own reading alone (the others dropped)."""


@dataclass(frozen=True)
class FieldReference:
    """The undisturbed field: norm and dip (positive downwards, northern hemisphere)."""

    norm: float
    dip_rad: float


def field_norm_dip(world_R_body: gtsam.Rot3, mag_body: FloatArray) -> tuple[float, float]:
    """Norm and dip of a body-frame field reading levelled with an attitude."""
    x, y, z = world_R_body.rotate(np.asarray(mag_body, dtype=float)).tolist()  # scalar math: numpy's per-call checks cost more
    return math.sqrt(x * x + y * y + z * z), math.atan2(-z, math.hypot(x, y))


# VQF's magnetic disturbance thresholds (Laidig & Seel, "VQF: Highly accurate IMU orientation estimation with bias
# estimation and magnetic disturbance rejection", Information Fusion 91, 2023, Sec. 5; its published defaults
# magNormTh, magDipTh, magNewMinGyr, magMinUndisturbedTime): literature constants, fitted to no recording here
FIELD_AGREES_NORM = 0.1
"""A field agrees with a reference when its norm is within this fraction of the reference's..."""
FIELD_AGREES_DIP_RAD = math.radians(10.0)
"""...and its dip within this many radians."""
NEW_FIELD_MIN_RATE_RAD_S = math.radians(20.0)
"""A steady new field counts time only while the sensor turns at least this fast (a still sensor reads a magnet's
field as steadily as the Earth's)."""
UNDISTURBED_S = 0.5
"""The reference follows a field only after it has agreed with it this long."""


class FieldTracker:
    """The undisturbed field's norm and dip as the sensor moves (VQF's disturbance model, Laidig & Seel 2023, Sec. 5).

    A room's field differs by a few percent and degrees from place to place (steel in floors, tables, walls): on BROAD
    trial 06 the field read 41.6 uT and 71.3 deg dip where the trial starts and 44.3 uT, 69 deg while the hand moves,
    so a reference fixed at the start judged the whole movement disturbed and the causal heading ran on the gyro. Here
    the reference follows a field that agrees with it (``MagNoise.reference_tau_s``), and a field that disagrees but
    holds steady by itself for ``MagNoise.new_field_s`` while the sensor turns is taken as a new place's Earth field and
    becomes the reference: a magnet near the path changes the field as the sensor moves, so it does not hold steady
    while turning; a disturbance that does not change with place reads the same as another place's Earth field (on
    BROAD trial 10 the moving hand's field was taken and its headings were worse than the gyro's: norm and dip cannot
    tell them apart). Fed once per keyframe; causal."""

    def __init__(self, noise: MagNoise, reference: FieldReference):
        self.noise = noise
        self.reference = reference
        """The reference now."""
        self._undisturbed_s = UNDISTURBED_S  # the start's field has agreed with itself since the start
        self._candidate = (reference.norm, reference.dip_rad)
        self._candidate_n = 0
        self._candidate_s = 0.0
        self._t: float | None = None  # the time of the reading taken last
        self.adopted: list[tuple[float, FieldReference]] = []
        """Every new field taken as the reference: (time of the reading, the field)."""

    @staticmethod
    def _agrees(norm: float, dip_rad: float, ref_norm: float, ref_dip_rad: float) -> bool:
        return abs(norm - ref_norm) < FIELD_AGREES_NORM * ref_norm and abs(dip_rad - ref_dip_rad) < FIELD_AGREES_DIP_RAD

    def update(self, t_s: float, norm: float, dip_rad: float, rate_rad_s: float) -> FieldReference:
        """One levelled reading taken at ``t_s`` (after the previous one), the sensor turning at ``rate_rad_s``; the
        reference now."""
        dt_s = t_s - self._t if self._t is not None else 0.0
        self._t = t_s
        ref = self.reference
        agrees = self._agrees(norm, dip_rad, ref.norm, ref.dip_rad)
        self._undisturbed_s = self._undisturbed_s + dt_s if agrees else 0.0
        if agrees and self.noise.reference_tau_s > 0 and self._undisturbed_s >= UNDISTURBED_S:
            gain = 1.0 - math.exp(-dt_s / self.noise.reference_tau_s)
            self.reference = FieldReference(ref.norm + gain * (norm - ref.norm), ref.dip_rad + gain * (dip_rad - ref.dip_rad))
        if self.noise.new_field_s <= 0:
            return self.reference
        c_norm, c_dip = self._candidate
        if self._candidate_n and self._agrees(norm, dip_rad, c_norm, c_dip):
            self._candidate_n += 1  # the candidate is the mean of the readings that agreed with it
            self._candidate = (c_norm + (norm - c_norm) / self._candidate_n, c_dip + (dip_rad - c_dip) / self._candidate_n)
            if rate_rad_s >= NEW_FIELD_MIN_RATE_RAD_S:
                self._candidate_s += dt_s
            if not agrees and self._candidate_s >= self.noise.new_field_s:
                self.reference = FieldReference(*self._candidate)
                self._undisturbed_s = UNDISTURBED_S
                self.adopted.append((t_s, self.reference))
        else:
            self._candidate, self._candidate_n, self._candidate_s = (norm, dip_rad), 1, 0.0
        return self.reference


def _solve3_floats(a: Sequence[Sequence[float]], y: Sequence[float]) -> tuple[float, float, float]:
    """One 3 x 3 system (rows of ``a``) solved by its cofactors, in floats (~5x faster per call than numpy's, whose
    overhead dominates at this size: the hard-iron estimate solves one per keyframe)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    y0, y1, y2 = y
    c00, c01, c02 = a11 * a22 - a12 * a21, a12 * a20 - a10 * a22, a10 * a21 - a11 * a20
    c10, c11, c12 = a02 * a21 - a01 * a22, a00 * a22 - a02 * a20, a01 * a20 - a00 * a21
    c20, c21, c22 = a01 * a12 - a02 * a11, a02 * a10 - a00 * a12, a00 * a11 - a01 * a10
    det = a00 * c00 + a01 * c01 + a02 * c02
    if det == 0.0:
        raise np.linalg.LinAlgError("singular 3 x 3 system")
    return ((c00 * y0 + c10 * y1 + c20 * y2) / det, (c01 * y0 + c11 * y1 + c21 * y2) / det, (c02 * y0 + c12 * y1 + c22 * y2) / det)


class HardIron:
    """A magnet carried with the sensor: a constant offset ``b`` in the sensor frame on top of the Earth's field,
    m_k = world_R_body_k^T B + b. As the body turns, the Earth's part turns in the sensor frame and ``b`` does not, so
    (B, b) follow linearly from the readings and the attitudes (the gyro's relative rotations carry the separation):
    recursive least squares with a memory of ``MagNoise.hard_iron_s`` (a magnet attached or removed is forgotten at that
    pace). The readings are corrected by ``b`` only while the model explains them (residual RMS under
    ``MagNoise.hard_iron_fit`` of the norm) and ``b`` is observable (the sensor turned enough in the memory: the smallest
    eigenvalue of its information, per reading, above ``_MIN_SPREAD``) and the field it leaves is the Earth's (its norm
    within that fraction of the reference's, its dip within that many radians); else they pass as read and the norm/dip
    gate judges them. A magnet near the path (a field that depends on where the sensor is) fits no constant ``b`` with the
    Earth's field beside it."""

    _MIN_SPREAD = 0.1
    """Least rotation spread (the b-block's information per reading after the field's is removed: 0 without any turn,
    up to 2/3 for turns about every axis) for ``b`` to be taken."""

    def __init__(self, noise: MagNoise, reference: FieldReference):
        self.noise = noise
        self.reference = reference
        # the normal equations of m = R^T B + b have a fixed shape: [[W I, C], [C^T, W I]] (R R^T = I), C = sum of w R.
        # Kept in Python floats: one reading per keyframe, where numpy's per-call cost on 3-vectors dominated
        self._weight = 0.0
        self._rotations = [0.0] * 9  # C, row by row
        self._vector = [0.0] * 6  # sum of w (R m, m)
        self._square = 0.0
        self._t: float | None = None
        self.bias = np.zeros(3)
        """The current estimate of b (sensor frame, the readings' unit)."""
        self.trusted = False
        """Whether the readings are being corrected by it."""

    def _solve(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """(B, b) from the normal equations, B eliminated first (a 3 x 3 solve): b's information is W I - C^T C / W."""
        W, (c00, c01, c02, c10, c11, c12, c20, c21, c22), (v0, v1, v2, v3, v4, v5) = self._weight, self._rotations, self._vector
        columns = ((c00, c10, c20), (c01, c11, c21), (c02, c12, c22))
        diagonal = W * (1.0 + 1e-6)  # without a turn: the least-norm split
        schur = [[(diagonal if i == j else 0.0) - (ci[0] * cj[0] + ci[1] * cj[1] + ci[2] * cj[2]) / W for j, cj in enumerate(columns)]
                 for i, ci in enumerate(columns)]
        y = [v3 - (c00 * v0 + c10 * v1 + c20 * v2) / W, v4 - (c01 * v0 + c11 * v1 + c21 * v2) / W, v5 - (c02 * v0 + c12 * v1 + c22 * v2) / W]
        b0, b1, b2 = _solve3_floats(schur, y)
        field = ((v0 - (c00 * b0 + c01 * b1 + c02 * b2)) / W, (v1 - (c10 * b0 + c11 * b1 + c12 * b2)) / W, (v2 - (c20 * b0 + c21 * b1 + c22 * b2)) / W)
        return field, (b0, b1, b2)

    def correct(self, t_s: float, world_R_body: gtsam.Rot3, mag_body: FloatArray) -> FloatArray:
        """Take a reading at ``t_s`` with the attitude it was taken at; the reading corrected by the estimate so far."""
        m = np.asarray(mag_body, dtype=float)
        m0, m1, m2 = m.tolist()
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rows = world_R_body.matrix().tolist()
        forget = math.exp(-(t_s - self._t) / self.noise.hard_iron_s) if self._t is not None else 1.0
        self._t = t_s
        theta = self._solve() if self._weight > 6 else None
        residual = 0.0
        if theta is not None:  # the reading's misfit to the memory's (B, b): m - R^T B - b
            (f0, f1, f2), (b0, b1, b2) = theta
            residual = ((m0 - (r00 * f0 + r10 * f1 + r20 * f2) - b0) ** 2 + (m1 - (r01 * f0 + r11 * f1 + r21 * f2) - b1) ** 2
                        + (m2 - (r02 * f0 + r12 * f1 + r22 * f2) - b2) ** 2)
        self._weight = forget * self._weight + 1.0
        self._rotations = [forget * c + r for c, r in zip(self._rotations, rows[0] + rows[1] + rows[2], strict=True)]
        rm = (r00 * m0 + r01 * m1 + r02 * m2, r10 * m0 + r11 * m1 + r12 * m2, r20 * m0 + r21 * m1 + r22 * m2)
        self._vector = [forget * v + x for v, x in zip(self._vector, (*rm, m0, m1, m2), strict=True)]
        self._square = forget * self._square + residual
        self.trusted = False
        self.bias = np.zeros(3)
        if theta is not None:
            tolerance = self.noise.hard_iron_fit
            # (f0, f1, f2): the Earth's part in the world: must be the reference field (norm and dip), else no carried magnet
            norm = self.reference.norm
            fits = (math.sqrt(self._square / self._weight / 3.0) < tolerance * norm
                    and abs(math.sqrt(f0 * f0 + f1 * f1 + f2 * f2) - norm) < tolerance * norm
                    and abs(math.atan2(-f2, math.hypot(f0, f1)) - self.reference.dip_rad) < tolerance
                    and math.sqrt(b0 * b0 + b1 * b1 + b2 * b2) > self.noise.hard_iron_min * norm)
            # observability of b: its information once the field's is eliminated, per reading: 1 - (largest singular value
            # of the memory's mean rotation)^2 (0 without a turn)
            if fits:
                mean_rotation = np.array(self._rotations).reshape(3, 3) / self._weight
                self.trusted = 1.0 - float(np.linalg.norm(mean_rotation, 2)) ** 2 > self._MIN_SPREAD
            if self.trusted:
                self.bias = np.array([b0, b1, b2])
        return m - self.bias


def _sample_turns(gyro_rad_s: FloatArray, dt_s: FloatArray, gyro_bias_rad_s: FloatArray) -> FloatArray:
    """The body's turn (quaternion) from each sample to the next: sample j's gyro, less the bias, over ``dt_s[j]``."""
    return quat_from_rotvec((np.asarray(gyro_rad_s[1:]) - gyro_bias_rad_s) * np.asarray(dt_s[1:])[:, None])


def interval_mean_reading(mag: FloatArray, gyro_rad_s: FloatArray, dt_s: FloatArray, gyro_bias_rad_s: FloatArray) -> FloatArray:
    """The mean of an interval's readings (rows; the last is the keyframe's) in the body frame at the last: sample j's gyro
    (less the bias) turns the body over ``dt_s[j]`` from sample j-1 to j, so reading i is carried by the rotations of samples
    i+1 .. last. Its noise is the single reading's over the square root of their count (a heading sigma per keyframe fitted to
    one reading is then conservative)."""
    turn = matrix_from_quat(_sample_turns(gyro_rad_s, dt_s, gyro_bias_rad_s))  # each sample's turn in numpy once, then a scalar carry: ~20-60 samples,
    # where numpy's per-call cost would dominate
    readings = np.asarray(mag, dtype=float).tolist()
    x, y, z = readings[0]
    for (r0, r1, r2), (mx, my, mz) in zip(turn.tolist(), readings[1:], strict=True):  # v_j = turn_j^T v_(j-1), plus reading j
        x, y, z = r0[0] * x + r1[0] * y + r2[0] * z + mx, r0[1] * x + r1[1] * y + r2[1] * z + my, r0[2] * x + r1[2] * y + r2[2] * z + mz
    return np.array([x, y, z]) / len(readings)


class CarriedReadings:
    """``interval_mean_reading`` for every interval of one long push at once (a batch's whole recording): each reading
    turned into the body frame at the push's first sample (numpy, once), their running sum, and per interval a difference
    of two sums turned to its last sample. Equal to ``interval_mean_reading`` to rounding (the products are associated
    in another order)."""

    def __init__(self, mag: FloatArray, gyro_rad_s: FloatArray, dt_s: FloatArray, gyro_bias_rad_s: FloatArray) -> None:
        # first_R_sample per sample as matrices, once: they turn the readings here and each interval's sum back in ``mean``
        self._first_R_sample = matrix_from_quat(quat_running_product(np.array([1.0, 0.0, 0.0, 0.0]), _sample_turns(gyro_rad_s, dt_s, gyro_bias_rad_s)))
        self._sums = np.vstack([np.zeros(3), np.cumsum(np.einsum("nij,nj->ni", self._first_R_sample, np.asarray(mag, dtype=float)), axis=0)])

    def mean(self, first: int, last: int) -> FloatArray:
        """The mean of rows ``first`` .. ``last`` (inclusive) in the body frame at ``last``."""
        # one 3 x 3 product (``rotate_by_quat``'s array set-up for a single row cost ~60 us a keyframe, an eighth of the batch)
        return self._first_R_sample[last].T @ ((self._sums[last + 1] - self._sums[first]) / (last + 1 - first))


def heading_sigma_rad(noise: MagNoise, reference: FieldReference, norm: float, dip_rad: float) -> float:
    """Heading sigma inflated by the field's departure from the reference (disturbance gating)."""
    departure = noise.norm_gain * abs(norm - reference.norm) / reference.norm + noise.dip_gain * abs(dip_rad - reference.dip_rad)
    return math.radians(noise.heading_sigma_deg) * (1.0 + departure)


def heading_factor(pose_key: int, world_R_body: gtsam.Rot3, mag_body: FloatArray, sigma_rad: float, cauchy_k: float = 0.0) -> gtsam.AttitudeFactorPose3:
    """Heading-only factor: the field levelled with ``world_R_body`` points to magnetic north."""
    x, y, _ = world_R_body.rotate(np.asarray(mag_body, dtype=float)).tolist()
    size = math.hypot(x, y)
    if size < 1e-9:
        raise ValueError("the field is vertical: no heading information")
    body_direction = world_R_body.unrotate(np.array([x / size, y / size, 0.0]))
    precisions = np.full(2, 1.0 / sigma_rad**2)
    precisions[_VERTICAL_COMPONENT] = 0.0
    model: gtsam.noiseModel.Base = gtsam.noiseModel.Diagonal.Precisions(precisions)
    return gtsam.AttitudeFactorPose3(pose_key, _NORTH, robust(model, cauchy_k), gtsam.Unit3(body_direction))

CATALOGUE = (
    SensorKind(
        kind="mag",
        summary="magnetometer: the local magnetic field (raw: gain and offset errors allowed)",
        columns=("mx", "my", "mz"),
        units=("uT, or any unit said in units (converted to uT on loading: nT, mT, gauss, T); normalised readings are accepted",) * 3,
        unit_conversions={"uT": 1.0, "nT": 1e-3, "mT": 1e3, "gauss": 100.0, "G": 100.0, "T": 1e6},
        frame="body (sensor) axes",
        factors="heading from the tilt-compensated, calibrated field (AttitudeFactorPose3 to north with the vertical component free); "
        "sigma grows with the field's norm and dip departures; Cauchy kernel against disturbances; attitude9/gaze: a magnet carried on the "
        "sensor (a sensor-frame offset the rotation separates from the Earth's field) estimated and removed while it explains the readings",
        keys=(
            KeySpec("calibration_gain", None, "per-axis gain [gx, gy, gz] (calibrated = gain * (raw - offset)); else fitted to a mag_cal stream"),
            KeySpec("calibration_offset", None, "per-axis offset [ox, oy, oz], in the stream's unit"),
            KeySpec("reference_tau_s", None, "attitude9: time constant with which the reference field follows a field that agrees with it, s "
                    "(0: the start's throughout; default: chosen on BROAD, tuned.toml [broad_field])"),
            KeySpec("new_field_s", None, "attitude9: a steady field off the reference held this long while the sensor turns becomes the "
                    "reference, s (0: never; default: chosen on BROAD, whose trials share one room, tuned.toml [broad_field]; a recording "
                    "carried between places: e.g. 20, VQF's)"),
        ),
    ),
)
