"""What a graph builder hands to a solver: new factors (tagged by keyframe) and initial values."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gtsam

#: ``Values.insert``'s keyword for a value type. pybind11 tries the ~46 overloads in order and converts the value to
#: each one's type first; naming the parameter skips those conversions (measured, Values() included: a Rot3 10 -> 6 us,
#: a Pose3 7 -> 4 us, a ConstantBias 56 -> 17 us per insert). Vectors are the first overload and go positionally.
_INSERT_KEYWORD: dict[type, str] = {gtsam.Rot3: "rot3", gtsam.Pose3: "pose3", gtsam.imuBias.ConstantBias: "constant_bias", gtsam.Pose2: "pose2"}


def insert(values: gtsam.Values, key: int, value: Any) -> None:
    """``values.insert(key, value)`` without pybind11's overload search where the type is known."""
    name = _INSERT_KEYWORD.get(type(value))
    if name is None:
        values.insert(key, value)
    else:
        values.insert(j=key, **{name: value})  # type: ignore[call-overload]  # the stubs list each overload's keyword


@dataclass
class GraphIncrement:
    """New factors and the initial values of the variables they introduce.

    Each factor carries the index of the OLDEST keyframe it touches, so that an online solver can
    marginalise everything older than a keyframe without looking inside factors.
    """

    factors: list[tuple[int, gtsam.NonlinearFactor]] = field(default_factory=list)
    values: gtsam.Values = field(default_factory=gtsam.Values)

    def add(self, oldest_keyframe: int, factor: gtsam.NonlinearFactor) -> None:
        self.factors.append((oldest_keyframe, factor))

    def insert(self, key: int, value: Any) -> None:
        """The initial value of a new variable (see ``insert``)."""
        insert(self.values, key, value)

    def __bool__(self) -> bool:
        return bool(self.factors)

    def graph(self) -> gtsam.NonlinearFactorGraph:
        out = gtsam.NonlinearFactorGraph()
        for _, factor in self.factors:
            out.add(factor)
        return out

    def extend(self, other: GraphIncrement) -> None:
        self.factors.extend(other.factors)
        self.values.insert(other.values)
