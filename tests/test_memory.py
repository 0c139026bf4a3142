"""Episodic memory backend: exact kNN, LRU order, embeddings, CEC (Eq. 4.3-4.5) and MFEC (Eq. 5.2) rules."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from scipy import stats
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_gcrl import CEC, MFEC
from sb3_gcrl.memory import (
    CECMemory,
    EpisodeBuffers,
    KeyEmbedding,
    KNNIndex,
    MFECMemory,
    MFECTable,
    RecencyOrder,
    discounted_returns,
)


def brute_force(reference: np.ndarray, queries: np.ndarray, k: int) -> np.ndarray:
    dist = np.sqrt(((queries[:, None, :].astype(np.float64) - reference[None]) ** 2).sum(-1))
    return np.sort(dist, axis=1)[:, :k]


# ---------------------------------------------------------------- KNNIndex
@pytest.mark.parametrize("backend", ["kdtree", "flat"])
@pytest.mark.parametrize("dim", [1, 3, 8])
def test_knn_exact_under_adds_and_overwrites(backend, dim):
    rng = np.random.default_rng(dim)
    capacity = 400
    index = KNNIndex(dim, capacity, backend=backend, rebuild_threshold=25)
    reference = np.zeros((capacity, dim), dtype=np.float32)
    for step in range(1200):
        key = rng.standard_normal(dim).astype(np.float32)
        if index.size < capacity and rng.random() < 0.6:
            reference[index.add(key)] = key
        elif index.size:
            row = int(rng.integers(index.size))
            index.set_key(row, key)
            reference[row] = key
        if step % 5 == 0:
            queries = rng.standard_normal((4, dim)).astype(np.float32)
            dist, rows = index.search(queries, 5)
            n = index.size
            expected = brute_force(reference[:n], queries, 5)
            kk = min(5, n)
            np.testing.assert_allclose(dist[:, :kk], expected[:, :kk], rtol=1e-5, atol=1e-5)
            # the returned rows really are at the returned distances
            recomputed = np.linalg.norm(reference[rows[:, :kk]] - queries[:, None, :], axis=-1)
            np.testing.assert_allclose(recomputed, dist[:, :kk], rtol=1e-5, atol=1e-5)
            # one query at a time (the per-env-step path) gives the batch's answer
            for i in range(len(queries)):
                dist_one, rows_one = index.search(queries[i : i + 1], 5)
                np.testing.assert_allclose(dist_one, dist[i : i + 1], rtol=1e-6)
                np.testing.assert_array_equal(rows_one, rows[i : i + 1])
    if backend == "kdtree":
        assert index.n_rebuilds > 1  # lazily rebuilt, not per write


def test_knn_pads_when_fewer_rows_than_k_and_validates_input():
    index = KNNIndex(2, 10)
    dist, rows = index.search(np.zeros((1, 2), np.float32), 3)
    assert np.all(np.isinf(dist)) and np.all(rows == -1)
    index.add(np.array([1.0, 0.0], np.float32))
    dist, rows = index.search(np.zeros((2, 2), np.float32), 3)
    np.testing.assert_allclose(dist[:, 0], 1.0)
    assert (rows[:, 0] == 0).all() and (rows[:, 1:] == -1).all() and np.isinf(dist[:, 1:]).all()
    with pytest.raises(ValueError, match=r"shape \(n, 2\)"):
        index.search(np.zeros((1, 3), np.float32), 1)
    with pytest.raises(ValueError, match="backend"):
        KNNIndex(2, 10, backend="annoy")  # type: ignore[arg-type]
    full = KNNIndex(1, 1)
    full.add(np.zeros(1, np.float32))
    with pytest.raises(RuntimeError, match="set_key"):
        full.add(np.zeros(1, np.float32))


# ---------------------------------------------------------------- RecencyOrder
def test_recency_order_touch_evict_and_restore():
    order = RecencyOrder(4)
    for row in (0, 1, 2, 3):
        order.touch(row)
    assert order.oldest() == 0
    order.touch(0)  # 0 becomes the most recent
    assert order.oldest() == 1
    order.touch(2)
    order.touch(1)
    assert order.oldest() == 3
    restored = RecencyOrder(4)
    restored.rebuild_from_timestamps(order.last_update[:4].copy(), order.clock)
    for expected in (3, 0, 2, 1):
        assert restored.oldest() == expected == order.oldest()
        restored.touch(expected)
        order.touch(expected)


# ---------------------------------------------------------------- CEC update rule (Eq. 4.3 / 4.4)
def make_cec(capacity=3, **kwargs):
    params = dict(distance_threshold=0.5, filter_factor=1.0, n_neighbors=3, temperature=1.0)
    params.update(kwargs)
    return CECMemory(key_dim=1, action_dim=1, capacity=capacity, **params)


def test_cec_update_add_replace_refresh_evict():
    memory = make_cec()
    # one episode of three far-apart states, processed from the end (Algorithm 1)
    counts = memory.update_episode(np.array([[0.0], [1.0], [2.0]]), np.array([[0.1], [0.2], [0.3]]), [3.0, 2.0, 1.0])
    assert counts == {"added": 3, "evicted": 0, "replaced": 0, "refreshed": 0}
    np.testing.assert_allclose(memory.keys[:, 0], [2.0, 1.0, 0.0])  # rows 0,1,2 hold s=2,1,0
    # within d of s=0 (row 2) and higher value -> replace the row by (s, a, v)
    assert memory.update(np.array([0.2], np.float32), np.array([0.9], np.float32), 5.0) == "replaced"
    assert memory.keys[2, 0] == pytest.approx(0.2) and memory.actions[2, 0] == pytest.approx(0.9)
    assert memory.values[2] == 5.0
    # within d of s=1 (row 1) but lower value -> row kept, only its update time refreshed
    assert memory.update(np.array([1.1], np.float32), np.array([-0.5], np.float32), 0.0) == "refreshed"
    assert memory.keys[1, 0] == 1.0 and memory.actions[1, 0] == pytest.approx(0.2) and memory.values[1] == 2.0
    # update times: row 0 (s=2) is now the least recently updated -> a far state evicts it (Eq. 4.4)
    assert memory.update(np.array([10.0], np.float32), np.array([0.7], np.float32), 0.5) == "evicted"
    assert len(memory) == 3
    np.testing.assert_allclose(np.sort(memory.keys[:, 0]), [0.2, 1.0, 10.0])
    assert memory.values[0] == 0.5 and memory.actions[0, 0] == pytest.approx(0.7)
    # the next eviction takes the oldest remaining row: row 2 (replaced before row 1 was refreshed)
    memory.update(np.array([-10.0], np.float32), np.zeros(1, np.float32), 0.0)
    np.testing.assert_allclose(np.sort(memory.keys[:, 0]), [-10.0, 1.0, 10.0])


def test_cec_update_sees_rows_written_earlier_in_the_same_episode():
    memory = make_cec(capacity=10)
    # s=0.1 (processed first, value 1) then s=0.0 (value 2) lies within d of it -> replace, not add
    counts = memory.update_episode(np.array([[0.0], [0.1]]), np.array([[0.5], [0.6]]), [2.0, 1.0])
    assert counts["added"] == 1 and counts["replaced"] == 1 and len(memory) == 1
    assert memory.keys[0, 0] == 0.0 and memory.values[0] == 2.0


def test_cec_selection_distribution_matches_eq_4_5():
    memory = make_cec(capacity=10, n_neighbors=4, temperature=0.5, distance_threshold=0.05, filter_factor=20.0)
    # three rows within n*d = 1 of the query, one outside it
    keys = np.array([[0.1], [0.3], [-0.4], [1.5]])
    actions = np.array([[-1.0], [0.0], [1.0], [0.5]])
    values = np.array([0.0, 1.0, 0.5, 100.0])
    for key, action, value in zip(keys, actions, values):
        memory.update(key.astype(np.float32), action.astype(np.float32), value)
    query = np.zeros((20_000, 1), np.float32)
    chosen, found = memory.select_actions(query, np.random.default_rng(0))
    assert found.all()
    counts = np.array([(chosen[:, 0] == a).sum() for a in (-1.0, 0.0, 1.0, 0.5)])
    assert counts[3] == 0  # the row outside n*d never votes, whatever its value
    expected = np.exp(values[:3] / 0.5) / np.exp(values[:3] / 0.5).sum()
    assert stats.chisquare(counts[:3], expected * len(query)).pvalue > 1e-3


def test_cec_softmax_is_numerically_safe_and_no_neighbour_is_reported():
    memory = make_cec(capacity=10, temperature=1e-3)
    memory.update(np.zeros(1, np.float32), np.ones(1, np.float32), 1e6)
    memory.update(np.ones(1, np.float32), -np.ones(1, np.float32), 1e6 - 1)
    rows, probs = memory.selection_probabilities(np.array([[0.0], [0.45], [3.0]], np.float32))
    assert np.isfinite(probs).all()
    np.testing.assert_allclose(probs[0].sum(), 1.0)
    assert probs[2].sum() == 0  # nothing within n * d
    actions, found = memory.select_actions(np.array([[0.0], [3.0]], np.float32), np.random.default_rng(0))
    assert found.tolist() == [True, False] and actions[0, 0] == 1.0


def test_cec_greedy_takes_nearest_row_without_threshold():
    memory = make_cec(capacity=10)
    memory.update(np.array([0.0], np.float32), np.array([0.3], np.float32), 0.0)
    memory.update(np.array([2.0], np.float32), np.array([-0.3], np.float32), 10.0)
    actions, found = memory.greedy_actions(np.array([[0.4], [50.0]], np.float32))
    assert found.all()
    np.testing.assert_allclose(actions[:, 0], [0.3, -0.3])


def test_cec_memory_state_dict_round_trip_and_errors():
    memory = make_cec(capacity=50, distance_threshold=0.05)
    rng = np.random.default_rng(0)
    memory.update_episode(rng.uniform(-1, 1, (40, 1)), rng.uniform(-1, 1, (40, 1)), rng.random(40))
    state = memory.state_dict()
    assert len(state["keys"]) == len(memory)  # used rows only
    restored = make_cec(capacity=50, distance_threshold=0.05)
    restored.load_state_dict(state)
    queries = rng.uniform(-1, 1, (30, 1)).astype(np.float32)
    np.testing.assert_array_equal(memory.greedy_actions(queries)[0], restored.greedy_actions(queries)[0])
    np.testing.assert_array_equal(
        memory.select_actions(queries, np.random.default_rng(1))[0],
        restored.select_actions(queries, np.random.default_rng(1))[0],
    )
    assert memory.recency.oldest() == restored.recency.oldest()
    with pytest.raises(ValueError, match="capacity"):
        make_cec(capacity=5).load_state_dict(state)
    for bad, match in (
        (dict(distance_threshold=0.0), "distance_threshold"),
        (dict(temperature=-1.0), "temperature"),
        (dict(n_neighbors=0), "n_neighbors"),
        (dict(filter_factor=0.0), "filter_factor"),
    ):
        with pytest.raises(ValueError, match=match):
            make_cec(**bad)


# ---------------------------------------------------------------- MFEC (Eq. 5.2)
def test_mfec_max_update_add_knn_estimate_and_untried_actions():
    memory = MFECMemory(key_dim=1, n_actions=2, capacity_per_action=10, n_neighbors=2)
    memory.update_episode(np.array([[0.0], [1.0], [2.0]]), np.array([0, 0, 0]), [1.0, 2.0, 3.0])
    table = memory.tables[0]
    assert len(table) == 3 and len(memory.tables[1]) == 0
    # exact match: max update (Eq. 5.2)
    memory.update_episode(np.array([[1.0]]), np.array([0]), [1.5])
    assert table.values[table.lookup(np.array([1.0], np.float32))] == 2.0
    memory.update_episode(np.array([[1.0]]), np.array([0]), [7.0])
    assert table.values[table.lookup(np.array([1.0], np.float32))] == 7.0
    q = memory.estimate(np.array([[1.0], [0.4], [10.0]], np.float32))
    np.testing.assert_allclose(q[:, 0], [7.0, (1.0 + 7.0) / 2, (3.0 + 7.0) / 2])  # exact, then mean of k=2 nearest
    assert np.isinf(q[:, 1]).all()  # untried action: +inf, so it is preferred
    np.testing.assert_array_equal(memory.greedy_actions(np.array([[1.0]], np.float32)), [1])


def test_mfec_eviction_is_least_recently_updated_and_state_round_trips():
    table = MFECTable(key_dim=1, capacity=2, n_neighbors=1)
    table.update(np.array([0.0], np.float32), 1.0)
    table.update(np.array([1.0], np.float32), 1.0)
    table.update(np.array([0.0], np.float32), 0.5)  # refreshes s=0 (value kept at 1.0)
    assert table.update(np.array([5.0], np.float32), 3.0)  # evicts s=1
    assert table.lookup(np.array([1.0], np.float32)) == -1
    assert table.lookup(np.array([0.0], np.float32)) >= 0
    memory = MFECMemory(key_dim=1, n_actions=2, capacity_per_action=2, n_neighbors=1)
    memory.tables[0] = table
    restored = MFECMemory(key_dim=1, n_actions=2, capacity_per_action=2, n_neighbors=1)
    restored.load_state_dict(memory.state_dict())
    q = np.array([[0.0], [4.0], [2.4]], np.float32)
    np.testing.assert_array_equal(memory.estimate(q), restored.estimate(q))
    assert restored.tables[0].recency.oldest() == table.recency.oldest()
    with pytest.raises(ValueError, match=r"actions must lie in \[0, 2\)"):
        memory.update_episode(np.zeros((1, 1)), np.array([2]), [0.0])


# ---------------------------------------------------------------- embedding, episodes
def test_random_projection_is_fixed_by_the_seed():
    space = spaces.Box(-1, 1, (20,))
    obs = np.random.default_rng(0).uniform(-1, 1, (5, 20))
    a, b, c = (KeyEmbedding(space, projection_dim=4, seed=s) for s in (3, 3, 4))
    np.testing.assert_array_equal(a(obs), b(obs))
    assert not np.allclose(a(obs), c(obs))
    assert a(obs).shape == (5, 4) and a(obs).dtype == np.float32
    np.testing.assert_allclose(a(obs), obs.astype(np.float32) @ a.projection, rtol=1e-6)
    d = KeyEmbedding(space, projection_dim=4, seed=99)
    d.set_state(a.get_state())
    np.testing.assert_array_equal(a(obs), d(obs))


def test_dict_embedding_order_and_errors():
    box = spaces.Box(-1, 1, (1,))
    space = spaces.Dict({"observation": spaces.Box(-1, 1, (2,)), "achieved_goal": box, "desired_goal": box})
    embedding = KeyEmbedding(space)
    assert embedding.observation_keys == ("observation", "desired_goal") and embedding.key_dim == 3
    obs = {"observation": np.array([[1.0, 2.0]]), "achieved_goal": np.array([[9.0]]), "desired_goal": np.array([[3.0]])}
    np.testing.assert_array_equal(embedding(obs), [[1.0, 2.0, 3.0]])
    custom = KeyEmbedding(space, observation_keys=["desired_goal", "achieved_goal"])
    np.testing.assert_array_equal(custom(obs), [[3.0, 9.0]])
    with pytest.raises(ValueError, match="not in the Dict observation space"):
        KeyEmbedding(space, observation_keys=["goal"])
    with pytest.raises(ValueError, match="NaN"):
        embedding({**obs, "observation": np.array([[np.nan, 0.0]])})
    with pytest.raises(ValueError, match="FlattenObservation"):
        KeyEmbedding(spaces.Tuple([spaces.Discrete(2)]))


def test_discounted_returns_and_episode_buffers():
    np.testing.assert_allclose(discounted_returns(np.array([0.0, 0.0, 1.0]), 0.5), [0.25, 0.5, 1.0])
    buffers = EpisodeBuffers(n_envs=2, key_shape=1, action_shape=(1,), initial_length=2)
    for t in range(5):  # grows past the initial length
        buffers.add(np.array([[t], [10 + t]]), np.array([[t], [-t]]), np.array([t, 2 * t]))
    keys, actions, rewards = buffers.pop(1)
    np.testing.assert_array_equal(keys[:, 0], [10, 11, 12, 13, 14])
    np.testing.assert_array_equal(rewards, [0, 2, 4, 6, 8])
    assert buffers.lengths.tolist() == [5, 0]


@pytest.mark.parametrize("capacity", [15, 200])
def test_cec_batched_episode_update_equals_sequential_updates(capacity):
    rng = np.random.default_rng(capacity)
    batched, sequential = make_cec(capacity, distance_threshold=0.3), make_cec(capacity, distance_threshold=0.3)
    for _ in range(6):
        # a random walk revisits its own states, so the episode overwrites rows it wrote itself
        keys = np.cumsum(rng.normal(0, 0.2, (60, 1)), axis=0).astype(np.float32)
        actions, returns = rng.uniform(-1, 1, (60, 1)).astype(np.float32), rng.random(60)
        counts = batched.update_episode(keys, actions, returns)
        outcomes = [sequential.update(keys[t], actions[t], returns[t]) for t in range(59, -1, -1)]
        assert counts == {name: outcomes.count(name) for name in counts}
        for name in ("keys", "actions", "values", "last_update"):
            np.testing.assert_array_equal(batched.state_dict()[name], sequential.state_dict()[name])


# ---------------------------------------------------------------- learn loop (EpisodicControlAlgorithm)
class _CountingEnv(gym.Env):
    """Observation ``10 * env_id + t``, reward ``t``; env 0 terminates after 3 steps, env 1 is truncated after 5."""

    def __init__(self, env_id: int, discrete: bool) -> None:
        self.observation_space = spaces.Box(0, 100, (1,), np.float32)
        self.action_space = spaces.Discrete(2) if discrete else spaces.Box(-1, 1, (1,), np.float32)
        self.env_id, self.length, self.t = env_id, 3 + 2 * env_id, 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.array([10 * self.env_id], np.float32), {}

    def step(self, action):
        self.t += 1
        end = self.t >= self.length
        obs = np.array([10 * self.env_id + self.t], np.float32)
        return obs, float(self.t), end and self.env_id == 0, end and self.env_id == 1, {}


@pytest.mark.parametrize("algo", [CEC, MFEC])
def test_learn_loop_updates_memory_with_each_envs_whole_episode(algo):
    """n_envs=2 with different episode lengths, termination and truncation: every memory update gets exactly
    one env's episode, from its reset observation to its last step, with its own discounted returns."""
    venv = DummyVecEnv([lambda i=i: _CountingEnv(i, discrete=algo is MFEC) for i in range(2)])
    model = algo("MlpPolicy", venv, gamma=0.5, projection_dim=None, seed=0)
    episodes = []
    update_memory = model._update_memory

    def record(keys, actions, returns):
        episodes.append((keys[:, 0].copy(), returns.copy()))
        return update_memory(keys, actions, returns)

    model._update_memory = record
    model.learn(30, log_interval=None)
    assert len(episodes) == 30 // 2 // 3 + 30 // 2 // 5  # 5 episodes of env 0, 3 of env 1
    for keys, returns in episodes:
        env_id = int(keys[0]) // 10
        length = 3 + 2 * env_id
        np.testing.assert_array_equal(keys, 10 * env_id + np.arange(length))
        np.testing.assert_allclose(returns, discounted_returns(np.arange(1.0, length + 1), 0.5))


# ---------------------------------------------------------------- SB3 contracts of CEC and MFEC (shared plumbing)
class _SpacesEnv(gym.Env):
    """Random observations of a given space; reward 1 with probability 0.2, episodes of 5 steps."""

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Space, reward: float = 1.0) -> None:
        self.observation_space, self.action_space, self.reward, self.t = observation_space, action_space, reward, 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.observation_space.seed(int(self.np_random.integers(2**31)))
        self.t = 0
        return self.observation_space.sample(), {}

    def step(self, action):
        self.t += 1
        reward = self.reward if self.np_random.random() < 0.2 else 0.0
        return self.observation_space.sample(), reward, False, self.t >= 5, {}


BOX_OBS = spaces.Box(-1, 1, (3,), np.float32)
DICT_OBS = spaces.Dict({"observation": spaces.Box(-1, 1, (2,), np.float32), "desired_goal": spaces.Box(-1, 1, (2,))})
ACTION_SPACES = {CEC: spaces.Box(-1, 1, (2,), np.float32), MFEC: spaces.Discrete(3)}


def _make(algo, obs_space=BOX_OBS, reward=1.0, **kwargs):
    policy = "MultiInputPolicy" if isinstance(obs_space, spaces.Dict) else "MlpPolicy"
    return algo(policy, _SpacesEnv(obs_space, ACTION_SPACES[algo], reward), projection_dim=None, **kwargs)


@pytest.mark.parametrize("obs_space", [BOX_OBS, DICT_OBS], ids=["box", "dict"])
@pytest.mark.parametrize("algo", [CEC, MFEC])
def test_predict_returns_what_stock_sb3_returns(algo, obs_space):
    """One observation -> ndarray of shape action_space.shape (shape () for Discrete, as DQN); a batch -> (n, ...)."""
    from stable_baselines3 import DQN, SAC

    stock_algo = DQN if algo is MFEC else SAC
    env = _SpacesEnv(obs_space, ACTION_SPACES[algo])
    policy = "MultiInputPolicy" if isinstance(obs_space, spaces.Dict) else "MlpPolicy"
    stock = stock_algo(policy, env, policy_kwargs=dict(net_arch=[4]), buffer_size=10, seed=0)
    model = _make(algo, obs_space, seed=0)
    single = obs_space.sample()
    batch = {k: np.stack([v] * 4) for k, v in single.items()} if isinstance(single, dict) else np.stack([single] * 4)
    for obs in (single, batch):
        for deterministic in (True, False):
            ours, _ = model.predict(obs, deterministic=deterministic)
            expected, _ = stock.predict(obs, deterministic=deterministic)
            assert type(ours) is type(expected) is np.ndarray
            assert ours.shape == expected.shape and ours.dtype == expected.dtype
            assert ACTION_SPACES[algo].contains(ours if obs is single else ours[0])


@pytest.mark.parametrize("algo", [CEC, MFEC])
def test_policy_save_load_restores_memory_exactly(algo, tmp_path):
    model = _make(algo, seed=0)
    model.learn(200, log_interval=None)
    assert len(model.policy.memory) > 0
    model.policy.save(str(tmp_path / "policy.pth"))
    loaded = type(model.policy).load(str(tmp_path / "policy.pth"))
    original, restored = model.policy.memory.state_dict(), loaded.memory.state_dict()
    assert original.keys() == restored.keys()
    for name in original:
        np.testing.assert_array_equal(original[name], restored[name])
    obs = np.random.default_rng(0).uniform(-1, 1, (50, 3)).astype(np.float32)
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])


def _save_with_corrupted_memory(model, path, corrupt) -> None:
    from stable_baselines3.common.save_util import load_from_zip_file, save_to_zip_file

    model.save(path)
    data, params, variables = load_from_zip_file(path)
    corrupt(params["policy"]["_extra_state"])
    save_to_zip_file(path, data=data, params=params, pytorch_variables=variables)


def _drop_values(state):
    name = next(k for k in state if k.endswith("values"))
    state[name] = state[name][:-1]


def _widen_keys(state):
    for name in [k for k in state if k.endswith("keys")]:
        state[name] = th.cat([state[name], state[name][:, :1]], dim=1)


@pytest.mark.parametrize(
    "corrupt, match",
    [(_drop_values, r"'values' has shape"), (_widen_keys, r"keys have shape .* expects \(n, 3\)")],
    ids=["rows", "key_dim"],
)
@pytest.mark.parametrize("algo", [CEC, MFEC])
def test_load_surfaces_the_memorys_own_error(algo, corrupt, match, tmp_path):
    """A memory that cannot be restored fails with its own error, not SB3's KeyError: 'policy.optimizer'."""
    from sb3_gcrl.memory.serialization import MemoryRestoreError

    model = _make(algo, seed=0)
    model.learn(200, log_interval=None)
    _save_with_corrupted_memory(model, tmp_path / "bad.zip", corrupt)
    with pytest.raises(MemoryRestoreError, match=match) as info:
        algo.load(tmp_path / "bad.zip")
    assert isinstance(info.value.__cause__, ValueError)


@pytest.mark.parametrize("reward", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("algo", [CEC, MFEC])
def test_non_finite_rewards_raise_before_reaching_the_memory(algo, reward):
    model = _make(algo, reward=reward, seed=0)
    with pytest.raises(ValueError, match=rf"reward {reward}.*finite"):
        model.learn(100, log_interval=None)
    assert np.isfinite(
        model.policy.memory.state_dict()[next(k for k in model.policy.memory.state_dict() if "values" in k)]
    ).all()


def test_memories_reject_non_finite_returns():
    cec, mfec = CECMemory(key_dim=1, action_dim=1), MFECMemory(key_dim=1, n_actions=2)
    keys, returns = np.zeros((3, 1)), np.array([1.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="returns contain nan"):
        cec.update_episode(keys, np.zeros((3, 1)), returns)
    with pytest.raises(ValueError, match="returns contain inf"):
        cec.update(keys[0], np.zeros(1), np.inf)
    with pytest.raises(ValueError, match="returns contain nan"):
        mfec.update_episode(keys, np.zeros(3, dtype=np.int64), returns)
    assert len(cec) == len(mfec) == 0


@pytest.mark.parametrize("algo", [CEC, MFEC])
def test_replay_buffer_calls_warn_that_the_memory_is_in_the_model_file(algo, tmp_path):
    """rl_zoo3's --save-replay-buffer calls save_replay_buffer when it exists: say where the memory is."""
    model = _make(algo, seed=0)
    with pytest.warns(UserWarning, match="episodic memory is saved in the model file"):
        model.save_replay_buffer(tmp_path / "replay_buffer.pkl")
    assert not (tmp_path / "replay_buffer.pkl").exists()
    with pytest.warns(UserWarning, match="restored from the model file"):
        model.load_replay_buffer(tmp_path / "replay_buffer.pkl")


@pytest.mark.parametrize("algo", [CEC, MFEC])
def test_tensorboard_run_is_named_after_the_algorithm(algo, tmp_path):
    pytest.importorskip("tensorboard")
    model = _make(algo, seed=0, tensorboard_log=str(tmp_path))
    model.learn(20, log_interval=None)
    model.learn(20, log_interval=None)
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{algo.__name__}_1", f"{algo.__name__}_2"]


@pytest.mark.parametrize("algo", [CEC, MFEC])
def test_set_random_seed_after_load_makes_predict_and_learn_reproducible(algo, tmp_path):
    model = _make(algo, seed=0, exploration_fraction=0.5)
    model.learn(300, log_interval=None)
    model.save(tmp_path / "model.zip")
    obs = np.random.default_rng(0).uniform(-1, 1, (200, 3)).astype(np.float32)
    model.set_random_seed(3)
    reference_actions = model.predict(obs)[0]  # the loaded copies explore as the saved model did (same epsilon)
    runs = []
    for env_first in (True, False, True, False):
        loaded = algo.load(tmp_path / "model.zip")
        env = _SpacesEnv(BOX_OBS, ACTION_SPACES[algo])
        if env_first:
            loaded.set_env(env)
        loaded.set_random_seed(3)
        if not env_first:
            loaded.set_env(env)  # the seed given before the env seeds the env too
        actions = loaded.predict(obs)[0]
        np.testing.assert_array_equal(actions, reference_actions)
        loaded.learn(100, log_interval=None)
        runs.append(loaded.policy.memory.state_dict())
    for run in runs[1:]:
        assert run.keys() == runs[0].keys()
        for name in run:
            np.testing.assert_array_equal(run[name], runs[0][name])
