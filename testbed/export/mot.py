"""``testbed export RUN --format mot [--out DIR]``: the run as a MOTChallenge sequence (truth, detections, tracks)
laid out as TrackEval's ``MotChallenge2DBox`` reads it, so the MOT tools (TrackEval's scripts, the MOTChallenge
devkit) evaluate a testbed run. Field by field in docs/formats.md ("MOTChallenge").

DIR (default ``RUN/mot/``)::

    gt/seqmaps/ROADTRACK-all.txt        "name", then the sequence name (TrackEval's seqmap)
    gt/SEQ/seqinfo.ini                  [Sequence] name, frameRate, seqLength (+ comments: the conventions)
    gt/SEQ/gt/gt.txt                    truth:      frame, id, bb_left, bb_top, bb_width, bb_height, conf, class, visibility
    gt/SEQ/det/det.txt                  detections: frame, -1, bb_left, bb_top, bb_width, bb_height, conf, x, y, z
    trackers/TRACKER/data/SEQ.txt       confirmed tracks: frame, id, bb_left, bb_top, bb_width, bb_height, conf, -1, -1, -1

SEQ is the scenario's name and seed (``cut_in_out-s7``), TRACKER the run's tracker, both with any character
outside ``A-Za-z0-9_.-`` replaced by ``_``.

How the bird's-eye-view world maps onto MOTChallenge's image boxes:

* frames are 1-based (MOTChallenge frame = our frame + 1); ``seqLength`` = the run's frames;
* a "box" is the car's footprint seen from above, in metres in the world frame: the image's horizontal axis is
  world x (along the road), its vertical axis world y (to the left); every object gets the same axis-aligned
  :data:`FOOTPRINT_M` (5 m x 2 m, highway-env's car) centred on its position, so ``bb_left = x - 2.5``,
  ``bb_top = y - 1``, and the box centre is exactly the position the testbed scores. A fixed footprint makes a box
  overlap (IoU) a function of the position error alone, the same for truth, detections and tracks (tracks have no
  size); the true sizes are in the CSV export;
* truth: the ego car is left out (as in the testbed's scores); a car hit by at least ``scoring.visible_min_points``
  LiDAR points that frame is class 1 (the class TrackEval's MOTChallenge2DBox evaluates), conf 1, visibility 1; a
  hidden car (out of range or occluded) is class 8, *distractor*, conf 0, visibility 0: TrackEval removes the tracks
  it matches to one and does not count it as missed: the testbed's "visible truth" (testbed/scoring/mot_metrics.py);
* detections: id -1, conf 1, x, y the measurement [m], z 0 (the road plane); clutter included;
* tracks: the confirmed rows only (what the testbed scores), conf 1, and x, y, z = -1 as in a MOTChallenge
  submission: TrackEval reads a tracker file's 8th column as its class and refuses any class above 1, so the world
  position is the box centre, not columns 8-10.

TrackEval scores MOTChallenge boxes by IoU; the testbed by the centre distance, ``s = max(0, 1 - d / scale)``.
:func:`trackeval_dataset` gives TrackEval's own reader either way: ``similarity="iou"`` as the MOTChallenge
benchmark, ``"distance"`` (the box centres' distance) to reproduce the testbed's HOTA / CLEAR / Identity numbers.

    write(run, path) -> Path                                   run: testbed.pipeline.runfolder.RunData
    trackeval_config(folder) -> dict                           the dataset config that reads ``folder``
    trackeval_dataset(folder, similarity="iou", scale_m=3.0)   a trackeval.datasets.MotChallenge2DBox on it
"""
from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import pandas as pd

from ..common.safe_io import make_folder, write_text
from ..config import ConfigError
from ..scenario.spec import ScoringSpec

FOOTPRINT_M = (5.0, 2.0)  # length along world x, width along world y [m]: every box
BENCHMARK, SPLIT = "ROADTRACK", "all"  # TrackEval's gt_set "ROADTRACK-all"
EVALUATED, DISTRACTOR = 1, 8  # MOTChallenge classes: the one TrackEval evaluates ("pedestrian"), "distractor"
DECIMALS = 6  # metres to the micrometre: the similarity from the files equals the testbed's to ~1e-7
F = f"%.{DECIMALS}f"


def write(run, path: str | Path) -> Path:
    """Write ``run`` as a MOTChallenge sequence into the folder ``path`` (layout in the module docstring; created if
    missing, a symbolic link there or at any name written is refused). ConfigError (one line) for a negative id."""
    out = Path(path)
    seq, tracker = sequence_name(run), safe_name(str(run.scores.get("tracker", "tracker")))
    sc = run.scenario.scoring if run.scenario is not None else ScoringSpec()
    gt_text, det_text, trk_text = (gt_rows(run.truth, sc.visible_min_points), det_rows(run.detections),
                                   track_rows(run.tracks))
    make_folder(out, "--out")
    gt = make_folder(out / "gt")
    write_text(make_folder(gt / "seqmaps") / f"{BENCHMARK}-{SPLIT}.txt", f"name\n{seq}\n")
    seq_dir = make_folder(gt / seq)
    write_text(seq_dir / "seqinfo.ini", seqinfo(seq, run))
    write_text(make_folder(seq_dir / "gt") / "gt.txt", gt_text)
    write_text(make_folder(seq_dir / "det") / "det.txt", det_text)
    data = make_folder(make_folder(make_folder(out / "trackers") / tracker) / "data")
    write_text(data / f"{seq}.txt", trk_text)
    return out


def safe_name(name: str) -> str:
    """``name`` with every character outside ``A-Za-z0-9_.-`` replaced by ``_`` (a file or folder name)."""
    s = re.sub(r"[^A-Za-z0-9_.-]", "_", name).strip(".")
    return s or "_"


def sequence_name(run) -> str:
    """The sequence's name: scenario and seed (``cut_in_out-s7``), or the run folder's name without scores.json."""
    if "scenario" in run.scores:
        name = f"{run.scores['scenario']}-s{run.scores.get('seed', 0)}"
    else:
        name = run.folder.name
    name = safe_name(name)
    return name + "_" if name == "seqmaps" else name


def seqinfo(seq: str, run) -> str:
    """seqinfo.ini: the keys TrackEval reads (``seqLength``) and MOTChallenge's name and frameRate; no images."""
    dt = run.scenario.dt if run.scenario is not None else _frame_dt(run.truth)
    rate = 1.0 / dt if dt > 0 else 0.0
    rate_text = str(int(round(rate))) if abs(rate - round(rate)) < 1e-9 else f"{rate:.6g}"
    return (f"; roadtrack run exported for the MOTChallenge tools (docs/formats.md, MOTChallenge)\n"
            f"; frames 1-based (frame = testbed frame + 1), one every {dt:g} s\n"
            f"; boxes: a fixed {FOOTPRINT_M[0]:g} m x {FOOTPRINT_M[1]:g} m footprint seen from above, in metres, "
            f"left = world x, top = world y; no images\n"
            f"[Sequence]\nname={seq}\nframeRate={rate_text}\nseqLength={run.n_frames}\n")


def _frame_dt(truth: pd.DataFrame) -> float:
    t = np.unique(truth["time"].to_numpy(dtype=np.float64)) if len(truth) else np.zeros(0)
    return float(np.min(np.diff(t))) if len(t) > 1 else 0.0


def boxes(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(N, 4) bb_left, bb_top, bb_width, bb_height [m] of the :data:`FOOTPRINT_M` boxes centred on ``x``, ``y``."""
    length, width = FOOTPRINT_M
    n = len(x)
    return np.column_stack([x - length / 2, y - width / 2, np.full(n, length), np.full(n, width)])


def _ids(values, what: str) -> np.ndarray:
    ids = np.asarray(values, dtype=np.int64)
    if len(ids) and ids.min() < 0:
        raise ConfigError(what, f"id {int(ids.min())} is negative; MOTChallenge ids must be >= 0")
    return ids


def _text(cols: list[np.ndarray], fmt: list[str]) -> str:
    buf = io.StringIO()
    if len(cols[0]):
        np.savetxt(buf, np.column_stack([np.asarray(c, dtype=np.float64) for c in cols]), fmt=fmt, delimiter=",")
    return buf.getvalue()


def gt_rows(truth: pd.DataFrame, visible_min_points: int) -> str:
    """gt.txt: frame (1-based), vehicle id, box, conf (1 visible, 0 hidden), class (1 visible, 8 hidden), visibility
    (1 / 0); the ego's rows left out; sorted by frame, then id."""
    g = truth[~truth["is_ego"].to_numpy(dtype=bool)] if "is_ego" in truth.columns else truth
    g = g.sort_values(["frame", "vehicle_id"], kind="stable")
    vis = g["n_points"].to_numpy(dtype=np.int64) >= visible_min_points
    b = boxes(g["x"].to_numpy(dtype=np.float64), g["y"].to_numpy(dtype=np.float64))
    return _text([g["frame"].to_numpy() + 1, _ids(g["vehicle_id"], "truth.vehicle_id"), *b.T, vis,
                  np.where(vis, EVALUATED, DISTRACTOR), vis], ["%d", "%d", F, F, F, F, "%d", "%d", "%d"])


def det_rows(det: pd.DataFrame) -> str:
    """det.txt: frame (1-based), -1, box, conf 1, x, y [m], z 0; in the table's order (frame by frame)."""
    x, y = det["x"].to_numpy(dtype=np.float64), det["y"].to_numpy(dtype=np.float64)
    n = len(det)
    return _text([det["frame"].to_numpy() + 1, np.full(n, -1), *boxes(x, y).T, np.ones(n), x, y, np.zeros(n)],
                 ["%d", "%d", F, F, F, F, "%d", F, F, "%d"])


def track_rows(tracks: pd.DataFrame) -> str:
    """The tracker file: frame (1-based), track id, box, conf 1, -1, -1, -1; confirmed rows only, by frame then id."""
    t = tracks[tracks["status"].astype(str).to_numpy() == "confirmed"] if "status" in tracks.columns else tracks
    t = t.sort_values(["frame", "track_id"], kind="stable")
    n = len(t)
    b = boxes(t["x"].to_numpy(dtype=np.float64), t["y"].to_numpy(dtype=np.float64))
    return _text([t["frame"].to_numpy() + 1, _ids(t["track_id"], "tracks.track_id"), *b.T, np.ones(n),
                  *np.full((3, n), -1)], ["%d", "%d", F, F, F, F, "%d", "%d", "%d", "%d"])


def trackeval_config(folder: str | Path) -> dict:
    """The config of TrackEval's ``MotChallenge2DBox`` that reads the export in ``folder`` (every tracker in it)."""
    folder = Path(folder)
    return {"GT_FOLDER": str(folder / "gt"), "TRACKERS_FOLDER": str(folder / "trackers"), "BENCHMARK": BENCHMARK,
            "SPLIT_TO_EVAL": SPLIT, "SKIP_SPLIT_FOL": True, "PRINT_CONFIG": False}


def trackeval_dataset(folder: str | Path, similarity: str = "iou", scale_m: float = 3.0):
    """TrackEval's ``MotChallenge2DBox`` reading the export in ``folder``: its reader, its preprocessing (the
    distractors) and its box similarity ``"iou"``, or with ``"distance"`` the testbed's similarity of the boxes'
    centres, ``max(0, 1 - d / scale_m)`` (testbed/scoring/mot_metrics.py), everything else TrackEval's own."""
    from trackeval.datasets import MotChallenge2DBox

    if similarity == "iou":
        return MotChallenge2DBox(trackeval_config(folder))
    if similarity != "distance":
        raise ValueError(f"similarity must be 'iou' or 'distance', got {similarity!r}")

    class CentreDistance(MotChallenge2DBox):
        """MotChallenge2DBox with the similarity of the boxes' centres instead of their IoU."""

        def _calculate_similarities(self, gt_dets_t, tracker_dets_t):
            g = np.asarray(gt_dets_t, dtype=np.float64).reshape(-1, 4)
            t = np.asarray(tracker_dets_t, dtype=np.float64).reshape(-1, 4)
            cg, ct = g[:, :2] + g[:, 2:] / 2, t[:, :2] + t[:, 2:] / 2
            d = np.sqrt(np.sum((cg[:, None, :] - ct[None, :, :]) ** 2, axis=-1))
            return np.maximum(0.0, 1.0 - d / scale_m)

    return CentreDistance(trackeval_config(folder))
