"""Elimination orders for graphs that are chains in time (a state per keyframe, linked to the next).

Keyframe by keyframe is banded, but it makes the Bayes tree a chain as deep as the session, and gtsam's
elimination and marginals grow faster than the length along it (the 600 s head graph: 3.2 s per
elimination, 1.4 s per marginal covariance). Cutting the chain at its middle keyframe, recursively,
eliminates each half first and the cut last: a tree of depth log n with the same small separators
(1.1 s and 0.09 s there). A factor that spans a cut (a tracker error chain across a dropout) only adds
its variables to that separator.
"""

from __future__ import annotations

from collections.abc import Sequence

SYMBOL_INDEX_BITS = 56
"""A gtsam Symbol key: its character in the top 8 bits, its index (a keyframe's, for per-keyframe variables) below."""
SYMBOL_INDEX_MASK = (1 << SYMBOL_INDEX_BITS) - 1


def nested_dissection(steps: Sequence[Sequence[int]], shared: Sequence[int] = (), leaf_steps: int = 8) -> list[int]:
    """Every key of ``steps`` (the variables of each keyframe, in time order) by nested dissection over the
    keyframes, then ``shared`` (variables every keyframe touches, e.g. a calibration) last."""
    order: list[int] = []

    def dissect(lo: int, hi: int) -> None:
        if hi - lo <= leaf_steps:
            for step in steps[lo:hi]:
                order.extend(step)
            return
        mid = (lo + hi) // 2
        dissect(lo, mid)
        dissect(mid + 1, hi)
        order.extend(steps[mid])

    dissect(0, len(steps))
    return order + list(shared)
