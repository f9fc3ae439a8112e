"""Online (causal) smoothing with iSAM2, re-anchored to keep every update equally fast for hours.

Plain iSAM2 slows down as the graph grows (measured with gtsam 4.3: ~110x real time at 10 s of head
data, 13x at 300 s). Every ``reanchor_every`` keyframes this solver marginalises everything older
than ``window_s`` before now: it linearises the factors that touch old keyframes at the current
estimate, eliminates the old variables (an exact Schur complement at that linearisation point),
and starts a fresh iSAM2 from the kept factors plus that marginal as ``LinearContainerFactor``s.
Memory stays bounded; the causal estimate is unchanged up to relinearisation of old states.

Where the builder tells each variable's keyframe (``keyframe_of``), iSAM2 eliminates in keyframe order with the
variables of no keyframe last (``OnlineSmoother._time_order``), so that an update re-eliminates only the keyframes
its factors reach back to; the old keyframes, then leaves of the tree, are marginalised inside iSAM2 instead
(``ISAM2.marginalizeLeaves``, ``OnlineSmoother._marginalize_in_place``): no new solver, no full elimination, a tree the
size of the window.
"""

from __future__ import annotations

import bisect
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, Protocol

import gtsam
import numpy as np

from ..geometry import FloatArray
from ..graphs.increment import GraphIncrement


class IncrementalBuilder(Protocol):
    """What the online solver needs from a system's graph builder.

    Optional, looked up by name: ``read_latest(isam, k)`` (states that are not a Rot3 and a Vector3), ``feedback``
    (estimates the builder needs back), ``linear_keys`` (variables never to relinearise) and ``keyframe_of(key)``
    (the keyframe of a variable, None for one of no keyframe: iSAM2 then eliminates in time order, ``_time_order``, and
    old keyframes can be marginalised in place, ``_marginalize_in_place``).
    """

    keyframe_t: list[float]
    oldest_allowed_keyframe: int

    @property
    def started(self) -> bool: ...

    @property
    def latest_keyframe(self) -> int: ...

    def take(self) -> GraphIncrement: ...

    def state_keys(self, k: int) -> tuple[int, int | None]: ...

    def set_latest(self, state: Any, bias: FloatArray, /) -> None: ...  # a Rot3, or a Pose3 from read_latest


@dataclass(frozen=True)
class OnlineConfig:
    """Settings of the online solver."""

    window_s: float = 0.5
    """Keyframes younger than this (before now) stay as variables; must exceed the largest latency."""
    reanchor_every: int = 100
    """Re-anchor after this many new keyframes (100 = 2 s at 50 Hz): a small tree keeps updates fast. Marginalising in
    place (``in_place``), the old keyframes go in blocks of this many (block k: keyframes k * reanchor_every on)."""
    relinearize_threshold: float = 0.1
    """iSAM2 relinearisation threshold (rad for rotations); 0.01 was 2x slower with the same accuracy here."""
    relinearize: bool = True
    """Let iSAM2 relinearise; re-anchoring relinearises the kept factors at the estimate anyway."""
    update_every: int = 0
    """Run iSAM2 once this many new keyframes have closed, the first keyframe as it comes (the gyro carries the estimate
    in between; a late sample that arrives between keyframes waits for the next due update); 0: whenever new factors
    come, a late sample too. A 9-axis session declares it (``declared``)."""
    relinearize_skip: int = 1
    """Check for relinearisation every this many updates."""
    wildfire_threshold: float = 0.001
    """Back-substitution stops where the solution changes less than this (gtsam's default 0.001)."""
    covariance: bool = True
    """Compute the newest keyframe's marginal covariance after each update."""
    factorization: str = "CHOLESKY"
    """iSAM2's factorisation, CHOLESKY or QR (slower, but it survived the cyclist graph where Cholesky
    reported an indeterminate system on a well-posed problem)."""
    bias_covariance_every: int = 10
    """Refresh the bias marginal covariance every this many updates."""
    in_place: bool = True
    """Where the elimination is time-ordered, marginalise old keyframes inside iSAM2 (``ISAM2.marginalizeLeaves``) in
    blocks of ``reanchor_every`` keyframes instead of building a new solver (``OnlineSmoother._marginalize_in_place``)."""
    time_ordered: bool = True
    """Eliminate in keyframe order, variables of no keyframe last, where the builder tells a variable's keyframe
    (``keyframe_of``; see ``OnlineSmoother._time_order``). False: iSAM2's default (the new factors' variables last).
    Each update then re-eliminates every keyframe back to the one its late samples reach, so the gain shrinks with the
    latency: realistic head session (seed 7, 60 s, best of 3), tracker 0.1 s late 36.4x real time against 19.7x, 0.2 s
    32.4x against 30.8x, 0.3 s 31.7x against 34.8x."""

    def declared(self, meta: Mapping[str, Any], where: str) -> OnlineConfig:
        """This config with the update interval a session declares (``[online] update_every``: a whole number of
        keyframes, 0 or more); a ValueError naming the file and the key otherwise."""
        every = meta.get("online", {}).get("update_every")
        if every is None:
            return self
        if isinstance(every, bool) or not isinstance(every, int) or every < 0:
            raise ValueError(f"{where}: [online] update_every = {every!r}: a whole number of keyframes, 0 or more (0: an update at every keyframe)")
        return replace(self, update_every=every)


#: Sigma of the prior a rebuilt solver puts on every variable (tangent-space units: rad, rad/s, ...).
RECOVERY_PRIOR_SIGMA = 1e3


class SolverFailureError(RuntimeError):
    """An online update that failed numerically even on a rebuilt solver."""


class OnlineSmoother:
    """iSAM2 over a builder's factors; ``update()`` after each step, estimates of the newest keyframe."""

    _newest_keyed: int  # the filing of the window's variables (``_forget_keys``)

    def __init__(self, builder: IncrementalBuilder, config: OnlineConfig | None = None):
        self.builder = builder
        self.config = config or OnlineConfig()
        self._isam = self._new_isam()
        self._window: list[tuple[int, gtsam.NonlinearFactor]] = []
        self._keyframes_since_anchor = 0
        self._known_keyframe = -1
        self.reanchors = 0
        self._updates = 0
        # variables that enter only linear factors (exact at any point) never need relinearising;
        # relinearising a key shared by every factor would re-eliminate the whole tree each time
        self._no_relin = gtsam.KeyList()
        for key in getattr(builder, "linear_keys", ()):
            self._no_relin.push_back(key)
        """How many times the solver re-anchored."""
        self.latest_rot: gtsam.Rot3 | None = None
        self.latest_bias = np.zeros(3)
        self.latest_cov = np.full((3, 3), np.nan)
        self.latest_bias_cov = np.full((3, 3), np.nan)
        self.recoveries: list[str] = []
        """One line per update that failed numerically and was redone from a rebuilt solver (what gtsam said)."""
        self.defer_reanchor = False
        """Leave a due re-anchoring to ``maintain()`` (called after the estimate is read), for at most one update."""
        self._reanchor_due = False
        self.reeliminated = 0
        """Variables the last update re-eliminated (-1 when it failed and the solver was rebuilt)."""
        self._keyframe_of = getattr(builder, "keyframe_of", None) if self.config.time_ordered else None
        self._in_place = self._keyframe_of is not None and self.config.in_place
        self._forget_keys(gtsam.Values())
        self.in_place_marginalisations = 0
        """How many of the re-anchorings marginalised inside iSAM2 (the rest built a new solver)."""

    def _register(self, values: gtsam.Values) -> None:
        """File the new variables under their keyframes (see ``_time_order``)."""
        if self._keyframe_of is None:
            return
        self._registered += values.size()
        for key in values.keys():
            k = self._keyframe_of(key)
            if k is None:
                self._free_keys.append(key)
            else:
                self._keys_by_keyframe.setdefault(k, []).append(key)
                self._newest_keyed = max(self._newest_keyed, k)

    def _time_order(self, oldest: int) -> tuple[gtsam.KeyGroupMap | None, gtsam.KeyList | None]:
        """Constraint groups that eliminate the window's variables from ``oldest``'s keyframe on in time order, the variables
        of no keyframe (the gyro calibration) last, and the same variables to re-eliminate.

        iSAM2's default puts the variables of the new factors last. A late tracker sample's factors touch a keyframe a few
        periods back, so that put an old keyframe above the newer ones, and the calibration, which every keyframe's bias
        links, tied the tree together: each update re-eliminated every keyframe since the last re-anchoring (57 variables
        on average over 20-30 s of a realistic head session, 0.47 ms per update; in time order 15 variables, 0.15 ms).
        Re-eliminating the keyframes from ``oldest`` on costs nothing extra (in time order they are on the path to the
        root) and keeps every group number within the count of variables eliminated, as CCOLAMD requires. The variables
        older than ``oldest`` get no group: given groups by keyframe block as well, an update that left some of them
        alone built an ordering with variables outside it and crashed (gtsam 4.3). One that re-eliminates some of them
        (a relinearisation, a clique reaching back) orders those freely; ``update`` notices.
        """
        if self._keyframe_of is None:
            return None, None
        groups, extra = gtsam.KeyGroupMap(), gtsam.KeyList()
        group = 0
        for k in range(max(oldest, 0), self._newest_keyed + 1):
            keys = self._keys_by_keyframe.get(k)
            if keys:
                group += 1
                for key in keys:
                    groups.insert2(key, group)
                    extra.push_back(key)
        for key in self._free_keys:
            groups.insert2(key, group + 1)
            extra.push_back(key)
        return groups, extra

    def _forget_keys(self, kept: gtsam.Values) -> None:
        """File only the variables of ``kept`` (a new, re-anchored or rebuilt solver's)."""
        # the window's variables by keyframe (and those of no keyframe), for the time-ordered elimination (``_time_order``)
        self._keys_by_keyframe: dict[int, list[int]] = {}
        self._free_keys: list[int] = []
        self._newest_keyed = -1
        self._registered = 0  # variables filed (the tree's)
        self._register(kept)
        self._free_count_at_rebuild = len(self._free_keys)
        self._ordered = True  # every update since the last rebuild kept the tree in keyframe order (see update)

    def _new_isam(self, factorization: str | None = None) -> gtsam.ISAM2:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self.config.relinearize_threshold)
        params.relinearizeSkip = self.config.relinearize_skip
        params.enableRelinearization = self.config.relinearize
        params.setFactorization(factorization or self.config.factorization)
        gauss_newton = gtsam.ISAM2GaussNewtonParams()
        gauss_newton.setWildfireThreshold(self.config.wildfire_threshold)
        params.setOptimizationParams(gauss_newton)
        return gtsam.ISAM2(params)

    def update(self, force: bool = False) -> bool:
        """Take the builder's new factors into iSAM2; False when there was nothing new (or not yet due)."""
        # factors wait in the builder and the gyro carries the estimate on; the first keyframe is solved as it comes (no
        # estimate is carried before it)
        due = self.config.update_every if self._known_keyframe >= 0 else min(self.config.update_every, 1)
        if not force and self.builder.latest_keyframe - self._known_keyframe < due:
            return False
        increment = self.builder.take()
        if not increment:
            return False
        self._register(increment.values)
        groups, extra = self._time_order(min(oldest for oldest, _ in increment.factors))
        try:
            result = self._isam.update(increment.graph(), increment.values, [], groups, self._no_relin, extra)
        except RuntimeError as exc:  # gtsam's IndeterminantLinearSystemException and kin
            self._recover(increment, exc)
            self.reeliminated = -1
        else:
            self._window.extend(increment.factors)
            self.reeliminated = result.getVariablesReeliminated()
            if self._in_place and extra is not None:
                # gtsam counts the listed variables (the new factors' and the new ones among them) plus the existing ones
                # it re-eliminated. One more (496 of 499 updates of a realistic head session) is an older variable in a
                # clique with ``oldest``'s: alone, it goes first, older than all it precedes. Two or more older ones are
                # in gtsam's free order (a relinearisation does it): marginalising in place is unsafe until a rebuild.
                # So is a whole tree re-eliminated (gtsam's batch step, when most of it is affected: a small tree)
                listed = 2 * extra.size() - increment.values.size()
                self._ordered &= self.reeliminated <= listed + 1 and self.reeliminated < self._registered
        k = self.builder.latest_keyframe
        new_keyframe = k != self._known_keyframe
        self._keyframes_since_anchor += k - self._known_keyframe
        self._known_keyframe = k
        rot_key, bias_key = self.builder.state_keys(k)
        reader = getattr(self.builder, "read_latest", None)
        if reader is not None:  # a builder whose states are not (Rot3, Vector3) reads them itself
            self.latest_rot, self.latest_bias = reader(self._isam, k)
        else:
            self.latest_rot = self._isam.calculateEstimateRot3(rot_key)
            if bias_key is not None:
                self.latest_bias = self._isam.calculateEstimateVector(bias_key)
        # an update that only adds late measurements to older keyframes (a latency that is not a
        # multiple of the keyframe period) keeps the newest covariance until the next keyframe:
        # recomputing it there cost ~2 ms per update, 6x the whole loop, for a change of a few percent
        if self.config.covariance and (new_keyframe or np.isnan(self.latest_cov[0, 0])):
            self.latest_cov = self._marginal(rot_key, k)[:3, :3]  # rotation block (Rot3, or Pose3's first)
            self._updates += 1
            if bias_key is not None and (self._updates % self.config.bias_covariance_every == 1 or np.isnan(self.latest_bias_cov[0, 0])):
                # the bias uncertainty changes slowly; refreshing it every few updates halves the cost
                self.latest_bias_cov = self._marginal(bias_key, k)[-3:, -3:]  # gyro block (Vector3, or ConstantBias' last)
        self.builder.set_latest(self.latest_rot, self.latest_bias)
        feedback = getattr(self.builder, "feedback", None)
        if feedback is not None:
            feedback(self._isam.calculateEstimateVector)
        if self._keyframes_since_anchor >= self.config.reanchor_every:
            # deferred once when the caller maintains the solver itself after reading the estimate (a live
            # loop publishes first, so the re-anchoring's pause is not in that sample's latency); run here
            # when it was already due at the previous update
            if self.defer_reanchor and not self._reanchor_due:
                self._reanchor_due = True
            else:
                self._reanchor()
        return True

    def _marginal(self, key: int, k: int) -> FloatArray:
        """iSAM2's marginal covariance of ``key``; where Cholesky calls the system indeterminate (an update can pass
        and the covariance's own elimination fail: BROAD trial 06 at its fifth keyframe, the gyro's calibration not yet
        observable), the solver is rebuilt as after a failed update (``_recover``) and asked again."""
        try:
            return np.asarray(self._isam.marginalCovariance(key))
        except RuntimeError as exc:
            theta = gtsam.Values(self._isam.getLinearizationPoint())
            self._rebuild(self._window, theta, exc, f"keyframe {k}", f"covariance at keyframe {k}")
            return np.asarray(self._isam.marginalCovariance(key))

    def maintain(self) -> None:
        """Run a re-anchoring that ``update`` deferred (``defer_reanchor``); nothing when none is due."""
        if self._reanchor_due:
            self._reanchor()

    def _recover(self, increment: GraphIncrement, exc: RuntimeError) -> None:
        """Redo a failed update on a rebuilt solver instead of leaving iSAM2 broken for every later update.

        A failed ``update`` leaves gtsam's tree half-changed, so the solver is rebuilt from the factors it
        held (the window) plus the new ones, at the linearisation point it had, with QR (which survives the
        near-singular systems Cholesky calls indeterminate) and a negligible prior on every variable (sigma
        1e3 in its tangent space: information 1e-6 against the sensors' 1e4 and more, yet it makes the
        system positive definite, as Levenberg-Marquardt's damping does). The prior leaves with the next
        re-anchoring, marginalised with the old keyframes. Only when that fails too is the error raised.
        """
        theta = gtsam.Values(self._isam.getLinearizationPoint())
        theta.insert(_subset(increment.values, {k for k in increment.values.keys() if not theta.exists(k)}))
        k = self.builder.latest_keyframe
        self._rebuild(self._window + increment.factors, theta, exc, f"keyframe {k}", f"iSAM2 update at keyframe {k}")

    def _rebuild(self, factors: list[tuple[int, gtsam.NonlinearFactor]], theta: gtsam.Values, exc: RuntimeError, where: str, what: str) -> None:
        """Replace the solver by a QR iSAM2 holding ``factors`` at ``theta`` plus the negligible prior on every variable
        (see ``_recover``) after ``what`` failed with ``exc`` (listed in ``recoveries`` as ``where``); ``SolverFailureError``
        when even that fails."""
        zero = theta.zeroVectors()
        weak: list[tuple[int, gtsam.NonlinearFactor]] = []
        for key in theta.keys():
            dim = len(zero.at(key))
            jacobian = gtsam.JacobianFactor(key, np.eye(dim), np.zeros(dim), gtsam.noiseModel.Isotropic.Sigma(dim, RECOVERY_PRIOR_SIGMA))
            weak.append((-1, gtsam.LinearContainerFactor(jacobian, theta)))  # keeps only its key's value
        graph = gtsam.NonlinearFactorGraph()
        for _, factor in factors + weak:
            graph.add(factor)
        rebuilt = self._new_isam("QR")
        self._forget_keys(theta)
        try:
            rebuilt.update(graph, theta, [], self._time_order(0)[0])
        except RuntimeError as again:
            raise SolverFailureError(f"{what} failed ({exc}) and failed again on a rebuilt solver ({again}): a variable no measurement "
                                     "constrains, or a sensor sigma far too small") from again
        self._isam, self._window = rebuilt, factors + weak
        said = str(exc).strip()
        self.recoveries.append(f"{where}: {said.splitlines()[0] if said else type(exc).__name__}")

    @property
    def isam(self) -> gtsam.ISAM2:
        """The current iSAM2 (replaced at every re-anchoring)."""
        return self._isam

    def estimate(self) -> gtsam.Values:
        """Current estimate of every variable in the window."""
        return self._isam.calculateEstimate()

    def _reanchor(self) -> None:
        self._reanchor_due = False
        times = self.builder.keyframe_t
        anchor = bisect.bisect_left(times, times[-1] - self.config.window_s)
        # in place while the tree is in keyframe order and no variable of no keyframe has come since the last rebuild (a
        # drifting latency's next segment: iSAM2 cannot marginalise a root variable, a rebuild lets the old segments go)
        in_place = self._in_place and self._ordered and len(self._free_keys) == self._free_count_at_rebuild
        if in_place:
            anchor -= anchor % max(1, self.config.reanchor_every)  # whole blocks (see ``reanchor_every``)
        if anchor <= self.builder.oldest_allowed_keyframe:
            return
        if in_place:
            self._marginalize_in_place(anchor)
            self.in_place_marginalisations += 1
        else:
            self._anchor_new_solver(anchor)
        self.builder.oldest_allowed_keyframe = anchor
        self._keyframes_since_anchor = 0
        self.reanchors += 1

    def _anchor_new_solver(self, anchor: int) -> None:
        """A new iSAM2 from the window's factors from ``anchor`` on and the old ones' marginal at the estimate."""
        values = self._isam.calculateEstimate()
        old = gtsam.NonlinearFactorGraph()
        kept: list[tuple[int, gtsam.NonlinearFactor]] = []
        old_keys: set[int] = set()
        for oldest, factor in self._window:
            if oldest < anchor:
                old.add(factor)
                old_keys.update(factor.keys())
            else:
                kept.append((oldest, factor))
        kept_keys: set[int] = set()
        for _, factor in kept:
            kept_keys.update(factor.keys())
        separator = old_keys & kept_keys
        linear = old.linearize(values)
        # a fill-reducing order with the separator last; its prefix eliminates the old variables
        full_order = gtsam.Ordering.ColamdConstrainedLastGaussianFactorGraph(linear, sorted(separator))
        eliminate = gtsam.Ordering()
        for i in range(full_order.size()):
            if full_order.at(i) not in separator:
                eliminate.push_back(full_order.at(i))
        _, marginal = linear.eliminatePartialMultifrontal(eliminate)
        new_graph = gtsam.NonlinearFactorGraph()
        new_values = _subset(values, kept_keys)
        separator_values = _subset(values, separator)
        prior: list[tuple[int, gtsam.NonlinearFactor]] = []
        for i in range(marginal.size()):
            gaussian = marginal.at(i)
            if gaussian is None:
                continue
            container = gtsam.LinearContainerFactor(gaussian, separator_values)
            prior.append((anchor, container))
        for _, factor in prior + kept:
            new_graph.add(factor)
        self._isam = self._new_isam()
        self._forget_keys(new_values)
        try:
            self._isam.update(new_graph, new_values, [], self._time_order(0)[0])
            self._window = prior + kept
        except RuntimeError as exc:  # the re-anchored system near-singular for Cholesky: rebuilt as a failed update is
            self._rebuild(prior + kept, new_values, exc, f"re-anchoring at keyframe {anchor}", f"re-anchoring at keyframe {anchor}")

    def _marginalize_in_place(self, anchor: int) -> None:
        """Marginalise the keyframes older than ``anchor`` (whole blocks, see ``_time_order``) inside iSAM2.

        ``ISAM2.marginalizeLeaves`` folds them into linear factors on the kept variables, whose linearisation points it
        then holds fixed. No new solver, no re-linearisation of the window, no full elimination: the tree keeps the size
        of the window instead of growing between re-anchorings (each update's back-substitution visits every clique,
        since the calibration variable in the root is re-eliminated every time). The window's factor list follows, with
        the marginal factors tied to their linearisation points, so that a rebuild (``_recover``) or a later re-anchoring
        that builds a new solver starts from the same information.
        """
        gone = gtsam.KeyList()
        for k in sorted(k for k in self._keys_by_keyframe if k < anchor):
            for key in self._keys_by_keyframe.pop(k):
                gone.push_back(key)
        slots = self._isam.getFactorsUnsafe().size()
        self._isam.marginalizeLeaves(gone)
        self._registered -= gone.size()
        held = self._isam.getFactorsUnsafe()
        theta = self._isam.getLinearizationPoint()
        marginal: list[tuple[int, gtsam.NonlinearFactor]] = []
        for i in range(slots, held.size()):  # gtsam appends the marginal factors after every factor it holds
            if held.exists(i):
                factor = held.at(i)  # a LinearContainerFactor without a linearisation point: linearize returns its factor
                marginal.append((anchor, gtsam.LinearContainerFactor(factor.linearize(theta), _subset(theta, set(factor.keys())))))
        keyframe_of = self._keyframe_of
        assert keyframe_of is not None
        # gone from iSAM2: every factor on a marginalised variable (those of no keyframe alone stay)
        self._window = marginal + [(oldest, f) for oldest, f in self._window if oldest >= anchor or all(keyframe_of(key) is None for key in f.keys())]


def _subset(values: gtsam.Values, keys: set[int]) -> gtsam.Values:
    """A copy of ``values`` holding only ``keys`` (type-agnostic: copy, then erase the rest)."""
    out = gtsam.Values(values)
    for key in values.keys():
        if key not in keys:
            out.erase(key)
    return out
