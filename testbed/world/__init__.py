"""World: the traffic (our scripted highway-env roads or a registered highway-env environment) and the roadside
objects, as truth frames; and the world's checks of a scenario, which build its environment.

``load_scenario`` and ``parse_scenario`` here are the scenario layer's (testbed.scenario.spec) plus
:func:`check_world`: what ``testbed check`` accepts is exactly what ``testbed run`` can set up.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from ..scenario import spec


def check_world(scn: spec.Scenario) -> spec.Scenario:
    """``scn`` once its world can be set up: a scenario with ``[env]`` builds its environment and takes one step
    (testbed.world.envsource.check_env_world); one-line ConfigError otherwise."""
    if scn.env is not None:
        from .envsource import check_env_world

        check_env_world(scn)
    return scn


def load_scenario(path: str | Path, overrides: dict[str, Any] | None = None) -> spec.Scenario:
    """testbed.scenario.spec.load_scenario, then :func:`check_world`."""
    return check_world(spec.load_scenario(path, overrides))


def parse_scenario(data: dict) -> spec.Scenario:
    """testbed.scenario.spec.parse_scenario, then :func:`check_world`."""
    return check_world(spec.parse_scenario(data))
