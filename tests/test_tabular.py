"""Tabular Q-learning, tabular episodic control and tabular 2M (thesis Sec. 5.5.1)."""

from __future__ import annotations

from functools import partial
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml
from envs import ChainEnv as Chain
from stable_baselines3.common.env_util import make_vec_env

import sb3_gcrl  # noqa: F401  (registers GCRL/WindyGrid-v0)
from sb3_gcrl.memory.episode import discounted_returns
from sb3_gcrl.memory.mfec_memory import argmax_random_ties
from sb3_gcrl.tabular import (
    TabularEpisodicControl,
    TabularQLearning,
    TabularTwoMemory,
    q_learning_update,
)
from sb3_gcrl.tabular.policies import TabularECPolicy
from sb3_gcrl.two_memory import EPISODIC, PARAMETRIC, SourceTaggedReplayBuffer

WINDY = "GCRL/WindyGrid-v0"


def windy() -> gym.Env:
    return gym.make(WINDY)


#: states 0..4, start 0; action 1 moves right, 0 stays; reward -1 per step; terminal at 4 (deterministic)
ChainEnv = partial(Chain, n=5, stay_on_zero=True, step_reward=-1.0, goal_reward=0.0)


def test_q_learning_update_matches_hand_computation():
    q = np.zeros((3, 2))
    q[1] = [2.0, 4.0]
    states, actions = np.array([0, 0, 1]), np.array([1, 1, 0])
    rewards, next_states, dones = np.array([1.0, 1.0, -1.0]), np.array([1, 1, 2]), np.array([0.0, 0.0, 1.0])
    td = q_learning_update(q, states, actions, rewards, next_states, dones, learning_rate=0.5, gamma=0.9)
    # (0, 1): target 1 + 0.9 * 4 = 4.6, TD 4.6 twice (batched from the same table) -> Q = 0 + 0.5 * 9.2
    np.testing.assert_allclose(td, [4.6, 4.6, -3.0])
    assert q[0, 1] == pytest.approx(4.6)
    # (1, 0): terminal, target -1, TD -1 - 2 = -3 -> 2 + 0.5 * -3
    assert q[1, 0] == pytest.approx(0.5)
    assert q[1, 1] == 4.0 and q[2].sum() == 0.0


def test_ec_update_is_max_of_returns_eq_5_2():
    policy = TabularECPolicy(gym.spaces.Discrete(3), gym.spaces.Discrete(2), unseen_value=0.0)
    policy.update_episode(np.array([0, 1]), np.array([1, 0]), np.array([-5.0, -2.0]))
    policy.update_episode(np.array([0, 1]), np.array([1, 0]), np.array([-7.0, -1.0]))
    assert policy.ec_table[0, 1] == -5.0  # max(-5, -7): the better return is kept
    assert policy.ec_table[1, 0] == -1.0
    np.testing.assert_allclose(policy.q_values(np.array([0])), [[0.0, -5.0]])  # unseen -> unseen_value


def test_discounted_returns():
    np.testing.assert_allclose(discounted_returns(np.array([1.0, 0.0, 2.0]), 0.5), [1.5, 1.0, 2.0])


def test_greedy_tie_breaking():
    values = np.zeros((2000, 3))
    assert (argmax_random_ties(values, None) == 0).all()  # deterministic: the first maximum
    counts = np.bincount(argmax_random_ties(values, np.random.default_rng(0)), minlength=3)
    assert counts.min() > 500  # uniform over the tied actions


def test_episodic_control_learns_chain_exactly():
    model = TabularEpisodicControl(env=ChainEnv(), gamma=1.0, exploration_initial_eps=0.5, exploration_final_eps=0.5)
    model.learn(2000)
    # the best return after moving right from state s is -(4 - s)
    np.testing.assert_allclose(model.ec_table[np.arange(4), 1], [-4.0, -3.0, -2.0, -1.0])
    assert (model.predict(np.arange(4), deterministic=True)[0] == 1).all()


@pytest.mark.parametrize("update_truncated", [False, True])
def test_episodic_control_skips_truncated_episodes(update_truncated):
    # the goal (4 steps away) is never reached within 3 steps: every episode is cut by the time limit
    env = gym.wrappers.TimeLimit(ChainEnv(), max_episode_steps=3)
    model = TabularEpisodicControl(env=env, ec_update_truncated=update_truncated, seed=0)
    model.learn(60)
    assert np.isfinite(model.ec_table).any() == update_truncated


def test_q_learning_learns_chain():
    model = TabularQLearning(env=ChainEnv(), gamma=0.9, learning_rate=0.5, train_freq=1, batch_size=8, seed=0)
    model.learn(1500)
    assert (model.predict(np.arange(4), deterministic=True)[0] == 1).all()
    expected = -(1 - 0.9 ** np.arange(4, 0, -1)) / (1 - 0.9)  # V*(s) = -sum_{k<4-s} 0.9^k
    np.testing.assert_allclose(model.q_table[np.arange(4), 1], expected, atol=1e-3)


def test_two_memory_routes_actions_to_the_acting_memory():
    """With epsilon 0, an EC-run episode acts greedily on the EC table, an RL-run one on the Q-table."""
    for p_ec, expected_action in ((1.0, 1), (0.0, 0)):
        model = TabularTwoMemory(
            env=ChainEnv(), p_ec_schedule=p_ec, exploration_initial_eps=0.0, exploration_final_eps=0.0,
            learning_starts=10_000, train_freq=10_000, seed=0,
        )  # fmt: skip
        model.policy.ec_policy.ec_table[:, 1] = 10.0  # EC prefers "right"
        model.policy.q_policy.q_table[:, 0] = 10.0  # RL prefers "stay"
        model.learning_starts = 0
        model.learn(20)
        stored_actions = model.replay_buffer.actions[: model.replay_buffer.pos, 0, 0]
        assert (stored_actions == expected_action).all()


@pytest.mark.parametrize("data_sharing", [True, False])
def test_two_memory_data_sharing_routing(data_sharing):
    # only RL runs episodes: with sharing the EC table still learns from them, without it stays empty
    model = TabularTwoMemory(env=ChainEnv(), p_ec_schedule=0.0, data_sharing=data_sharing, seed=0, train_freq=1)
    model.learn(200)
    assert model.policy.episode_counts[EPISODIC] == 0 and model.policy.episode_counts[PARAMETRIC] > 0
    assert np.isfinite(model.ec_table).any() == data_sharing
    # only EC runs episodes: with sharing the Q-table trains on EC data, without it never trains
    model = TabularTwoMemory(env=ChainEnv(), p_ec_schedule=1.0, data_sharing=data_sharing, seed=0, train_freq=1)
    model.learn(200)
    buffer = model.replay_buffer
    assert isinstance(buffer, SourceTaggedReplayBuffer)
    assert buffer.source_fraction(EPISODIC) == 1.0
    assert (buffer.n_sampleable() > 0) == data_sharing
    assert (np.abs(model.q_table).sum() > 0) == data_sharing


def test_two_memory_evaluation_memory_eq_5_6():
    model = TabularTwoMemory(env=ChainEnv(), seed=0)
    model.policy.ec_policy.ec_table[:, 1] = 10.0
    model.policy.q_policy.q_table[:, 0] = 10.0
    states = np.arange(4)
    windows = model.policy.score_windows
    windows.push(EPISODIC, -4.0)
    assert (model.predict(states, deterministic=True)[0] == 1).all()  # only EC has a score
    windows.push(PARAMETRIC, -4.0)
    assert (model.predict(states, deterministic=True)[0] == 0).all()  # tie -> RL (s_rl >= s_ec)
    windows.push(EPISODIC, -2.0)
    assert (model.predict(states, deterministic=True)[0] == 1).all()  # s_ec = -3 > s_rl = -4


@pytest.mark.parametrize("cls", [TabularQLearning, TabularEpisodicControl, TabularTwoMemory])
def test_save_load_round_trip(cls, tmp_path):
    model = cls(env=windy(), seed=1)
    model.learn(800)
    model.save(tmp_path / "model.zip")
    loaded = cls.load(tmp_path / "model.zip")
    states = np.arange(70)
    np.testing.assert_array_equal(
        model.predict(states, deterministic=True)[0], loaded.predict(states, deterministic=True)[0]
    )
    for table in ("q_table", "ec_table"):
        if hasattr(model, table):
            np.testing.assert_array_equal(getattr(model, table), getattr(loaded, table))
    if cls is TabularTwoMemory:
        np.testing.assert_array_equal(model.policy.score_windows.returns, loaded.policy.score_windows.returns)
        np.testing.assert_array_equal(model.policy.score_windows.counts, loaded.policy.score_windows.counts)
        assert loaded.policy.evaluation_memory() == model.policy.evaluation_memory()


def test_two_memory_n_envs_and_windygrid():
    env = make_vec_env(windy, n_envs=3, seed=0)
    model = TabularTwoMemory(env=env, p_ec_schedule=0.5, seed=0)
    model.learn(3000)
    assert model.policy.episode_counts.min() > 0
    assert model.replay_buffer.sources.shape[1] == 3


def test_clear_errors():
    with pytest.raises(ValueError, match="Discrete observation space"):
        TabularQLearning(env="CartPole-v1")
    with pytest.raises(ValueError, match="decayed p_ec schedule needs start >= end"):
        TabularTwoMemory(env=windy(), p_ec_schedule={"type": "decayed", "start": 0.1, "end": 0.9, "decay": 10})
    with pytest.raises(ValueError, match="exploration_initial_eps"):
        TabularQLearning(env=windy(), exploration_initial_eps=1.5)
    with pytest.raises(ValueError, match="gamma"):
        TabularEpisodicControl(env=windy(), gamma=2.0)
    # a NaN start value would read as an unvisited entry forever
    with pytest.raises(ValueError, match="initial_value must be a finite number"):
        TabularQLearning(env=windy(), policy_kwargs={"initial_value": float("nan")})
    with pytest.raises(ValueError, match="unseen_value must be a finite number"):
        TabularEpisodicControl(env=windy(), policy_kwargs={"unseen_value": float("inf")})


# ------------------------------------------------------------------------------------------------ reliability
ALL_TABULAR = [TabularQLearning, TabularEpisodicControl, TabularTwoMemory]


@pytest.mark.parametrize("cls", ALL_TABULAR)
@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(learning_rate=1.5), "learning_rate"),
        (dict(learning_rate=0.0), "learning_rate"),
        (dict(learning_rate=lambda progress_remaining: 2.0), "learning_rate"),
        (dict(learning_rate="fast"), "learning_rate"),
        (dict(gamma=1.2), "gamma"),
        (dict(gamma=float("nan")), "gamma"),
        (dict(exploration_final_eps=-0.1), "exploration_final_eps"),
        (dict(exploration_fraction=2.0), "exploration_fraction"),
        (dict(batch_size=0), "batch_size"),
        (dict(learning_starts=-1), "learning_starts"),
    ],
)
def test_hyperparameters_are_validated_at_construction(cls, kwargs, name):
    with pytest.raises(ValueError, match=f"^{name}"):
        cls(env=windy(), **kwargs)


def test_a_valid_learning_rate_schedule_is_accepted():
    model = TabularQLearning(env=windy(), learning_rate=lambda progress_remaining: 0.1 * progress_remaining + 0.01)
    model.learn(100)


def test_no_sharing_ec_learns_from_its_own_episodes():
    # 2Mw/oDS on WindyGrid with the zoo config: EC learns only from the episodes it runs. Most early episodes are
    # cut by the 100-step limit; if cut episodes wrote nothing, EC's optimistic unvisited entries would never be
    # used up and EC would keep random-walking (seed 2: 5 EC updates in 30k steps).
    with open(Path(__file__).parents[1] / "zoo_configs" / "tabular_2m.yml") as file:
        config = dict(yaml.safe_load(file)[f"{WINDY}@no_sharing"])  # the variant 2Mw/oDS
    for key in ("n_timesteps", "policy"):
        config.pop(key)
    assert config["data_sharing"] is False
    model = TabularTwoMemory(env=windy(), seed=2, **config)
    policy = model.policy
    written = []
    update = policy.update_episodic_memory
    policy.update_episodic_memory = lambda *args: (written.append(len(args[0])), update(*args))[1]
    model.learn(3_000)
    ec_episodes = int(policy.episode_counts[EPISODIC])
    assert ec_episodes >= 10
    assert len(written) == ec_episodes  # every EC-run episode, cut or not, updates the table (and only those)
    assert np.isfinite(model.ec_table).sum() > 100


@pytest.mark.parametrize("cls", ALL_TABULAR)
def test_tensorboard_run_is_named_after_the_class(cls, tmp_path):
    model = cls(env=windy(), tensorboard_log=str(tmp_path))
    model.learn(20)
    assert [p.name for p in tmp_path.iterdir()] == [f"{cls.__name__}_1"]


# ------------------------------------------------------------------------------------------------ seeding
def _two_memory_run(seed: int) -> tuple[np.ndarray, ...]:
    """Memories drawn, Q-table and EC table of a short seeded TabularTwoMemory run on two WindyGrid envs."""
    model = TabularTwoMemory(env=make_vec_env(windy, n_envs=2, seed=seed), p_ec_schedule=0.5, seed=seed, train_freq=1)
    draws = []
    assign = model.policy.assign_memories
    model.policy.assign_memories = lambda p_ec, rng: (draws.append(assign(p_ec, rng).copy()), draws[-1])[1]
    model.learn(1_500)
    return np.concatenate(draws), model.q_table.copy(), model.ec_table.copy()


def test_two_memory_runs_the_same_under_the_same_seed():
    first, again, other = _two_memory_run(0), _two_memory_run(0), _two_memory_run(1)
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    assert any(a.shape != b.shape or not np.array_equal(a, b) for a, b in zip(first, other))


def _policy_generators(model) -> list[np.random.Generator]:
    return [module.rng for module in model.policy.modules() if hasattr(module, "rng")]


@pytest.mark.parametrize("cls", ALL_TABULAR)
def test_save_load_continues_the_generators(cls, tmp_path):
    """The exploration coins, the tie-breaking and (2M) the memory draws continue after load where they stopped."""
    model = cls(env=windy(), seed=4)
    model.learn(300)
    model.save(tmp_path / "model.zip")
    loaded = cls.load(tmp_path / "model.zip")
    assert loaded._rng.bit_generator.state == model._rng.bit_generator.state
    saved_policy, loaded_policy = _policy_generators(model), _policy_generators(loaded)
    assert saved_policy and [g.bit_generator.state for g in saved_policy] == [
        g.bit_generator.state for g in loaded_policy
    ]
    if cls is TabularTwoMemory:
        assert loaded.dispatcher.rng.bit_generator.state == model.dispatcher.rng.bit_generator.state
    states = np.arange(70)
    np.testing.assert_array_equal(loaded.predict(states)[0], model.predict(states)[0])  # the same random tie-breaks
