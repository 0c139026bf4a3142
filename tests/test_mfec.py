"""MFEC as an SB3 algorithm: Eq. 5.2 through learn(), greedy/tie-breaking, save/load, seeding, errors."""

import os
from functools import partial

import gymnasium as gym
import numpy as np
import pytest
import yaml
from envs import ChainEnv as Chain
from gymnasium import spaces
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecTransposeImage

import sb3_gcrl  # noqa: F401  (registers GCRL/ and MinAtar envs)
from sb3_gcrl import MFEC
from sb3_gcrl.algorithms import load_algorithm

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


#: states 0..4 on a chain; action 1 moves right, 0 moves left; reward 1 at state 4 (terminal); 20-step limit
ChainEnv = partial(Chain, n=5, horizon=20)


def test_learns_chain_and_memory_holds_max_discounted_returns():
    model = MFEC("MFECPolicy", ChainEnv(), projection_dim=None, n_neighbors=1, gamma=0.9, seed=0)
    model.learn(600, log_interval=None)
    table_right = model.policy.memory.tables[1]
    # Eq. 5.2: the best return ever seen after moving right from state 3 is 1, from state 0 it is 0.9^3
    assert table_right.values[table_right.lookup(np.array([3.0], np.float32))] == pytest.approx(1.0)
    assert table_right.values[table_right.lookup(np.array([0.0], np.float32))] == pytest.approx(0.9**3)
    actions, _ = model.predict(np.arange(4), deterministic=True)
    np.testing.assert_array_equal(actions, [1, 1, 1, 1])
    mean, _ = evaluate_policy(model, ChainEnv(), n_eval_episodes=3, deterministic=True)
    assert mean == 1.0


def test_untried_actions_are_preferred_and_ties_broken_at_random():
    model = MFEC("MFECPolicy", ChainEnv(), projection_dim=None, seed=0, exploration_initial_eps=0.0)
    model.policy.exploration_rate = 0.0
    actions, _ = model.predict(np.zeros(400, dtype=np.int64))  # every action is untried (+inf)
    assert set(np.unique(actions)) == {0, 1}
    assert abs(actions.mean() - 0.5) < 0.1
    det, _ = model.predict(np.zeros(5, dtype=np.int64), deterministic=True)
    np.testing.assert_array_equal(det, 0)  # deterministic: lowest index among ties


def test_minatar_with_projection_several_envs_save_load(tmp_path):
    vec_env = make_vec_env("MinAtar/Breakout-v1", n_envs=2, seed=0)
    model = MFEC("MFECPolicy", vec_env, capacity_per_action=2000, seed=0)
    assert model.policy.embedding.key_dim == 8
    model.learn(1500, log_interval=None)
    assert len(model.policy.memory) > 0
    obs = vec_env.reset()
    for _ in range(10):
        obs, *_ = vec_env.step(model.predict(obs)[0])
    model.save(tmp_path / "mfec.zip")
    loaded = MFEC.load(tmp_path / "mfec.zip")
    np.testing.assert_array_equal(loaded.policy.embedding.projection, model.policy.embedding.projection)
    keys = model.policy.embedding(obs)
    np.testing.assert_array_equal(model.policy.q_values(keys), loaded.policy.q_values(keys))
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    for m in (model, loaded):
        m.policy.set_seed(3)
    np.testing.assert_array_equal(model.predict(obs)[0], loaded.predict(obs)[0])


def test_errors_name_the_fix():
    with pytest.raises(ValueError, match="CEC"):
        MFEC("MFECPolicy", gym.make("Pendulum-v1"))
    with pytest.raises(ValueError, match="capacity_per_action"):
        MFEC("MFECPolicy", ChainEnv(), capacity_per_action=0)
    with pytest.raises(ValueError, match="n_neighbors"):
        MFEC("MFECPolicy", ChainEnv(), n_neighbors=0)
    with pytest.raises(ValueError, match="gamma"):
        MFEC("MFECPolicy", ChainEnv(), gamma=1.5)
    assert load_algorithm("mfec") is MFEC


def test_zoo_config_hyperparameters_build_models():
    with open(os.path.join(ROOT, "zoo_configs", "mfec.yml")) as f:
        config = yaml.safe_load(f)
    assert {"MinAtar/Breakout-v1", "MinAtar/Seaquest-v1", "GCRL/WindyGrid-v0"} <= set(config)
    for env_id, hyperparams in config.items():
        kwargs = {k: v for k, v in hyperparams.items() if k not in ("n_timesteps", "n_envs")}
        env = gym.make(env_id)
        model = MFEC(env=env, **kwargs)
        n_actions = env.action_space.n
        if env_id.startswith("MinAtar"):
            assert model.capacity_per_action == int(1e5 / (2 * n_actions))  # 2M code's capacity
        env.close()


class ImageChainEnv(Chain):
    """ChainEnv rendered as a channel-last uint8 image (4 x 5 x 3): column ``s`` is lit."""

    def __init__(self) -> None:
        super().__init__(n=5, horizon=20)
        self.observation_space = spaces.Box(0, 255, (4, 5, 3), np.uint8)

    def _image(self) -> np.ndarray:
        image = np.zeros((4, 5, 3), np.uint8)
        image[:, self.state] = 255
        return image

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return self._image(), {}

    def step(self, action):
        _, reward, terminated, truncated, info = super().step(action)
        return self._image(), reward, terminated, truncated, info


def test_image_observations_train_predict_on_raw_obs_and_evaluate():
    """Training sees VecTransposeImage's channel-first images; predict on the raw channel-last observation must
    transpose it the same way, so the memory is queried with the keys it was trained on."""
    model = MFEC("MFECPolicy", ImageChainEnv(), projection_dim=4, n_neighbors=1, gamma=0.9, seed=0)
    assert isinstance(model.get_env(), VecTransposeImage)
    assert model.policy.observation_space.shape == (3, 4, 5)
    model.learn(600, log_interval=None)
    env = ImageChainEnv()
    raw, _ = env.reset()
    action, _ = model.predict(raw, deterministic=True)
    expected, _ = model.policy.act(model.policy.embedding(np.transpose(raw, (2, 0, 1))[None]), deterministic=True)
    assert action.shape == () and action == expected[0] == 1  # the memory learnt "right" at the start
    batch = np.stack([raw, env.step(1)[0]])
    np.testing.assert_array_equal(model.predict(batch, deterministic=True)[0], [1, 1])
    mean, _ = evaluate_policy(model, ImageChainEnv(), n_eval_episodes=2, deterministic=True)
    assert mean == 1.0


def test_cnn_policy_alias_is_gone_and_names_the_right_policy():
    with pytest.raises(ValueError, match="no 'CnnPolicy'.*'MFECPolicy'"):
        MFEC("CnnPolicy", ImageChainEnv())
    with pytest.raises(ValueError, match=r"unknown for MFEC; use one of \['MFECPolicy'"):
        MFEC("MlpLstmPolicy", ChainEnv())


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(capacity_per_action=1.7), ValueError, "capacity_per_action must be an integer, got 1.7"),
        (dict(capacity_per_action=0), ValueError, "capacity_per_action must be >= 1"),
        (dict(capacity_per_action="100"), TypeError, "capacity_per_action must be an integer"),
        (dict(n_neighbors=2.5), ValueError, "n_neighbors"),
        (dict(n_neighbors=0), ValueError, "n_neighbors"),
        # a kNN estimate needs k + 1 rows: every unseen state would stay at +inf
        (dict(capacity_per_action=3, n_neighbors=3), ValueError, "capacity_per_action=3 must exceed n_neighbors=3"),
        (dict(projection_dim=0), ValueError, "projection_dim"),
        (dict(projection_dim=2.5), ValueError, "projection_dim"),
        (dict(gamma=np.nan), ValueError, "gamma"),
        (dict(exploration_initial_eps=-0.1), ValueError, "exploration_initial_eps"),
        (dict(exploration_fraction=1.5), ValueError, "exploration_fraction"),
        (dict(knn_backend="annoy"), ValueError, "knn_backend"),
        (dict(rebuild_threshold=0), ValueError, "rebuild_threshold"),
        (dict(stats_window_size=0), ValueError, "stats_window_size"),
    ],
)
def test_invalid_hyperparameters_fail_at_construction(kwargs, error, match):
    with pytest.raises(error, match=match):
        MFEC("MFECPolicy", ChainEnv(), **kwargs)


def test_integral_float_capacity_is_accepted():
    model = MFEC("MFECPolicy", ChainEnv(), capacity_per_action=1e3)  # YAML's !!float 1e3
    assert model.capacity_per_action == model.policy.memory.capacity_per_action == 1000
    assert isinstance(model.capacity_per_action, int)
