"""EMAC (Kuznetsov & Filchenkov, 2021): memory estimate, critic loss, episode-end memory writes, save/load, errors."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from gymnasium.wrappers import TimeLimit
from stable_baselines3 import HerReplayBuffer
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize
from torch.nn import functional as F

import sb3_gcrl
from sb3_gcrl import EMAC
from sb3_gcrl.emac import EMACMemory
from sb3_gcrl.memory.serialization import MemoryRestoreError

TINY = {"net_arch": [8]}
GAMMA = 0.9


class CountingEnv(gym.Env):
    """Observation ``[t]``, reward ``t + 1`` at step ``t``; terminates after ``length`` steps."""

    def __init__(self, length: int = 3) -> None:
        self.observation_space = spaces.Box(-100.0, 100.0, (1,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.length = length
        self.t = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.t = 0
        return np.array([0.0], dtype=np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        reward = float(self.t + 1)
        self.t += 1
        return np.array([self.t], dtype=np.float32), reward, self.t >= self.length, False, {}


def counting_model(env_fn: Any, **kwargs: Any) -> EMAC:
    defaults: dict[str, Any] = dict(
        gamma=GAMMA, projection_dim=None, learning_starts=10_000, policy_kwargs=TINY, seed=0, buffer_size=100
    )
    return EMAC("MlpPolicy", DummyVecEnv([env_fn]), **{**defaults, **kwargs})


# ------------------------------------------------------------------------------------------------ memory estimate
def test_memory_estimate_is_the_weighted_mean_of_the_k_nearest_returns():
    memory = EMACMemory(key_dim=2, capacity=10, n_neighbors=2)
    memory.add_episode(np.array([[0.0, 0.0], [1.0, 0.0], [10.0, 0.0]]), np.array([1.0, 3.0, 100.0]))
    query = np.array([[0.25, 0.0]], dtype=np.float32)
    w_near, w_far = np.exp(-0.25), np.exp(-0.75)  # softmin of the distances 0.25 and 0.75
    expected = (w_near * 1.0 + w_far * 3.0) / (w_near + w_far)
    np.testing.assert_allclose(memory.estimate(query), [expected], rtol=1e-6)

    uniform = EMACMemory(key_dim=2, capacity=10, n_neighbors=2, neighbour_weighting="uniform")
    uniform.load_state_dict(memory.state_dict())
    np.testing.assert_allclose(uniform.estimate(query), [2.0])
    # fewer rows than k: the rows there are
    single = EMACMemory(key_dim=2, capacity=10, n_neighbors=5)
    single.add_episode(np.array([[3.0, 3.0]]), np.array([7.0]))
    np.testing.assert_allclose(single.estimate(query), [7.0])


def test_memory_overwrites_its_oldest_rows_when_full():
    memory = EMACMemory(key_dim=1, capacity=3, n_neighbors=1)
    assert memory.add_episode(np.array([[0.0], [1.0], [2.0]]), np.array([0.0, 1.0, 2.0])) == 0
    assert memory.add_episode(np.array([[5.0], [6.0]]), np.array([5.0, 6.0])) == 2
    assert len(memory) == 3
    assert sorted(memory.values[:3]) == [2.0, 5.0, 6.0]
    np.testing.assert_allclose(memory.estimate(np.array([[0.0]], dtype=np.float32)), [2.0])


# ------------------------------------------------------------------------------------------------ critic loss
def test_critic_loss_and_update_match_a_hand_computation():
    alpha = 0.25
    model = EMAC(
        "MlpPolicy",
        "Pendulum-v1",
        alpha=alpha,
        n_neighbors=2,
        projection_dim=None,  # keys are the raw (observation, action): neighbours known by construction
        gamma=GAMMA,
        batch_size=4,
        learning_starts=0,
        policy_kwargs=TINY,
        seed=0,
    )
    obs = np.array([[1.0, 0.0, 0.5]], dtype=np.float32)
    action = np.array([[0.5]], dtype=np.float32)
    next_obs = np.array([[0.0, 1.0, -0.5]], dtype=np.float32)
    reward, done = 2.0, False
    # memory rows at distances 0.1 and 0.3 from the (obs, action) key, and a far one that must not count
    key = np.concatenate([obs, action], axis=1)
    keys = np.concatenate([key + [[0.1, 0, 0, 0]], key + [[0, 0.3, 0, 0]], key + [[5, 5, 5, 5]]])
    model.policy.memory.add_episode(keys, np.array([4.0, 10.0, -50.0]))
    w1, w2 = np.exp(-0.1), np.exp(-0.3)
    q_memory = (4.0 * w1 + 10.0 * w2) / (w1 + w2)
    # a replay buffer holding only this transition: every sample of the batch is it
    model.replay_buffer.add(obs, next_obs, action, np.array([reward]), np.array([done]), [{}])

    obs_t, action_t, next_t = (th.as_tensor(x) for x in (obs, action, next_obs))
    with th.no_grad():
        q_next = model.critic_target(next_t, model.actor_target(next_t))[0].item()
    y = reward + GAMMA * (1 - done) * q_next
    estimate = model.policy.memory_estimate(obs_t, action_t)
    assert estimate is not None
    np.testing.assert_allclose(estimate.numpy(), [[q_memory]], rtol=1e-5)

    critic = copy.deepcopy(model.critic)
    q = critic(obs_t, action_t)[0]
    hand_loss = (1 - alpha) * (q.item() - y) ** 2 + alpha * (q.item() - q_memory) ** 2
    loss = model.critic_loss([q], th.tensor([[y]]), th.tensor([[q_memory]]))
    assert loss.item() == pytest.approx(hand_loss, rel=1e-5)

    # one gradient step of train() equals one optimizer step on the hand loss
    assert not model.critic.optimizer.state  # fresh: a new optimizer with the same settings is its twin
    optimizer = type(model.critic.optimizer)(critic.parameters(), **model.critic.optimizer.defaults)
    expected_loss = (1 - alpha) * F.mse_loss(q, th.tensor([[y]])) + alpha * F.mse_loss(q, th.tensor([[q_memory]]))
    optimizer.zero_grad()
    expected_loss.backward()
    optimizer.step()
    model.set_logger(configure(None, []))
    model.train(gradient_steps=1, batch_size=4)
    for got, want in zip(model.critic.parameters(), critic.parameters()):
        th.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)


def test_critic_loss_without_memory_is_the_td_loss():
    model = EMAC("MlpPolicy", "Pendulum-v1", alpha=0.5, policy_kwargs=TINY, seed=0)
    q, y = th.tensor([[1.0]]), th.tensor([[3.0]])
    assert model.critic_loss([q], y, None).item() == pytest.approx(4.0)
    assert model.critic_loss([q], y, th.tensor([[2.0]])).item() == pytest.approx(0.5 * 4.0 + 0.5 * 1.0)
    assert model.policy.memory_estimate(th.zeros(2, 3), th.zeros(2, 1)) is None


# ------------------------------------------------------------------------------------------------ memory writes
def test_finished_episodes_write_their_discounted_returns():
    model = counting_model(lambda: CountingEnv(length=3))
    model.learn(3)  # exactly one episode
    memory = model.policy.memory
    assert len(memory) == 3
    expected = [1 + GAMMA * 2 + GAMMA**2 * 3, 2 + GAMMA * 3, 3.0]
    np.testing.assert_allclose(memory.values[:3], expected)
    # keys: (observation t, the action as the critic sees it, scaled to [-1, 1])
    actions = model.replay_buffer.actions[:3, 0]
    observations = model.replay_buffer.observations[:3, 0]
    np.testing.assert_allclose(memory.index.keys[:3], np.concatenate([observations, actions], axis=1))
    model.learn(2, reset_num_timesteps=False)  # a running episode is not written
    assert len(memory) == 3


def test_truncated_episodes_write_the_returns_seen_unless_disabled():
    def truncated() -> gym.Env:
        return TimeLimit(CountingEnv(length=100), max_episode_steps=2)

    model = counting_model(truncated)
    model.learn(2)
    np.testing.assert_allclose(model.policy.memory.values[:2], [1 + GAMMA * 2, 2.0])
    model = counting_model(truncated, memory_update_truncated=False)
    model.learn(4)
    assert len(model.policy.memory) == 0
    model = counting_model(lambda: TimeLimit(CountingEnv(length=2), max_episode_steps=5), memory_update_truncated=False)
    model.learn(2)  # terminated episodes are still written
    assert len(model.policy.memory) == 2


def test_several_envs_write_each_episode_separately():
    model = EMAC(
        "MlpPolicy",
        DummyVecEnv([lambda: CountingEnv(length=2), lambda: CountingEnv(length=3)]),
        gamma=GAMMA,
        projection_dim=None,
        learning_starts=10_000,
        policy_kwargs=TINY,
        seed=0,
    )
    model.learn(6)  # three steps of both envs: env 0 ends an episode of 2 (a second runs), env 1 one of 3
    assert sorted(model.policy.memory.values[: len(model.policy.memory)]) == pytest.approx(
        sorted([1 + GAMMA * 2, 2.0] + [1 + GAMMA * 2 + GAMMA**2 * 3, 2 + GAMMA * 3, 3.0])
    )


# ------------------------------------------------------------------------------------------------ save / load
def test_save_load_restores_the_memory_and_the_actions(tmp_path: Path):
    model = EMAC(
        "MlpPolicy",
        "Pendulum-v1",
        learning_starts=50,
        batch_size=16,
        buffer_size=1_000,
        train_freq=4,
        policy_kwargs=TINY,
        seed=0,
    )
    model.learn(450)
    observations = np.random.default_rng(0).uniform(-1, 1, (10, 3)).astype(np.float32)
    actions = np.random.default_rng(1).uniform(-1, 1, (10, 1)).astype(np.float32)
    expected_actions, _ = model.predict(observations, deterministic=True)
    expected_estimate = model.policy.memory.estimate(model.policy.memory_keys(observations, actions))
    model.save(tmp_path / "emac.zip")

    loaded = EMAC.load(tmp_path / "emac.zip")
    saved, restored = model.policy.memory.state_dict(), loaded.policy.memory.state_dict()
    assert len(loaded.policy.memory) == len(model.policy.memory) == 400  # two 200-step episodes
    for name in saved:
        np.testing.assert_array_equal(restored[name], saved[name])
    np.testing.assert_array_equal(
        loaded.policy.memory_embedding.get_state()["projection"],
        model.policy.memory_embedding.get_state()["projection"],
    )
    np.testing.assert_array_equal(loaded.predict(observations, deterministic=True)[0], expected_actions)
    # same rows and neighbours; the distances may differ in the last bits (KD-tree rebuilt vs tree + written delta)
    np.testing.assert_allclose(
        loaded.policy.memory.estimate(loaded.policy.memory_keys(observations, actions)), expected_estimate, rtol=1e-6
    )
    assert loaded.alpha == model.alpha and loaded.n_neighbors == model.n_neighbors


def test_a_corrupted_saved_memory_fails_with_what_is_wrong():
    model = EMAC("MlpPolicy", "Pendulum-v1", policy_kwargs=TINY, seed=0)
    model.policy.memory.add_episode(np.zeros((2, 4)), np.array([1.0, 2.0]))
    state = model.policy.state_dict()
    state["_extra_state"]["memory/values"] = th.tensor([1.0])
    with pytest.raises(MemoryRestoreError, match="values"):
        model.policy.load_state_dict(state)


# ------------------------------------------------------------------------------------------------ learning
@pytest.mark.slow  # 2,000 steps, 800 gradient steps: 30 s on a loaded 2-core machine
def test_learns_growing_tree():
    env = make_vec_env("GCRL/GrowingTree-v0", n_envs=1, seed=0)
    model = EMAC(
        "MlpPolicy",
        env,
        learning_starts=400,
        batch_size=64,
        train_freq=4,
        gradient_steps=2,
        policy_kwargs={"net_arch": [32, 32]},
        seed=0,
    )
    model.learn(2_000)
    assert len(model.policy.memory) > 0
    eval_env = gym.make("GCRL/GrowingTree-v0")
    successes = 0
    for episode in range(5):
        obs, _ = eval_env.reset(seed=100 + episode)
        done = False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, info = eval_env.step(action)
            done = terminated or truncated
        successes += bool(reward > 0)
    assert successes >= 3


# ------------------------------------------------------------------------------------------------ errors
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"alpha": 1.5}, "alpha must be <= 1"),
        ({"alpha": -0.1}, "alpha must be >= 0"),
        ({"n_neighbors": 0}, "n_neighbors"),
        ({"n_neighbors": 1.5}, "n_neighbors"),
        ({"projection_dim": 0}, "projection_dim"),
        ({"memory_capacity": 0}, "memory_capacity"),
        ({"neighbour_weighting": "max"}, "neighbour_weighting"),
        ({"knn_backend": "annoy"}, "knn_backend"),
        ({"policy_kwargs": {"n_neighbors": 3}}, "pass n_neighbors to EMAC itself"),
        ({"replay_buffer_class": HerReplayBuffer}, "HerReplayBuffer"),
        ({"policy_delay": 0}, "policy_delay must be >= 1"),  # TD3 would divide by it at the first update
        ({"target_noise_clip": -1.0}, "target_noise_clip must be >= 0"),
    ],
)
def test_bad_settings_fail_at_construction(kwargs: dict[str, Any], match: str):
    with pytest.raises(ValueError, match=match):
        EMAC("MlpPolicy", "Pendulum-v1", **kwargs)


def test_discrete_actions_are_refused_with_the_alternative():
    with pytest.raises(ValueError, match="Box.*TwoMemoryDQN"):
        EMAC("MlpPolicy", "CartPole-v1")


def test_reward_normalization_is_refused_at_learn():
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=1), norm_reward=True)
    model = EMAC("MlpPolicy", env, policy_kwargs=TINY)
    with pytest.raises(ValueError, match="norm_reward=False"):
        model.learn(10)


def test_memory_refuses_non_finite_returns_and_empty_estimates():
    memory = EMACMemory(key_dim=1, capacity=4)
    with pytest.raises(RuntimeError, match="empty"):
        memory.estimate(np.zeros((1, 1), dtype=np.float32))
    with pytest.raises(ValueError, match="finite"):
        memory.add_episode(np.zeros((2, 1)), np.array([1.0, np.nan]))
    assert len(memory) == 0


def test_exported_and_registered():
    from sb3_gcrl.algorithms import load_algorithm

    assert sb3_gcrl.EMAC is EMAC and load_algorithm("emac") is EMAC
