"""What a graph builder hands to a solver: new factors (tagged by keyframe) and initial values."""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam


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
