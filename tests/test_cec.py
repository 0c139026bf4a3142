"""CEC as an SB3 algorithm: learning loop, Dict observations, n_envs, save/load, seeding, logging, errors."""

import os

import gymnasium as gym
import numpy as np
import pytest
import yaml
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_checker import check_env
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.logger import configure

import sb3_gcrl  # noqa: F401  (registers GCRL/ envs)
from sb3_gcrl import CEC
from sb3_gcrl.algorithms import load_algorithm

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GROWING_TREE = dict(distance_threshold=0.01, noise_std=0.5, capacity=10_000, exploration_fraction=1.0)


class LineEnv(gym.Env):
    """1-D corridor: reward 1 and termination at x >= 1; optional NaN observation to test errors."""

    def __init__(self, nan: bool = False) -> None:
        self.observation_space = spaces.Box(-2.0, 2.0, (1,), np.float32)
        self.action_space = spaces.Box(-0.2, 0.2, (1,), np.float32)
        self.nan = nan
        self.x = 0.0
        self.t = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.t = 0.0, 0
        return np.array([np.nan if self.nan else self.x], np.float32), {}

    def step(self, action):
        self.x = float(np.clip(self.x + float(action[0]), -2, 2))
        self.t += 1
        done = self.x >= 1.0
        return np.array([self.x], np.float32), float(done), done, self.t >= 50, {"is_success": done}


def test_learns_and_logs_memory_statistics(tmp_path):
    model = CEC("CECPolicy", LineEnv(), distance_threshold=0.02, noise_std=0.3, capacity=500, seed=0)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(1500, log_interval=5)
    assert 0 < len(model.policy.memory) <= 500
    log = (tmp_path / "progress.csv").read_text().splitlines()
    header = log[0].split(",")
    for column in ("memory/size", "memory/hit_rate", "memory/added", "memory/refreshed", "rollout/success_rate"):
        assert column in header
    row = dict(zip(header, log[-1].split(",")))
    assert int(float(row["memory/size"])) == len(model.policy.memory)
    assert 0.0 <= float(row["memory/hit_rate"]) <= 1.0


def test_memory_update_uses_discounted_returns_of_finished_episodes():
    model = CEC("CECPolicy", LineEnv(), distance_threshold=1e-6, capacity=1000, gamma=0.9, seed=1)
    model.learn(400, log_interval=None)
    memory = model.policy.memory
    values = memory.values[: len(memory)]
    # every stored value is gamma^j for a successful episode (reward 1 at its last step) or 0
    nonzero = values[values > 0]
    assert len(nonzero) > 0
    exponents = np.log(nonzero) / np.log(0.9)
    np.testing.assert_allclose(exponents, np.round(exponents), atol=1e-6)
    assert values.max() == pytest.approx(1.0)


def test_dict_observations_and_several_envs():
    env_id = "GCRL/GrowingTreeGoal-v0"
    vec_env = make_vec_env(lambda: gym.make(env_id), n_envs=3, seed=0)
    model = CEC("MultiInputPolicy", vec_env, seed=0, **GROWING_TREE)
    space = vec_env.observation_space
    assert model.policy.embedding.observation_keys == ("observation", "desired_goal")
    assert model.policy.embedding.key_dim == space["observation"].shape[0] + space["desired_goal"].shape[0]
    model.learn(900, log_interval=None)
    assert model.num_timesteps == 900 and model._episode_num >= 3
    obs = vec_env.reset()
    actions, _ = model.predict(obs, deterministic=True)
    assert actions.shape == (3, *vec_env.action_space.shape)
    single = {k: v[0] for k, v in obs.items()}
    action, _ = model.predict(single, deterministic=True)
    assert action.shape == vec_env.action_space.shape
    np.testing.assert_array_equal(action, actions[0])


def test_save_load_round_trip_restores_memory_exactly(tmp_path):
    model = CEC("CECPolicy", gym.make("GCRL/GrowingTree-v0"), seed=3, **GROWING_TREE)
    model.learn(2000, log_interval=None)
    path = tmp_path / "cec.zip"
    model.save(path)
    loaded = CEC.load(path)
    obs = np.linspace(-2, 2, 101, dtype=np.float32)[:, None]
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    for m in (model, loaded):
        m.policy.set_seed(7)
        m.policy.exploration_rate = 0.5
    np.testing.assert_array_equal(model.predict(obs)[0], loaded.predict(obs)[0])
    original, restored = model.policy.memory, loaded.policy.memory
    assert len(original) == len(restored)
    np.testing.assert_array_equal(original.state_dict()["last_update"], restored.state_dict()["last_update"])
    assert loaded.distance_threshold == 0.01 and restored.capacity == 10_000
    # the file grows with the used rows, not with the capacity
    small = CEC("CECPolicy", gym.make("GCRL/GrowingTree-v0"), seed=3, **{**GROWING_TREE, "capacity": 1_000_000})
    small.save(tmp_path / "empty.zip")
    assert os.path.getsize(tmp_path / "empty.zip") < 50_000
    # training continues after loading
    loaded.set_env(gym.make("GCRL/GrowingTree-v0"))
    loaded.learn(300, reset_num_timesteps=False, log_interval=None)


def test_deterministic_predict_on_empty_memory_is_the_action_centre():
    model = CEC("CECPolicy", LineEnv(), seed=0)
    action, _ = model.predict(np.zeros(1, np.float32), deterministic=True)
    np.testing.assert_array_equal(action, [0.0])
    stochastic, _ = model.predict(np.zeros((200, 1), np.float32))
    assert (np.abs(stochastic) <= 0.2).all() and stochastic.std() > 0.05  # uniform random, within bounds


def test_errors_name_the_fix():
    with pytest.raises(ValueError, match="MFEC"):
        CEC("CECPolicy", gym.make("CartPole-v1"))
    unbounded = LineEnv()
    unbounded.action_space = spaces.Box(-np.inf, np.inf, (1,), np.float32)
    with pytest.raises(ValueError, match="bounded"):
        CEC("CECPolicy", unbounded)
    with pytest.raises(ValueError, match="distance_threshold"):
        CEC("CECPolicy", LineEnv(), distance_threshold=-1.0)
    with pytest.raises(ValueError, match="temperature"):
        CEC("CECPolicy", LineEnv(), temperature=0.0)
    with pytest.raises(ValueError, match="noise_std"):
        CEC("CECPolicy", LineEnv(), noise_std=-0.1)
    with pytest.raises(ValueError, match="exploration_final_eps"):
        CEC("CECPolicy", LineEnv(), exploration_final_eps=1.5)
    with pytest.raises(ValueError, match="NaN"):
        CEC("CECPolicy", LineEnv(nan=True)).learn(10)
    nan_reward = gym.wrappers.TransformReward(LineEnv(), lambda reward: np.nan)
    with pytest.raises(ValueError, match=r"Env 0 returned the reward nan at timestep 0: .*VecCheckNan"):
        CEC("CECPolicy", nan_reward).learn(10)


def test_check_env_on_the_test_env_and_registration():
    check_env(LineEnv())
    assert load_algorithm("cec") is CEC


def test_zoo_config_hyperparameters_build_models():
    with open(os.path.join(ROOT, "zoo_configs", "cec.yml")) as f:
        config = yaml.safe_load(f)
    assert {"GCRL/GrowingTree-v0", "GCRL/PointUMaze-v0", "GCRL/Point4Rooms-v0"} <= set(config)
    for env_id, hyperparams in config.items():
        kwargs = {k: v for k, v in hyperparams.items() if k not in ("n_timesteps", "n_envs", "normalize")}
        env = gym.make(env_id)
        model = CEC(env=env, **kwargs)
        assert isinstance(model.policy.memory.capacity, int)
        env.close()


class EvaluateEvery(BaseCallback):
    """Greedy evaluation return every ``freq`` steps."""

    def __init__(self, eval_env: gym.Env, freq: int) -> None:
        super().__init__()
        self.eval_env, self.freq, self.returns = eval_env, freq, []

    def _on_step(self) -> bool:
        if self.num_timesteps % self.freq == 0:
            self.returns.append(evaluate_policy(self.model, self.eval_env, n_eval_episodes=1)[0])
        return True


@pytest.mark.slow
def test_growing_tree_is_solved_within_5k_steps():
    solved = 0
    for seed in range(5):
        model = CEC("CECPolicy", gym.make("GCRL/GrowingTree-v0"), seed=seed, **GROWING_TREE)
        evaluation = EvaluateEvery(gym.make("GCRL/GrowingTree-v0"), 500)
        model.learn(5000, callback=evaluation, log_interval=None)
        solved += max(evaluation.returns) >= 1.0
    assert solved >= 4


def test_loading_another_algorithms_file_says_which_algorithm_saved_it(tmp_path):
    from sb3_gcrl import MFEC

    MFEC("MFECPolicy", gym.make("CartPole-v1"), seed=0).save(tmp_path / "mfec.zip")
    with pytest.raises(ValueError, match=r"a model of MFEC, not of CEC.*MFEC\.load"):
        CEC.load(tmp_path / "mfec.zip")
    with pytest.raises(ValueError, match=r"a model of MFEC, not of CEC"):
        CEC.load(tmp_path / "mfec.zip", env=gym.make("CartPole-v1"))
    CEC("CECPolicy", LineEnv(), seed=0).save(tmp_path / "cec.zip")
    with pytest.raises(ValueError, match=r"a model of CEC, not of MFEC.*CEC\.load"):
        MFEC.load(tmp_path / "cec.zip")


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(capacity=1.7), ValueError, "capacity must be an integer, got 1.7"),
        (dict(capacity=0), ValueError, "capacity must be >= 1"),
        (dict(capacity=None), TypeError, "capacity must be an integer"),
        (dict(distance_threshold=-0.1), ValueError, "distance_threshold"),
        (dict(distance_threshold=0.0), ValueError, "distance_threshold"),
        (dict(distance_threshold=np.inf), ValueError, "distance_threshold"),
        (dict(filter_factor=0.0), ValueError, "filter_factor"),
        (dict(n_neighbors=0), ValueError, "n_neighbors"),
        (dict(n_neighbors=1.5), ValueError, "n_neighbors"),
        (dict(temperature=0.0), ValueError, "temperature"),
        (dict(temperature=-1.0), ValueError, "temperature"),
        (dict(noise_std=-0.1), ValueError, "noise_std"),
        (dict(noise_std=np.nan), ValueError, "noise_std"),
        (dict(gamma=-0.1), ValueError, "gamma"),
        (dict(exploration_initial_eps=1.1), ValueError, "exploration_initial_eps"),
        (dict(exploration_final_eps=1.5), ValueError, "exploration_final_eps"),
        (dict(exploration_fraction=-1.0), ValueError, "exploration_fraction"),
        (dict(projection_dim=0), ValueError, "projection_dim"),
        (dict(knn_backend="annoy"), ValueError, "knn_backend"),
        (dict(rebuild_threshold=1.5), ValueError, "rebuild_threshold"),
        (dict(stats_window_size=0), ValueError, "stats_window_size"),
        (dict(observation_keys=["observation"]), ValueError, "observation_keys"),
        (dict(policy_kwargs=dict(capacity=2.5)), ValueError, "capacity"),
    ],
)
def test_invalid_hyperparameters_fail_at_construction(kwargs, error, match):
    with pytest.raises(error, match=match):
        CEC("CECPolicy", LineEnv(), **kwargs)


def test_integral_float_capacity_is_accepted():
    model = CEC("CECPolicy", LineEnv(), capacity=1e3)  # YAML's !!float 1e3
    assert model.capacity == model.policy.memory.capacity == 1000
    assert isinstance(model.capacity, int)
