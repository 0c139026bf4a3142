"""MEDAL and R3L (thesis Ch. 3 baselines): phases, buffers, reward models, save/load, demonstrations.

The SB3 contracts (predict shapes, callbacks, seeding, save/load of parameters, several envs) are in
``tests/test_contracts.py`` (cases ``medal`` and ``r3l``); this file tests what is particular to the
forward-backward agents.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.buffers import DictReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

import sb3_gcrl  # noqa: F401  (registers the GCRL/ envs)
from sb3_gcrl.callbacks import ResetFreeCallback
from sb3_gcrl.reset_free_baselines import (
    MEDAL,
    R3L,
    RND,
    BackwardRewardSAC,
    Demonstrations,
    Discriminator,
    ForwardBackwardSAC,
    ForwardBackwardWrapper,
    available_demos,
    load_demos,
)
from sb3_gcrl.wrappers import ResetFreeWrapper
from sb3_gcrl.zoo_config import config_sections, resolve_config

ENV_ID = "GCRL/GrowingTreeGoal-v0"  # height 0 -> goal 1, actions in [-0.1, 0.1]
SEGMENT = 12
TINY = {
    "buffer_size": 2_000,
    "batch_size": 16,
    "policy_kwargs": {"net_arch": [16]},
    "reward_model_batch_size": 32,
}


def wrap(env: gym.Env, segment_length: int = SEGMENT, hard_reset_every: int = 1_000) -> gym.Env:
    return ForwardBackwardWrapper(
        ResetFreeWrapper(env, hard_reset_every=hard_reset_every, segment_length=segment_length, eval_horizon=200)
    )


def make_model(cls: type[BackwardRewardSAC], n_envs: int = 1, seed: int = 0, **kwargs: Any) -> BackwardRewardSAC:
    env = make_vec_env(ENV_ID, n_envs=n_envs, seed=seed, wrapper_class=wrap)
    if cls is MEDAL:
        kwargs.setdefault("demos", ENV_ID)
    return cls("MultiInputPolicy", env, seed=seed, **{**TINY, **kwargs})


class PhaseRecorder(BaseCallback):
    """Records the phase reported at each step (``info["phase"]``) and whether the segment ended."""

    def __init__(self) -> None:
        super().__init__()
        self.phases: list[list[str]] = []
        self.dones: list[np.ndarray] = []

    def _on_step(self) -> bool:
        self.phases.append([info["phase"] for info in self.locals["infos"]])
        self.dones.append(self.locals["dones"].copy())
        return True


def constant_predict(value: float) -> Any:
    """A ``predict`` that returns ``value`` for every env (to tell the two policies apart by their actions)."""

    def predict(obs: dict[str, np.ndarray], state: Any = None, episode_start: Any = None, deterministic: bool = False):
        return np.full((len(obs["observation"]), 1), value, dtype=np.float32), None

    return predict


# ------------------------------------------------------------------------------------------------ phases and buffers
def test_wrapper_alternates_phases_ends_forward_at_the_goal_and_restarts_forward_after_a_hard_reset():
    env = wrap(gym.make(ENV_ID), segment_length=SEGMENT, hard_reset_every=60)
    assert env.phase == "forward"  # evaluation mode: always the forward (evaluated) policy
    env.set_training_mode(True)
    env.reset(seed=0)
    lengths: list[tuple[str, int, bool]] = []  # (phase, steps, physical reset next)
    for _ in range(8):
        phase, steps = env.phase, 0
        while True:
            # forward climbs to the goal (1.0 in 10 steps), backward climbs down
            _, _, terminated, truncated, info = env.step(np.array([0.1 if phase == "forward" else -0.1], np.float32))
            steps += 1
            assert info["phase"] == phase
            if terminated or truncated:
                break
        _, reset_info = env.reset()
        lengths.append((phase, steps, reset_info["physical_reset"]))
    phases = [p for p, _, _ in lengths]
    # forward ends at the goal after 10 steps (before the 12-step segment); backward runs its 12 steps
    assert lengths[0] == ("forward", 10, False) and lengths[1] == ("backward", SEGMENT, False)
    assert phases[:4] == ["forward", "backward", "forward", "backward"]
    # a hard reset every 60 steps cuts a segment, and the next segment is a forward one again
    cut = next(i for i, (_, _, physical) in enumerate(lengths) if physical)
    assert sum(n for _, n, _ in lengths[: cut + 1]) == 60
    assert lengths[cut + 1][0] == "forward"
    assert env.forward_backward_steps["forward"] + env.forward_backward_steps["backward"] == sum(
        n for _, n, _ in lengths
    )


@pytest.mark.parametrize("cls", [MEDAL, R3L])
@pytest.mark.parametrize("n_envs", [1, 2])
def test_each_policy_acts_in_its_phase_and_each_buffer_stores_its_policys_transitions(
    cls: type[BackwardRewardSAC], n_envs: int
):
    kwargs = {"demos_to_buffers": False} if cls is MEDAL else {}
    model = make_model(cls, n_envs=n_envs, learning_starts=0, train_freq=1, gradient_steps=1, **kwargs)
    # the forward policy always pushes up (+0.1), the backward one down (-0.1): stored actions tell who acted
    model.predict = constant_predict(0.1)  # type: ignore[method-assign]
    model.backward.predict = constant_predict(-0.1)  # type: ignore[method-assign]
    recorder = PhaseRecorder()
    model.learn(120, callback=[ResetFreeCallback(), recorder])
    phases = np.array(recorder.phases)  # (steps, n_envs)
    n_forward, n_backward = int((phases == "forward").sum()), int((phases == "backward").sum())
    assert n_forward > 0 and n_backward > 0
    assert list(model.phase_steps) == [n_forward, n_backward]
    assert model.replay_buffer.size() == n_forward and model.backward_buffer.size() == n_backward
    np.testing.assert_array_equal(model.replay_buffer.actions[:n_forward], 1.0)  # scaled +0.1
    np.testing.assert_array_equal(model.backward_buffer.actions[:n_backward], -1.0)
    assert not model.replay_buffer.is_demo.any() and not model.backward_buffer.is_demo.any()
    # only the policy that acted is updated: the gradient step of each VecEnv step (train_freq 1) is shared by the
    # phases of the envs in that step
    assert model._n_updates + model.backward._n_updates == 120 // n_envs
    assert abs(model._n_updates - n_forward / n_envs) <= 1 and abs(model.backward._n_updates - n_backward / n_envs) <= 1
    # segments of one env alternate forward / backward
    first_env = [p for p, done in zip(phases[:, 0], np.array(recorder.dones)[:, 0]) if done]
    assert first_env[1:5] == ["backward", "forward", "backward", "forward"]


def test_medal_puts_the_demonstrations_into_both_buffers_but_trains_the_discriminator_on_visited_states_only():
    demos = load_demos(ENV_ID)
    model = make_model(MEDAL, learning_starts=0)
    for buffer in (model.replay_buffer, model.backward_buffer):
        assert buffer.size() == len(demos) and buffer.is_demo[: len(demos)].all()
        np.testing.assert_array_equal(
            buffer.observations["observation"][: len(demos), 0], demos.observations["observation"]
        )
    assert model.backward_buffer.sample_visited_states(4, "observation") is None  # no visited state yet
    assert model._reward_model_step() is None  # nothing to discriminate against: no step
    model.learn(60, callback=ResetFreeCallback())
    visited = model.backward_buffer.n_visited()
    assert visited == model.phase_steps[1] > 0
    states = model.backward_buffer.sample_visited_states(500, "observation")
    online = model.backward_buffer.next_observations["observation"][len(demos) : len(demos) + visited, 0]
    assert set(np.round(states[:, 0], 6)) <= set(np.round(online[:, 0], 6))


def test_backward_policy_is_trained_on_the_reward_model_not_the_env_reward():
    model = make_model(MEDAL, learning_starts=0)
    model.learn(40, callback=ResetFreeCallback())
    th.manual_seed(0)
    np.random.seed(0)
    samples = model.backward.replay_buffer.sample(64)  # what SAC.train of the backward policy samples
    expected = model.discriminator.reward(samples.next_observations["observation"].float())
    np.testing.assert_allclose(samples.rewards.numpy(), expected.numpy(), rtol=1e-6)
    # the underlying buffer still holds the env's rewards
    np.random.seed(0)
    raw = model.backward_buffer.sample(64)
    assert not np.allclose(raw.rewards.numpy(), samples.rewards.numpy())


def test_predict_is_the_forward_policy():
    model = make_model(R3L, learning_starts=0)
    model.learn(40, callback=ResetFreeCallback())
    obs = model.get_env().reset()
    forward, _ = model.predict(obs, deterministic=True)
    np.testing.assert_array_equal(forward, model.policy.predict(obs, deterministic=True)[0])
    assert not np.array_equal(forward, model.backward.policy.predict(obs, deterministic=True)[0])


def test_medal_runs_the_same_under_the_same_seed():
    """Same seed, same run: the discriminator's batches (demonstration and visited states) are drawn with the
    algorithm's generator, seeded from the model's seed."""
    runs = []
    for seed in (0, 0, 1):
        model = make_model(MEDAL, seed=seed, learning_starts=0, reward_model_train_freq=2)
        model.learn(60, callback=ResetFreeCallback())
        runs.append({k: v.clone() for k, v in model.discriminator.state_dict().items()})
    first, again, other = runs
    assert all(th.equal(first[key], again[key]) for key in first)
    assert not all(th.equal(first[key], other[key]) for key in first)


# ------------------------------------------------------------------------------------------------ save / load
@pytest.mark.parametrize("cls", [MEDAL, R3L])
def test_save_load_restores_both_policies_the_reward_model_and_both_buffers(
    cls: type[BackwardRewardSAC], tmp_path: Path
):
    model = make_model(cls, learning_starts=10)
    model.learn(80, callback=ResetFreeCallback())
    model.save(tmp_path / "model.zip")
    model.save_replay_buffer(tmp_path / "buffers.pkl")
    loaded = cls.load(tmp_path / "model.zip", env=model.get_env())
    obs = model.get_env().reset()
    for a, b in ((model, loaded), (model.backward, loaded.backward)):
        np.testing.assert_array_equal(a.predict(obs, deterministic=True)[0], b.predict(obs, deterministic=True)[0])
    for key, value in model.reward_model.state_dict().items():  # weights and (RND) running statistics
        assert th.equal(value, loaded.reward_model.state_dict()[key]), key
    assert loaded.reward_model.optimizer.state_dict()["state"]  # the reward model's Adam moments came back
    assert list(loaded.phase_steps) == list(model.phase_steps)
    assert loaded._rng.bit_generator.state == model._rng.bit_generator.state  # the reward-model draws continue
    loaded.load_replay_buffer(tmp_path / "buffers.pkl")
    for a, b in ((model.replay_buffer, loaded.replay_buffer), (model.backward_buffer, loaded.backward_buffer)):
        assert a.size() == b.size()
        np.testing.assert_array_equal(a.is_demo, b.is_demo)
        np.testing.assert_array_equal(a.observations["observation"], b.observations["observation"])
    assert loaded.backward.replay_buffer.buffer is loaded.backward_buffer  # the backward SAC samples the loaded one
    loaded.learn(20, reset_num_timesteps=False, callback=ResetFreeCallback())


def test_a_failure_while_saving_the_buffers_leaves_the_previous_file_intact(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    import pickle

    model = make_model(R3L)
    model.save_replay_buffer(tmp_path / "buffers.pkl")
    before = (tmp_path / "buffers.pkl").read_bytes()
    model.learn(40, callback=ResetFreeCallback())

    def killed(*args: Any, **kwargs: Any) -> None:
        raise KeyboardInterrupt  # as a kill while the pickle is written

    monkeypatch.setattr(pickle, "dump", killed)
    with pytest.raises(KeyboardInterrupt):
        model.save_replay_buffer(tmp_path / "buffers.pkl")
    assert (tmp_path / "buffers.pkl").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["buffers.pkl"]  # no temporary file left behind


def test_load_replay_buffer_rejects_a_single_buffer(tmp_path: Path):
    from stable_baselines3.common.save_util import save_to_pkl

    model = make_model(R3L)
    save_to_pkl(tmp_path / "one.pkl", model.replay_buffer)
    with pytest.raises(ValueError, match="forward and backward buffers"):
        model.load_replay_buffer(tmp_path / "one.pkl")


# ------------------------------------------------------------------------------------------------ reward models
def test_discriminator_separates_demonstration_states_from_other_states():
    th.manual_seed(0)
    disc = Discriminator(2, hidden=[32], learning_rate=1e-2)
    demo = th.randn(256, 2) * 0.1 + th.tensor([1.0, 1.0])
    other = th.randn(256, 2) * 0.1 - th.tensor([1.0, 1.0])
    losses = [disc.train_step(demo, other) for _ in range(150)]
    assert losses[-1] < losses[0]
    assert th.sigmoid(disc(demo)).mean() > 0.8 and th.sigmoid(disc(other)).mean() < 0.2
    # MEDAL's reward -log(1 - D(s)) is higher on demonstration-like states
    assert disc.reward(demo).mean() > disc.reward(other).mean() + 1.0


def test_rnd_novelty_falls_on_repeatedly_visited_states():
    th.manual_seed(0)
    rnd = RND(2, hidden=[32, 32], learning_rate=1e-2)
    visited = th.tensor([[0.5, -0.5]]) + 0.05 * th.randn(64, 2)
    others = th.tensor([[-2.0, 2.0]]) + 0.05 * th.randn(64, 2)
    rnd.obs_rms.update(th.cat([visited, others]))  # statistics of both regions, then only one is visited
    before = rnd.novelty(visited).mean()
    for _ in range(200):
        rnd.obs_rms.update(th.cat([visited, others]))
        x = rnd._normalise(visited)
        loss = th.nn.functional.mse_loss(rnd.predictor(x), rnd.target(x))
        rnd.optimizer.zero_grad()
        loss.backward()
        rnd.optimizer.step()
    after = rnd.novelty(visited).mean()
    assert after < 0.1 * before
    assert rnd.novelty(others).mean() > 5 * after
    rewards = rnd.reward(th.cat([visited, others]))  # min-max normalised over the batch (DI-engine)
    assert rewards.min() == 0 and rewards.max() <= 1 and rewards[64:].mean() > rewards[:64].mean()


def test_rnd_train_step_learns_the_states_it_is_given():
    th.manual_seed(0)
    rnd = RND(2, hidden=[32, 32])
    states = th.tensor([[0.5, -0.5]]) + 0.05 * th.randn(64, 2)
    first = rnd.train_step(states)
    for _ in range(100):
        last = rnd.train_step(states)
    assert last < 0.2 * first


# ------------------------------------------------------------------------------------------------ demonstrations
@pytest.mark.parametrize("task", ["GCRL/GrowingTreeGoal-v0", "GCRL/PointUMazeGoal-v0", "GCRL/Tabletop-v0"])
def test_shipped_demonstrations_match_their_env_and_reach_the_goal(task: str):
    assert task.split("/")[-1] in available_demos()
    env = gym.make(task)
    demos = load_demos(task, env.observation_space, env.action_space)
    assert demos.n_episodes == 30 and len(demos.metadata["seeds"]) == 30 and demos.metadata["env_id"] == task
    last = np.append(np.flatnonzero(demos.episode_starts)[1:], len(demos)) - 1
    reward_at_goal = env.unwrapped.compute_reward(
        demos.next_observations["achieved_goal"][last], demos.next_observations["desired_goal"][last], {}
    )
    np.testing.assert_array_equal(reward_at_goal, 1.0)  # every episode ends at its goal
    # the recorded seeds reproduce the episodes' first states
    first = np.flatnonzero(demos.episode_starts)
    obs, _ = env.reset(seed=int(demos.metadata["seeds"][3]))
    np.testing.assert_allclose(demos.observations["observation"][first[3]], obs["observation"], rtol=1e-6)


def write_demos(path: Path, **changes: Any) -> Path:
    demos = load_demos(ENV_ID)
    arrays: dict[str, Any] = {f"observations/{k}": v for k, v in demos.observations.items()}
    arrays.update({f"next_observations/{k}": v for k, v in demos.next_observations.items()})
    arrays.update(actions=demos.actions, rewards=demos.rewards, episode_starts=demos.episode_starts)
    arrays.update(env_id=ENV_ID, seeds=demos.metadata["seeds"])
    for key, value in changes.items():
        if value is None:
            arrays.pop(key)
        else:
            arrays[key] = value
    np.savez_compressed(path, **arrays)
    return path


def test_demo_loader_rejects_bad_files_naming_what_is_wrong(tmp_path: Path):
    env = gym.make(ENV_ID)
    spaces_ = (env.observation_space, env.action_space)
    load_demos(write_demos(tmp_path / "good.npz"), *spaces_)  # the control: an unchanged file loads
    with pytest.raises(ValueError, match=r"lacks \['actions'\]"):
        load_demos(write_demos(tmp_path / "a.npz", actions=None), *spaces_)
    with pytest.raises(ValueError, match="observations/<key>"):
        load_demos(write_demos(tmp_path / "b.npz", **{f"observations/{k}": None for k in env.observation_space}))
    n = len(load_demos(ENV_ID))
    with pytest.raises(ValueError, match=r"observations/observation has shape \(2,\) per row, the env's space \(1,\)"):
        load_demos(write_demos(tmp_path / "c.npz", **{"observations/observation": np.zeros((n, 2))}), *spaces_)
    with pytest.raises(ValueError, match=r"actions have shape \(3,\)"):
        load_demos(write_demos(tmp_path / "d.npz", actions=np.zeros((n, 3), np.float32)), *spaces_)
    nan = np.zeros((n, 1), np.float32)
    nan[5] = np.nan
    with pytest.raises(ValueError, match="next_observations/achieved_goal holds NaN"):
        load_demos(write_demos(tmp_path / "e.npz", **{"next_observations/achieved_goal": nan}))
    with pytest.raises(ValueError, match=r"rewards has shape \(3,\)"):
        load_demos(write_demos(tmp_path / "f.npz", rewards=np.zeros(3, np.float32)))
    with pytest.raises(FileNotFoundError, match="shipped"):
        load_demos("GCRL/NoSuchTask-v0")
    # MEDAL checks its demonstrations against its env
    with pytest.raises(ValueError, match=r"MEDAL's demos: observations/\w+ has shape \(\d,\) per row"):
        make_model(MEDAL, demos=load_demos("GCRL/Tabletop-v0"))


def test_demonstrations_round_trip_through_save(tmp_path: Path):
    demos = load_demos("GCRL/Tabletop-v0")
    demos.save(tmp_path / "copy.npz")
    copy = load_demos(tmp_path / "copy.npz")
    assert isinstance(copy, Demonstrations) and len(copy) == len(demos)
    np.testing.assert_array_equal(copy.observations["observation"], demos.observations["observation"])
    np.testing.assert_array_equal(copy.metadata["seeds"], demos.metadata["seeds"])
    states = demos.states()
    assert states.shape == (len(demos) + demos.n_episodes, 6)


# ------------------------------------------------------------------------------------------------ construction errors
def test_construction_errors_name_the_fix():
    plain = make_vec_env(ENV_ID, n_envs=1)
    with pytest.raises(ValueError, match="ForwardBackwardWrapper"):
        R3L("MultiInputPolicy", plain)
    env = make_vec_env(ENV_ID, n_envs=1, wrapper_class=wrap)
    with pytest.raises(ValueError, match="needs demonstrations"):
        MEDAL("MultiInputPolicy", env)
    with pytest.raises(ValueError, match="PhaseReplayBuffer"):
        R3L("MultiInputPolicy", env, replay_buffer_class=DictReplayBuffer)
    with pytest.raises(ValueError, match="reward_model_train_freq"):
        R3L("MultiInputPolicy", env, reward_model_train_freq=0)
    with pytest.raises(ValueError, match="segment_length"):
        ForwardBackwardWrapper(ResetFreeWrapper(gym.make(ENV_ID)))
    with pytest.raises(ValueError, match="state_key"):
        R3L("MultiInputPolicy", env, state_key="state")


@pytest.mark.parametrize(
    ("argument", "value", "reason"),
    [
        ("optimize_memory_usage", True, "own phases only"),
        ("n_steps", 3, "one-step rewards"),
        ("use_sde", True, "forward actor only"),
    ],
)
def test_sac_arguments_that_cannot_work_with_two_learners_are_refused_saying_why(
    argument: str, value: Any, reason: str
):
    env = make_vec_env(ENV_ID, n_envs=1, wrapper_class=wrap)
    with pytest.raises(ValueError, match=f"{argument}.*{reason}"):
        R3L("MultiInputPolicy", env, **{argument: value})
    R3L("MultiInputPolicy", env, sde_sample_freq=4, use_sde_at_warmup=True)  # no effect without use_sde, as in SAC


# ------------------------------------------------------------------------------------------------ zoo configs
ZOO_CONFIGS = Path(sb3_gcrl.__file__).parent / "zoo_configs"
#: (algorithm, env id) of every section of medal.yml and r3l.yml
BASELINE_CONFIGS = [
    (algo, env_id) for algo in ("medal", "r3l") for env_id in config_sections(ZOO_CONFIGS / f"{algo}.yml")
]
#: RL-Zoo keys that are not constructor arguments
ZOO_KEYS = {"n_timesteps", "policy", "env_wrapper", "callback", "monitor_kwargs"}


def test_configs_exist_for_every_task_with_demonstrations_and_r3l_for_every_reset_free_task():
    names = set(BASELINE_CONFIGS)
    # the reset-free tasks: those with the naive reset-free baseline of MoReFree-SAC
    tasks = {env for env, variants in config_sections(ZOO_CONFIGS / "sac.yml").items() if "naive" in variants}
    assert {("r3l", task) for task in tasks} <= names and len(tasks) == 8
    assert {("medal", "GCRL/PointUMazeGoal-v0"), ("medal", "GCRL/Tabletop-v0")} <= names


@pytest.mark.parametrize(("algo", "env_id"), BASELINE_CONFIGS, ids=lambda p: str(p))
def test_config_keys_are_constructor_arguments(algo: str, env_id: str):
    import inspect

    section = resolve_config(algo, env_id).hyperparams
    cls = MEDAL if algo == "medal" else R3L
    accepted = set(inspect.signature(cls).parameters)
    for base in (BackwardRewardSAC, ForwardBackwardSAC):  # the reward model's and SAC's arguments
        accepted |= set(inspect.signature(base).parameters)
    assert set(section) - ZOO_KEYS <= accepted
    assert "sb3_gcrl.reset_free_baselines.ForwardBackwardWrapper" in section["env_wrapper"]
    if cls is MEDAL:
        load_demos(section["demos"], gym.make(env_id).observation_space, gym.make(env_id).action_space)


@pytest.mark.parametrize(("name", "env_id"), [("medal", "GCRL/PointUMazeGoal-v0"), ("r3l", "GCRL/Tabletop-v0")])
def test_config_builds_and_trains_briefly(name: str, env_id: str):
    from rl_zoo3.utils import get_wrapper_class

    section = resolve_config(name, env_id).hyperparams
    env = make_vec_env(env_id, n_envs=1, seed=0, wrapper_class=get_wrapper_class(section))
    kwargs = {k: v for k, v in section.items() if k not in ZOO_KEYS | {"policy_kwargs"}}
    kwargs.update(learning_starts=20, batch_size=16, buffer_size=5_000, reward_model_batch_size=32)
    cls = MEDAL if name == "medal" else R3L
    model = cls(section["policy"], env, policy_kwargs={"net_arch": [16]}, seed=0, **kwargs)
    model.learn(320, callback=ResetFreeCallback(), log_interval=None)  # the first backward phase starts at step 300
    assert model.num_timesteps == 320 and model.backward_buffer.n_visited() == 20
