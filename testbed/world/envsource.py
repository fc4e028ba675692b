"""Any registered highway-env environment as the traffic source of a scenario (``[env]`` table).

A scenario with ``[env] id = "merge-v0"`` takes its road, its traffic and its ego car from that environment
instead of from ``[road]``/``[ego]``/``[[vehicles]]``. The env is created with
``gymnasium.make(id, render_mode=None, config=...)`` and reset with the scenario seed, so its traffic (which
highway-env draws from the env's seeded generator) varies with the seed and is reproducible. One
``env.step`` is one sensor frame: ``policy_frequency = rate_hz`` and
``simulation_frequency = rate_hz * physics_substeps``.

The ego is the env's controlled vehicle. Its action each frame comes from ``env.policy``:

* ``idle``: the action that keeps the lane and the speed. For discrete meta-actions it is the env's
  ``IDLE``. For continuous actions (``[acceleration, steering]`` in [-1, 1]), "idle" is zero
  acceleration and the steering that holds the car on the centre of its current lane: zero steering
  would drive straight off a curved road. For ``DiscreteAction`` it is the grid action nearest to that.
* ``idm``: at reset the ego is replaced by highway-env's ``IDMVehicle`` (same pose, speed, target lane,
  target speed and route). It then drives like the env's other traffic (IDM car following, MOBIL lane
  changes) and ignores actions. A ``TimeToCollision`` observation (u-turn, two-way) is switched to
  ``Kinematics``: it needs the env's own vehicle class, and the observation is unused. Most envs' egos
  have no car following of their own: an ``idle`` ego rear-ends slower traffic, the ``idm`` one does not.

A scenario file names only these built-in policies: it is data and never names code (README, "What a
scenario file can do"). A user's own policy, a callable ``policy(observation, info) -> action``, comes
through the Python API (``run_scenario(scn, policy=f)``, ``EnvSimulation(scn, policy=f)``) or the
command-line option the user types, ``testbed run SCENARIO --policy module:function`` or
``--policy path/to/file.py:function`` (:func:`load_policy`; the current directory is never put on
``sys.path``). ``info`` is the env's info dict plus ``time_s`` (time of the frame the action starts from
[s]) and ``frame``. The action may be a meta-action name (``"LANE_LEFT"``), an index or a list of numbers;
one that is not an action of the env stops the run with a RunError (exit 1) naming the time.

``env.actions`` (``[[env.actions]] at_s / action / hold_s``) are scripted actions: from ``at_s`` for
``hold_s`` seconds (at least one frame) they replace the policy's action. With ``idle`` between them
they are a scripted action list.

When the env terminates (a crash, or its goal: merge-v0 ends when the ego passes x = 370 m) or truncates
(its own ``duration``, which we set beyond the scenario's), ``env.on_end`` decides: ``stop`` (default)
ends the frames there with an :class:`EpisodeEndWarning`, and the run scores the frames it has;
``continue`` keeps stepping (highway-env allows it; a crashed car brakes to a standstill).
"""
from __future__ import annotations

import itertools
import math
import os
import warnings
from typing import TYPE_CHECKING, Any, Callable, Iterator

import numpy as np

from ..common.errors import RunError
from ..config import ConfigError
from ..scenario.env import env_class, gymnasium_with_envs
from ..common.usercode import load_object

if TYPE_CHECKING:
    from ..scenario.spec import Scenario
    from .simulation import TruthFrame

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

# highway-env vehicles have a length and a width but no height. By length [m]: up to 5 m (highway-env's
# car, Vehicle.LENGTH) a car 1.6 m high; up to 7 m a van 2.5 m; longer a truck or bus 3.5 m.
# A ``HEIGHT`` attribute on the vehicle (or its class) wins.
HEIGHT_CLASSES = ((5.0, 1.6, "car"), (7.0, 2.5, "van"), (math.inf, 3.5, "truck"))


class EpisodeEndWarning(RuntimeWarning):
    """The env terminated or truncated before the end of the scenario."""


Policy = Callable[[Any, dict], Any]


def load_policy(path: str) -> Policy:
    """The callable named by a command-line option the user typed: ``"module:function"`` or
    ``"path/to/file.py:function"`` (testbed/common/usercode.py). ConfigError at ``--policy`` (one line) when it cannot
    be loaded or is not callable."""
    obj = load_object(path, "--policy", "function")
    if not callable(obj):
        raise ConfigError("--policy", f"{path!r} is not callable")
    return obj


def _merge(base: dict, over: dict) -> dict:
    """``over`` merged key by key into a copy of ``base``; a nested table naming another ``type`` replaces."""
    out = dict(base)
    for key, value in over.items():
        old = out.get(key)
        if isinstance(old, dict) and isinstance(value, dict) and value.get("type", old.get("type")) == old.get("type"):
            out[key] = _merge(old, value)
        else:
            out[key] = value
    return out


def env_config(scn: Scenario) -> dict:
    """The full config passed to ``gymnasium.make``: env defaults, then ours, then ``env.config``."""
    spec = scn.env
    defaults = env_class(spec.id).default_config()
    ours: dict[str, Any] = dict(simulation_frequency=int(round(scn.rate_hz)) * scn.physics_substeps,
                                policy_frequency=int(round(scn.rate_hz)), offscreen_rendering=True,
                                real_time_rendering=False, manual_control=False)
    if "duration" in defaults:
        ours["duration"] = scn.duration_s + 1.0
    cfg = _merge(_merge(defaults, ours), spec.config)
    if spec.policy == "idm" and cfg["observation"].get("type") == "TimeToCollision":
        cfg["observation"] = {"type": "Kinematics"}  # it needs the env's own ego class; unused with idm
    return cfg


_PRISTINE: dict[type, dict[str, Any]] = {}
_MISSING = object()


def _vehicle_classes(cfg: dict) -> list[type]:
    """Vehicle classes whose constants an env may retune at reset (the IDM family and the traffic class)."""
    from highway_env import utils
    from highway_env.vehicle.behavior import IDMVehicle

    classes = set(IDMVehicle.__mro__)
    try:
        classes |= set(utils.class_from_path(cfg["other_vehicles_type"]).__mro__)
    except Exception:  # noqa: BLE001 - a bad class path is reported by gymnasium.make
        pass
    return [c for c in classes if c is not object]


def restore_vehicle_classes(classes: list[type]) -> None:
    """Put back the UPPER_CASE class constants as first seen.

    intersection-v0 sets ``IDMVehicle.DISTANCE_WANTED``, ``COMFORT_ACC_MAX`` and ``COMFORT_ACC_MIN`` on the
    class at every reset; without this, one intersection run would change the traffic of every later run
    (ours included) in the same process.
    """
    for cls in classes:
        now = {k: v for k, v in vars(cls).items() if k.isupper()}
        saved = _PRISTINE.setdefault(cls, now)
        for key in set(now) - set(saved):
            delattr(cls, key)
        for key, value in saved.items():
            if now.get(key, _MISSING) is not value:
                setattr(cls, key, value)


def make_env(scn: Scenario) -> tuple[Any, Any, dict, list[type]]:
    """``gymnasium.make`` the scenario's env with :func:`env_config` and reset it with the scenario seed.

    Returns (env, observation, info, the vehicle classes to restore when done). Any failure of the env
    to build from its config is a one-line ConfigError at ``env.config``.
    """
    gym = gymnasium_with_envs()
    cfg = env_config(scn)
    kwargs: dict[str, Any] = dict(render_mode=None, config=cfg)
    if gym.spec(scn.env.id).max_episode_steps is not None:  # two-way-v0's TimeLimit counts env steps
        kwargs["max_episode_steps"] = scn.n_frames + 1
    classes = _vehicle_classes(cfg)
    restore_vehicle_classes(classes)
    try:
        with warnings.catch_warnings():  # "merge-v0 is out of date": we run the version the scenario names
            warnings.filterwarnings("ignore", message=".*is out of date", category=DeprecationWarning)
            env = gym.make(scn.env.id, **kwargs)
            obs, info = env.reset(seed=scn.seed)
    except Exception as err:  # noqa: BLE001 - the env's own error, as one config line
        restore_vehicle_classes(classes)
        msg = str(err).splitlines()[0] if str(err) else ""
        raise ConfigError("env.config", f"{scn.env.id} cannot be built from it ({type(err).__name__}: {msg})") from None
    return env, obs, info, classes


def _allowed(action_type: Any, space: Any) -> str:
    names = list(getattr(action_type, "actions_indexes", {}))
    if hasattr(space, "n"):
        return ", ".join(names + [f"0..{space.n - 1}"])
    return f"a list of {space.shape[0]} numbers in [{float(np.min(space.low)):g}, {float(np.max(space.high)):g}]"


def to_action(action_type: Any, value: Any, where: str, env_id: str) -> Any:
    """``value`` (meta-action name, index, list of numbers) as an action of ``action_type``.

    Raises ConfigError at ``where`` when it is not in the env's action space.
    """
    from highway_env.envs.common.action import MultiAgentAction

    if isinstance(action_type, MultiAgentAction):
        agents = action_type.agents_action_types
        if not isinstance(value, (list, tuple)) or len(value) != len(agents):
            raise ConfigError(where, f"{value!r}: {env_id} takes a list of {len(agents)} actions, one per "
                                     "controlled vehicle")
        return tuple(to_action(a, v, where, env_id) for a, v in zip(agents, value))
    space = action_type.space()
    out: Any = None
    if isinstance(value, str):
        out = getattr(action_type, "actions_indexes", {}).get(value)
    elif hasattr(space, "n"):
        if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool) \
                and float(value).is_integer():
            out = int(value)
    elif not isinstance(value, bool):
        try:
            out = np.asarray(value, dtype=space.dtype).reshape(space.shape)
        except (TypeError, ValueError):
            out = None
    if out is None or not space.contains(out):
        raise ConfigError(where, f"{value!r} is not an action of {env_id}; allowed: {_allowed(action_type, space)}")
    return out


def lane_keeping_steering(vehicle: Any) -> float:
    """Steering angle [rad] that holds ``vehicle`` on the centre of its current lane.

    highway-env's ``ControlledVehicle.steering_control`` law and gains: lateral offset -> lateral speed ->
    heading reference (lane heading ``TAU_PURSUIT`` seconds ahead) -> heading rate -> bicycle steering.
    """
    from highway_env import utils
    from highway_env.vehicle.controller import ControlledVehicle as C

    lane = vehicle.road.network.get_lane(vehicle.lane_index)
    s, lat = lane.local_coordinates(vehicle.position)
    speed = utils.not_zero(vehicle.speed)
    heading_cmd = np.arcsin(np.clip(-C.KP_LATERAL * lat / speed, -1.0, 1.0))
    heading_ref = lane.heading_at(s + vehicle.speed * C.TAU_PURSUIT) + np.clip(heading_cmd, -np.pi / 4, np.pi / 4)
    rate = C.KP_HEADING * utils.wrap_to_pi(heading_ref - vehicle.heading)
    slip = np.arcsin(np.clip(vehicle.LENGTH / 2 / speed * rate, -1.0, 1.0))
    return float(np.clip(np.arctan(2 * np.tan(slip)), -C.MAX_STEERING_ANGLE, C.MAX_STEERING_ANGLE))


def _to_unit(x: float, bounds: tuple[float, float]) -> float:
    """Physical value -> the action's [-1, 1] (inverse of highway-env's ``lmap``)."""
    lo, hi = bounds
    return float(np.clip(2.0 * (x - lo) / (hi - lo) - 1.0, -1.0, 1.0))


def idle_action(action_type: Any) -> Any:
    """The action that keeps the lane and the speed (see the module docstring)."""
    from highway_env.envs.common.action import (ContinuousAction, DiscreteAction, DiscreteMetaAction,
                                                MultiAgentAction)

    if isinstance(action_type, MultiAgentAction):
        return tuple(idle_action(a) for a in action_type.agents_action_types)
    if isinstance(action_type, DiscreteMetaAction):
        return action_type.actions_indexes["IDLE"]
    if not isinstance(action_type, ContinuousAction):
        raise ValueError(f"env.policy: 'idle' does not know the action type {type(action_type).__name__}")
    unit = []
    if action_type.longitudinal:
        unit.append(_to_unit(0.0, action_type.acceleration_range))
    if action_type.lateral:
        unit.append(_to_unit(lane_keeping_steering(action_type.controlled_vehicle), action_type.steering_range))
    u = np.array(unit, dtype=np.float32)
    if isinstance(action_type, DiscreteAction):  # the grid action nearest to it, in DiscreteAction's order
        grid = np.linspace(-1.0, 1.0, action_type.actions_per_axis)
        actions = np.array(list(itertools.product(*[grid] * action_type.size)))
        return int(np.argmin(np.sum((actions - u) ** 2, axis=1)))
    return u


def install_idm_ego(env: Any) -> None:
    """Replace the env's ego by highway-env's ``IDMVehicle`` at the same pose, speed, target and route."""
    from highway_env.vehicle.behavior import IDMVehicle

    ego = env.vehicle
    idm = IDMVehicle(env.road, np.array(ego.position, dtype=np.float64), heading=ego.heading, speed=ego.speed,
                     target_lane_index=getattr(ego, "target_lane_index", None),
                     target_speed=getattr(ego, "target_speed", None), route=getattr(ego, "route", None))
    idm.LENGTH, idm.WIDTH = ego.LENGTH, ego.WIDTH
    idm.diagonal = np.hypot(idm.LENGTH, idm.WIDTH)
    for key, value in vars(ego).items():  # what the env's reward reads: speed_index (two-way), goal (parking)
        if not hasattr(idm, key):
            setattr(idm, key, value)
    env.road.vehicles[env.road.vehicles.index(ego)] = idm
    env.controlled_vehicles[0] = idm


def vehicle_height(vehicle: Any) -> tuple[float, str]:
    """(height [m], kind) of a highway-env vehicle, from its ``HEIGHT`` or its length (``HEIGHT_CLASSES``)."""
    for max_length, height, kind in HEIGHT_CLASSES:
        if vehicle.LENGTH <= max_length:
            return float(getattr(vehicle, "HEIGHT", height)), kind
    raise ValueError(f"vehicle length {vehicle.LENGTH!r} m")  # NaN


def scripted_actions(scn: Scenario, action_type: Any) -> dict[int, Any]:
    """Frame index k -> action sent on the step from frame k to k + 1, from ``env.actions``."""
    out: dict[int, Any] = {}
    for i, a in enumerate(scn.env.actions):
        action = to_action(action_type, a.action, f"env.actions[{i}].action", scn.env.id)
        first = int(math.ceil(a.at_s * scn.rate_hz - 1e-9))
        last = max(first + 1, int(math.ceil((a.at_s + a.hold_s) * scn.rate_hz - 1e-9)))
        for k in range(first, min(last, scn.n_frames - 1)):
            out[k] = action
    return out


def _ego_flag(flag: Any) -> bool:
    """A terminated/truncated flag for the ego: multi-agent wrappers return one per controlled vehicle."""
    return bool(flag[0]) if isinstance(flag, (tuple, list)) else bool(flag)


class EnvSimulation:
    """A highway-env environment stepped at the sensor rate; the interface of :class:`~testbed.world.simulation.Simulation`.

    ``network`` is the env's road network (lanes and roadside objects); :meth:`frames` yields the truth.
    Vehicle ids: the ego is 0; every other vehicle gets the next id when first seen. Ids are never
    reused: envs add vehicles (merge ramp, intersection spawns) and remove them (intersection exits).
    """

    def __init__(self, scenario: Scenario, policy: Policy | None = None):
        self.scenario = scenario
        self.spec = scenario.env
        self.env, self._obs, self._info, self._classes = make_env(scenario)
        u = self.env.unwrapped
        try:
            if self.spec.policy == "idm" and policy is None:
                install_idm_ego(u)
            self._policy = policy
            self._script = scripted_actions(scenario, u.action_type)
        except Exception:
            self.close()
            raise
        from highway_env.road.road import Road

        from .stepping import BatchRoad

        if type(u.road) is Road:  # the env's tick for all vehicles at once: the same numbers (world/stepping.py)
            u.road.__class__ = BatchRoad
        self.network = u.road.network
        # id(vehicle) -> (stable id, the vehicle): holding the vehicle keeps id() from being reused
        self._ids: dict[int, tuple[int, Any]] = {}
        self._id_of(u.vehicle)
        self.ended = ""  # why the env ended before the scenario did ("" if it did not)

    def _id_of(self, vehicle: Any) -> int:
        key = id(vehicle)
        if key not in self._ids:
            self._ids[key] = (len(self._ids), vehicle)
        return self._ids[key][0]

    def _truth(self, frame: int, time: float) -> TruthFrame:
        from .simulation import TruthFrame

        u = self.env.unwrapped
        ego = u.vehicle
        others = sorted((v for v in u.road.vehicles if v is not ego), key=self._id_of)
        vs = [ego, *others]
        ids = np.array([self._id_of(v) for v in vs], dtype=np.int64)
        heights = [vehicle_height(v) for v in vs]
        names = ("ego", *(f"{kind}{i}" for (_, kind), i in zip(heights[1:], ids[1:])))
        return TruthFrame(
            frame=frame, time=time, ids=ids, names=names,
            xy=np.array([v.position for v in vs], dtype=np.float64).reshape(-1, 2),
            heading=np.array([v.heading for v in vs], dtype=np.float64),
            velocity=np.array([v.velocity for v in vs], dtype=np.float64).reshape(-1, 2),
            size=np.array([[v.LENGTH, v.WIDTH, h] for v, (h, _) in zip(vs, heights)], dtype=np.float64),
            lane=np.array([v.lane_index[2] if v.lane_index else -1 for v in vs], dtype=np.int64),
            crashed=np.array([v.crashed for v in vs], dtype=bool),
        )

    def _action(self, k: int, obs: Any, info: dict) -> Any:
        """The ego's action on the step from frame k to k + 1."""
        if k in self._script:
            return self._script[k]
        action_type = self.env.unwrapped.action_type
        if self._policy is None:
            return idle_action(action_type)
        t = k * self.scenario.dt
        raw = self._policy(obs, {**info, "time_s": t, "frame": k})
        try:
            return to_action(action_type, raw, "policy", self.spec.id)
        except ConfigError as err:  # the run has started: a run-time failure (exit 1), not bad input
            name = getattr(self._policy, "__qualname__", type(self._policy).__name__)
            raise RunError(f"the ego policy {name} returned {str(err).split(': ', 1)[1]} (at t = {t:.1f} s)") \
                from None

    def _end_reason(self, terminated: bool) -> str:
        u = self.env.unwrapped
        if terminated and u.vehicle.crashed:
            return "terminated: the ego crashed"
        if terminated:
            return "terminated: its end condition was met (e.g. the ego reached its goal)"
        return "truncated: its time limit ran out"

    def frames(self) -> Iterator[TruthFrame]:
        """Truth at t = 0, dt, ... duration; fewer frames if the env ends early and ``on_end`` is stop."""
        scn, obs, info = self.scenario, self._obs, self._info
        try:
            for k in range(scn.n_frames):
                if k > 0:
                    obs, _, terminated, truncated, info = self.env.step(self._action(k - 1, obs, info))
                    terminated, truncated = _ego_flag(terminated), _ego_flag(truncated)
                    if (terminated or truncated) and not self.ended and k < scn.n_frames - 1:
                        self.ended = f"{self.spec.id} {self._end_reason(terminated)} at t = {k * scn.dt:.1f} s"
                        if self.spec.on_end == "continue":
                            warnings.warn(f"{self.ended}; stepping on (env.on_end = 'continue')",
                                          EpisodeEndWarning, stacklevel=2)
                yield self._truth(k, k * scn.dt)
                if self.ended and self.spec.on_end == "stop":
                    warnings.warn(f"{self.ended}; the run stops there with {k + 1} of {scn.n_frames} frames "
                                  "(env.on_end = 'continue' steps on)", EpisodeEndWarning, stacklevel=2)
                    return
        finally:
            self.close()

    def close(self) -> None:
        """Close the env and undo its class-constant changes (idempotent)."""
        self.env.close()
        restore_vehicle_classes(self._classes)


def check_env_world(scn: Scenario) -> None:
    """The world's checks of a scenario with ``[env]`` (after the spec's, testbed.scenario.env): the env builds
    from its config, every scripted action is one of its actions and it takes its first step; one-line
    ConfigErrors naming the dotted key."""
    sim = EnvSimulation(scn)  # builds and resets the env: config and action errors surface here
    try:
        sim.env.step(idle_action(sim.env.unwrapped.action_type))
    except Exception as err:  # noqa: BLE001 - e.g. an env whose reward needs its own ego class (idm)
        msg = str(err).splitlines()[0] if str(err) else ""
        raise ConfigError("env.policy" if scn.env.policy == "idm" else "env.config",
                          f"{scn.env.id} fails on its first step ({type(err).__name__}: {msg})") from None
    finally:
        sim.close()


def make_simulation(scn: Scenario, policy: Policy | None = None) -> Any:
    """The traffic source of ``scn``: :class:`EnvSimulation` with ``[env]`` (its ego driven by ``policy`` when
    given), else our scripted ``Simulation``; a ``policy`` without ``[env]`` is a ConfigError."""
    if scn.env is not None:
        return EnvSimulation(scn, policy)
    if policy is not None:
        raise ConfigError("--policy", f"scenario {scn.name} has no [env] table; an ego policy drives a highway-env "
                                      "environment's ego (see scenarios/merge.toml)")
    from .simulation import Simulation

    return Simulation(scn)
