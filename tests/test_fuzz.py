"""Fuzz the scenario and campaign loaders, ``--set`` and the command line with mutated inputs.

Every mutated input must either be accepted (exit 0) or refused with exit 2 and ONE line on stderr,
never a traceback, another exception or another exit code. Mutations start from the shipped scenario and
campaign files: a value replaced by a hostile one (NaN, 1e308, 2**64, "", "../..", a table, a list ...),
a key deleted or added, a table turned into a scalar, bytes flipped / inserted / cut, the file re-encoded
(Latin-1, UTF-16, binary), and ``--set KEY=VALUE`` pairs on real and made-up keys.

The hypothesis tests run a fixed budget (``ROADTRACK_FUZZ_EXAMPLES`` scales it; CI uses the default).
``python tests/test_fuzz.py N`` runs N seeded mutations of each kind through the command line and prints
the tally (the counts quoted in the hardening note).
"""
from __future__ import annotations

import contextlib
import io
import json
import math
import os
import random
import sys
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from roadtrack.testbed.cli.main import main
from roadtrack.testbed.perception.report import dumps_toml

REPO = Path(__file__).resolve().parent.parent

SCENARIOS = sorted((REPO / "scenarios").glob("*.toml"))
CAMPAIGNS = sorted((REPO / "campaigns").glob("*.toml"))
RUNNABLE = [p for p in SCENARIOS if p.stem in ("cut_in_out", "convoy", "straight_curve")]  # quick to start
BUDGET = float(os.environ.get("ROADTRACK_FUZZ_EXAMPLES", "1"))

HOSTILE = [0, -1, 1, 2, 7, 2**31, 2**32, 2**63 - 1, -2**63, 10**9, 10**12, 1e308, -1e308, 1e-300, 1e-9, 0.5,
           -0.5, 1e9, float("nan"), float("inf"), -float("inf"), "", "x", "../../escaped", "/tmp", ".", "caf\u00e9",
           "a" * 300, "\u0000", True, False, [], [1, 2], ["a"], [[1]], {}, {"a": 1}, {"x": {"y": []}},
           "builtins:exec", "os:system", "this:s", "os.system", "highway_env.utils.class_from_path"]  # names of code
JUNK_KEYS = ["", "x", "a.b.c", "name.x", "vehicles.99.speed", "vehicles.-1", "sensor..lidar", "seed.seed",
             "tracker.management.nope", "__class__", "sensor.lidar.n_beams.x"]


# ------------------------------------------------------------------ mutations (rng: random.Random)
def _leaves(data, path=()):
    """Every (path, value) in a parsed TOML document; paths are tuples of keys and list indices."""
    out = [(path, data)] if path else []
    if isinstance(data, dict):
        for k, v in data.items():
            out += _leaves(v, path + (k,))
    elif isinstance(data, list):
        for i, v in enumerate(data):
            out += _leaves(v, path + (i,))
    return out


def _set_in(data, path, value, delete=False):
    node = data
    for p in path[:-1]:
        node = node[p]
    if delete:
        del node[path[-1]]
    else:
        node[path[-1]] = value


def _hostile(rng: random.Random):
    value = rng.choice(HOSTILE)
    if isinstance(value, (int, float)) and not isinstance(value, bool) and rng.random() < 0.3:
        value = value * rng.choice([-1, 10, 0.1, 1000])
    return json.loads(json.dumps(value)) if not isinstance(value, float) else value


def mutate_document(data: dict, rng: random.Random) -> dict:
    """One to three structural mutations of a parsed TOML document (in place, returned)."""
    for _ in range(rng.randint(1, 3)):
        leaves = _leaves(data)
        kind = rng.choice(["value", "value", "value", "delete", "add", "retype", "scale", "scale"])
        path, value = rng.choice(leaves) if leaves else ((), None)
        if not path:
            continue
        if kind == "value":
            _set_in(data, path, _hostile(rng))
        elif kind == "delete" and isinstance(path[-1], str):
            _set_in(data, path, None, delete=True)
        elif kind == "add":
            target = value if isinstance(value, dict) else data
            target[rng.choice(JUNK_KEYS[1:] + ["seed", "name", "count", "speed_mps"])] = _hostile(rng)
        elif kind == "scale" and isinstance(value, (int, float)) and not isinstance(value, bool):
            factor = rng.choice([0, 0.5, 0.9, 1.1, 2, 3, -1])  # plausible edits that often still load
            _set_in(data, path, type(value)(value * factor) if math.isfinite(value * factor) else value)
        elif kind == "retype":
            _set_in(data, path, rng.choice([1, "s", [1], {"k": 1}]))
    return data


def _dump(data: dict) -> bytes | None:
    try:
        text = dumps_toml(data)
    except (TypeError, ValueError, RecursionError):
        return None
    return text.encode("utf-8", "surrogatepass")


def mutate_bytes(raw: bytes, rng: random.Random) -> bytes:
    """Byte-level damage: flips, inserts, cuts, a foreign encoding, or plain binary."""
    kind = rng.choice(["flip", "insert", "cut", "latin1", "utf16", "binary", "nul"])
    b = bytearray(raw)
    if kind == "flip" and b:
        for _ in range(rng.randint(1, 8)):
            b[rng.randrange(len(b))] = rng.randrange(256)
    elif kind == "insert":
        pos = rng.randrange(len(b) + 1)
        b[pos:pos] = rng.choice([b"[", b"]]", b"=", b'"', b"\xe9", b"\xff\xfe", b"\n[x]\n", b"= = ="])
    elif kind == "cut" and b:
        b = b[: rng.randrange(len(b))]
    elif kind == "latin1":
        text = raw.decode("utf-8").replace('name = "', 'name = "caf\u00e9', 1)
        return text.encode("latin-1", "replace")
    elif kind == "utf16":
        return raw.decode("utf-8").encode("utf-16")
    elif kind == "binary":
        return bytes(rng.randrange(256) for _ in range(rng.randint(0, 400)))
    elif kind == "nul":
        b[rng.randrange(len(b) + 1):0] = b"\x00"
    return bytes(b)


def mutated_file(source: Path, rng: random.Random) -> bytes:
    """A mutated copy of ``source``: structural (70 %) or byte-level (30 %)."""
    import tomllib

    raw = source.read_bytes()
    if rng.random() < 0.7:
        out = _dump(mutate_document(tomllib.loads(raw.decode()), rng))
        if out is not None:
            return out
    return mutate_bytes(raw, rng)


def set_pairs(source: Path, rng: random.Random) -> list[str]:
    """One to three ``--set KEY=VALUE`` strings on real keys of ``source`` and made-up ones."""
    import tomllib

    keys = [".".join(map(str, p)) for p, _ in _leaves(tomllib.loads(source.read_text()))]
    out = []
    for _ in range(rng.randint(1, 3)):
        key = rng.choice(keys + JUNK_KEYS) if rng.random() < 0.8 else rng.choice(keys) + ".x"
        value = _hostile(rng)
        text = rng.choice(["nan", "inf", "-inf", "1e999", "[", "{", "'", '"unterminated', "=", "1=2", "x y"]) \
            if rng.random() < 0.25 else (dumps_toml({"v": value})[4:].strip() if _dump({"v": value}) else "1")
        out.append(f"{key}={text}" if rng.random() < 0.95 else text)
    return out


# ------------------------------------------------------------------ the oracle
def run_cli(argv: list[str]) -> tuple[int, list[str]]:
    """``testbed ARGV`` in this process: exit code and the non-empty stderr lines."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse refuses an option
            code = exc.code if isinstance(exc.code, int) else 2
    return code, [line for line in err.getvalue().splitlines() if line.strip()]


def verdict(code: int, lines: list[str]) -> str:
    """'accepted', 'refused' (exit 2, one line) or a failure description."""
    if any("Traceback" in line for line in lines):
        return "traceback"
    if code == 0:
        return "accepted"
    if code == 2 and len(lines) == 1 and lines[0].startswith(("error:", "usage:", "testbed:")):
        return "refused"
    if code == 2 and len(lines) == 2 and lines[0].startswith("usage:"):  # argparse: usage line + error line
        return "refused"
    return f"exit {code}, {len(lines)} stderr lines: {lines[-1] if lines else ''}"


def check_scenario_file(data: bytes, tmp: Path, run: bool) -> str:
    path = tmp / "fuzzed.toml"
    path.write_bytes(data)
    argv = ["run", str(path), "--no-record", "--quiet", "--out", str(tmp / "out"), "--set", "duration_s=0.2"] \
        if run else ["check", str(path)]
    return verdict(*run_cli(argv))


def check_campaign_file(data: bytes, tmp: Path) -> str:
    path = tmp / "fuzzed_campaign.toml"
    path.write_bytes(data)
    return verdict(*run_cli(["check", str(path)]))


def check_sets(source: Path, pairs: list[str], tmp: Path, run: bool) -> str:
    argv = ["run" if run else "check", str(source)]
    for p in pairs:
        argv += ["--set", p]
    if run:
        argv += ["--no-record", "--quiet", "--out", str(tmp / "out"), "--set", "duration_s=0.2"]
    return verdict(*run_cli(argv))


# ------------------------------------------------------------------ hypothesis tests (CI budget)
def _fuzz(n: int) -> settings:
    """Seeded (derandomized) settings with a budget of ``n`` examples times ROADTRACK_FUZZ_EXAMPLES."""
    return settings(max_examples=max(1, int(n * BUDGET)), deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


@_fuzz(300)
@given(source=st.sampled_from(SCENARIOS), rng=st.randoms(use_true_random=False))
def test_mutated_scenario_files_are_accepted_or_refused_in_one_line(source, rng):
    with tempfile.TemporaryDirectory() as tmp:
        assert check_scenario_file(mutated_file(source, rng), Path(tmp), run=False) in ("accepted", "refused")


@_fuzz(200)
@given(source=st.sampled_from(CAMPAIGNS), rng=st.randoms(use_true_random=False))
def test_mutated_campaign_files_are_accepted_or_refused_in_one_line(source, rng):
    with tempfile.TemporaryDirectory() as tmp:
        assert check_campaign_file(mutated_file(source, rng), Path(tmp)) in ("accepted", "refused")


@_fuzz(200)
@given(source=st.sampled_from(SCENARIOS), rng=st.randoms(use_true_random=False))
def test_set_overrides_are_accepted_or_refused_in_one_line(source, rng):
    with tempfile.TemporaryDirectory() as tmp:
        assert check_sets(source, set_pairs(source, rng), Path(tmp), run=False) in ("accepted", "refused")


@_fuzz(20)
@given(source=st.sampled_from(RUNNABLE), rng=st.randoms(use_true_random=False))
def test_mutated_scenarios_that_load_also_run(source, rng):
    """Accepted mutations are run for 0.2 s: the run must end with exit 0 (or 2), never 1 or a traceback."""
    with tempfile.TemporaryDirectory() as tmp:
        data = mutated_file(source, rng)
        if check_scenario_file(data, Path(tmp), run=False) == "accepted":
            assert check_scenario_file(data, Path(tmp), run=True) in ("accepted", "refused")


def test_the_oracle_can_fail():
    """The verdict tells a traceback and a multi-line error from a clean refusal."""
    assert verdict(2, ["error: x: bad"]) == "refused"
    assert verdict(0, []) == "accepted"
    assert verdict(1, ["error: x"]).startswith("exit 1")
    assert verdict(2, ["Traceback (most recent call last):", "ValueError"]) == "traceback"
    assert verdict(2, ["error: a", "more"]).startswith("exit 2")
    assert not math.isnan(len(HOSTILE))


# ------------------------------------------------------------------ the tally for the closing note
def _run_if_accepted(rng: random.Random, tmp: Path) -> str:
    """A mutated small scenario: checked, then (if accepted) run for 0.2 s."""
    data = mutated_file(rng.choice(RUNNABLE), rng)
    first = check_scenario_file(data, tmp, run=False)
    return check_scenario_file(data, tmp, run=True) if first == "accepted" else first


def tally(n: int, seed: int = 0) -> dict[str, dict[str, int]]:
    """Run ``n`` seeded mutations of each kind through the CLI; counts of each verdict per kind."""
    from collections import Counter

    from tqdm import tqdm

    out = {}
    kinds = {
        "scenario file": lambda rng, tmp: check_scenario_file(mutated_file(rng.choice(SCENARIOS), rng), tmp, False),
        "campaign file": lambda rng, tmp: check_campaign_file(mutated_file(rng.choice(CAMPAIGNS), rng), tmp),
        "--set": lambda rng, tmp: check_sets((s := rng.choice(SCENARIOS)), set_pairs(s, rng), tmp, False),
        "scenario file, run 0.2 s": _run_if_accepted,
    }
    for kind, fn in kinds.items():
        counts: Counter = Counter()
        for i in tqdm(range(n), desc=kind, leave=False):
            with tempfile.TemporaryDirectory() as tmp:
                v = fn(random.Random(seed * 1_000_003 + i), Path(tmp))
            counts[v if v in ("accepted", "refused") else "FAILED: " + v[:120]] += 1
        out[kind] = dict(counts)
    return out


if __name__ == "__main__":
    result = tally(int(sys.argv[1]) if len(sys.argv) > 1 else 500)
    for kind, counts in result.items():
        bad = {k: v for k, v in counts.items() if k.startswith("FAILED")}
        print(f"{kind}: {sum(counts.values())} tried, {counts.get('accepted', 0)} accepted, "
              f"{counts.get('refused', 0)} refused in one line, {sum(bad.values())} failed")
        for k, v in sorted(bad.items(), key=lambda kv: -kv[1]):
            print(f"    {v:4d} x {k}")
