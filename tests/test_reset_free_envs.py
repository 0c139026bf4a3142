"""Tests of the reset-free task suite (sb3_gcrl/envs/reset_free, thesis Section 3.7.1)."""

from __future__ import annotations

import glob
import importlib.util
import os
import pickle
import sys
import tempfile
import warnings

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_gcrl  # noqa: F401  (registers the GCRL/ ids)
from sb3_gcrl.envs.reset_free import ant as ant_module
from sb3_gcrl.envs.reset_free import fetch as fetch_module
from sb3_gcrl.envs.reset_free import sawyer_door as door_module
from sb3_gcrl.envs.reset_free import tabletop as tabletop_module
from sb3_gcrl.envs.reset_free.tabletop import TabletopEnv
from sb3_gcrl.envs.tasks import RESET_FREE_ENV_IDS, TASKS, register_tasks

HAS_METAWORLD = importlib.util.find_spec("metaworld") is not None
needs_metaworld = pytest.mark.skipif(not HAS_METAWORLD, reason="metaworld not installed (optional)")

ENV_IDS = [
    pytest.param(env_id, marks=needs_metaworld) if env_id == "GCRL/SawyerDoor-v0" else env_id
    for env_id in RESET_FREE_ENV_IDS
]
FETCH_IBC_IDS = ["GCRL/ErgodicFetchPush-v0", "GCRL/ErgodicFetchPickAndPlace-v0"]
FETCH_HARD_IDS = ["GCRL/FetchPushHard-v0", "GCRL/FetchPickAndPlaceHard-v0"]

# Documented spaces: (observation dim, goal dim, action dim).
SPACES = {
    "GCRL/ErgodicFetchPush-v0": (25, 3, 4),
    "GCRL/ErgodicFetchPickAndPlace-v0": (25, 3, 4),
    "GCRL/FetchPushHard-v0": (25, 3, 4),
    "GCRL/FetchPickAndPlaceHard-v0": (25, 3, 4),
    "GCRL/AntArena-v0": (27, 2, 8),
    "GCRL/Tabletop-v0": (6, 4, 3),
    "GCRL/SawyerDoor-v0": (7, 3, 4),
}


@pytest.fixture(scope="module")
def envs():
    """One instance of each env, shared by the read-only tests of this module."""
    made = {}
    yield made
    for env in made.values():
        env.close()


def get_env(envs: dict, env_id: str) -> gym.Env:
    if env_id not in envs:
        envs[env_id] = gym.make(env_id)
    return envs[env_id]


def test_registry_matches_task_table():
    register_tasks()  # idempotent
    reset_free = {env_id for env_id, task in TASKS.items() if task.reset_free}
    assert len(RESET_FREE_ENV_IDS) == 7 and reset_free == {*RESET_FREE_ENV_IDS, "GCRL/PointUMazeGoal-v0"}
    for env_id in reset_free:
        assert gym.spec(env_id).max_episode_steps == TASKS[env_id].eval_horizon
        assert env_id.startswith("GCRL/") and TASKS[env_id].train_horizon == TASKS[env_id].hard_reset_every
    point_maze = TASKS["GCRL/PointUMazeGoal-v0"]
    assert (point_maze.eval_horizon, point_maze.hard_reset_every) == (300, 200_000)
    env = gym.make(point_maze.env_id).unwrapped
    rng = np.random.default_rng(0)
    for goal in (env.sample_initial_goal(rng), env.sample_evaluation_goal(rng)):
        assert np.all(goal >= point_maze.goal_low) and np.all(goal <= point_maze.goal_high)
    env.close()
    # the thesis's protocol (Section 3.7.1): evaluation steps and hard-reset interval per task
    protocol = {env_id: (TASKS[env_id].eval_horizon, TASKS[env_id].hard_reset_every) for env_id in RESET_FREE_ENV_IDS}
    assert protocol == {
        "GCRL/ErgodicFetchPush-v0": (50, 100_000),
        "GCRL/ErgodicFetchPickAndPlace-v0": (50, 100_000),
        "GCRL/FetchPushHard-v0": (50, 100_000),
        "GCRL/FetchPickAndPlaceHard-v0": (50, 100_000),
        "GCRL/AntArena-v0": (500, 200_000),
        "GCRL/Tabletop-v0": (200, 200_000),
        "GCRL/SawyerDoor-v0": (300, 200_000),
    }


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_and_spaces(env_id):
    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gym_check_env(env.unwrapped, skip_render_check=True)
        sb3_check_env(env.unwrapped, warn=False)
    obs_dim, goal_dim, act_dim = SPACES[env_id]
    space = env.observation_space
    assert isinstance(space, gym.spaces.Dict)
    assert space["observation"].shape == (obs_dim,)
    assert space["achieved_goal"].shape == space["desired_goal"].shape == (goal_dim,)
    assert env.action_space.shape == (act_dim,)
    unwrapped = env.unwrapped
    assert callable(unwrapped.sample_initial_goal) and callable(unwrapped.sample_evaluation_goal)
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_compute_reward_vectorised_and_consistent_with_step(envs, env_id):
    env = get_env(envs, env_id)
    unwrapped = env.unwrapped
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    desired = np.stack([unwrapped.sample_evaluation_goal(rng) for _ in range(16)])
    # Offsets of 0, 0.5 and 1.5 success radii in random directions: both outcomes occur.
    direction = rng.normal(size=desired.shape)
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    threshold = TASKS[env_id].success_threshold  # the task table's, the env's by its usual name
    assert unwrapped.distance_threshold == pytest.approx(threshold)
    radius = threshold * np.resize([0.0, 0.5, 1.5, 1.5], len(desired))[:, None]
    achieved = desired + radius * direction
    batch = unwrapped.compute_reward(achieved, desired, {})
    single = np.array([unwrapped.compute_reward(a, d, {}) for a, d in zip(achieved, desired)])
    assert batch.shape == (16,)
    np.testing.assert_array_equal(batch, single)
    success = unwrapped.compute_reward(desired, desired, {})[0]
    np.testing.assert_array_equal(batch == success, radius[:, 0] < threshold)
    for _ in range(5):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert reward == unwrapped.compute_reward(obs["achieved_goal"], obs["desired_goal"], info)
        assert "is_success" in info
        assert not terminated


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_seeding_is_deterministic(env_id):
    def rollout(seed: int) -> list[np.ndarray]:
        env = gym.make(env_id)
        env.action_space.seed(0)
        obs, _ = env.reset(seed=seed)
        trace = [np.concatenate([obs[k] for k in ("observation", "achieved_goal", "desired_goal")])]
        for _ in range(10):
            obs, *_ = env.step(env.action_space.sample())
            trace.append(np.concatenate([obs[k] for k in ("observation", "achieved_goal", "desired_goal")]))
        env.close()
        return trace

    first = np.stack(rollout(7))
    np.testing.assert_array_equal(first, np.stack(rollout(7)))
    # The seed matters: some other seed gives another start or goal (Tabletop has 4 goals, so try a few).
    assert any(not np.array_equal(first[0], rollout(seed)[0]) for seed in (8, 9, 10))


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_samplers_use_only_the_given_rng(envs, env_id):
    unwrapped = get_env(envs, env_id).unwrapped
    unwrapped.reset(seed=0)
    env_rng_state = unwrapped.np_random.bit_generator.state
    for sampler in (unwrapped.sample_initial_goal, unwrapped.sample_evaluation_goal):
        first = [sampler(np.random.default_rng(5)) for _ in range(3)]
        second = [sampler(np.random.default_rng(5)) for _ in range(3)]
        np.testing.assert_array_equal(first, second)
    assert unwrapped.np_random.bit_generator.state == env_rng_state


def _samples(sampler, n: int = 300) -> np.ndarray:
    rng = np.random.default_rng(1)
    return np.stack([sampler(rng) for _ in range(n)])


@pytest.mark.parametrize("env_id", FETCH_IBC_IDS)
def test_ibc_fetch_goal_regions(envs, env_id):
    env = get_env(envs, env_id).unwrapped
    center, h = env.initial_gripper_xpos[:2], env.height_offset
    starts = _samples(env.sample_initial_goal)
    assert np.all(np.abs(starts[:, :2] - center) <= 0.15)
    assert np.all(np.linalg.norm(starts[:, :2] - center, axis=1) >= 0.1)
    np.testing.assert_allclose(starts[:, 2], h)
    goals = _samples(env.sample_evaluation_goal)
    assert np.all(np.abs(goals[:, :2] - center) <= 0.15)
    in_air = goals[:, 2] > h + 1e-9
    if env_id.endswith("PickAndPlace-v0"):
        assert 0.35 < in_air.mean() < 0.65 and goals[:, 2].max() <= h + 0.45
    else:
        assert not in_air.any()
    # Every start and goal lies inside the object box, so the walls never cut the distributions.
    half = fetch_module.IBC_BOX_HALF_SIZE - 0.025
    for points in (starts, goals):
        assert np.all(np.abs(points[:, :2] - np.asarray(fetch_module.IBC_BOX_CENTER)) <= half)


@pytest.mark.parametrize("env_id", FETCH_HARD_IDS)
def test_hard_fetch_goal_regions(envs, env_id):
    env = get_env(envs, env_id).unwrapped
    start, h = np.asarray(fetch_module.HARD_OBJECT_START), env.height_offset
    starts = _samples(env.sample_initial_goal)
    np.testing.assert_allclose(starts, np.tile([start[0], start[1], h], (len(starts), 1)))  # fixed start
    goals = _samples(env.sample_evaluation_goal)
    if env_id == "GCRL/FetchPushHard-v0":
        assert np.all(np.abs(goals[:, :2] - start) <= 0.15) and np.abs(goals[:, :2] - start).max() > 0.14
        np.testing.assert_allclose(goals[:, 2], h)
    else:  # goals only in the air, in a 5 x 5 x 10 cm box
        assert np.all(np.abs(goals[:, :2] - start) <= 0.025)
        assert np.all((goals[:, 2] >= h + 0.10) & (goals[:, 2] <= h + 0.20))
        assert np.ptp(goals[:, 2]) > 0.09
    # The env's own reset draws from the same samplers.
    obs, _ = env.reset(seed=11)
    np.testing.assert_allclose(obs["achieved_goal"][:2], start, atol=1e-3)


def test_ant_goal_regions_and_reset(envs):
    env = get_env(envs, "GCRL/AntArena-v0").unwrapped
    starts = _samples(env.sample_initial_goal)
    assert np.all(np.abs(starts) <= 0.1) and np.abs(starts).max() > 0.09
    goals = _samples(env.sample_evaluation_goal)
    assert np.all((goals >= 2.0) & (goals <= 3.0))
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        assert np.all(np.abs(obs["achieved_goal"]) <= 0.1 + 1e-6)
        assert np.all((obs["desired_goal"] >= 2.0) & (obs["desired_goal"] <= 3.0))
        assert info["is_success"] is False


def test_ant_arena_is_an_open_square_with_walls():
    env = ant_module.AntArenaEnv()
    maze = env.maze
    free = [maze.cell_rowcol_to_xy(np.array([i, j])) for i in (1, 2) for j in (1, 2)]
    np.testing.assert_allclose(np.abs(np.array(free)), 2.0)  # free square [-4, 4]^2
    env.reset(seed=0)
    # Throw the torso at the +x wall: it stops at the wall instead of leaving the arena.
    data = env.ant_env.data
    data.qpos[:2] = [2.5, 0.0]
    data.qvel[:] = 0.0
    data.qvel[0] = 20.0
    mujoco.mj_forward(env.ant_env.model, data)
    for _ in range(40):
        obs, *_ = env.step(np.zeros(8))
    assert obs["achieved_goal"][0] < ant_module.ARENA_HALF_SIZE
    env.close()


def test_ant_leaves_no_temporary_xml(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # this process's own temp dir: no other worker's files
    pattern = os.path.join(tempfile.gettempdir(), "ant_maze*.xml")
    before = set(glob.glob(pattern))
    env = ant_module.AntArenaEnv()
    env.close()
    assert set(glob.glob(pattern)) - before == set()


def _launch_block(env: fetch_module.WalledFetchEnv, direction: np.ndarray, speed: float = 3.0) -> np.ndarray:
    """Give the block a horizontal velocity towards ``direction``; return its path over 1.2 s of zero actions."""
    env.reset(seed=0)
    qvel = env._utils.get_joint_qvel(env.model, env.data, "object0:joint").copy()
    qvel[:] = 0.0
    qvel[:2] = speed * direction
    env._utils.set_joint_qvel(env.model, env.data, "object0:joint", qvel)
    return np.array([env.step(np.zeros(4))[0]["achieved_goal"] for _ in range(30)])


DIRECTIONS = [np.array(d, dtype=float) for d in ((1, 0), (-1, 0), (0, 1), (0, -1))]


@pytest.mark.parametrize("cls", [fetch_module.ErgodicFetchPushEnv, fetch_module.FetchPushHardEnv])
def test_walls_stop_a_launched_block(cls):
    env = cls()
    low, high = np.asarray(env.wall_low), np.asarray(env.wall_high)
    for direction in DIRECTIONS:
        path = _launch_block(env, direction)
        assert np.all(path[:, :2] >= low) and np.all(path[:, :2] <= high), direction
        assert np.all(path[:, 2] > fetch_module.TABLE_TOP_Z)  # still on the table
        # It hit the wall it was thrown at: its centre came within the block's half diagonal (3.5 cm) of the face.
        gap = np.where(direction > 0, high - path[:, :2].max(0), path[:, :2].min(0) - low)[direction != 0]
        assert gap.item() < 0.036
    env.close()


def _press_block_into_wall(env: fetch_module.WalledFetchEnv, direction: np.ndarray) -> np.ndarray:
    """Bring the gripper behind the block, then keep shoving it towards ``direction``; return the block path."""
    obs, _ = env.reset(seed=0)
    path = []
    for t in range(100):
        gripper, block = obs["observation"][:3], obs["achieved_goal"]
        behind = block[:2] - 0.06 * direction
        action = np.zeros(4)
        if t < 40 and np.linalg.norm(gripper[:2] - behind) > 0.01:  # approach from behind, 3 cm higher
            action[:2] = np.clip((behind - gripper[:2]) / 0.05, -1, 1)
            action[2] = np.clip((block[2] + 0.03 - gripper[2]) / 0.05, -1, 1)
        else:
            action[:2] = direction
            action[2] = np.clip((block[2] - gripper[2]) / 0.05, -1, 1)
        obs, *_ = env.step(action)
        path.append(obs["achieved_goal"].copy())
    return np.array(path)


@pytest.mark.parametrize("cls", [fetch_module.ErgodicFetchPushEnv, fetch_module.FetchPushHardEnv])
def test_gripper_cannot_squeeze_the_block_through_a_wall(cls):
    """The arm presses the block into each wall. Object-only walls alone would let it through (the arm passes
    them and soft contacts yield: the block ends up off the table); stiff wall contacts plus the position clamp
    keep the block centre within 1 cm of the wall faces."""
    env = cls()
    low, high = np.asarray(env.wall_low) + 0.015, np.asarray(env.wall_high) - 0.015
    for direction in DIRECTIONS:
        path = _press_block_into_wall(env, direction)
        assert np.all(path[:, :2] >= low) and np.all(path[:, :2] <= high), direction
        # The block did reach the wall it was pushed at.
        reached = np.where(direction > 0, high - path[:, :2].max(0), path[:, :2].min(0) - low)[direction != 0]
        assert reached.item() < 0.02
    env.close()


def test_same_launch_without_walls_leaves_the_box():
    """Control for the wall test: with stock FetchPush the same throw carries the block past the walls' line."""
    env = gym.make("FetchPush-v4").unwrapped
    env.reset(seed=0)
    qvel = env._utils.get_joint_qvel(env.model, env.data, "object0:joint").copy()
    qvel[:] = 0.0
    qvel[0] = 3.0
    env._utils.set_joint_qvel(env.model, env.data, "object0:joint", qvel)
    for _ in range(30):
        obs, *_ = env.step(np.zeros(4))
    assert obs["achieved_goal"][0] > fetch_module.IBC_BOX_CENTER[0] + fetch_module.IBC_BOX_HALF_SIZE
    env.close()


def _drive_gripper(env: fetch_module.WalledFetchEnv, direction: np.ndarray, steps: int = 40) -> np.ndarray:
    env.reset(seed=0)
    action = np.zeros(4)
    action[:2] = direction
    for _ in range(steps):
        obs, *_ = env.step(action)
    return obs["observation"][:3]  # gripper position


def test_ibc_walls_act_on_the_block_only():
    env = fetch_module.ErgodicFetchPushEnv()
    gripper = _drive_gripper(env, np.array([0.0, 1.0]))
    assert gripper[1] > env.wall_high[1] + 0.05  # the arm passes through the object-only wall
    env.close()


def test_hard_walls_limit_the_gripper_and_release_it():
    env = fetch_module.FetchPushHardEnv()
    assert env.block_gripper is False
    for direction in DIRECTIONS:
        gripper = _drive_gripper(env, direction)
        assert np.all(gripper[:2] >= np.asarray(env.wall_low)) and np.all(gripper[:2] <= np.asarray(env.wall_high))
    # The released gripper opens: finger joints move apart under an "open" command.
    env.reset(seed=0)
    closed = env.step(np.array([0.0, 0.0, 0.0, -1.0]))[0]["observation"][9:11].sum()
    for _ in range(5):
        obs, *_ = env.step(np.array([0.0, 0.0, 0.0, 1.0]))
    assert obs["observation"][9:11].sum() > closed + 0.02
    env.close()


def test_pick_and_place_hard_air_goal_is_not_solved_on_the_table():
    env = fetch_module.FetchPickAndPlaceHardEnv()
    obs, _ = env.reset(seed=0)
    # The block rests right below the goal: still a failure (goals need >= 10 cm of lift).
    resting = np.array([obs["desired_goal"][0], obs["desired_goal"][1], env.height_offset])
    assert env.compute_reward(resting, obs["desired_goal"], {}) == -1.0
    assert env.compute_reward(obs["desired_goal"], obs["desired_goal"], {}) == 0.0
    env.close()


def test_tabletop_dynamics_by_hand():
    env = TabletopEnv()
    obs, _ = env.reset(seed=0)
    np.testing.assert_array_equal(obs["observation"], [0, 0, 2.5, 0, -1, -1])
    # Move right at full speed (0.2/step) without gripping: the mug stays.
    for _ in range(11):
        obs, *_ = env.step(np.array([1.0, 0.0, -1.0]))
    np.testing.assert_allclose(obs["observation"][:4], [2.2, 0.0, 2.5, 0.0], atol=1e-6)
    # Grip while 0.3 < 0.4 away: grasped; carry up by 1.0 (the mug follows the fist).
    for _ in range(5):
        obs, *_ = env.step(np.array([0.0, 1.0, 1.0]))
    np.testing.assert_allclose(obs["observation"], [2.2, 1.0, 2.5, 1.0, 0.0, 0.0], atol=1e-6)
    # Held mug moves by the fist's *clipped* displacement at the table edge (2.8).
    for _ in range(4):
        obs, *_ = env.step(np.array([1.0, 0.0, 1.0]))
    np.testing.assert_allclose(obs["observation"][:4], [2.8, 1.0, 3.1 - 0.3, 1.0], atol=1e-6)
    # Release and move away: the mug stays put.
    obs, *_ = env.step(np.array([-1.0, 0.0, -1.0]))
    np.testing.assert_allclose(obs["observation"], [2.6, 1.0, 2.8, 1.0, -1.0, -1.0], atol=1e-6)
    # Gripping 0.4 or more away grasps nothing (the fist is at 1.8, the mug 1.0 away).
    for _ in range(4):
        obs, *_ = env.step(np.array([-1.0, 0.0, -1.0]))
    for _ in range(3):
        obs, *_ = env.step(np.array([-1.0, 0.0, 1.0]))
    np.testing.assert_allclose(obs["observation"], [1.2, 1.0, 2.8, 1.0, -1.0, -1.0], atol=1e-6)


def test_tabletop_goals_and_scripted_solution():
    env = TabletopEnv()
    rng = np.random.default_rng(0)
    goals = _samples(env.sample_evaluation_goal, 200)
    assert {tuple(g) for g in goals} == {tuple(g) for g in tabletop_module.EVALUATION_GOALS.astype(np.float32)}
    np.testing.assert_array_equal(env.sample_initial_goal(rng), [0.0, 0.0, 2.5, 0.0])
    # A scripted policy reaches each goal within the 200-step evaluation horizon.
    for seed in range(4):
        obs, _ = env.reset(seed=seed)
        success = False
        for _ in range(TASKS["GCRL/Tabletop-v0"].eval_horizon):
            fist, mug, target = obs["observation"][:2], obs["observation"][2:4], obs["desired_goal"][2:]
            held = obs["observation"][4] == 0.0
            if np.linalg.norm(mug - target) > 0.05:
                aim, grip = (target - mug, 1.0) if held or np.linalg.norm(fist - mug) < 0.3 else (mug - fist, -1.0)
            else:
                aim, grip = -fist, -1.0
            obs, reward, _, _, info = env.step(np.append(np.clip(aim / 0.2, -1, 1), grip))
            if info["is_success"]:
                success = reward == 1.0
                break
        assert success, seed


def test_bad_input_raises_clear_errors():
    with pytest.raises(ValueError, match="renders only 'rgb_array'"):
        TabletopEnv(render_mode="human")
    env = TabletopEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="non-finite"):
        env.step(np.array([np.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        env.step(np.zeros(2))
    with pytest.raises(ValueError, match="reward_type must be 'sparse' or 'dense'"):
        fetch_module.ErgodicFetchPushEnv(reward_type="shaped")
    with pytest.raises(ValueError, match="reward_type must be 'sparse' or 'dense'"):
        ant_module.AntArenaEnv(reward_type="shaped")


def test_sawyer_door_without_metaworld_names_the_install_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "metaworld.envs.sawyer_door_close_v3", None)  # import fails
    with pytest.raises(ImportError, match=r"pip install metaworld==3\.0\.0"):
        door_module.SawyerDoorEnv()


@needs_metaworld
def test_sawyer_door_start_goal_and_scripted_close():
    from metaworld.policies.sawyer_door_close_v3_policy import SawyerDoorCloseV3Policy

    env = door_module.SawyerDoorEnv()
    obs, info = env.reset(seed=0)
    assert -np.pi / 3 <= env.door_angle <= -np.pi / 3 + np.pi / 20
    np.testing.assert_allclose(obs["observation"][:3], door_module.HAND_START, atol=0.01)
    assert not info["is_success"]
    # rho_0: open-door handle positions, all far from the single closed-door goal.
    starts = _samples(env.sample_initial_goal, 20)
    assert np.ptp(starts[:, 0]) > 0.005
    assert np.all(np.linalg.norm(starts - env.sample_evaluation_goal(None), axis=1) > 0.2)
    np.testing.assert_allclose(obs["desired_goal"], env.sample_evaluation_goal(None))
    # metaworld's scripted door-close policy closes it within the evaluation horizon.
    policy = SawyerDoorCloseV3Policy()
    for _ in range(TASKS["GCRL/SawyerDoor-v0"].eval_horizon):
        raw = env._sim._get_obs()
        raw[-3:] = env._sim._target_pos
        obs, reward, *_, info = env.step(policy.get_action(raw))
        if info["is_success"]:
            break
    assert info["is_success"] and reward == 1.0 and abs(env.door_angle) < 0.1
    env.close()


@pytest.mark.parametrize("env_id", ["GCRL/FetchPushHard-v0", "GCRL/AntArena-v0"])
def test_pickle_round_trip(envs, env_id):
    env = get_env(envs, env_id).unwrapped
    clone = pickle.loads(pickle.dumps(env))
    a, _ = env.reset(seed=4)
    b, _ = clone.reset(seed=4)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    clone.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_sac_her_runs_on_each_env(env_id):
    """SB3 integration: HerReplayBuffer relabels with the env's batched compute_reward (short episodes)."""
    from stable_baselines3 import SAC, HerReplayBuffer

    env = gym.make(env_id, max_episode_steps=10)
    model = SAC(
        "MultiInputPolicy",
        env,
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs={"n_sampled_goal": 4, "goal_selection_strategy": "future"},
        learning_starts=40,
        batch_size=16,
        policy_kwargs={"net_arch": [16]},
        seed=0,
        device="cpu",
    )
    model.learn(60)
    assert model.replay_buffer.size() == 60 and model.replay_buffer.ep_length.max() == 10  # 6 full episodes
    batch = model.replay_buffer.sample(32)
    assert set(np.unique(batch.rewards.numpy())) <= {-1.0, 0.0, 1.0}
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_goal_box_contains_task_goals_and_visited_goals(envs, env_id):
    task = TASKS[env_id]
    env = get_env(envs, env_id)
    low, high = np.asarray(task.goal_low), np.asarray(task.goal_high)
    assert low.shape == high.shape == env.observation_space["achieved_goal"].shape
    assert len(set(task.visitation_dims)) == 2 and max(task.visitation_dims) < len(low)  # the heatmap's axes
    for sampler in (env.unwrapped.sample_initial_goal, env.unwrapped.sample_evaluation_goal):
        goals = _samples(sampler, 100)
        assert np.all(goals >= low) and np.all(goals <= high)
    # seeded random rollouts (seed 40 presses the Pick&Place block into the table: its centre dips below the top)
    for seed in range(50):
        env.action_space.seed(seed)
        obs, _ = env.reset(seed=seed)
        for _ in range(30):
            obs, *_ = env.step(env.action_space.sample())
            assert np.all(obs["achieved_goal"] >= low) and np.all(obs["achieved_goal"] <= high), seed


def test_tabletop_renders_a_top_view():
    env = TabletopEnv(render_mode="rgb_array", render_size=112)
    env.reset(seed=0)
    image = env.render()
    assert image.shape == (112, 112, 3) and image.dtype == np.uint8
    # The mug (2.5, 0) is drawn red at its pixel: column (2.5 + 2.8) / 5.6 * 112 = 106, row 56.
    np.testing.assert_array_equal(image[56, 106], [200, 40, 40])
    assert TabletopEnv().render() is None


def test_pick_and_place_hard_is_solvable_by_a_scripted_grasp():
    """Air goals are reachable inside the limited workspace: approach, open, descend, close, lift to the goal."""
    env = fetch_module.FetchPickAndPlaceHardEnv()
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        phase, info = "approach", {}
        for _ in range(TASKS["GCRL/FetchPickAndPlaceHard-v0"].eval_horizon):
            gripper, block, fingers = obs["observation"][:3], obs["observation"][3:6], obs["observation"][9:11]
            if phase == "approach":
                target, grip = block + np.array([0.0, 0.0, 0.05]), 1.0
                if np.linalg.norm(gripper[:2] - block[:2]) < 0.01 and abs(gripper[2] - target[2]) < 0.02:
                    phase = "descend"
            elif phase == "descend":
                target, grip = block, 1.0
                if abs(gripper[2] - block[2]) < 0.01:
                    phase = "close"
            elif phase == "close":
                target, grip = block, -1.0
                if fingers.sum() < 0.055:
                    phase = "lift"
            if phase == "lift":
                target, grip = obs["desired_goal"], -1.0
            action = np.append(np.clip((target - gripper) * 10, -1, 1), grip)
            obs, reward, _, _, info = env.step(action)
            if info["is_success"]:
                break
        assert info["is_success"] and reward == 0.0, seed
        assert obs["achieved_goal"][2] > env.height_offset + 0.05  # really lifted
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_reset_goal_option_commands_the_goal_and_unknown_options_raise(envs, env_id):
    """``reset(options={"goal": g})`` (as evaluate_all_goals sends it) sets the desired goal instead of being
    silently ignored; other options and malformed goals raise."""
    env = get_env(envs, env_id).unwrapped
    space = env.observation_space["desired_goal"]
    goal = env.sample_evaluation_goal(np.random.default_rng(7)) + 0.05
    obs, _ = env.reset(seed=0, options={"goal": goal})
    np.testing.assert_allclose(obs["desired_goal"], goal.astype(space.dtype))
    assert obs["desired_goal"].dtype == space.dtype
    obs, reward, *_ = env.step(np.zeros(env.action_space.shape))
    np.testing.assert_allclose(obs["desired_goal"], goal.astype(space.dtype))
    assert reward == pytest.approx(float(env.compute_reward(obs["achieved_goal"], obs["desired_goal"], None)))
    with pytest.raises(ValueError, match="accepts only 'goal'"):
        env.reset(options={"start": goal})
    with pytest.raises(ValueError, match="finite array of shape"):
        env.reset(options={"goal": np.append(goal, 0.0)})
