"""IBC (reset-free baseline of thesis Ch. 3): phases, curriculum rule, the two agents, save/load and errors."""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_util import make_vec_env, unwrap_wrapper
from stable_baselines3.common.logger import configure
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer
from test_contracts import assert_same_state

import sb3_gcrl  # noqa: F401  (registers the GCRL/ envs)
from sb3_gcrl.callbacks import ResetFreeCallback
from sb3_gcrl.reset_free_baselines import IBC, IBCCurriculumScheduler, find_ibc_scheduler, ibc_go_explore
from sb3_gcrl.wrappers import GoExploreWrapper, ResetFreeWrapper
from sb3_gcrl.zoo_config import read_zoo_config

ENV_ID = "GCRL/GrowingTreeGoal-v0"  # 1-D heights; rho_0 = 0, rho_g* = 1; actions change the height by <= 0.1
TINY = {"net_arch": [16]}
HER = {"replay_buffer_class": HerReplayBuffer, "replay_buffer_kwargs": {"n_sampled_goal": 2}}


def ibc_env(env: gym.Env, go_steps: int = 10, **curriculum: Any) -> gym.Env:
    env = ResetFreeWrapper(env, hard_reset_every=100_000, eval_horizon=40)
    return ibc_go_explore(env, go_steps=go_steps, curriculum_kwargs={"n_targets": 4, "update_every": 3, **curriculum})


def make_model(seed: int = 0, n_envs: int = 1, **kwargs: Any) -> IBC:
    env = make_vec_env(ENV_ID, n_envs=n_envs, seed=seed, wrapper_class=ibc_env)
    settings = {"learning_starts": 30, "batch_size": 16, "buffer_size": 2_000, "policy_kwargs": TINY, **HER}
    return IBC("MultiInputPolicy", env, seed=seed, **{**settings, **kwargs})


class Task:
    """Task-relevant goals of a 1-D test: rho_0 = {start}, rho_g* = {goal}."""

    def __init__(self, start: float = 0.0, goal: float = 10.0) -> None:
        self.start, self.goal = start, goal

    def sample(self, kind: str, rng: np.random.Generator, n: int = 1) -> np.ndarray:
        return np.full((n, 1), self.start if kind == "initial" else self.goal)


def near(achieved: np.ndarray, goal: np.ndarray) -> bool:
    return bool(np.linalg.norm(np.asarray(achieved) - np.asarray(goal)) < 0.5)


def goal_obs(achieved: float) -> dict[str, np.ndarray]:
    return {"observation": np.array([achieved]), "achieved_goal": np.array([achieved]), "desired_goal": np.zeros(1)}


# ------------------------------------------------------------------------------------------------------------ phases
def test_phases_forward_then_back_unless_reached_then_auxiliary():
    scheduler = IBCCurriculumScheduler(Task(), near, n_targets=2, update_every=100)  # type: ignore[arg-type]
    rng = np.random.default_rng(0)
    kinds = []
    goal = scheduler.next_goal(goal_obs(0.0), rng)
    kinds.append(scheduler.kind)
    # the forward segment ends far from its goal -> the backward agent gets a backward curriculum goal
    goal = scheduler.next_goal(goal_obs(goal[0] + 5.0), rng)
    kinds.append(scheduler.kind)
    # after a backward segment, the forward agent again (reached or not)
    goal = scheduler.next_goal(goal_obs(goal[0]), rng)
    kinds.append(scheduler.kind)
    # the forward segment reached its goal -> the forward agent goes on (auxiliary)
    goal = scheduler.next_goal(goal_obs(goal[0]), rng)
    kinds.append(scheduler.kind)
    scheduler.next_goal(goal_obs(goal[0]), rng)  # reached again -> auxiliary again
    kinds.append(scheduler.kind)
    scheduler.reset_pending()  # a physical reset: the forward agent starts
    scheduler.next_goal(goal_obs(0.0), rng)
    kinds.append(scheduler.kind)
    assert kinds == ["forward", "back", "forward", "auxiliary", "auxiliary", "forward"]
    assert scheduler.segment_counts == {"forward": 3, "back": 1, "auxiliary": 2}


def test_forward_goal_already_reached_twice_becomes_a_task_goal():
    scheduler = IBCCurriculumScheduler(Task(), near, n_targets=3)  # type: ignore[arg-type]
    # before the first update the pool is rho_0 (= 0): both draws are reached at height 0 -> a rho_g* goal
    goal = scheduler.next_goal(goal_obs(0.0), np.random.default_rng(0))
    np.testing.assert_array_equal(goal, [10.0])
    assert scheduler.kind == "forward"


def test_commanded_goals_and_acting_agent_through_the_wrapper_and_ibc():
    model = make_model(learning_starts=0)
    fixed = np.array([[0.05]], dtype=np.float32)  # the backward agent's spy action (scaled: 0.5)
    calls = []

    def backward_predict(observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = False):
        calls.append(model.env.get_attr("goal_kind")[0])  # type: ignore[union-attr]
        return fixed.copy(), None

    model.backward.predict = backward_predict  # type: ignore[method-assign]
    model.learn(400, callback=ResetFreeCallback(log_freq=100))
    scheduler = find_ibc_scheduler(model.env.envs[0])  # type: ignore[union-attr]
    assert scheduler is not None and scheduler.agent is model
    # the backward agent acts exactly in the back segments, the forward agent in the others
    assert set(calls) == {"back"} and len(calls) == model.agent_steps["backward"] > 0
    assert model.agent_steps["forward"] + model.agent_steps["backward"] == model.num_timesteps
    # ... and each agent's transitions go to its own buffer
    assert model.backward.replay_buffer.size() == model.agent_steps["backward"]
    assert model.replay_buffer.size() == model.agent_steps["forward"]
    stored = model.backward.replay_buffer.actions[: model.backward.replay_buffer.size(), 0]
    np.testing.assert_allclose(stored, 0.5, rtol=1e-6)
    assert not np.allclose(model.replay_buffer.actions[: model.replay_buffer.size(), 0], 0.5)
    # only the agent that acted is updated (official), one gradient step per env step
    assert model.backward._n_updates > 0 and model._n_updates > 0
    assert model._n_updates + model.backward._n_updates <= model.num_timesteps
    # back segments are commanded backward curriculum goals, forward segments forward ones (or a task goal)
    assert scheduler.segment_counts["back"] >= 1 and scheduler.n_updates >= 1
    assert scheduler.backward_pool is not None and scheduler.forward_pool is not None


def test_segments_end_at_go_steps_or_at_success_without_explore_phase():
    env = ibc_env(gym.make(ENV_ID), go_steps=7)
    env.set_training_mode(True)  # type: ignore[attr-defined]
    env.reset(seed=0)
    lengths, steps = [], 0
    while len(lengths) < 6:
        _, _, _, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        steps += 1
        assert "executed_action" not in info  # no Explore phase: the agent's action is always executed
        if truncated:
            lengths.append(steps)
            steps = 0
            env.reset()
    assert all(1 <= n <= 7 for n in lengths) and 7 in lengths


# ------------------------------------------------------------------------------------------------------- curriculum
class HandValues:
    """A hand-made forward value: goals up to 5 are reachable from anywhere (V = 1 / (1 - gamma)), others not (0)."""

    gamma = 0.9

    def curriculum_values(self, observations: dict[str, np.ndarray]) -> np.ndarray:
        return np.where(observations["desired_goal"][:, 0] <= 5.0, 1.0 / (1.0 - self.gamma), 0.0)


def official_cost(
    scheduler: IBCCurriculumScheduler, trajectory: np.ndarray, s0: float, g: float
) -> tuple[float, float]:
    """The authors' matching cost of one trajectory for one target pair, and the goal it proposes."""
    values = scheduler.agent.curriculum_values({"desired_goal": trajectory})  # type: ignore[union-attr]
    gamma = scheduler.agent.gamma  # type: ignore[union-attr]
    values = np.clip(values - 1.0 / (1.0 - gamma), -1.0 / (1.0 - gamma), 0.0)
    d_max = 10.0
    res = np.abs(trajectory[:, 0] - g) - values / (scheduler.hgg_l / d_max / (1.0 - gamma))
    return float(res.min() + scheduler.hgg_c * abs(trajectory[0, 0] - s0)), float(trajectory[res.argmin(), 0])


@pytest.mark.parametrize("with_values", [True, False])
def test_curriculum_goal_follows_the_value_based_rule(with_values: bool):
    scheduler = IBCCurriculumScheduler(Task(), near, n_targets=1, trajectory_capacity=4, hgg_l=1.0)  # type: ignore[arg-type]
    if with_values:
        scheduler.attach(HandValues())
    scheduler.trajectories = [(goal_obs(0.0), np.array([[0.0], [4.0], [8.0]]))]
    scheduler.update(np.random.default_rng(0))
    # distance alone prefers 8 (closest to g* = 10); the value says 8 is out of reach, so the curriculum proposes 4
    assert scheduler.forward_pool[0, 0] == (4.0 if with_values else 8.0)  # type: ignore[index]
    np.testing.assert_array_equal(scheduler.backward_pool, [[0.0]])  # the matched trajectory's start


def test_matching_minimises_the_total_official_cost():
    task = Task(start=0.0, goal=10.0)
    scheduler = IBCCurriculumScheduler(task, near, n_targets=2, trajectory_capacity=3, hgg_l=1.0)  # type: ignore[arg-type]
    scheduler.attach(HandValues())
    trajectories = [np.array([[0.0], [3.0], [6.0]]), np.array([[2.0], [5.0], [9.0]]), np.array([[7.0], [9.5]])]
    scheduler.trajectories = [(goal_obs(float(t[0, 0])), t) for t in trajectories]
    targets = (np.array([[0.0], [8.0]]), np.array([[10.0], [10.0]]))
    scheduler.targets = targets
    scheduler.update(np.random.default_rng(0))
    # brute force over one-to-one assignments (the trajectory pool is padded with copies up to its capacity, 3)
    best = min(
        itertools.permutations(range(3), 2),
        key=lambda pick: sum(
            official_cost(scheduler, trajectories[i], targets[0][j, 0], targets[1][j, 0])[0] for j, i in enumerate(pick)
        ),
    )
    expected = [official_cost(scheduler, trajectories[i], targets[0][j, 0], 10.0)[1] for j, i in enumerate(best)]
    np.testing.assert_array_equal(scheduler.forward_pool[:, 0], expected)  # type: ignore[index]
    np.testing.assert_array_equal(scheduler.backward_pool[:, 0], [trajectories[i][0, 0] for i in best])  # type: ignore[index]


def test_curriculum_values_are_the_forward_critics():
    model = make_model()
    obs = {k: np.repeat(v, 3, axis=0) for k, v in model.env.reset().items()}  # type: ignore[union-attr]
    values = model.curriculum_values(obs)
    assert values.shape == (3,) and np.all(np.isfinite(values))
    model.critic.q_networks[0][-1].bias.data += 100.0  # type: ignore[index]
    model.critic.q_networks[1][-1].bias.data += 100.0  # type: ignore[index]
    assert np.all(model.curriculum_values(obs) > values + 99.0)


# ------------------------------------------------------------------------------------------------ agents, save/load
def test_predict_is_the_forward_policy():
    model = make_model()
    obs = model.env.reset()  # type: ignore[union-attr]
    forward, _ = model.policy.predict(obs, deterministic=True)
    backward, _ = model.backward.policy.predict(obs, deterministic=True)
    action, _ = model.predict(obs, deterministic=True)
    np.testing.assert_array_equal(action, forward)
    assert not np.array_equal(forward, backward)  # two independently initialised agents


def test_save_load_restores_both_agents_and_logs_ibc_keys(tmp_path: Path):
    model = make_model()
    model.set_logger(configure(str(tmp_path / "log"), ["csv"]))
    model.learn(300, callback=ResetFreeCallback(log_freq=100), log_interval=1)
    header = (tmp_path / "log" / "progress.csv").read_text().splitlines()[0].split(",")
    for key in (
        "ibc/forward_step_share",
        "ibc/backward_step_share",
        "ibc/back_segment_share",
        "ibc/curriculum_updates",
    ):
        assert key in header
    assert "backward/critic_loss" in header and "train/critic_loss" in header
    obs = {k: np.concatenate([v, v + 0.5]) for k, v in model.env.reset().items()}  # type: ignore[union-attr]
    model.save(tmp_path / "ibc.zip")
    loaded = IBC.load(tmp_path / "ibc.zip", env=make_vec_env(ENV_ID, seed=1, wrapper_class=ibc_env))
    for agent, copy in ((model, loaded), (model.backward, loaded.backward)):
        np.testing.assert_array_equal(
            agent.predict(obs, deterministic=True)[0], copy.predict(obs, deterministic=True)[0]
        )
    # SB3's load-time overrides reach both agents
    tuned = IBC.load(tmp_path / "ibc.zip", env=make_vec_env(ENV_ID, wrapper_class=ibc_env), batch_size=8, tau=0.2)
    assert (tuned.backward.batch_size, tuned.backward.tau) == (tuned.batch_size, tuned.tau) == (8, 0.2)
    params = loaded.get_parameters()
    assert {"policy", "backward.policy", "backward.critic.optimizer", "backward.ent_coef_optimizer"} <= set(params)
    model.save_replay_buffer(tmp_path / "buffers.pkl")
    loaded.load_replay_buffer(tmp_path / "buffers.pkl")
    for agent, copy in ((model, loaded), (model.backward, loaded.backward)):
        assert copy.replay_buffer.size() == agent.replay_buffer.size() > 0
        np.testing.assert_array_equal(copy.replay_buffer.actions, agent.replay_buffer.actions)
    loaded.learn(60, reset_num_timesteps=False, callback=ResetFreeCallback())
    with pytest.raises(ValueError, match="forward and backward"):
        loaded.load_replay_buffer(_save_other(tmp_path / "other.pkl"))


def _save_other(path: Path) -> Path:
    from stable_baselines3.common.save_util import save_to_pkl

    save_to_pkl(path, {"forward": None})
    return path


# -------------------------------------------------------------------------------------------------------------- errors
def test_a_plain_goal_env_warns_that_ibc_trains_plain_sac():
    with pytest.warns(UserWarning, match="not wrapped in sb3_gcrl.reset_free_baselines.ibc_go_explore"):
        IBC("MultiInputPolicy", make_vec_env(ENV_ID), learning_starts=30, policy_kwargs=TINY)


def test_errors_name_the_fix():
    with pytest.raises(ValueError, match="value_samples"):
        make_model(value_samples=0)
    with pytest.raises(ValueError, match="n_envs=1"):
        make_model(n_envs=2)
    with pytest.raises(ValueError, match=r"n_sampled_goal must be an integer >= 0.*got -1"):  # SB3's HER buffer
        make_model(replay_buffer_kwargs={"n_sampled_goal": -1})
    with pytest.raises(TypeError, match="Dict goal observation"):
        IBC("MultiInputPolicy", "Pendulum-v1")
    with pytest.raises(ValueError, match="MlpPolicy unknown"):  # SB3's error: only Dict observations are supported
        IBC("MlpPolicy", "Pendulum-v1")
    with pytest.raises(ValueError, match="n_targets"):
        IBCCurriculumScheduler(Task(), near, n_targets=0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="reward_range"):
        IBCCurriculumScheduler(Task(), near, reward_range=(1.0, 0.0))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="trajectory_capacity"):
        IBCCurriculumScheduler(Task(), near, n_targets=10, trajectory_capacity=5)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="sets success itself"):
        ibc_go_explore(ResetFreeWrapper(gym.make(ENV_ID), eval_horizon=20), curriculum_kwargs={"success": near})
    with pytest.raises(ValueError, match="go_steps"):
        ibc_go_explore(gym.make(ENV_ID))


def test_subprocess_envs_are_refused():
    from stable_baselines3.common.vec_env import SubprocVecEnv

    env = make_vec_env(ENV_ID, n_envs=1, seed=0, wrapper_class=ibc_env, vec_env_cls=SubprocVecEnv)
    try:
        with pytest.raises(TypeError, match="DummyVecEnv"):  # the curriculum could not reach the critic there
            IBC("MultiInputPolicy", env)
    finally:
        env.close()


# ---------------------------------------------------------------------------------------------------------- configs
REPO = Path(__file__).resolve().parents[1]
#: ibc.yml (CPU sizes, the defaults) and ibc_thesis.yml (the official sizes)
IBC_FILES = [REPO / "sb3_gcrl" / "zoo_configs" / name for name in ("ibc.yml", "ibc_thesis.yml")]
#: (file, env id) of every section
IBC_CONFIGS = [(path, env_id) for path in IBC_FILES for env_id in read_zoo_config(path)]


def test_a_config_for_every_reset_free_task():
    from sb3_gcrl.envs.tasks import TASKS

    cpu, thesis = (set(read_zoo_config(path)) for path in IBC_FILES)
    assert thesis == {env_id for env_id, task in TASKS.items() if task.reset_free}
    assert cpu == {"GCRL/PointUMazeGoal-v0", "GCRL/Tabletop-v0"}  # the CPU presets measured (docs/results.md)


@pytest.mark.parametrize(("config", "env_id"), IBC_CONFIGS, ids=[f"{p.stem}-{e}" for p, e in IBC_CONFIGS])
def test_config_keys_are_constructor_arguments(config: Path, env_id: str):
    import inspect

    from stable_baselines3 import SAC

    section = read_zoo_config(config)[env_id]
    accepted = set(inspect.signature(IBC).parameters) | set(inspect.signature(SAC).parameters)
    assert set(section) - {"n_timesteps", "policy", "env_wrapper", "callback", "monitor_kwargs"} <= accepted


@pytest.mark.slow
@pytest.mark.parametrize(("config", "env_id"), IBC_CONFIGS, ids=[f"{p.stem}-{e}" for p, e in IBC_CONFIGS])
def test_every_config_builds_its_ibc_env(config: Path, env_id: str):
    """The env_wrapper chain RL-Zoo builds from each config accepts its kwargs and runs IBC's segments reset-free."""
    from rl_zoo3.utils import get_wrapper_class

    hyperparams = read_zoo_config(config)[env_id]
    env = get_wrapper_class(hyperparams)(gym.make(env_id))
    scheduler = find_ibc_scheduler(env)
    assert scheduler is not None and scheduler.n_targets == 50
    env.reset(seed=0)
    env.set_training_mode(True)
    env.action_space.seed(0)
    wrapper = unwrap_wrapper(env, GoExploreWrapper)
    for _ in range(2 * wrapper.go_steps + 2):  # a forward segment (random actions: no success), then a back one
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
        if scheduler.segment_counts["back"]:
            break
    assert wrapper.explore_steps == 0 and scheduler.segment_counts["back"] == 1
    env.close()


@pytest.mark.slow
def test_pointumaze_config_trains_under_rl_zoo(tmp_path: Path):
    import subprocess
    import sys

    cmd = [
        sys.executable, "-m", "sb3_gcrl", "train", "--algo", "ibc", "--env", "GCRL/PointUMazeGoal-v0",
        "-conf", "ibc_thesis", "--gym-packages", "sb3_gcrl", "-n", "700", "--eval-freq", "600",
        "--eval-episodes", "1", "--seed", "0", "--num-threads", "1", "--log-interval", "2", "-f", str(tmp_path),
        "-params", "learning_starts:300", "batch_size:32", "policy_kwargs:dict(net_arch=[16])",
    ]  # fmt: skip
    result = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=900)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "backward_step_share" in result.stdout and "| backward/" in result.stdout
    evaluations = np.load(next(tmp_path.glob("ibc/*/evaluations.npz")))
    assert np.all(evaluations["ep_lengths"] == 300)  # evaluation stays episodic (T_eval)


def test_seeded_reset_free_training_is_deterministic():
    runs = []
    for _ in range(2):
        model = make_model(seed=3)
        model.learn(250, callback=ResetFreeCallback())
        scheduler = find_ibc_scheduler(model.env.envs[0])  # type: ignore[union-attr]
        runs.append((model.get_parameters(), scheduler.forward_pool.copy(), dict(model.agent_steps)))  # type: ignore[union-attr]
    assert_same_state(runs[0][0], runs[1][0], "parameters")
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    assert runs[0][2] == runs[1][2]
