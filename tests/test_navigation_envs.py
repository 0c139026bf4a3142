"""Tests of the Ch. 4 navigation tasks: Safety-Gym-style PointGoal / CarGoal and Point4Rooms with sub-goals."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from test_envs import FOUR_ROOMS_WAYPOINTS, _drive

import sb3_gcrl  # noqa: F401  (registers the envs)
from sb3_gcrl.envs import GCRL_ENV_IDS, CarGoalEnv, PointGoalEnv, PointMazeGoalTaskEnv, SafetyGoalEnv
from sb3_gcrl.envs.point_maze import FOUR_ROOMS_MAP
from sb3_gcrl.envs.safety_nav import pseudo_lidar

SAFETY_IDS = ("GCRL/PointGoal-v0", "GCRL/CarGoal-v0")
OBS_DIMS = {"GCRL/PointGoal-v0": 24, "GCRL/CarGoal-v0": 36}
LIDAR = {"GCRL/PointGoal-v0": slice(3, 15), "GCRL/CarGoal-v0": slice(15, 27)}  # after accelerometer (+ ball joint)


def _heading_error(env: SafetyGoalEnv, forward_angle: float) -> float:
    """Angle from the robot's driving direction (its x axis turned by ``forward_angle``) to the goal, in (-pi, pi]."""
    offset = env.goal - env.robot_xy
    error = math.atan2(offset[1], offset[0]) - (env.robot_yaw + forward_angle)
    return (error + math.pi) % (2 * math.pi) - math.pi


def point_controller(env: SafetyGoalEnv) -> np.ndarray:
    """Turn toward the goal (actuator 1), push forward (actuator 0) once roughly facing it."""
    error = _heading_error(env, 0.0)
    return np.array([max(0.0, 1 - 3 * abs(error)), np.clip(3 * error, -1, 1)], dtype=np.float32)


def car_controller(env: SafetyGoalEnv) -> np.ndarray:
    """Differential drive: the car rolls along its -y axis; forward = both wheels, turning = their difference."""
    error = _heading_error(env, -math.pi / 2)
    forward, turn = max(0.0, 1 - 2 * abs(error)), float(np.clip(2 * error, -1, 1))
    return np.clip([forward + turn, forward - turn], -1, 1).astype(np.float32)


CONTROLLERS = {"GCRL/PointGoal-v0": point_controller, "GCRL/CarGoal-v0": car_controller}


# ---------------------------------------------------------------------------------------------------------------
# PointGoal / CarGoal
# ---------------------------------------------------------------------------------------------------------------
def test_new_ids_are_registered() -> None:
    for env_id in (*SAFETY_IDS, "GCRL/Point4RoomsSubgoals-v0"):
        assert env_id in GCRL_ENV_IDS and env_id in gym.registry
        assert gym.spec(env_id).max_episode_steps == 1000


@pytest.mark.parametrize("env_id", SAFETY_IDS)
def test_safety_goal_envs_pass_the_env_checkers_with_table_4_2_dims(env_id: str) -> None:
    env = gym.make(env_id)
    assert env.observation_space.shape == (OBS_DIMS[env_id],)
    assert env.action_space == gym.spaces.Box(-1, 1, (2,), np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unbounded sensor readings
        # rendering is checked in its own process (test_rgb_array_rendering): an EGL context in a long-lived pytest
        # worker depends on what other tests did with EGL before
        gym_check_env(env.unwrapped, skip_render_check=True)
        sb3_check_env(env.unwrapped, warn=False)
    obs, info = env.reset(seed=0)
    assert obs.dtype == np.float32 and not info["is_success"]
    for _ in range(5):  # the car settles onto its wheels
        obs, *_ = env.step(np.zeros(2, dtype=np.float32))
    assert obs[2] == pytest.approx(9.81, abs=0.05)  # the accelerometer at rest reads gravity


def test_car_observation_holds_the_rear_ball_rotation_matrix() -> None:
    env = CarGoalEnv()
    env.reset(seed=0)
    for _ in range(20):
        obs, *_ = env.step(np.array([1.0, 0.3], dtype=np.float32))
    matrix = obs[6:15].reshape(3, 3).astype(np.float64)
    np.testing.assert_allclose(matrix @ matrix.T, np.eye(3), atol=1e-5)
    assert not np.allclose(matrix, np.eye(3), atol=1e-3)  # the ball has rolled


def test_pseudo_lidar_formula() -> None:
    # 12 bins of 30 degrees; goal at 45 degrees, distance 1.5 of max 3: bin 1 reads 0.5, alias 0.5 into 0 and 2.
    lidar = pseudo_lidar(np.array([1.5, 1.5]) / math.sqrt(2), num_bins=12, max_dist=3.0)
    np.testing.assert_allclose(lidar[[0, 1, 2]], [0.25, 0.5, 0.25])
    assert np.count_nonzero(lidar) == 3
    # at 10 degrees (a third into bin 0): next bin 1/3 of the reading, previous bin (11) 2/3
    angle = math.radians(10)
    lidar = pseudo_lidar(np.array([math.cos(angle), math.sin(angle)]), num_bins=12, max_dist=3.0)
    np.testing.assert_allclose(lidar[[11, 0, 1]], [2 / 3 * 2 / 3, 2 / 3, 1 / 3 * 2 / 3])
    assert not pseudo_lidar(np.array([-4.0, 0.0]), num_bins=12, max_dist=3.0).any()  # beyond max_dist


@pytest.mark.parametrize("env_cls", [PointGoalEnv, CarGoalEnv])
def test_goal_lidar_is_in_the_robot_frame(env_cls: type[SafetyGoalEnv]) -> None:
    env = env_cls()
    lidar = LIDAR["GCRL/PointGoal-v0" if env_cls is PointGoalEnv else "GCRL/CarGoal-v0"]
    # goal 1 unit away at 100 degrees; robot heading 0 -> the goal lies in bin 3 (90-120 degrees) of its frame
    goal = (math.cos(math.radians(100)), math.sin(math.radians(100)))
    obs, _ = env.reset(seed=0, options={"reset_pos": (0.0, 0.0), "goal": goal, "heading": 0.0})
    assert int(np.argmax(obs[lidar])) == 3 and obs[lidar][3] == pytest.approx(2 / 3, abs=1e-3)
    # robot turned by +90 degrees: the goal lies at 10 degrees (bin 0)
    obs, _ = env.reset(seed=0, options={"reset_pos": (0.0, 0.0), "goal": goal, "heading": math.pi / 2})
    assert int(np.argmax(obs[lidar])) == 0 and obs[lidar][0] == pytest.approx(2 / 3, abs=1e-3)


def test_positions_have_small_noise_and_the_heading_is_uniform() -> None:
    env = PointGoalEnv()
    starts, goals, headings = [], [], []
    for seed in range(20):
        env.reset(seed=seed)
        starts.append(env.robot_xy)
        goals.append(env.goal)
        headings.append(env.robot_yaw)
    assert np.abs(np.array(starts) - (-0.5, 0.0)).max() <= 0.1 + 1e-9
    assert np.abs(np.array(goals) - (0.5, 0.0)).max() <= 0.1 + 1e-9
    # Safety-Gym's uniform heading: a fixed one would let a constant full push solve PointGoal without sensing
    assert np.abs(headings).max() <= math.pi + 1e-9 and np.abs(headings).max() > 2.0
    assert np.unique(np.array(starts)[:, 0]).size == 20 and np.unique(headings).size == 20
    env.reset(seed=0, options={"heading": 0.3})
    assert env.robot_yaw == pytest.approx(0.3, abs=1e-6)
    with pytest.raises(ValueError, match="Unknown reset options"):
        env.reset(options={"goal_cell": (1, 1)})


@pytest.mark.parametrize("env_id", SAFETY_IDS)
def test_scripted_controller_reaches_the_goal_within_the_horizon(env_id: str) -> None:
    env = gym.make(env_id)
    controller = CONTROLLERS[env_id]
    for seed in range(3):
        env.reset(seed=seed)
        rewards, actions = [], []
        while True:
            actions.append(controller(env.unwrapped))
            _, reward, terminated, truncated, info = env.step(actions[-1])
            rewards.append(reward)
            if terminated or truncated:
                break
        assert terminated and not truncated and info["is_success"], (env_id, seed)
        assert rewards[-1] == 1.0 and sum(rewards) == 1.0 and len(rewards) < 300
        if env_id == "GCRL/CarGoal-v0":  # both wheels drive: forward with both, steering by their difference
            actions = np.array(actions)
            assert (np.abs(actions) > 0.1).all(axis=1).mean() > 0.5
            assert np.abs(actions[:, 0] - actions[:, 1]).max() > 0.5


def test_car_needs_both_wheels_to_drive_straight() -> None:
    env = CarGoalEnv()

    def displacement(action: list[float]) -> tuple[float, float]:
        env.reset(seed=0, options={"reset_pos": (0.0, 0.0), "heading": 0.0, "goal": (3.0, 3.0)})
        for _ in range(25):
            env.step(np.array(action, dtype=np.float32))
        return float(np.linalg.norm(env.robot_xy)), abs(env.robot_yaw)

    straight, straight_yaw = displacement([1.0, 1.0])
    one_wheel, one_wheel_yaw = displacement([1.0, 0.0])
    spin, spin_yaw = displacement([1.0, -1.0])
    assert straight > 0.4 and straight_yaw < 0.1
    assert one_wheel < straight / 2 and one_wheel_yaw > 0.5
    assert spin < 0.1 and spin_yaw > one_wheel_yaw


@pytest.mark.parametrize("env_id", SAFETY_IDS)
def test_same_seed_same_trajectory(env_id: str) -> None:
    def rollout(seed: int) -> np.ndarray:
        env = gym.make(env_id)
        env.action_space.seed(seed)
        trace = [env.reset(seed=seed)[0]]
        for _ in range(40):
            obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            trace.append(np.append(obs, [reward, terminated, truncated]))
        return np.concatenate(trace)

    first = rollout(5)
    np.testing.assert_array_equal(first, rollout(5))
    assert not np.array_equal(first, rollout(6))


def test_random_actions_rarely_reach_the_goal() -> None:
    env = gym.make("GCRL/PointGoal-v0")
    env.action_space.seed(0)
    env.reset(seed=0)
    for _ in range(200):
        _, reward, terminated, _, info = env.step(env.action_space.sample())
        assert reward == 0.0 and not terminated and not info["is_success"]


RENDER_SCRIPT = """
import gymnasium as gym, numpy as np, sb3_gcrl
env = gym.make("GCRL/CarGoal-v0", render_mode="rgb_array", width=64, height=64)
env.reset(seed=0)
frame = env.render()
assert frame.dtype == np.uint8 and frame.shape == (64, 64, 3), (frame.dtype, frame.shape)
for _ in range(10):
    env.step(np.ones(2, dtype=np.float32))
assert not np.array_equal(frame, env.render()), "the car moved but the frame did not change"
env.close()
print("rendered")
"""


def test_rgb_array_rendering() -> None:
    """``render_mode="rgb_array"`` draws the scene (in a fresh process, with MuJoCo's headless EGL backend)."""
    result = subprocess.run(
        [sys.executable, "-c", RENDER_SCRIPT],
        env={**os.environ, "MUJOCO_GL": "egl"},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0 and "rendered" in result.stdout, result.stderr[-2000:]


def test_bad_arguments_raise() -> None:
    with pytest.raises(ValueError, match="robot must be one of"):
        SafetyGoalEnv(robot="doggo")
    with pytest.raises(ValueError, match="lidar_num_bins must be a positive integer"):
        PointGoalEnv(lidar_num_bins=0)
    with pytest.raises(ValueError, match="goal_size must be positive"):
        PointGoalEnv(goal_size=0.0)
    with pytest.raises(ValueError, match="render_mode must be None or 'rgb_array'"):
        PointGoalEnv(render_mode="human")
    with pytest.raises(ValueError, match=r"goal_xy must be a finite \(x, y\) pair"):
        PointGoalEnv(goal_xy=(1.0, 2.0, 3.0))
    env = PointGoalEnv()
    with pytest.raises(ValueError, match=r"reset_pos must be a finite \(x, y\) pair"):
        env.reset(options={"reset_pos": (np.nan, 0.0)})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="needs 2 finite action values"):
        env.step(np.array([np.nan, 0.0]))
    with pytest.raises(ValueError, match="needs 2 finite action values"):
        env.step(np.zeros(3))


# ---------------------------------------------------------------------------------------------------------------
# Point4Rooms with mujoco_maze's sub-goals
# ---------------------------------------------------------------------------------------------------------------
TO_TOP_LEFT_SUBGOAL = [(8, 1), (6, 2), (5, 2), (4, 2), (1, 1)]  # through the left doorway
TO_BOTTOM_RIGHT_SUBGOAL = [(8, 1), (8, 5), (8, 8), (9, 9)]  # through the bottom doorway


@pytest.mark.parametrize("waypoints", [TO_TOP_LEFT_SUBGOAL, TO_BOTTOM_RIGHT_SUBGOAL])
def test_subgoal_pays_half_and_terminates_without_success(waypoints: list) -> None:
    env = gym.make("GCRL/Point4RoomsSubgoals-v0")
    steps, reward, terminated, truncated, info = _drive(env, waypoints, 1000)
    assert terminated and not truncated and reward == 0.5
    assert info["subgoal_reached"] and not info["is_success"] and not info["success"]
    # the plain Point4Rooms task has no sub-goals: the same drive pays nothing and goes on
    plain = gym.make("GCRL/Point4Rooms-v0")
    _, reward, terminated, _, info = _drive(plain, waypoints, steps)
    assert reward == 0.0 and not terminated and "subgoal_reached" not in info


def test_subgoal_env_pays_one_at_the_goal() -> None:
    env = gym.make("GCRL/Point4RoomsSubgoals-v0")
    _, reward, terminated, truncated, info = _drive(env, FOUR_ROOMS_WAYPOINTS, 1000)
    assert terminated and reward == 1.0 and info["is_success"] and not info["subgoal_reached"]
    np.testing.assert_allclose(env.unwrapped.subgoals, [[-4.0, 4.0], [4.0, -4.0]])  # (1, 1) and (9, 9) centres


def test_subgoal_arguments_are_checked() -> None:
    with pytest.raises(ValueError, match="wall cell"):
        gym.make("GCRL/Point4Rooms-v0", subgoal_cells=[(0, 0)])
    with pytest.raises(ValueError, match="is the start or the goal cell"):
        gym.make("GCRL/Point4Rooms-v0", subgoal_cells=[(9, 1)])
    with pytest.raises(ValueError, match="episodic PointMazeTaskEnv only"):
        PointMazeGoalTaskEnv(maze_map=FOUR_ROOMS_MAP, start_cell=(9, 1), goal_cell=(1, 9), subgoal_cells=[(1, 1)])
