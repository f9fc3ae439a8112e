"""Peer estimators that users run today, measured in the same run as ours: VQF (Laidig & Seel 2023).

The ``vqf`` package (C++ with a Python wrapper) is a benchmark dependency; default parameters, 9D
(gyro + accelerometer + magnetometer), the online filter or its offline (acausal) variant.
"""

from __future__ import annotations

import time

import numpy as np

from ..estimate import Estimate
from ..session import Session


def run_vqf(session: Session, offline: bool = False) -> Estimate:
    """VQF 9D with default parameters on a session's gyro/accel/mag streams (same rate, same clock)."""
    import vqf

    gyro, accel, mag = session.stream("gyro"), session.stream("accel"), session.stream("mag")
    if not (len(gyro) == len(accel) == len(mag)) or not np.allclose(gyro.t, accel.t) or not np.allclose(gyro.t, mag.t):
        raise ValueError("VQF needs gyro, accel and mag sampled together (same length and times)")
    sample_time = float(np.median(np.diff(gyro.t)))
    gyr, acc, mg = (np.ascontiguousarray(s.values, dtype=float) for s in (gyro, accel, mag))
    start = time.perf_counter()
    result = vqf.offlineVQF(gyr, acc, mg, sample_time) if offline else vqf.VQF(sample_time).updateBatch(gyr, acc, mg)
    quat = result["quat9D"]
    runtime = time.perf_counter() - start
    return Estimate("vqf_offline" if offline else "vqf", gyro.t.copy(), np.asarray(quat, dtype=float), None, runtime)
