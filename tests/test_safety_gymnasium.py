"""Our PointGoal / CarGoal robots against safety-gymnasium's, and the real Goal0 tasks registered from it.

The oracle tests put safety-gymnasium's robot and ours in the same pose, apply the same actions, and compare them
step by step; they and the real-task tests skip where safety-gymnasium is not installed (CI installs it, `.ci/run`).
The check of the Point's turning actuator runs everywhere.
"""

from __future__ import annotations

import math

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from test_navigation_envs import car_controller, point_controller

import sb3_gcrl  # noqa: F401  (registers the envs)
from sb3_gcrl.envs.safety_gymnasium_compat import INSTALL_COMMAND, make_builder, safety_gymnasium_available
from sb3_gcrl.envs.safety_nav import SafetyGoalEnv
from sb3_gcrl.envs.tasks import OPTIONAL_ENV_IDS

needs_safety_gymnasium = pytest.mark.skipif(
    not safety_gymnasium_available(),
    reason=f"safety-gymnasium is not installed ({INSTALL_COMMAND}): the oracle of our Safety-Gym robots",
)

#: steps compared per layout; the actions are random, each held for HOLD steps (turns, runs, stops and reversals)
STEPS, HOLD = 400, 10
#: safety-gymnasium's layout (and our action sequence) seed
LAYOUT_SEED = 0
#: positions (m), orientation matrices, velocities (m/s, rad/s) and sensors agree to this (absolute); measured:
#: Point 0 (bit for bit), Car 4e-13 (its start quaternion is rebuilt from the yaw)
ATOL = 1e-9
_SENSORS = {"point": ("accelerometer", "velocimeter", "gyro", "magnetometer")}
_SENSORS["car"] = (*_SENSORS["point"], "ballangvel_rear")


def _body_velocity(model: mujoco.MjModel, data: mujoco.MjData, body: int) -> np.ndarray:
    velocity = np.zeros(6)  # angular, then linear, in the world frame
    mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, body, velocity, 0)
    return velocity


@needs_safety_gymnasium
@pytest.mark.parametrize("robot", ["point", "car"])
def test_our_robot_moves_as_safety_gymnasiums(robot: str) -> None:
    seed = LAYOUT_SEED
    real = make_builder(robot.title(), f"Safety{robot.title()}Goal0-v0", {"observation_flatten": False})
    ours = SafetyGoalEnv(robot=robot, lidar_num_bins=16, terminate_at_goal=False)  # Safety-Gym's 16 bins
    real_obs, _ = real.reset(seed=seed)
    task = real.task
    real_body, our_body = task.model.body("agent").id, ours.model.body("robot").id
    matrix = task.data.xmat[real_body]
    ours.reset(
        options={
            "reset_pos": task.data.xpos[real_body, :2],
            "goal": task.goal.pos[:2],
            "heading": math.atan2(matrix[3], matrix[0]),
        }
    )
    rng = np.random.default_rng(seed)
    actions = np.repeat(rng.uniform(-1, 1, (STEPS // HOLD, 2)).astype(np.float32), HOLD, axis=0)
    keys = sorted(real_obs)  # Safety-Gym's flattening order, which ours follows
    start_xy, start_yaw, turned = ours.robot_xy, ours.robot_yaw, 0.0
    for step, action in enumerate(actions):
        real_obs, _, _, _, _, info = real.step(action.astype(np.float64))
        our_obs, *_ = ours.step(action)
        if info.get("goal_met"):  # the real task has drawn a new goal; ours follows (goals do not touch the physics)
            ours.goal = task.goal.pos[:2].copy()
            our_obs = ours._observation()
        turned = max(turned, abs((ours.robot_yaw - start_yaw + math.pi) % (2 * math.pi) - math.pi))
        where = f"{robot}, layout {seed}, step {step}"
        pairs = {
            "position": (task.data.xpos[real_body], ours.data.xpos[our_body]),
            "orientation": (task.data.xmat[real_body], ours.data.xmat[our_body]),
            "velocity": (
                _body_velocity(task.model, task.data, real_body),
                _body_velocity(ours.model, ours.data, our_body),
            ),
        }
        for name in _SENSORS[robot]:
            pairs[name] = (real_obs[name], ours.data.sensordata[ours._sensor_slice(name)])
        for name, (expected, actual) in pairs.items():
            np.testing.assert_allclose(actual, expected, rtol=0, atol=ATOL, err_msg=f"{name}, {where}")
        # our float32 observation is the real sensor dict (ball rotation matrix, goal lidar) in sorted key order
        flat = np.concatenate([np.ravel(real_obs[key]) for key in keys]).astype(np.float32)
        np.testing.assert_allclose(our_obs, flat, rtol=1e-6, atol=1e-6, err_msg=f"observation, {where}")
    # the comparison covered a robot that drove and turned, not one at rest
    assert np.linalg.norm(ours.robot_xy - start_xy) > 0.3
    assert turned > 0.5


def test_the_points_turning_actuator_is_a_velocity_servo() -> None:
    model = SafetyGoalEnv(robot="point").model
    turn = model.actuator("z")
    assert turn.trntype[0] == mujoco.mjtTrn.mjTRN_JOINT and model.joint(turn.trnid[0]).name == "z"
    assert turn.gear[0] == pytest.approx(0.3) and turn.biastype[0] == mujoco.mjtBias.mjBIAS_AFFINE
    np.testing.assert_allclose(turn.gainprm[:1], [1.0])
    np.testing.assert_allclose(turn.biasprm[:3], [0.0, 0.0, -1.0])  # kv = 1: force u - gear * omega
    np.testing.assert_allclose(turn.forcerange, [-0.05, 0.05])


def test_the_points_turn_rate_chatters_below_saturation() -> None:
    """Euler integration of the servo's velocity feedback: the rate alternates around the commanded one, the heading
    holds (docs/envs.md)."""
    env = SafetyGoalEnv(robot="point")
    env.reset(seed=0, options={"heading": 0.0})
    for _ in range(4):
        env.step(np.array([0.0, 0.5], dtype=np.float32))  # turning
    env.data.ctrl[:] = 0.0
    mujoco.mj_step(env.model, env.data, nstep=200)
    yaw = env.robot_yaw
    rates = []
    for _ in range(20):
        mujoco.mj_step(env.model, env.data)
        rates.append(env.data.qvel[2])
    assert all(a * b < 0 for a, b in zip(rates, rates[1:]))  # the sign flips on every physics step
    np.testing.assert_allclose(np.abs(rates), 0.48, atol=0.01)
    mujoco.mj_step(env.model, env.data, nstep=1000)
    assert abs(env.robot_yaw - yaw) < 1e-3


@needs_safety_gymnasium
@pytest.mark.parametrize("env_id", OPTIONAL_ENV_IDS)
def test_real_goal_tasks_pass_the_env_checkers(env_id: str) -> None:
    env = gym.make(env_id)
    dims = {"GCRL/SafetyPointGoal0-v0": 28, "GCRL/SafetyCarGoal0-v0": 40}[env_id]
    assert env.observation_space.shape == (dims,) and env.observation_space.dtype == np.float32
    assert env.action_space == gym.spaces.Box(-1, 1, (2,), np.float32)
    assert env.spec.max_episode_steps == 1000
    # SB3's checker (gymnasium's resets a dozen times, and a reset recompiles safety-gymnasium's scene: ~0.5 s)
    sb3_check_env(env.unwrapped, warn=False)
    obs, info = env.reset(seed=3)
    assert obs.dtype == np.float32 and info == {"is_success": False}
    again, _ = env.reset(seed=3)
    np.testing.assert_array_equal(obs, again)  # a seed gives one layout


@needs_safety_gymnasium
@pytest.mark.parametrize("env_id", OPTIONAL_ENV_IDS)
def test_real_goal_tasks_pay_one_at_the_goal_and_end_there(env_id: str) -> None:
    env = gym.make(env_id)
    controller = point_controller if "Point" in env_id else car_controller
    env.reset(seed=0)
    rewards = []
    while True:
        _, reward, terminated, truncated, info = env.step(controller(env.unwrapped))
        rewards.append(reward)
        if terminated or truncated:
            break
    assert terminated and not truncated and info["is_success"] and info["cost"] == 0.0
    assert rewards[-1] == 1.0 and sum(rewards) == 1.0 and len(rewards) < 300
    unwrapped = env.unwrapped
    assert np.linalg.norm(unwrapped.robot_xy - unwrapped.goal) <= unwrapped.goal_size


@needs_safety_gymnasium
def test_real_goal_tasks_check_their_arguments() -> None:
    with pytest.raises(ValueError, match="robot must be one of"):
        gym.make("GCRL/SafetyPointGoal0-v0", robot="doggo")
    env = gym.make("GCRL/SafetyPointGoal0-v0").unwrapped
    with pytest.raises(ValueError, match="takes no reset options"):
        env.reset(options={"goal": (0.0, 0.0)})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="needs 2 finite action values"):
        env.step(np.array([np.nan, 0.0]))
