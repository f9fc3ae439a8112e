"""Peer estimators that users run today, measured in the same run as ours: VQF (Laidig & Seel 2023) and x-io's Fusion
(``imufusion``, Madgwick's revised AHRS with magnetic and acceleration rejection).

The ``vqf`` package (C++ with a Python wrapper) is a benchmark dependency; default parameters, 9D
(gyro + accelerometer + magnetometer), the online filter or its offline (acausal) variant. ``imufusion`` runs with the
settings of its own example (``IMUFUSION_EXAMPLE``), its ``Bias`` gyro offset correction first, in the ENU convention.
"""

from __future__ import annotations

import time

import numpy as np

from ..estimate import Estimate
from ..session import Session

IMUFUSION_EXAMPLE = {"gain": 0.5, "gyroscope_range_deg_s": 2000.0, "acceleration_rejection_deg": 10.0, "magnetic_rejection_deg": 10.0,
                     "rejection_timeout_s": 5.0}
"""The Fusion library's Python example settings (gain 0.5, gyro range 2000 deg/s, rejections 10 deg, timeout 5 s)."""


def run_imufusion(session: Session) -> Estimate:
    """imufusion (x-io Fusion) 9D on a session's gyro/accel/mag (same rate, same clock), the example's settings: its
    ``Bias`` removes the gyro offset at rest, then ``Ahrs.update`` per sample. Units as Fusion takes them: gyro deg/s,
    accel g, mag in any unit (uT here). In imufusion 1.3 the settings are passed with ``set_settings`` after
    construction (a convention given to ``AhrsSettings``' constructor is not kept: heading would be 90 deg off)."""
    import imufusion

    gyro, accel, mag = session.synchronous("gyro", "accel", "mag")  # a one-stream dropout cut from all (said)
    period = float(np.median(np.diff(gyro.t)))
    rate = 1.0 / period
    settings = imufusion.AhrsSettings()
    settings.convention = imufusion.CONVENTION_ENU
    settings.gain = IMUFUSION_EXAMPLE["gain"]
    settings.gyroscope_range = IMUFUSION_EXAMPLE["gyroscope_range_deg_s"]
    settings.acceleration_rejection = IMUFUSION_EXAMPLE["acceleration_rejection_deg"]
    settings.magnetic_rejection = IMUFUSION_EXAMPLE["magnetic_rejection_deg"]
    settings.rejection_timeout = int(IMUFUSION_EXAMPLE["rejection_timeout_s"] * rate)
    settings.sample_rate = rate
    ahrs = imufusion.Ahrs()
    ahrs.set_settings(settings)
    ahrs.set_sample_period(period)
    bias_settings = imufusion.BiasSettings()
    bias_settings.sample_rate = rate
    bias = imufusion.Bias()
    bias.set_settings(bias_settings)
    gyr = np.ascontiguousarray(np.rad2deg(gyro.values), dtype=float)
    acc = np.ascontiguousarray(accel.values / 9.80665, dtype=float)
    mg = np.ascontiguousarray(mag.values, dtype=float)
    quat = np.empty((len(gyr), 4))
    start = time.perf_counter()
    for i in range(len(gyr)):
        ahrs.update(bias.update(gyr[i]), acc[i], mg[i])
        quat[i] = ahrs.get_quaternion()  # w, x, y, z
    return Estimate("imufusion", gyro.t.copy(), quat, None, time.perf_counter() - start)


def run_vqf(session: Session, offline: bool = False) -> Estimate:
    """VQF 9D with default parameters on a session's gyro/accel/mag streams (same rate, same clock)."""
    import vqf

    gyro, accel, mag = session.synchronous("gyro", "accel", "mag")  # a one-stream dropout cut from all (said)
    sample_time = float(np.median(np.diff(gyro.t)))
    gyr, acc, mg = (np.ascontiguousarray(s.values, dtype=float) for s in (gyro, accel, mag))
    start = time.perf_counter()
    result = vqf.offlineVQF(gyr, acc, mg, sample_time) if offline else vqf.VQF(sample_time).updateBatch(gyr, acc, mg)
    quat = result["quat9D"]
    runtime = time.perf_counter() - start
    return Estimate("vqf_offline" if offline else "vqf", gyro.t.copy(), np.asarray(quat, dtype=float), None, runtime)
