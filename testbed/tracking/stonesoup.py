"""Stone Soup's trackers on the testbed's detections (optional extra: ``pip install 'roadtrack[stonesoup]'``).

``stonesoup-gnn-kf`` and ``stonesoup-jpda-kf`` are built from Stone Soup 1.9's own components (its Kalman
predictor and updater, hypothesisers, data associators, multi-measurement initiator, deleters and multi-target
trackers) and fed by a Stone Soup detection reader holding our detections, so a Stone Soup user compares a
Stone Soup tracker with ours on the same traffic. JPDA is Stone Soup's exact EHM2 associator (the probabilities
of its plain JPDA, without listing the joint events) with a node budget per cluster and Stone Soup's LBP JPDA
as the counted fallback (:class:`GuardedJPDAwithEHM2`): a dense scene never hangs it. The settings are the
scenario's ``jpda-kf`` tables, mapped one to one where Stone Soup has the quantity (see docs/api.md, "Stone
Soup", for the mapping and the differences). :class:`RunDetectionReader` reads a run folder's
``detections.parquet`` for a Stone Soup script of one's own.

Stone Soup's state is [x, vx, y, vy] (ours [x, y, vx, vy]); times are ``datetime`` from an arbitrary epoch.
"""
from __future__ import annotations

import collections
import datetime
import math
from pathlib import Path
from typing import Iterator

import numpy as np

from ..config import ConfigError

try:
    from stonesoup.base import Property
    from stonesoup.buffered_generator import BufferedGenerator
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.dataassociator._ehm import EHMNode, EHMTree, TrackClusterer  # what JPDAwithEHM2 uses
    from stonesoup.dataassociator.probability import JPDAwithEHM2, JPDAwithLBP
    from stonesoup.deleter.error import CovarianceBasedDeleter
    from stonesoup.deleter.multi import CompositeDeleter
    from stonesoup.deleter.time import UpdateTimeStepsDeleter
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.measures import Mahalanobis
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.reader.base import DetectionReader
    from stonesoup.tracker.simple import MultiTargetMixtureTracker, MultiTargetTracker
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleProbabilityHypothesis
    from stonesoup.types.multihypothesis import MultipleHypothesis
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import KalmanUpdater
except ImportError as err:  # pragma: no cover - exercised by the missing-extra message only
    raise ConfigError("tracker", f"the Stone Soup trackers need Stone Soup 1.9.1, which cannot be imported here "
                      f"({err.name or err}): pip install 'roadtrack[stonesoup]'") from None

from roadtrack.trackers import JPDAOverflowError

from .protocol import Frame, TrackSet

EPOCH = datetime.datetime(2000, 1, 1)
"""Scan time t [s] is Stone Soup's ``EPOCH + t``."""
SS_ORDER = np.array([0, 2, 1, 3])
"""Our [x, y, vx, vy] from Stone Soup's [x, vx, y, vy] (and back: the permutation is its own inverse)."""
INITIAL_SPEED_SIGMAS = 4.0
"""A new track's velocity std is v_max / 4, so its second detection is in the initiator's gate (4 sigma) out
to v_max dt away: the reach of our two-point initiation."""


SS_MAX_NODES = 5_000
"""Budget of Stone Soup's EHM2 tree per cluster (nodes). Its pure-Python net took, on the 2-core test machine,
0.3 s for a cluster of 8 tracks in a row (896 nodes), 6.9 s for 12 (20 544 nodes), 37 s for 14 (65 747): about
2 s at the budget. Exact JPDA by EHM2 below it; above it the cluster falls back (:class:`GuardedJPDAwithEHM2`)."""


class TreeOverBudget(Exception):
    """Stone Soup's EHM2 tree of one cluster needs more than its node budget."""


class BudgetEHMTree(EHMTree):
    """Stone Soup's EHM2 tree (``make_tree=True``) that stops with TreeOverBudget once it has made more than
    ``max_nodes`` nodes, before the forward and backward passes (whose cost is linear in the nodes)."""

    def __init__(self, track_hypotheses, max_nodes: int):
        self.max_nodes, self.n_nodes = max_nodes, 0
        super().__init__(track_hypotheses, make_tree=True)

    def _make_child_nodes(self, level):  # Stone Soup 1.9.1's, with the node count
        for child_track in level.child_tracks:
            child = self.levels[child_track]
            for usedmeas in level.nodes:
                for hypothesis in level.measurement_hypotheses:
                    if hypothesis.measurement not in usedmeas:
                        new = (usedmeas | {hypothesis.measurement}) & child.accumulated_measurements
                        if new not in child.nodes:
                            self.n_nodes += 1
                            if self.n_nodes > self.max_nodes:
                                raise TreeOverBudget
                            child.nodes[new] = EHMNode()
            self._make_child_nodes(child)


class GuardedJPDAwithEHM2(JPDAwithEHM2):
    """Stone Soup's exact JPDA by EHM2 (Horridge & Maskell 2006), same probabilities as its JPDA, with a budget:
    a cluster (Stone Soup's TrackClusterer) whose EHM2 tree needs more than ``max_nodes`` nodes is associated by
    Stone Soup's loopy-belief-propagation JPDA (JPDAwithLBP, Williams & Lau 2014: approximate marginals in
    O(iterations x tracks x detections)) instead, or raises JPDAOverflowError with ``on_overflow = "raise"``.
    ``fallbacks``: the clusters of the last ``associate`` call that fell back."""

    max_nodes: int = Property(default=SS_MAX_NODES, doc="EHM2 tree nodes per cluster before the fallback")
    on_overflow: str = Property(default="k_best", doc="the scenario's tracker.associator.on_overflow: 'raise' gives "
                                "JPDAOverflowError, 'k_best' or 'pda' the LBP fallback")

    def associate(self, tracks, detections, timestamp, **kwargs):
        hypotheses = self.generate_hypotheses(tracks, detections, timestamp, **kwargs)
        self.fallbacks = 0
        out = {}
        for cluster in TrackClusterer(hypotheses).clustered_hypotheses:
            try:
                tree = BudgetEHMTree(cluster, self.max_nodes)
            except TreeOverBudget:
                meas = {h.measurement for _, hyps in cluster for h in hyps if h}
                if self.on_overflow == "raise":
                    raise JPDAOverflowError(f"Stone Soup JPDA (EHM2) cluster of {len(cluster)} tracks and {len(meas)} "
                                            f"detections needs more than max_nodes={self.max_nodes} tree nodes") from None
                self.fallbacks += 1
                lbp = JPDAwithLBP(self.hypothesiser)
                out.update(lbp.associate({track for track, _ in cluster}, meas, timestamp))
                continue
            for track, posterior in tree.get_posterior_hypotheses().items():
                out[track] = MultipleHypothesis(
                    [SingleProbabilityHypothesis(h.prediction, h.measurement, probability=prob,
                                                 measurement_prediction=h.measurement_prediction)
                     for h, prob in posterior], True, 1)
        return out


def timestamp(time_s: float) -> datetime.datetime:
    """Stone Soup's timestamp of scan time ``time_s`` [s]."""
    return EPOCH + datetime.timedelta(seconds=float(time_s))


def detections(time_s: float, z: np.ndarray, model: LinearGaussian) -> set[Detection]:
    """Stone Soup detections of positions ``z`` (M, 2) [m] at ``time_s`` [s] with measurement ``model``."""
    when = timestamp(time_s)
    return {Detection(np.asarray(p, dtype=np.float64).reshape(2, 1), timestamp=when, measurement_model=model,
                      metadata={"index": j}) for j, p in enumerate(z)}


class FeedReader(DetectionReader):
    """A detection reader fed one scan at a time (:meth:`push`), for a tracker stepped scan by scan."""

    def push(self, when: datetime.datetime, dets: set[Detection]) -> None:
        self.__dict__.setdefault("_pending", collections.deque()).append((when, dets))

    @BufferedGenerator.generator_method
    def detections_gen(self) -> Iterator[tuple[datetime.datetime, set[Detection]]]:
        while True:
            yield self._pending.popleft()  # the adapter pushes a scan before each step


class RunDetectionReader(DetectionReader):
    """The detections of a run folder's ``detections.parquet`` as Stone Soup scans (every frame, empty ones
    included), with the given measurement model: ``RunDetectionReader("runs/cut_in_out", model)``."""

    folder: Path = Property(doc="a run folder (testbed run ... --out FOLDER)")
    measurement_model: LinearGaussian = Property(doc="the detections' measurement model")

    @BufferedGenerator.generator_method
    def detections_gen(self) -> Iterator[tuple[datetime.datetime, set[Detection]]]:
        import pandas as pd

        folder = Path(self.folder)
        det = pd.read_parquet(folder / "detections.parquet", columns=["frame", "time", "x", "y"])
        times = pd.read_parquet(folder / "truth.parquet", columns=["frame", "time"]).drop_duplicates("frame")
        by_frame = {f: g for f, g in det.groupby("frame")}
        for f, t in zip(times.frame.to_numpy(), times.time.to_numpy()):
            g = by_frame.get(f)
            z = np.zeros((0, 2)) if g is None else g[["x", "y"]].to_numpy(np.float64)
            yield timestamp(t), detections(t, z, self.measurement_model)


def components(scenario, associator: str) -> dict:
    """The Stone Soup components of ``stonesoup-<associator>-kf`` from the scenario's ``jpda-kf`` settings."""
    ours = scenario.tracker.build("jpda-kf")
    sigma_v, sigma_w = ours.filter.motion.sigma_v, ours.filter.measurement.sigma_w
    a, m = ours.association, ours.management
    dt = 1.0 / scenario.rate_hz
    # Stone Soup's CV is the continuous white-acceleration model, Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]; ours
    # the discrete one, sigma_v^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]] (thesis §1.1): q = sigma_v^2 dt gives the
    # same velocity and cross terms, and 4/3 of our position term (sigma_v^2 dt^4 / 3 instead of / 4).
    cv = ConstantVelocity(sigma_v ** 2 * dt)
    transition = CombinedLinearGaussianTransitionModel([cv, cv])
    model = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=np.eye(2) * sigma_w ** 2)
    predictor, updater = KalmanPredictor(transition), KalmanUpdater(model)
    gate = math.sqrt(a.gate_alpha)  # Stone Soup's Mahalanobis measure is the distance, our gate its square
    if associator == "gnn":
        assoc = GNNWith2DAssignment(DistanceHypothesiser(predictor, updater, measure=Mahalanobis(),
                                                         missed_distance=gate))
    elif associator == "jpda":
        pg = 1.0 - math.exp(-a.gate_alpha / 2.0)  # chi-square(2) gate probability (thesis §4.1)
        pg = pg if a.pg is None else a.pg  # the associator's P_G when it sets one
        assoc = GuardedJPDAwithEHM2(PDAHypothesiser(predictor, updater, clutter_spatial_density=a.clutter_density,
                                                    prob_detect=a.pd, prob_gate=pg),
                                    on_overflow=a.on_overflow)
    else:
        raise ValueError(f"associator {associator!r}: expected 'gnn' or 'jpda'")
    # deletion as ours: coast_scans missed scans in a row, or a position std above max_position_std_m
    deleters = [UpdateTimeStepsDeleter(m.coast_scans + 1)]
    if m.max_position_std_m is not None:
        deleters.append(CovarianceBasedDeleter(2 * m.max_position_std_m ** 2, mapping=[0, 2]))
    deleter = CompositeDeleter(deleters, intersect=False)
    speed = m.v_max / INITIAL_SPEED_SIGMAS
    prior = GaussianState(np.zeros((4, 1)), np.diag([sigma_w ** 2, speed ** 2, sigma_w ** 2, speed ** 2]))
    initiator = MultiMeasurementInitiator(
        prior_state=prior, measurement_model=model, deleter=UpdateTimeStepsDeleter(2),
        data_associator=GNNWith2DAssignment(DistanceHypothesiser(predictor, updater, measure=Mahalanobis(),
                                                                 missed_distance=gate)),
        updater=updater, min_points=2)
    return dict(model=model, associator=assoc, updater=updater, initiator=initiator, deleter=deleter)


class StoneSoupTracker:
    """A Stone Soup multi-target tracker behind the tracker protocol: each ``step`` pushes the scan's detections
    into its reader and advances the tracker one scan. Tracks are "confirmed" (the initiator's held tracks,
    awaiting their second detection, are "tentative"); ids are 1, 2, ... in order of birth."""

    def __init__(self, scenario, associator: str = "jpda"):
        parts = components(scenario, associator)
        self.name = f"stonesoup-{associator}-kf"
        self.model = parts["model"]
        self.associator = parts["associator"]
        self.reader = FeedReader()
        kind = MultiTargetMixtureTracker if associator == "jpda" else MultiTargetTracker
        self.tracker = kind(initiator=parts["initiator"], deleter=parts["deleter"], detector=self.reader,
                            data_associator=parts["associator"], updater=parts["updater"])
        self._iter = iter(self.tracker)
        self._ids: dict[str, int] = {}

    def _label(self, track) -> int:
        return self._ids.setdefault(track.id, len(self._ids) + 1)

    def step(self, frame: Frame) -> TrackSet:
        self.reader.push(timestamp(frame.time), detections(frame.time, frame.z, self.model))
        _, tracks = next(self._iter)
        fallbacks = int(getattr(self.associator, "fallbacks", 0))  # GuardedJPDAwithEHM2's, this scan
        held = getattr(self.tracker.initiator, "holding_tracks", set())
        rows = [(t, "confirmed") for t in tracks] + [(t, "tentative") for t in held]
        rows.sort(key=lambda r: self._label(r[0]))
        if not rows:
            return TrackSet(ids=np.zeros(0, dtype=np.int64), xy=np.zeros((0, 2)), fallbacks=fallbacks)
        x = np.stack([np.asarray(t.state_vector, dtype=np.float64).reshape(4)[SS_ORDER] for t, _ in rows])
        cov = np.stack([np.asarray(t.covar, dtype=np.float64)[np.ix_(SS_ORDER, SS_ORDER)] for t, _ in rows])
        return TrackSet(ids=np.array([self._label(t) for t, _ in rows], dtype=np.int64), xy=x[:, :2], v=x[:, 2:],
                        cov=cov, status=np.array([s for _, s in rows], dtype=object), fallbacks=fallbacks)


def gnn_kf(scenario) -> StoneSoupTracker:
    """Stone Soup: global nearest neighbour (2-D assignment) of Kalman filters, Mahalanobis gate."""
    return StoneSoupTracker(scenario, "gnn")


def jpda_kf(scenario) -> StoneSoupTracker:
    """Stone Soup: JPDA (exact by EHM2; a cluster over SS_MAX_NODES tree nodes by LBP, counted) of Kalman
    filters, PDA hypotheses with P_D, P_G, clutter."""
    return StoneSoupTracker(scenario, "jpda")
