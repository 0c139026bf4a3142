"""Executed-action storage and task-relevant HER relabeling (thesis Sec. 3.4.2)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import SAC, HerReplayBuffer
from stable_baselines3.common.env_util import make_vec_env
from test_wrappers import FixedGoalScheduler, LineGoalEnv

import sb3_gcrl  # noqa: F401 (registers GCRL/ envs)
from sb3_gcrl.her import ExecutedActionHerReplayBuffer, TaskRelevantHerReplayBuffer
from sb3_gcrl.wrappers import EXECUTED_ACTION_KEY, GoalCommandWrapper, GoExploreWrapper, ResetFreeWrapper

TINY = {"net_arch": [16, 16]}


class ActionRecorder(gym.Wrapper):
    """Outermost wrapper recording the agent's action and the executed action of every step."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.agent_actions: list[np.ndarray] = []
        self.executed: list[np.ndarray | None] = []

    def step(self, action):
        out = self.env.step(action)
        self.agent_actions.append(np.array(action, dtype=np.float64))
        self.executed.append(out[4].get(EXECUTED_ACTION_KEY))
        return out


def go_explore_line(env: gym.Env) -> gym.Env:
    # unreachable goal: Go 4 steps, then Explore 4 steps with random actions replacing the agent's
    inner = GoExploreWrapper(ResetFreeWrapper(env), FixedGoalScheduler(np.array([5.0])), go_steps=4, explore_steps=4)
    return ActionRecorder(inner)


def enable(model: SAC) -> None:
    model.get_env().env_method("set_training_mode", True)


@pytest.mark.parametrize("buffer_class", [ExecutedActionHerReplayBuffer, TaskRelevantHerReplayBuffer])
def test_executed_action_is_stored(buffer_class: type) -> None:
    env = make_vec_env(LineGoalEnv, n_envs=2, seed=0, wrapper_class=go_explore_line)
    kwargs = {"task_goal_ratio": 0.2} if buffer_class is TaskRelevantHerReplayBuffer else None  # no alpha to read
    model = SAC(
        "MultiInputPolicy",
        env,
        replay_buffer_class=buffer_class,
        replay_buffer_kwargs=kwargs,
        learning_starts=10_000,
        policy_kwargs=TINY,
    )
    env.env_method("set_training_mode", False)  # first 8 steps per env are episodic on purpose; enable, then continue
    model.learn(64, callback=None)
    enable(model)
    model.learn(96, reset_num_timesteps=False)
    buffer = model.replay_buffer
    low, high = env.action_space.low, env.action_space.high
    replaced = 0
    for env_idx, recorder in enumerate(env.envs):
        for t, (agent, executed) in enumerate(zip(recorder.agent_actions, recorder.executed)):
            expected = agent if executed is None else executed
            scaled = 2.0 * (expected - low) / (high - low) - 1.0
            np.testing.assert_allclose(buffer.actions[t, env_idx], scaled, atol=1e-6)
            replaced += executed is not None and not np.allclose(agent, executed)
    assert replaced > 40  # Explore phases really replaced actions


def test_stock_her_buffer_would_store_the_ignored_action() -> None:
    """Negative control pinning why the executed-action buffers exist."""
    env = make_vec_env(LineGoalEnv, n_envs=1, seed=0, wrapper_class=go_explore_line)
    model = SAC(
        "MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer, learning_starts=10_000, policy_kwargs=TINY
    )
    model.learn(8)
    enable(model)
    model.learn(40, reset_num_timesteps=False)
    recorder = env.envs[0]
    t = next(i for i, e in enumerate(recorder.executed) if e is not None)
    low, high = env.action_space.low, env.action_space.high
    scaled_agent = 2.0 * (recorder.agent_actions[t] - low) / (high - low) - 1.0
    np.testing.assert_allclose(model.replay_buffer.actions[t, 0], scaled_agent, atol=1e-6)


class FarTaskGoals(LineGoalEnv):
    """rho_0 = {-100}, rho_g* = {+100}: easy to tell apart from replayed goals in [-1, 1]."""

    def __init__(self) -> None:
        super().__init__(declare=False)
        self.sample_initial_goal = lambda rng: np.array([-100.0])
        self.sample_evaluation_goal = lambda rng: np.array([100.0])


def filled_buffer(alpha: float, n_envs: int = 2) -> TaskRelevantHerReplayBuffer:
    def make_env() -> gym.Env:
        return gym.wrappers.TimeLimit(FarTaskGoals(), max_episode_steps=10)  # the limit Monitor sees

    def wrap(env: gym.Env) -> gym.Env:
        return GoalCommandWrapper(ResetFreeWrapper(env, eval_horizon=10))

    env = make_vec_env(make_env, n_envs=n_envs, seed=0, wrapper_class=wrap)
    model = SAC(
        "MultiInputPolicy",
        env,
        replay_buffer_class=TaskRelevantHerReplayBuffer,
        replay_buffer_kwargs={"task_goal_ratio": alpha},
        learning_starts=10_000,
        policy_kwargs=TINY,
    )
    model.learn(200)
    return model.replay_buffer  # type: ignore[return-value]


@pytest.mark.parametrize("alpha", [0.2, 1.0])
def test_relabeling_proportions(alpha: float) -> None:
    buffer = filled_buffer(alpha)
    np.random.seed(0)
    n = 20_000
    batch = np.random.randint(0, 90, n)  # inside finished episodes
    envs = np.random.randint(0, 2, n)
    goals = buffer._sample_goals(batch, envs)[:, 0]
    p_eval, p_init = np.mean(goals == 100.0), np.mean(goals == -100.0)
    tol = 4 * np.sqrt(0.25 / n)
    assert abs(p_eval - alpha / 2) < tol and abs(p_init - alpha / 2) < tol
    replayed = goals[np.abs(goals) < 50]
    assert len(replayed) == n - np.sum(np.abs(goals) == 100.0)
    assert np.all(np.abs(replayed) <= 1.0)  # the standard 'future' strategy: achieved goals of the episode


def test_task_relevant_relabeling_is_reproducible_under_the_env_seed() -> None:
    """The alpha/2 + alpha/2 draws come from the env's generator, seeded by SB3's seed (make_vec_env(seed=0) seeds
    the envs and their action spaces): same seed, same relabeled goals."""
    batch, envs = np.arange(10, 90), np.zeros(80, dtype=np.int64)
    draws = []
    for _ in range(2):
        buffer = filled_buffer(0.6)
        np.random.seed(0)  # SB3's own HER draws ("future" goals) use numpy's global generator
        draws.append(buffer._sample_goals(batch, envs))
    np.testing.assert_array_equal(draws[0], draws[1])
    assert np.any(np.abs(draws[0]) == 100.0)  # task-relevant goals among them


def test_relabeled_rewards_use_the_task_goals() -> None:
    buffer = filled_buffer(1.0)
    np.random.seed(0)
    samples = buffer.sample(256)
    desired = samples.observations["desired_goal"][:, 0].numpy()
    her_part = np.abs(desired) == 100.0
    assert her_part.mean() == pytest.approx(buffer.her_ratio, abs=0.05)
    assert np.all(samples.rewards.numpy()[her_part] == 0.0)  # nothing reaches +-100


def task_relevant_sac(env, task_goal_ratio: float | None = None) -> SAC:  # type: ignore[no-untyped-def]
    kwargs = None if task_goal_ratio is None else {"task_goal_ratio": task_goal_ratio}
    return SAC(
        "MultiInputPolicy",
        env,
        replay_buffer_class=TaskRelevantHerReplayBuffer,
        replay_buffer_kwargs=kwargs,
        policy_kwargs=TINY,
    )


def test_task_relevant_buffer_errors() -> None:
    env = make_vec_env(LineGoalEnv, n_envs=1, seed=0)
    with pytest.raises(TypeError, match="wrap it in sb3_gcrl.wrappers.GoalCommandWrapper"):
        task_relevant_sac(env, 0.2)
    with pytest.raises(ValueError, match="pass task_goal_ratio"):  # no alpha given and none to read
        task_relevant_sac(env)
    with pytest.raises(ValueError, match=r"task_goal_ratio \(alpha\) must be in \[0, 1\]"):
        task_relevant_sac(env, 1.5)
    task_relevant_sac(env, 0.0)  # alpha = 0 is standard HER and needs no goal-commanding wrapper


@pytest.mark.parametrize("buffer_class", [ExecutedActionHerReplayBuffer, TaskRelevantHerReplayBuffer])
def test_n_sampled_goal_out_of_range_names_the_valid_range(buffer_class: type) -> None:
    env = make_vec_env(LineGoalEnv, n_envs=1, seed=0)
    kwargs = {"task_goal_ratio": 0.0} if buffer_class is TaskRelevantHerReplayBuffer else {}
    for n_sampled_goal in (-1, -3, 2.5, "4"):  # -1 used to divide by zero in SB3's HerReplayBuffer
        with pytest.raises(ValueError, match=rf"n_sampled_goal must be an integer >= 0.*got '?{n_sampled_goal}"):
            buffer_class(100, env.observation_space, env.action_space, env, n_sampled_goal=n_sampled_goal, **kwargs)
    buffer = buffer_class(100, env.observation_space, env.action_space, env, n_sampled_goal=0, **kwargs)
    assert buffer.her_ratio == 0.0  # 0 is plain replay through a HER buffer


def test_task_relevant_relabeling_needs_relabeled_goals() -> None:
    env = make_vec_env(LineGoalEnv, n_envs=1, seed=0, wrapper_class=morefree_line(0.3))
    space, actions = env.observation_space, env.action_space
    with pytest.raises(ValueError, match=r"integer >= 1 .* got 0; task_goal_ratio \(alpha\) = 0.3"):
        TaskRelevantHerReplayBuffer(100, space, actions, env, n_sampled_goal=0)  # alpha read from the scheduler
    assert TaskRelevantHerReplayBuffer(100, space, actions, env, n_sampled_goal=1).task_goal_ratio == 0.3


def morefree_line(alpha: float) -> object:
    def wrap(env: gym.Env) -> gym.Env:
        scheduler_kwargs = {"alpha": alpha, "exploratory": "env_default"}
        return GoExploreWrapper(ResetFreeWrapper(env), "back_and_forth", scheduler_kwargs, eval_horizon=10)

    return wrap


def test_alpha_is_read_from_the_scheduler_and_a_second_different_alpha_is_refused() -> None:
    env = make_vec_env(LineGoalEnv, n_envs=2, seed=0, wrapper_class=morefree_line(0.3))
    assert task_relevant_sac(env).replay_buffer.task_goal_ratio == 0.3  # stated once, in the scheduler
    assert task_relevant_sac(env, 0.3).replay_buffer.task_goal_ratio == 0.3  # the same value twice is fine
    with pytest.raises(ValueError, match="alpha given twice with different values"):
        task_relevant_sac(env, 0.2)


def reset_free_her_sac(learning_starts: int, n_envs: int = 1, **wrapper_kwargs: int) -> SAC:
    """SAC + SB3's HerReplayBuffer on a reset-free line env whose segments end at the hard reset (or segment_length)."""
    env = make_vec_env(
        LineGoalEnv, n_envs=n_envs, seed=0, wrapper_class=ResetFreeWrapper, wrapper_kwargs=wrapper_kwargs
    )
    return SAC(
        "MultiInputPolicy",
        env,
        replay_buffer_class=HerReplayBuffer,
        learning_starts=learning_starts,
        batch_size=16,
        policy_kwargs={"net_arch": [8]},
        seed=0,
    )


def test_first_update_before_the_first_segment_ends_fails_in_sb3() -> None:
    """Negative control: switched to reset-free mode without the callback, SB3's HER fails at its first update."""
    model = reset_free_her_sac(learning_starts=50, hard_reset_every=500)
    enable(model)
    with pytest.raises(RuntimeError, match="Unable to sample before the end of the first episode"):
        model.learn(200)
    assert model.num_timesteps == 51


def test_first_update_before_the_first_segment_ends_is_refused_before_training() -> None:
    from sb3_gcrl.callbacks import ResetFreeCallback

    model = reset_free_her_sac(learning_starts=50, hard_reset_every=500)
    match = r"after 51 steps per env \(learning_starts=50\).*lasts up to 500 steps.*learning_starts to at least 499"
    with pytest.raises(ValueError, match=match):
        model.learn(200, callback=ResetFreeCallback())
    assert model.num_timesteps == 0  # refused before the first step
    assert model.get_env().get_attr("longest_segment") == [500]

    # n envs share learning_starts: 2 envs x 29 steps end no 30-step segment, 2 x 30 do
    model = reset_free_her_sac(learning_starts=57, n_envs=2, segment_length=30)
    with pytest.raises(ValueError, match=r"29 steps per env \(learning_starts=57 \(2 envs\)\).*at least 58"):
        model.learn(100, callback=ResetFreeCallback())
    model = reset_free_her_sac(learning_starts=58, n_envs=2, segment_length=30)
    model.learn(100, callback=ResetFreeCallback())
    assert model.num_timesteps == 100

    # a budget that ends before the first update samples nothing: not refused (SB3's warm-up warning is the matter)
    model = reset_free_her_sac(learning_starts=50, hard_reset_every=500)
    model.learn(40, callback=ResetFreeCallback())
    assert model.num_timesteps == 40


def test_longest_segment_of_the_wrapper_chain() -> None:
    assert ResetFreeWrapper(LineGoalEnv(), hard_reset_every=500).longest_segment == 500
    assert ResetFreeWrapper(LineGoalEnv(), hard_reset_every=500, segment_length=40).longest_segment == 40
    go_explore = GoExploreWrapper(
        ResetFreeWrapper(LineGoalEnv(), hard_reset_every=500), "env_default", go_steps=6, explore_steps=4
    )
    assert go_explore.longest_segment == 10
    assert GoalCommandWrapper(ResetFreeWrapper(LineGoalEnv(), segment_length=7)).longest_segment == 7
