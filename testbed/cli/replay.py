"""``testbed replay SEQUENCE_DIR``: a recorded KITTI-tracking sequence through our perception, a tracker and, with
labels, the scoring and the recording (testbed.pipeline.replay; docs/formats.md)."""
from __future__ import annotations

import argparse
from pathlib import Path


def add_replay_parser(sub, func) -> None:
    """Add ``replay`` to the sub-commands; ``func(args) -> exit code`` runs it (testbed.cli.main)."""
    r = sub.add_parser("replay", help="run a KITTI-tracking sequence (velodyne scans, oxts poses, optional "
                                      "label_02 truth; e.g. one `testbed export --format kitti` wrote) through "
                                      "the perception, a tracker, the scoring and the recording")
    r.add_argument("sequence_dir", help="the KITTI-tracking folder (velodyne/, oxts/, calib/, label_02/)")
    r.add_argument("--sequence", help="the sequence's name, e.g. 0000 (default: the folder's only one)")
    r.add_argument("--scenario", help="scenario file or shipped name giving the sensor, perception, tracker and "
                                      "scoring settings (default: the roadtrack_scenario.json beside the "
                                      "sequence, else the defaults); its traffic is not used")
    r.add_argument("--road", action=argparse.BooleanOptionalAction, default=None,
                   help="use the scenario's road as the lane map (default: only when the scenario came with "
                        "the sequence)")
    r.add_argument("--tracker", help="tracker name overriding the scenario's, e.g. jpda-kf, or my_module:MyTracker")
    r.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a scenario key (repeatable)")
    r.add_argument("--out", help="output folder (default runs/replay-<sequence>)")
    r.add_argument("--no-record", action="store_true", help="skip the rerun recording")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=func, no_plot=True)
