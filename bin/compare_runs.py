"""Compare run folders of two code versions bit for bit (issue 32: "every earlier command gives identical outputs").

    python bin/compare_runs.py BASE_DIR NEW_DIR

BASE_DIR and NEW_DIR each hold one run folder per case (``testbed run ... --out DIR/<case>``). Every parquet table
must be equal (schema and values); scores.json must be equal but for ``timings_ms_per_frame`` (wall-clock) and
scenario keys the new version added at their default (listed, e.g. ``config.sensor.extra = []``). Exit 1 on any
difference.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pyarrow.parquet as pq


def added_defaults(old, new, path: str = "") -> list[str]:
    """Keys of ``new`` missing from ``old`` (dicts compared recursively), removed from ``new`` in place."""
    out = []
    if isinstance(old, dict) and isinstance(new, dict):
        for k in list(new):
            if k not in old:
                out.append(f"{path}{k} = {json.dumps(new.pop(k))}")
            else:
                out += added_defaults(old[k], new[k], f"{path}{k}.")
    return out


def same_file(f: Path, g: Path) -> tuple[bool, str]:
    if f.suffix == ".parquet":
        ta, tb = pq.read_table(f), pq.read_table(g)
        return ta.schema.equals(tb.schema) and ta.equals(tb), f"{ta.num_rows} rows"
    if f.suffix == ".json":
        ja, jb = json.loads(f.read_text()), json.loads(g.read_text())
        for j in (ja, jb):
            j.pop("timings_ms_per_frame", None)
        added = added_defaults(ja.get("config", {}), jb.get("config", {}), "config.")
        return ja == jb, "without timings_ms_per_frame" + (f"; added: {', '.join(added)}" if added else "")
    return f.read_bytes() == g.read_bytes(), "bytes"


def main(base: str, new: str) -> int:
    ok = True
    for case in sorted(p for p in Path(base).iterdir() if p.is_dir()):
        for f in sorted(case.iterdir()):
            same, what = same_file(f, Path(new, case.name, f.name))
            ok &= same
            print(f"{case.name}/{f.name}: {'identical' if same else 'DIFFERENT'} ({what})")
    print("all identical" if ok else "differences found")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
