"""Reset-free, goal-commanding and Go/Explore wrappers."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_gcrl  # noqa: F401 (registers GCRL/ envs)
from sb3_gcrl.goals import GoalScheduler
from sb3_gcrl.wrappers import (
    EXECUTED_ACTION_KEY,
    GoalCommandWrapper,
    GoExploreWrapper,
    IsSuccessWrapper,
    ResetFreeWrapper,
)

UMAZE_GOAL = "GCRL/PointUMazeGoal-v0"


class LineGoalEnv(gym.Env):
    """Tiny goal env on a line: x += action, goal reached within 0.1; optional terminal state at x >= wall.

    Declares rho_0 = {0} and rho_g* = {1} when ``declare=True`` (the goal-env contract of the README).
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, declare: bool = True, terminal_at: float | None = None) -> None:
        self.observation_space = spaces.Dict(
            {
                "observation": spaces.Box(-10, 10, (1,), np.float64),
                "achieved_goal": spaces.Box(-10, 10, (1,), np.float64),
                "desired_goal": spaces.Box(-10, 10, (1,), np.float64),
            }
        )
        self.action_space = spaces.Box(-0.1, 0.1, (1,), np.float32)
        self.terminal_at = terminal_at
        self.x = 0.0
        self.goal = 1.0
        if declare:
            self.sample_initial_goal = lambda rng: np.array([0.0])
            self.sample_evaluation_goal = lambda rng: np.array([1.0])

    def _obs(self) -> dict[str, np.ndarray]:
        x = np.array([self.x])
        return {"observation": x.copy(), "achieved_goal": x.copy(), "desired_goal": np.array([self.goal])}

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        return (np.abs(achieved_goal - desired_goal)[..., 0] <= 0.1).astype(np.float64)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.x = float(self.np_random.uniform(-0.05, 0.05))
        self.goal = float(1.0 + self.np_random.uniform(-0.05, 0.05))
        return self._obs(), {"is_success": False}

    def step(self, action):
        self.x = float(np.clip(self.x + float(np.asarray(action).reshape(-1)[0]), -10, 10))
        obs = self._obs()
        reward = float(self.compute_reward(obs["achieved_goal"], obs["desired_goal"], {}))
        terminated = self.terminal_at is not None and self.x >= self.terminal_at
        return obs, reward, terminated, False, {"is_success": reward > 0}


class FixedGoalScheduler(GoalScheduler):
    """Commands a fixed goal (for tests)."""

    kind = "fixed"

    def __init__(self, goal: np.ndarray) -> None:
        self.goal = np.asarray(goal, dtype=np.float64)

    def next_goal(self, obs, rng):
        return self.goal.copy()


def umaze_morefree(alpha: float = 0.2, hard_reset_every: int = 200_000, eval_horizon: int = 100) -> gym.Env:
    env = ResetFreeWrapper(gym.make(UMAZE_GOAL), hard_reset_every=hard_reset_every, eval_horizon=eval_horizon)
    kwargs = {"alpha": alpha, "goal_low": [-1.5, -1.5], "goal_high": [1.5, 1.5], "n_bins": 6}
    return GoExploreWrapper(env, "back_and_forth", kwargs, eval_horizon=eval_horizon)


# --- checkers ------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("reset_free", [False, True])
def test_full_chain_passes_env_checkers(reset_free: bool) -> None:
    env = umaze_morefree()
    if reset_free:
        env.set_training_mode(True)
    gym_check_env(env, skip_render_check=True)
    sb3_check_env(env, warn=False)


@pytest.mark.parametrize("wrapper", [GoalCommandWrapper, GoExploreWrapper, IsSuccessWrapper])
def test_non_goal_env_is_rejected_with_the_fix(wrapper: type) -> None:
    with pytest.raises(TypeError, match="needs a goal env"):
        wrapper(gym.make("Pendulum-v1"))


def test_bad_hyperparameters_raise() -> None:
    with pytest.raises(ValueError, match="hard_reset_every must be a positive integer"):
        ResetFreeWrapper(LineGoalEnv(), hard_reset_every=0)
    with pytest.raises(ValueError, match="eval_horizon"):
        GoExploreWrapper(LineGoalEnv(), "env_default")
    with pytest.raises(ValueError, match="pass both goal_low and goal_high, or neither"):
        GoalCommandWrapper(LineGoalEnv(), "novelty", {"goal_low": [-1.0]})
    with pytest.raises(ValueError, match=r"scheduler 'novelty' does not use \['alpha'\]"):
        GoalCommandWrapper(LineGoalEnv(), "novelty", {"alpha": 0.2})  # alpha belongs to back_and_forth
    with pytest.raises(ValueError, match=r"scheduler 'env_default' does not use \['n_bins'\]"):
        GoalCommandWrapper(LineGoalEnv(), "back_and_forth", {"exploratory": "env_default", "n_bins": 4})
    with pytest.raises(ValueError, match="Unknown goal scheduler 'peg'"):
        GoalCommandWrapper(LineGoalEnv(), "peg")
    with pytest.raises(ValueError, match="explore_policy"):
        GoExploreWrapper(LineGoalEnv(), "env_default", eval_horizon=10, explore_policy="rnd")
    for kwargs, message in [
        ({"eval_horizon": 0}, "eval_horizon must be >= 2"),  # no Go phase and no Explore phase to halve it into
        ({"eval_horizon": 10, "go_steps": 2.5}, "go_steps must be an integer, got 2.5"),
        ({"eval_horizon": 10, "explore_steps": -1}, "explore_steps must be >= 0"),
        ({"eval_horizon": 10, "end_go_on_success": "false"}, "end_go_on_success must be True or False"),
    ]:
        with pytest.raises(ValueError, match=message):
            GoExploreWrapper(LineGoalEnv(), "env_default", **kwargs)


# --- reset-free wrapper ----------------------------------------------------------------------------------------------
def run(env: gym.Env, n_steps: int, action: float = 0.0) -> list[tuple[bool, bool, dict]]:
    """Step like a VecEnv: reset after every terminated/truncated step. Returns (terminated, truncated, info)."""
    out = []
    for _ in range(n_steps):
        _, _, terminated, truncated, info = env.step(np.array([action], dtype=np.float32))
        out.append((terminated, truncated, info))
        if terminated or truncated:
            env.reset()
    return out


def test_an_explore_policy_that_returns_no_action_of_the_env_is_named() -> None:
    def wrong(obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        return np.full(7, 0.05)  # 7-D for a 1-D action space

    env = GoExploreWrapper(
        ResetFreeWrapper(LineGoalEnv(), hard_reset_every=1000, eval_horizon=10),
        "env_default",
        go_steps=1,
        explore_steps=2,
        explore_policy=wrong,
    )
    env.reset(seed=0)
    env.set_training_mode(True)
    env.reset()
    env.step(np.zeros(1, dtype=np.float32))  # the Go phase: the agent's action
    with pytest.raises(ValueError, match=r"explore_policy returned array\(\[0.05, .*not an action of the env's Box"):
        env.step(np.zeros(1, dtype=np.float32))


def test_interventions_and_segments() -> None:
    env = ResetFreeWrapper(LineGoalEnv(), hard_reset_every=50, segment_length=20)
    env.reset(seed=0)
    env.set_training_mode(True)
    steps = run(env, 200)
    truncations = [i + 1 for i, (term, trunc, _) in enumerate(steps) if trunc]
    # segments of 20 restarted at every hard reset (step 50, 100, 150, 200): 20, 40, 50, 70, 90, 100, ...
    assert truncations == [20, 40, 50, 70, 90, 100, 120, 140, 150, 170, 190, 200]
    assert not any(term for term, _, _ in steps)
    # the initial reset + hard resets after steps 50, 100, 150, 200
    assert env.interventions == 5 and env.terminal_interventions == 0


def test_segment_reset_keeps_the_physical_state() -> None:
    env = ResetFreeWrapper(LineGoalEnv(), hard_reset_every=1000, segment_length=5)
    env.reset(seed=0)
    env.set_training_mode(True)
    for _ in range(5):
        obs, _, _, truncated, _ = env.step(np.array([0.1], dtype=np.float32))
    assert truncated
    obs_after, info = env.reset()
    assert info["physical_reset"] is False
    np.testing.assert_array_equal(obs_after["achieved_goal"], obs["achieved_goal"])
    assert obs_after["achieved_goal"][0] > 0.4  # not back at the start
    assert env.interventions == 1


def test_true_terminal_is_passed_and_counted() -> None:
    env = ResetFreeWrapper(LineGoalEnv(terminal_at=0.5), hard_reset_every=1000, segment_length=100)
    env.reset(seed=0)
    env.set_training_mode(True)
    steps = run(env, 8, action=0.1)
    terminated = [i + 1 for i, (term, _, _) in enumerate(steps) if term]
    assert terminated and not steps[terminated[0] - 1][1]  # terminated, not disguised as a truncation
    assert env.terminal_interventions == 1 and env.interventions == 2


def test_inner_time_limit_is_lifted_in_reset_free_mode() -> None:
    env = ResetFreeWrapper(gym.make(UMAZE_GOAL), hard_reset_every=10_000, segment_length=100)  # inner limit 300
    env.reset(seed=0)
    env.set_training_mode(True)
    rng = np.random.default_rng(0)
    for _ in range(700):
        _, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        if terminated or truncated:
            env.reset()
    assert env.interventions == 1


def test_episodic_mode_resets_every_episode_with_eval_horizon() -> None:
    env = ResetFreeWrapper(LineGoalEnv(), hard_reset_every=1000, segment_length=7, eval_horizon=30)
    env.reset(seed=0)
    steps = run(env, 90)
    assert [i + 1 for i, (_, trunc, _) in enumerate(steps) if trunc] == [30, 60, 90]
    assert env.interventions == 4


# --- goal commanding -------------------------------------------------------------------------------------------------
def test_commanded_goal_reward_and_success_are_recomputed() -> None:
    goal = np.array([0.3])
    env = GoalCommandWrapper(ResetFreeWrapper(LineGoalEnv(), segment_length=50), FixedGoalScheduler(goal))
    env.reset(seed=0)
    env.set_training_mode(True)
    obs, _ = env.reset()
    assert obs["desired_goal"][0] == pytest.approx(0.3)
    rewards, successes = [], []
    for _ in range(6):
        obs, reward, _, _, info = env.step(np.array([0.1], dtype=np.float32))
        np.testing.assert_allclose(obs["desired_goal"], goal)
        expected = float(abs(obs["achieved_goal"][0] - 0.3) <= 0.1)
        assert reward == expected and info["is_success"] == bool(expected)
        rewards.append(reward)
        successes.append(info["is_success"])
    assert 1.0 in rewards and 0.0 in rewards  # passes through the goal at x ~ 0.2..0.4
    assert env.goal_counts == {"fixed": 1} and env.goal_reached == {"fixed": 1}  # episodic first reset not counted


def test_commanding_does_not_leak_into_inner_observations() -> None:
    inner = ResetFreeWrapper(LineGoalEnv(), segment_length=3)
    env = GoalCommandWrapper(inner, FixedGoalScheduler(np.array([-2.0])))
    env.reset(seed=0)
    env.set_training_mode(True)
    env.reset()
    for _ in range(3):
        env.step(np.zeros(1, dtype=np.float32))
    assert inner._last_obs["desired_goal"][0] == pytest.approx(1.0, abs=0.05)  # the env's own goal


def test_episodic_mode_keeps_the_env_goal() -> None:
    env = GoalCommandWrapper(ResetFreeWrapper(LineGoalEnv(), eval_horizon=10), FixedGoalScheduler(np.array([-2.0])))
    obs, _ = env.reset(seed=0)
    obs2, reward, *_ = env.step(np.zeros(1, dtype=np.float32))
    assert obs["desired_goal"][0] == pytest.approx(1.0, abs=0.05) == obs2["desired_goal"][0]


def test_task_goals_learned_from_physical_resets_only() -> None:
    env = GoalCommandWrapper(ResetFreeWrapper(LineGoalEnv(declare=False), segment_length=5))
    assert not env.task_goals.declared
    for seed in range(3):
        env.reset(seed=seed)
    env.set_training_mode(True)
    for _ in range(20):
        _, _, _, truncated, _ = env.step(np.array([0.1], dtype=np.float32))
        if truncated:
            env.reset()
    assert env.task_goals.n_recorded == 3
    initial = env.sample_task_goals("initial", 100)
    evaluation = env.sample_task_goals("evaluation", 100)
    assert np.all(np.abs(initial) <= 0.05) and np.all(np.abs(evaluation - 1.0) <= 0.05)


# --- Go / Explore phases --------------------------------------------------------------------------------------------
def go_explore_line(goal: float, go: int = 5, explore: int = 3) -> GoExploreWrapper:
    env = GoExploreWrapper(
        ResetFreeWrapper(LineGoalEnv()), FixedGoalScheduler(np.array([goal])), go_steps=go, explore_steps=explore
    )
    env.reset(seed=0)
    env.set_training_mode(True)
    env.reset()
    return env


def test_go_then_explore_phases_and_executed_actions() -> None:
    env = go_explore_line(goal=5.0)  # unreachable: the full Go phase is used
    agent_action = np.array([0.0], dtype=np.float32)
    records = []
    for _ in range(8):
        _, _, _, truncated, info = env.step(agent_action)
        records.append((info.get(EXECUTED_ACTION_KEY), truncated))
    assert all(executed is None for executed, _ in records[:5])
    explore = [executed for executed, _ in records[5:]]
    assert all(executed is not None and executed[0] != 0.0 for executed in explore)
    assert [trunc for _, trunc in records] == [False] * 7 + [True]
    assert env.phase_steps_total == {"go": 5, "explore": 3}


def test_go_phase_ends_when_the_goal_is_reached() -> None:
    env = go_explore_line(goal=0.0)  # reached at the first step
    truncated = [env.step(np.zeros(1, dtype=np.float32))[3] for _ in range(4)]
    assert truncated == [False, False, False, True]
    assert env.phase_steps_total == {"go": 1, "explore": 3}


def test_back_and_forth_phase_sequence_through_the_wrapper() -> None:
    env = umaze_morefree(alpha=1.0, eval_horizon=20)
    env.reset(seed=0)
    env.set_training_mode(True)
    kinds, goals = [], []
    for _ in range(6):
        env.reset()
        kinds.append(env.goal_kind)
        goals.append(env.goal.copy())
        for _ in range(20):
            if env.step(env.action_space.sample())[3]:
                break
    assert kinds == ["forward", "back"] * 3
    forward, back = np.array(goals[0::2]), np.array(goals[1::2])
    np.testing.assert_allclose(forward, np.tile([-1.0, 1.0], (3, 1)), atol=0.1)  # top-left of the U (rho_g*)
    np.testing.assert_allclose(back, np.tile([-1.0, -1.0], (3, 1)), atol=0.1)  # bottom-left start (rho_0)


def test_seeding_is_deterministic() -> None:
    def trajectory() -> np.ndarray:
        env = umaze_morefree(alpha=0.5, eval_horizon=20)
        env.reset(seed=3)
        env.action_space.seed(3)
        env.set_training_mode(True)
        out = []
        for _ in range(120):
            obs, _, _, truncated, _ = env.step(env.action_space.sample())
            out.append(np.concatenate([obs["achieved_goal"], obs["desired_goal"]]))
            if truncated:
                env.reset()
        return np.array(out)

    np.testing.assert_array_equal(trajectory(), trajectory())


def test_is_success_adapter() -> None:
    env = IsSuccessWrapper(gym.make("PointMaze_UMaze-v3"))
    env.reset(seed=0)
    info = env.step(env.action_space.sample())[4]
    assert info["is_success"] == info["success"]
    with pytest.raises(ValueError, match="success_distance must be > 0.0, got -1.0"):
        IsSuccessWrapper(gym.make("PointMaze_UMaze-v3"), success_distance=-1.0)  # never a success
    env = IsSuccessWrapper(gym.make("PointMaze_UMaze-v3"), source_key="missing")
    env.reset(seed=0)
    with pytest.raises(KeyError, match="success_distance"):
        env.step(env.action_space.sample())


def _maze_with_success_logged(wrappers: list[type[gym.Wrapper]], training: bool) -> Any:
    """PointMaze built as RL-Zoo builds it: Monitor(info_keywords=("is_success",)) inside, env_wrapper above.

    Evaluation episodes end after 20 steps, training segments after 10.
    """
    from stable_baselines3.common.env_util import make_vec_env

    def wrap(env: gym.Env) -> gym.Env:
        for wrapper in wrappers:
            env = wrapper(env, eval_horizon=20, segment_length=10) if wrapper is ResetFreeWrapper else wrapper(env)
        return env

    vec_env = make_vec_env(
        "PointMaze_UMaze-v3", n_envs=1, seed=0, wrapper_class=wrap, monitor_kwargs=dict(info_keywords=("is_success",))
    )
    vec_env.env_method("set_training_mode", training)
    return vec_env


@pytest.mark.parametrize("training", [False, True])
def test_is_success_adapter_above_monitor_feeds_its_info_keywords(training: bool) -> None:
    """RL-Zoo's env_wrapper sits above the Monitor: the adapter still provides the key the Monitor logs."""
    vec_env = _maze_with_success_logged([IsSuccessWrapper, ResetFreeWrapper], training)
    vec_env.reset()
    episodes = []
    for _ in range(40):
        infos = vec_env.step(np.zeros((1, 2), np.float32))[3]
        episodes += [info["episode"] for info in infos if "episode" in info]
    assert episodes and all("is_success" in episode for episode in episodes)


@pytest.mark.parametrize("training", [False, True])
def test_monitor_info_keyword_the_env_lacks_names_the_fix(training: bool) -> None:
    vec_env = _maze_with_success_logged([ResetFreeWrapper], training)
    vec_env.reset()
    with pytest.raises(ValueError, match="IsSuccessWrapper first in env_wrapper"):
        for _ in range(40):
            vec_env.step(np.zeros((1, 2), np.float32))


def test_eval_horizon_sets_the_inner_time_limit_seen_by_monitor() -> None:
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.monitor import Monitor

    def wrap(env: gym.Env) -> gym.Env:
        return ResetFreeWrapper(env, eval_horizon=25)

    env = make_vec_env(UMAZE_GOAL, n_envs=1, seed=0, wrapper_class=wrap)  # Monitor sits below the wrapper

    class RandomAgent:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.zeros((1, 2), dtype=np.float32), None

    _, lengths = evaluate_policy(RandomAgent(), env, n_eval_episodes=2, return_episode_rewards=True)
    assert lengths == [25, 25]
    with pytest.raises(ValueError, match="needs a TimeLimit inside the Monitor"):
        ResetFreeWrapper(Monitor(LineGoalEnv()), eval_horizon=10)


# --- SB3's BitFlippingEnv: MultiBinary, Discrete and image goals ----------------------------------------------------
BIT_FLIPPING_VARIANTS = {
    "continuous": {"continuous": True},
    "discrete_actions": {},
    "discrete_obs": {"discrete_obs_space": True},
    "image": {"image_obs_space": True},
}


def bit_flipping(variant: str, scheduler: str = "back_and_forth", **scheduler_kwargs: Any) -> gym.Env:
    from stable_baselines3.common.envs import BitFlippingEnv

    env = gym.wrappers.TimeLimit(BitFlippingEnv(n_bits=4, **BIT_FLIPPING_VARIANTS[variant]), max_episode_steps=8)
    return GoExploreWrapper(ResetFreeWrapper(env, eval_horizon=8), scheduler, scheduler_kwargs or None)


@pytest.mark.parametrize("variant", list(BIT_FLIPPING_VARIANTS))
def test_bit_flipping_env_trains_with_sb3_her_in_every_variant(variant: str) -> None:
    from stable_baselines3 import DQN, SAC

    from sb3_gcrl.callbacks import ResetFreeCallback
    from sb3_gcrl.her import TaskRelevantHerReplayBuffer

    # image goals cannot be binned: Back-and-Forth with the env's own goal as exploratory goal
    kwargs = {"exploratory": "env_default"} if variant == "image" else {}
    env = bit_flipping(variant, **kwargs)
    algo = SAC if variant == "continuous" else DQN
    model = algo(
        "MultiInputPolicy",
        env,
        replay_buffer_class=TaskRelevantHerReplayBuffer,  # alpha = 0.2 read from the scheduler
        learning_starts=40,
        batch_size=16,
        policy_kwargs={"net_arch": [8]},
        seed=0,
    )
    model.learn(120, callback=ResetFreeCallback())
    assert model.replay_buffer.task_goal_ratio == 0.2
    model.replay_buffer.sample(16)  # task-relevant relabeling in the buffer's goal layout
    assert sum(env.goal_counts.values()) > 0
    obs, _ = env.reset()
    assert env.observation_space.contains(obs)


@pytest.mark.parametrize("variant", ["discrete_actions", "discrete_obs"])
def test_novelty_bins_discrete_goals_one_bin_per_value(variant: str) -> None:
    env = bit_flipping(variant, "novelty")
    space = env.scheduler.goal_space
    assert space.n_cells == 16  # 4 bits: 2 x 2 x 2 x 2 bins, or Discrete(16): 16 bins
    env.set_training_mode(True)
    env.reset(seed=0)
    for _ in range(200):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
        assert env.observation_space["desired_goal"].contains(env.goal.astype(np.int64).reshape(env._goal_shape))
    assert space.n_visited > 4  # visits counted per bit pattern, not lumped together
    with pytest.raises(ValueError, match="discrete and is binned exactly"):
        bit_flipping(variant, "novelty", n_bins=3)


def test_image_goals_refuse_binning_with_the_fix() -> None:
    with pytest.raises(ValueError, match="cannot be binned.*exploratory='env_default'"):
        bit_flipping("image", "novelty")
    with pytest.raises(ValueError, match="cannot be binned"):
        bit_flipping("image")  # back_and_forth's default exploratory scheduler is novelty


# --- plain envs: reset-free yes, task-relevant goals no ------------------------------------------------------------
def test_reset_free_training_of_a_plain_env_and_goal_wrappers_refusing_it() -> None:
    env = ResetFreeWrapper(gym.make("Pendulum-v1"), hard_reset_every=450, segment_length=100)  # TimeLimit 200 inside
    env.set_training_mode(True)
    env.reset(seed=0)
    ends = [t for t, (_, truncated, _) in enumerate(run(env, 900)) if truncated]
    assert ends == [99, 199, 299, 399, 449, 549, 649, 749, 849, 899]  # segments, hard reset at 450, no 200-step limit
    assert env.interventions == 3
    with pytest.raises(TypeError, match="needs a goal env"):
        GoExploreWrapper(ResetFreeWrapper(gym.make("Pendulum-v1"), eval_horizon=200))


# --- one place for each setting --------------------------------------------------------------------------------------
def test_eval_horizon_is_read_from_the_reset_free_wrapper_and_a_second_different_one_is_refused() -> None:
    env = GoExploreWrapper(ResetFreeWrapper(LineGoalEnv(), eval_horizon=40), "env_default")
    assert (env.go_steps, env.explore_steps) == (20, 20)
    GoExploreWrapper(ResetFreeWrapper(LineGoalEnv(), eval_horizon=40), "env_default", eval_horizon=40)
    with pytest.raises(ValueError, match="eval_horizon given twice with different values"):
        GoExploreWrapper(ResetFreeWrapper(LineGoalEnv(), eval_horizon=40), "env_default", eval_horizon=30)


# --- training without the switching callback warns -------------------------------------------------------------------
def test_training_without_the_callback_warns_and_evaluation_does_not() -> None:
    import warnings

    from stable_baselines3 import SAC
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.evaluation import evaluate_policy

    from sb3_gcrl.callbacks import ResetFreeCallback
    from sb3_gcrl.her import ExecutedActionDictReplayBuffer

    def make(env: gym.Env) -> gym.Env:
        return GoExploreWrapper(ResetFreeWrapper(env, eval_horizon=10), "env_default")

    def model() -> SAC:
        env = make_vec_env(lambda: gym.wrappers.TimeLimit(LineGoalEnv(), 10), n_envs=1, seed=0, wrapper_class=make)
        return SAC(
            "MultiInputPolicy",
            env,
            learning_starts=1000,
            replay_buffer_class=ExecutedActionDictReplayBuffer,  # the Explore phase's random actions are stored
            policy_kwargs={"net_arch": [8]},
        )

    forgot = model()
    with pytest.warns(UserWarning, match=r"never switched to training mode.*callback=ResetFreeCallback\(\)"):
        forgot.learn(30)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        model().learn(30, callback=ResetFreeCallback())
        fresh = model()
        evaluate_policy(fresh, fresh.get_env(), n_eval_episodes=2)  # evaluation: episodic, no warning
        on_purpose = model()
        on_purpose.get_env().env_method("set_training_mode", False)  # episodic training chosen explicitly
        on_purpose.learn(30)


# --- training curves: segments reported as Monitor episodes -----------------------------------------------------------
def monitored_line_env(tmp_path, hard_reset_every: int = 45, terminal_at: float | None = None) -> gym.Env:
    """LineGoalEnv -> TimeLimit(10) -> Monitor(CSV) -> ResetFreeWrapper -> GoExploreWrapper, as make_vec_env builds."""
    from stable_baselines3.common.monitor import Monitor

    env = gym.wrappers.TimeLimit(LineGoalEnv(terminal_at=terminal_at), max_episode_steps=10)
    env = Monitor(env, str(tmp_path / "0"), info_keywords=("is_success",))
    env = ResetFreeWrapper(env, hard_reset_every=hard_reset_every, eval_horizon=10)
    return GoExploreWrapper(env, FixedGoalScheduler(np.array([0.3])), go_steps=6, explore_steps=4)


def test_training_segments_are_the_episodes_of_info_and_the_monitor_csv(tmp_path) -> None:
    from stable_baselines3.common.monitor import load_results

    env = monitored_line_env(tmp_path)
    env.reset(seed=0)
    env.set_training_mode(True)
    env.reset()
    reported, segment_return, segment_length, reached = [], 0.0, 0, False
    for _ in range(100):
        _, reward, terminated, truncated, info = env.step(np.array([0.1], dtype=np.float32))
        segment_return, segment_length = segment_return + float(reward), segment_length + 1
        reached = reached or float(reward) > 0  # the commanded goal 0.3 is reached on the way, then left
        if terminated or truncated:
            assert info["episode"]["r"] == pytest.approx(segment_return) and info["episode"]["l"] == segment_length
            assert info["is_success"] is reached and info["goal_kind"] == "fixed"
            reported.append((segment_return, segment_length, reached))
            segment_return, segment_length, reached = 0.0, 0, False
            env.reset()
        else:
            assert "episode" not in info and "goal_kind" not in info
    # Go ends at the goal (3 steps from x ~ 0) then 4 explore steps; hard resets at 45 and 90 cut segments short
    assert any(length < 7 for _, length, _ in reported) and max(length for _, length, _ in reported) <= 10
    assert env.get_wrapper_attr("interventions") == 3
    env.close()
    rows = load_results(str(tmp_path))
    # one row per segment, none for the physical episodes (hard resets) that the Monitor below saw end
    assert [(r, int(n), bool(s)) for r, n, s in zip(rows.r, rows.l, rows.is_success)] == reported
    assert rows.l.sum() == 100 - segment_length


def test_only_the_outermost_mode_wrapper_reports_and_evaluation_gives_the_monitor_back(tmp_path) -> None:
    from stable_baselines3.common.monitor import load_results

    env = monitored_line_env(tmp_path, hard_reset_every=1000)
    reset_free = env.env
    env.reset(seed=0)
    env.set_training_mode(True)
    assert env._recording and not reset_free._recording
    for _ in range(20):
        _, _, terminated, truncated, info = env.step(np.array([0.0], dtype=np.float32))
        if terminated or truncated:
            env.reset()
    env.set_training_mode(False)  # episodic again: the Monitor writes its own (physical) episodes
    env.reset()
    for _ in range(10):
        _, _, _, truncated, info = env.step(np.array([0.0], dtype=np.float32))
    assert truncated and info["episode"]["l"] == 10 and "goal_kind" not in info
    env.close()
    lengths = list(load_results(str(tmp_path)).l)
    assert lengths[-1] == 10 and sum(lengths[:-1]) <= 20 and len(lengths) >= 3


def test_reset_free_wrapper_alone_reports_its_segments_and_true_terminals(tmp_path) -> None:
    from stable_baselines3.common.monitor import Monitor, load_results

    env = Monitor(LineGoalEnv(terminal_at=0.5), str(tmp_path / "0"))
    env = ResetFreeWrapper(env, hard_reset_every=1000, segment_length=3)
    env.reset(seed=0)
    env.set_training_mode(True)
    ends = []
    for _ in range(7):
        _, _, terminated, truncated, info = env.step(np.array([0.1], dtype=np.float32))
        if terminated or truncated:
            ends.append((terminated, info["episode"]["l"], info["is_success"]))
            env.reset()
    env.close()
    # x ~ 0.3 after 3 steps, the terminal at 0.5 after 2 more, then a new segment of 3 from the physical reset
    assert ends == [(False, 3, False), (True, 2, False)]
    assert list(load_results(str(tmp_path)).l) == [3, 2]


def test_reset_free_envs_doc_example_runs_and_states_no_horizon() -> None:
    """docs/reset_free_envs.md's example: ResetFreeWrapper takes T_eval from the task table, GoExploreWrapper reads it
    from the ResetFreeWrapper below it."""
    import re
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "reset_free_envs.md").read_text()
    code = "\n".join(re.findall(r"```python\n(.*?)```", doc, flags=re.S))
    assert "eval_horizon=" not in code and "hard_reset_every=" not in code  # the task table's
    namespace: dict[str, Any] = {}
    exec(compile(code, "reset_free_envs.md", "exec"), namespace)  # noqa: S102 (the doc's own example)
    env = namespace["env"]
    assert isinstance(env, GoExploreWrapper) and env.go_steps == env.explore_steps == 25  # T_eval 50 // 2
    env.close()


def test_a_nan_reward_of_the_sac_ports_goal_command_names_vec_check_nan():
    """A non-finite compute_reward stops at the step, as CEC/MFEC's does, instead of a torch error inside SAC."""

    class NanRewardGoalEnv(LineGoalEnv):
        def compute_reward(self, achieved_goal: Any, desired_goal: Any, info: Any) -> np.ndarray:
            return np.full(np.shape(super().compute_reward(achieved_goal, desired_goal, info)), np.nan)

    env = ResetFreeWrapper(NanRewardGoalEnv(), hard_reset_every=100, eval_horizon=20)
    env = GoExploreWrapper(env, "back_and_forth", dict(alpha=0.2, n_bins=4))
    env.set_training_mode(True)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"compute_reward returned the reward nan .*VecCheckNan"):
        env.step(env.action_space.sample())


class NanRewardAfter(gym.Wrapper):
    """The env's reward turns NaN from the ``after``-th step on (a sensor fault, a division by zero)."""

    def __init__(self, env: gym.Env, after: int) -> None:
        super().__init__(env)
        self.after, self.steps = after, 0

    def step(self, action: Any) -> Any:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.steps += 1
        return obs, float("nan") if self.steps >= self.after else reward, terminated, truncated, info


@pytest.mark.parametrize("training", [True, False])
def test_a_nan_env_reward_stops_stock_sac_at_the_step_that_returned_it(training: bool) -> None:
    """Stock SAC on the reset-free wrappers (no goal command): a NaN reward of the env stops at its step, naming
    VecCheckNan, instead of failing inside torch at a later update."""
    from stable_baselines3 import SAC
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_gcrl.callbacks import ResetFreeCallback

    def wrap(env: gym.Env) -> gym.Env:
        return ResetFreeWrapper(NanRewardAfter(env, after=30), hard_reset_every=1000, segment_length=10)

    env = make_vec_env("Pendulum-v1", n_envs=1, seed=0, wrapper_class=wrap)
    model = SAC("MlpPolicy", env, learning_starts=10, batch_size=8, policy_kwargs={"net_arch": [8]}, seed=0)
    callback = ResetFreeCallback()
    if not training:  # episodic training on purpose
        env.env_method("set_training_mode", False)
        callback = None
    mode = "training" if training else "evaluation"
    match = rf"The env wrapped in ResetFreeWrapper returned the reward nan in {mode} mode: .*VecCheckNan"
    with pytest.raises(ValueError, match=match):
        model.learn(100, callback=callback)
    assert model.num_timesteps == 29  # stopped in the 30th step, before SB3 stored it


def test_the_outermost_mode_switched_wrapper_checks_the_reward_it_returns() -> None:
    """Under a goal wrapper the env's reward is checked where it is returned: in evaluation mode (the env's own)."""
    env = GoalCommandWrapper(ResetFreeWrapper(NanRewardAfter(LineGoalEnv(), after=2), eval_horizon=10))
    env.reset(seed=0)
    env.step(env.action_space.sample())
    with pytest.raises(ValueError, match=r"wrapped in GoalCommandWrapper returned the reward nan in evaluation"):
        env.step(env.action_space.sample())
    env.set_training_mode(True)  # training mode: the commanded goal's reward (compute_reward) replaces the env's
    env.reset()
    _, reward, *_ = env.step(env.action_space.sample())
    assert np.isfinite(reward)
