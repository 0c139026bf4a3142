"""Reset-free callbacks: training env switched, evaluation stays episodic, logging, visitation, save/load."""

from __future__ import annotations

import os

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.env_util import make_vec_env

import sb3_gcrl  # noqa: F401 (registers GCRL/ envs)
from sb3_gcrl.callbacks import (
    ResetFreeCallback,
    VisitationCallback,
    nearest_distances,
    task_relevant_fraction,
    visitation_histogram,
)
from sb3_gcrl.her import TaskRelevantHerReplayBuffer
from sb3_gcrl.wrappers import GoExploreWrapper, ResetFreeWrapper

ENV_ID = "GCRL/PointUMazeGoal-v0"
EVAL_HORIZON = 40


def morefree_wrapper(env: gym.Env) -> gym.Env:
    """The same wrapper for train and eval env, as RL-Zoo does with ``env_wrapper``."""
    env = ResetFreeWrapper(env, hard_reset_every=200_000, eval_horizon=EVAL_HORIZON)
    kwargs = {"alpha": 0.5, "goal_low": [-1.5, -1.5], "goal_high": [1.5, 1.5], "n_bins": 6}
    return GoExploreWrapper(env, "back_and_forth", kwargs, eval_horizon=EVAL_HORIZON)


def make_model(n_envs: int = 2, seed: int = 0) -> SAC:
    env = make_vec_env(ENV_ID, n_envs=n_envs, seed=seed, wrapper_class=morefree_wrapper)
    return SAC(
        "MultiInputPolicy",
        env,
        replay_buffer_class=TaskRelevantHerReplayBuffer,  # alpha read from the scheduler
        learning_starts=100,
        batch_size=32,
        policy_kwargs={"net_arch": [16, 16]},
        seed=seed,
    )


def test_training_env_is_reset_free_and_evaluation_stays_episodic(tmp_path) -> None:
    model = make_model()
    eval_env = make_vec_env(ENV_ID, n_envs=1, seed=100, wrapper_class=morefree_wrapper)
    n_eval_episodes = 3
    eval_callback = EvalCallback(eval_env, n_eval_episodes=n_eval_episodes, eval_freq=100, log_path=str(tmp_path))
    model.learn(400, callback=[ResetFreeCallback(log_freq=50), eval_callback])

    assert model.get_env().get_attr("training") == [True, True]
    assert model.get_env().get_attr("interventions") == [1, 1]  # only the initial reset in 200 steps per env
    assert eval_env.get_attr("training") == [False]
    evaluations = np.load(tmp_path / "evaluations.npz")
    assert np.all(evaluations["ep_lengths"] == EVAL_HORIZON)  # T_eval, no Go/Explore segments
    n_evaluations = len(evaluations["timesteps"])
    # every evaluation episode began with a physical reset (the final reset of each evaluation included)
    assert eval_env.get_attr("interventions")[0] >= n_evaluations * n_eval_episodes
    # the evaluation goal is rho_g* (top-left of the U), never a scheduled goal
    assert eval_env.get_attr("goal_counts") == [{}]
    logged = model.logger.name_to_value
    assert logged["reset_free/interventions"] == 2
    assert logged["reset_free/goals_explore"] + logged.get("reset_free/goals_forward", 0) > 0
    assert 0.0 < logged["reset_free/explore_step_share"] < 1.0


def test_callback_errors_without_the_wrappers() -> None:
    model = SAC("MultiInputPolicy", make_vec_env(ENV_ID, n_envs=1, seed=0), policy_kwargs={"net_arch": [8]})
    with pytest.raises(TypeError, match="wrap it in sb3_gcrl.wrappers.ResetFreeWrapper"):
        model.learn(10, callback=ResetFreeCallback())
    with pytest.raises(TypeError, match="GoalCommandWrapper"):
        model.learn(10, callback=VisitationCallback(0.45, [-1.5, -1.5], [1.5, 1.5]))
    with pytest.raises(ValueError, match="log_freq must be >= 1"):
        ResetFreeCallback(log_freq=0)


def test_callback_refuses_a_buffer_that_would_store_actions_the_env_did_not_execute() -> None:
    """Random Explore actions replace the agent's; SB3's own HER buffer would store the agent's instead."""
    from stable_baselines3 import HerReplayBuffer

    env = make_vec_env(ENV_ID, n_envs=1, seed=0, wrapper_class=morefree_wrapper)
    model = SAC("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer, policy_kwargs={"net_arch": [8]})
    with pytest.raises(TypeError, match="HerReplayBuffer.*use replay_buffer_class=sb3_gcrl.her.ExecutedActionHer"):
        model.learn(10, callback=ResetFreeCallback())
    assert model.num_timesteps == 0

    def agent_explores(env: gym.Env) -> gym.Env:  # the agent acts in Explore too: nothing is replaced
        env = ResetFreeWrapper(env, hard_reset_every=200_000, eval_horizon=EVAL_HORIZON)
        kwargs = {"alpha": 0.5, "goal_low": [-1.5, -1.5], "goal_high": [1.5, 1.5], "n_bins": 6}
        return GoExploreWrapper(env, "back_and_forth", kwargs, explore_policy="agent")

    env = make_vec_env(ENV_ID, n_envs=1, seed=0, wrapper_class=agent_explores)
    model = SAC("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer, policy_kwargs={"net_arch": [8]})
    model.learn(10, callback=ResetFreeCallback())
    assert model.num_timesteps == 10


def test_save_load_round_trip_of_a_reset_free_model(tmp_path) -> None:
    model = make_model(n_envs=2, seed=1)
    model.learn(300, callback=ResetFreeCallback(log_freq=100))
    model.save(tmp_path / "model")
    model.save_replay_buffer(tmp_path / "buffer")
    env = make_vec_env(ENV_ID, n_envs=2, seed=1, wrapper_class=morefree_wrapper)
    loaded = SAC.load(tmp_path / "model", env=env)
    loaded.load_replay_buffer(tmp_path / "buffer")
    assert isinstance(loaded.replay_buffer, TaskRelevantHerReplayBuffer)
    assert loaded.replay_buffer.task_goal_ratio == 0.5
    obs = env.reset()
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    loaded.learn(100, callback=ResetFreeCallback(log_freq=50), reset_num_timesteps=False)  # keeps training


def test_seeded_training_is_deterministic() -> None:
    def run() -> np.ndarray:
        model = make_model(n_envs=1, seed=5)
        model.learn(250, callback=ResetFreeCallback())
        return model.replay_buffer.next_observations["achieved_goal"][:250].copy()

    np.testing.assert_array_equal(run(), run())


def test_task_relevant_fraction_and_histogram_by_hand() -> None:
    achieved = np.array([[0.0, 0.0], [0.3, 0.0], [1.0, 1.0], [5.0, 5.0]])
    task = np.array([[0.0, 0.0], [1.0, 1.2]])
    assert task_relevant_fraction(achieved, task, radius=0.25) == 0.5  # (0,0) and (1,1)
    assert task_relevant_fraction(achieved, task, radius=0.35, chunk=1) == 0.75
    assert task_relevant_fraction(np.zeros((0, 2)), task, radius=1.0) == 0.0
    np.testing.assert_allclose(nearest_distances(achieved, task, chunk=3), [0.0, 0.3, 0.2, np.hypot(4.0, 3.8)])
    hist, xedges, yedges = visitation_histogram(achieved, [-1, -1], [2, 2], n_bins=3)
    assert hist.sum() == 3  # (5, 5) is outside the plotted range
    assert hist[1, 1] == 2 and hist[2, 2] == 1


def test_visitation_callback_logs_and_saves(tmp_path) -> None:
    model = make_model(n_envs=1)
    callback = VisitationCallback(0.45, [-1.5, -1.5], [1.5, 1.5], log_freq=100, save_path=str(tmp_path))
    model.learn(300, callback=[ResetFreeCallback(), callback])
    assert 0.0 <= callback.last_fraction <= 1.0
    assert model.logger.name_to_value["reset_free/task_relevant_pct"] == pytest.approx(100 * callback.last_fraction)
    saved = np.load(tmp_path / "visitation.npz")
    assert saved["hist"].sum() <= 300 and saved["hist"].shape == (50, 50)
    assert os.path.getsize(tmp_path / "visitation.png") > 1000


def test_reset_free_training_logs_rollout_curves_per_segment(tmp_path) -> None:
    import pandas as pd
    from stable_baselines3.common.logger import configure

    model = make_model(n_envs=2)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(600, callback=ResetFreeCallback(log_freq=100))
    # SB3's own episode statistics come from the segments (one Go + Explore, at most EVAL_HORIZON steps) ...
    lengths = [episode["l"] for episode in model.ep_info_buffer]
    assert len(lengths) >= 10 and max(lengths) <= EVAL_HORIZON
    assert len(model.ep_success_buffer) == len(lengths)
    progress = pd.read_csv(tmp_path / "progress.csv")
    assert progress["rollout/ep_len_mean"].dropna().between(1, EVAL_HORIZON).all()
    assert "rollout/success_rate" in progress
    # ... and the commanded goals' success per kind (thesis names of Algorithm 3's goals)
    kinds = {column.removeprefix("rollout/goal_success_") for column in progress if "goal_success_" in column}
    assert {"exploratory", "evaluation"} <= kinds <= {"evaluation", "initial", "exploratory"}
    assert progress["rollout/goal_success_exploratory"].dropna().between(0, 1).all()


def test_goal_success_log_by_hand() -> None:
    from stable_baselines3.common.logger import Logger

    from sb3_gcrl.callbacks.goal_success import GoalSuccessLog

    log, logger = GoalSuccessLog(window=2), Logger(None, [])
    segment = [{"goal_kind": "forward", "is_success": True}, {"goal_kind": "back", "is_success": False}]
    log.update(segment, [True, False], logger)  # the second env's segment has not ended
    assert logger.name_to_value == {"rollout/goal_success_evaluation": 1.0}
    log.update([{"goal_kind": "env", "is_success": False}, {"is_success": True}], [True, True], logger)
    log.update([{"goal_kind": "forward", "is_success": False}, {}], [True, False], logger)
    assert logger.name_to_value["rollout/goal_success_evaluation"] == 0.0  # window 2: the first success dropped
    logger.dump()
    log.update([{}], [False], logger)  # every step re-records the current rates for the next dump
    assert logger.name_to_value == {"rollout/goal_success_evaluation": 0.0}
    with pytest.raises(ValueError, match="window must be >= 1"):
        GoalSuccessLog(window=0)
