"""The ``[env]`` table: a registered highway-env environment as a scenario's traffic source, as a spec.

What the table may say and the load-time checks that need no environment built: the id is a registered
highway-env environment we support, the config keys are the env's own and data only (testbed/scenario/envcheck.py),
the policy is a built-in one (a file names no code), the tables the env replaces are left out, the rate is whole
Hz. Building the env and taking its first step is the world's check (testbed/world/envsource.py,
``check_env_world``); the env as a traffic source is testbed/world/envsource.py.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from ..config import ConfigError, field, non_negative
from .envcheck import check_env_config

POLICIES = ("idle", "idm")
ON_END = ("stop", "continue")
RESERVED = ("simulation_frequency", "policy_frequency")  # set from rate_hz and physics_substeps
UNSUPPORTED = dict.fromkeys(("lane-keeping-v0", "parking-ActionRepeat-v0", "parking-parked-v0"),
                           "its constructor takes no render_mode")
NOT_WITH_ENV = ("road", "ego", "vehicles", "convoy", "traffic")  # Scenario tables the env replaces

@dataclass(frozen=True)
class ScriptedAction:
    """The ego's action from ``at_s`` for ``hold_s`` seconds (at least one frame), replacing the policy's.

    Where held actions overlap, the later entry wins.
    """

    at_s: float = field(doc="time the action starts [s]", **non_negative())
    action: str | int | tuple[float, ...] = field(
        doc="meta-action name (IDLE, LANE_LEFT, LANE_RIGHT, FASTER, SLOWER), action index, or list of numbers "
            "in [-1, 1] for continuous actions")
    hold_s: float = field(0.0, doc="how long the action is repeated, 0 = one frame [s]", **non_negative())


@dataclass(frozen=True)
class EnvSpec:
    """A registered highway-env environment as the traffic source (replaces road, ego, vehicles, convoy, traffic)."""

    id: str = field(doc="registered highway-env id, e.g. highway-v0, merge-v0, roundabout-v0, intersection-v0, "
                        "u-turn-v0 (a wrong id lists them all)")
    config: dict[str, Any] = field({}, doc="env config, merged key by key over the env's defaults (a nested "
                                       "table naming another `type` replaces the default's); the frequencies "
                                       "come from rate_hz and physics_substeps, duration defaults to duration_s + 1")
    policy: str = field("idle", doc="ego policy: idle (keep lane and speed) or idm (highway-env's IDM driver, "
                                    "actions ignored); a user's own policy comes from `testbed run --policy` or "
                                    "the Python API, never from a file",
                        check=(lambda v: v in POLICIES, "idle or idm: a scenario file names no code (a user's own "
                               "policy comes from `testbed run --policy module:function` or the Python API)"))
    actions: tuple[ScriptedAction, ...] = field((), doc="scripted ego actions, replacing the policy's")
    on_end: str = field("stop", doc="when the env terminates or truncates early: stop the run there (a warning) "
                                    "or continue stepping", choices=ON_END)

    def __post_init__(self) -> None:
        ids = env_ids()
        if self.id not in ids:
            why = f" ({UNSUPPORTED[self.id]})" if self.id in UNSUPPORTED else ""
            raise ConfigError("id", f"{self.id!r} is not a supported highway-env environment{why}; "
                                    f"allowed: {', '.join(ids)}")
        defaults = env_class(self.id).default_config()
        for key in self.config:
            if key in RESERVED:
                raise ConfigError(f"config.{key}", "is set from rate_hz and physics_substeps (one env step = "
                                                   "one sensor frame); remove it")
            if key not in defaults:
                raise ConfigError(f"config.{key}", f"unknown key for {self.id}; allowed: "
                                                   f"{', '.join(sorted(k for k in defaults if k not in RESERVED))}")
        check_env_config(self.config, defaults)
        if self.policy == "idm" and self.actions:
            raise ConfigError("actions", "policy 'idm' ignores actions; use policy 'idle' or a callable")
        times = [a.at_s for a in self.actions]
        if times != sorted(times):
            raise ConfigError("actions", "must be in increasing at_s order")


def gymnasium_with_envs() -> Any:
    """Import gymnasium with highway-env's environments registered."""
    import gymnasium
    import highway_env  # noqa: F401 - registers the envs

    return gymnasium


def env_ids() -> tuple[str, ...]:
    """Registered highway-env environment ids we support, sorted."""
    gym = gymnasium_with_envs()
    ids = (k for k, s in gym.registry.items() if str(s.entry_point).startswith("highway_env"))
    return tuple(sorted(k for k in ids if k not in UNSUPPORTED))


def env_class(env_id: str) -> type:
    """The environment class registered as ``env_id``."""
    gym = gymnasium_with_envs()
    from gymnasium.envs.registration import load_env_creator

    return load_env_creator(gym.spec(env_id).entry_point)


def check_env_scenario(scn) -> None:
    """Load-time checks of a scenario with ``[env]``: one-line ConfigErrors naming the dotted key.

    The tables the env replaces must be left out; the rate must be whole Hz (highway-env's frequencies
    are integers); the env must build from its config and every scripted action must be one of its actions.
    """
    for f in dataclasses.fields(type(scn)):
        if f.name in NOT_WITH_ENV:
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
            if getattr(scn, f.name) != default:
                raise ConfigError(f.name, f"not used with env (the env {scn.env.id} brings its own road, ego and "
                                          "traffic); remove it")
    if not float(scn.rate_hz).is_integer():
        raise ConfigError("rate_hz", f"{scn.rate_hz} is not allowed with env; must be a whole number of Hz")
