"""Installed like any package (issue 31.6): the shipped scenarios and campaigns are package data, found by name
through one lookup (testbed/config/files.py, shipped_dir) in a checkout, an editable install and a plain install.

The lookup tests here are fast; tests/test_install_wheel.py builds a wheel, installs it into a fresh venv and runs
a shipped scenario by name from outside the checkout.
"""
from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("kind", ["scenario", "campaign"])
def test_in_a_checkout_the_shipped_files_are_the_repository_folders(kind):
    from roadtrack.testbed.config import shipped_dir, shipped_names

    folder = REPO / f"{kind}s"
    assert shipped_dir(kind) == folder.resolve()
    assert shipped_names(kind) == sorted(p.stem for p in folder.glob("*.toml"))
    assert len(shipped_names(kind)) >= 5
    # the package's own path to them (what a wheel copies) points at the same folder
    assert (REPO / "testbed" / "_shipped" / f"{kind}s").resolve() == folder.resolve()


def test_the_scenario_and_campaign_modules_use_the_one_lookup():
    from roadtrack.testbed.campaign.spec import CAMPAIGN_DIR
    from roadtrack.testbed.config import shipped_dir
    from roadtrack.testbed.scenario.spec import SCENARIO_DIR, list_scenarios

    assert SCENARIO_DIR == shipped_dir("scenario") and CAMPAIGN_DIR == shipped_dir("campaign")
    assert list_scenarios() == sorted(p.stem for p in (REPO / "scenarios").glob("*.toml"))


def test_the_package_data_covers_every_shipped_file():
    """pyproject.toml's package-data globs match each shipped file through the package's path to it."""
    conf = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["roadtrack.testbed"]
    package = REPO / "testbed"
    matched = {p.resolve() for pattern in conf for p in package.glob(pattern)}
    shipped = {p.resolve() for kind in ("scenarios", "campaigns") for p in (REPO / kind).glob("*.toml")}
    assert matched == shipped and len(shipped) >= 10


def test_an_unknown_kind_is_refused():
    from roadtrack.testbed.config import shipped_dir

    with pytest.raises(ValueError, match="kind must be one of"):
        shipped_dir("tracker")


def test_an_installation_without_its_shipped_files_says_so_in_one_line(tmp_path, monkeypatch, capsys):
    """A build that lost the package data: `testbed scenarios` and a run by name fail in one line naming the
    cause (before: `testbed scenarios` printed nothing and exited 0, a run said '(shipped: )')."""
    import roadtrack.testbed.config.files as files
    from roadtrack.testbed.cli.main import main

    monkeypatch.setattr(files, "SHIPPED", tmp_path / "_shipped")
    for argv in (["scenarios"], ["run", "cut_in_out", "--no-record"], ["check", "smoke"]):
        code = main(argv)
        out, err = capsys.readouterr()
        lines = err.strip().splitlines()
        assert code == 2 and out == "" and len(lines) == 1, (argv, out, err)
        assert "this installation of roadtrack has no shipped" in lines[0] and "reinstall" in lines[0], lines
