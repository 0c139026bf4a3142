"""The one task table (sb3_gcrl/envs/tasks.py): registration, horizons, success thresholds, and the wrappers and
configs that read it instead of stating its values again."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import TimeLimit

import sb3_gcrl  # noqa: F401  (registers the GCRL/ ids)
from sb3_gcrl.envs import GCRL_ENV_IDS
from sb3_gcrl.envs.tasks import EARL_HARD_RESET_EVERY, OPTIONAL_ENV_IDS, RESET_FREE_ENV_IDS, TASKS, find_task
from sb3_gcrl.wrappers import GoExploreWrapper, ResetFreeWrapper
from sb3_gcrl.zoo_config import ZOO_CONFIGS_DIR, read_zoo_config, split_section_key

#: tasks cheap to make (the reset-free suite has its own tests, tests/test_reset_free_envs.py)
EPISODIC_IDS = [env_id for env_id in GCRL_ENV_IDS if "Tabular" not in env_id]


def test_every_registered_id_is_in_the_table_once() -> None:
    assert set(TASKS) == {*GCRL_ENV_IDS, *RESET_FREE_ENV_IDS, *OPTIONAL_ENV_IDS}
    assert not set(GCRL_ENV_IDS) & set(RESET_FREE_ENV_IDS)
    assert not set(OPTIONAL_ENV_IDS) & {*GCRL_ENV_IDS, *RESET_FREE_ENV_IDS}
    assert set(OPTIONAL_ENV_IDS) == {"GCRL/SafetyPointGoal0-v0", "GCRL/SafetyCarGoal0-v0"}
    for env_id, task in TASKS.items():
        assert (env_id in gym.registry) == task.installed  # an optional package's task only where it is installed
        if not task.installed:
            continue
        spec = gym.spec(env_id)
        assert (spec.entry_point, spec.max_episode_steps, spec.kwargs) == (
            task.entry_point,
            task.eval_horizon,
            task.kwargs,
        )


@pytest.mark.parametrize("env_id", EPISODIC_IDS)
def test_success_threshold_is_the_envs_own(env_id: str) -> None:
    task = TASKS[env_id]
    env = gym.make(env_id).unwrapped
    radius = getattr(env, "distance_threshold", getattr(env, "goal_size", None))
    assert task.success_threshold == (None if radius is None else pytest.approx(radius))
    env.close()


def test_tasks_are_hashable_values() -> None:
    assert len(set(TASKS.values())) == len(TASKS)
    with pytest.raises(AttributeError):
        TASKS["GCRL/Tabletop-v0"].eval_horizon = 1  # type: ignore[misc]


def test_horizons() -> None:
    maze, umaze_goal = TASKS["GCRL/PointUMaze-v0"], TASKS["GCRL/PointUMazeGoal-v0"]
    assert not maze.reset_free and maze.train_horizon == maze.eval_horizon == 1000
    assert umaze_goal.reset_free and (umaze_goal.eval_horizon, umaze_goal.train_horizon) == (300, 200_000)
    assert TASKS["GCRL/FourRoomsTabular-v0"].eval_horizon is None  # MiniGrid ends its own episodes


def test_find_task() -> None:
    env = gym.make("GCRL/Tabletop-v0")
    assert find_task(env) is find_task("GCRL/Tabletop-v0") is TASKS["GCRL/Tabletop-v0"]
    assert find_task(ResetFreeWrapper(env)) is TASKS["GCRL/Tabletop-v0"]  # through wrappers
    assert find_task("FetchReach-v4") is None and find_task(gym.make("FetchReach-v4")) is None
    env.close()


@pytest.mark.parametrize("env_id", ["GCRL/ErgodicFetchPush-v0", "GCRL/PointUMazeGoal-v0", "GCRL/Tabletop-v0"])
def test_reset_free_wrapper_reads_the_table(env_id: str) -> None:
    task = TASKS[env_id]
    env = ResetFreeWrapper(gym.make(env_id))
    assert (env.hard_reset_every, env.eval_horizon) == (task.hard_reset_every, task.eval_horizon)
    # Go-Explore's default phases are read through the wrapper: H_G = H_E = T_eval // 2
    go_explore = GoExploreWrapper(env, "novelty")
    assert go_explore.go_steps == go_explore.explore_steps == task.eval_horizon // 2
    go_explore.close()


def test_stated_values_override_the_table() -> None:
    env = ResetFreeWrapper(gym.make("GCRL/PointUMazeGoal-v0"), hard_reset_every=1000, eval_horizon=40)
    assert (env.hard_reset_every, env.eval_horizon) == (1000, 40)
    env.reset(seed=0)
    steps = 0
    truncated = terminated = False
    while not (truncated or terminated):
        *_, terminated, truncated, _ = env.step(np.zeros(2))
        steps += 1
    assert steps == 40  # evaluation mode: episodes of the stated horizon
    env.close()


def test_an_env_of_your_own_keeps_its_time_limit_and_earls_interval() -> None:
    env = ResetFreeWrapper(gym.make("FetchReach-v4"))
    assert (env.hard_reset_every, env.eval_horizon) == (EARL_HARD_RESET_EVERY, 50)  # FetchReach's 50 steps
    bare = ResetFreeWrapper(gym.make("FetchReach-v4", max_episode_steps=None).unwrapped)
    assert bare.eval_horizon is None
    assert isinstance(gym.make("FetchReach-v4"), TimeLimit)
    env.close()
    bare.close()


def test_no_config_repeats_the_tables_horizons() -> None:
    """The shipped configs leave the hard-reset interval and the evaluation horizon to the table: a value stated
    in a section must differ from the table's on purpose, and none does today."""
    stated = []
    for path in sorted(ZOO_CONFIGS_DIR.glob("*.yml")):
        for key, section in read_zoo_config(path).items():
            wrappers = section.get("env_wrapper") or []
            for wrapper in wrappers if isinstance(wrappers, list) else [wrappers]:
                kwargs = next(iter(wrapper.values())) if isinstance(wrapper, dict) else {}
                for name in ("hard_reset_every", "eval_horizon"):
                    if name in (kwargs or {}):
                        stated.append((path.name, key, name, split_section_key(key)[0]))
    assert not stated, stated
