"""SB3's contracts for every algorithm of this package, modelled on SB3's own test suite.

One parametrized module instead of per-algorithm copies: save/load of the model and of the policy
(``test_save_load.py``), predict shapes for single and batched observations (``test_predict.py``), seeded
determinism (``test_deterministic.py``), the callbacks and their ``locals`` (``test_callbacks.py``), and seeding
after load. Every entry of :data:`sb3_gcrl.algorithms.ALGORITHMS` needs a case below (checked), so a new algorithm
cannot skip these contracts. Where an episodic table legitimately lacks a feature of SB3 (no optimizer, no
gradient step), the test says so instead of skipping silently.
"""

from __future__ import annotations

import inspect
import io
import warnings
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from envs import MOREFREE_TINY_NET
from stable_baselines3 import A2C, DDPG, DQN, PPO, SAC, TD3
from stable_baselines3.common import save_util
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import (
    BaseCallback,
    CallbackList,
    CheckpointCallback,
    EvalCallback,
    EveryNTimesteps,
    StopTrainingOnMaxEpisodes,
    StopTrainingOnNoModelImprovement,
)
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.logger import configure
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

import sb3_gcrl  # noqa: F401  (registers the GCRL/ envs)
from sb3_gcrl.algorithms import ALGORITHMS, load_algorithm
from sb3_gcrl.common.saving import SAVED_BY_ENTRY, ModelFileError

N_STEPS = 300
# the "ibc" case trains on a plain goal env on purpose (its phases are tested in tests/test_ibc.py)
pytestmark = pytest.mark.filterwarnings("ignore:IBC. the training env is not wrapped")


@dataclass(frozen=True)
class Case:
    """How to build a small model of one algorithm on one env."""

    algo: str
    env_id: str
    policy: str
    kwargs: dict[str, Any] = field(default_factory=dict)
    #: False for an algorithm that runs one env (SB3's ``support_multi_env=False``)
    multi_env: bool = True

    @property
    def n_envs(self) -> int:
        """Envs of the "several envs" tests: 2, or 1 where the algorithm runs one env."""
        return 2 if self.multi_env else 1

    @property
    def cls(self) -> type[BaseAlgorithm]:
        return load_algorithm(self.algo)

    def make_env(self, n_envs: int = 1, seed: int = 0) -> VecEnv:
        return make_vec_env(self.env_id, n_envs=n_envs, seed=seed)

    def make(self, env: VecEnv | gym.Env | None = None, seed: int = 0, **overrides: Any) -> BaseAlgorithm:
        env = self.make_env(seed=seed) if env is None else env
        return self.cls(self.policy, env, seed=seed, **{**self.kwargs, **overrides})


TINY_NET = {"net_arch": [16]}


def _forward_backward_growing_tree() -> gym.Env:
    """GrowingTreeGoal in MEDAL/R3L's forward/backward phases (20-step segments), switched to reset-free training."""
    from sb3_gcrl.reset_free_baselines import ForwardBackwardWrapper
    from sb3_gcrl.wrappers import ResetFreeWrapper

    inner = ResetFreeWrapper(gym.make("GCRL/GrowingTreeGoal-v0"), hard_reset_every=500, segment_length=20)
    env = ForwardBackwardWrapper(inner)
    env.set_training_mode(True)
    return env


gym.register("GCRLTest/GrowingTreeForwardBackward-v0", entry_point=_forward_backward_growing_tree)
FORWARD_BACKWARD_KWARGS = {
    "learning_starts": 50,
    "buffer_size": 1_000,
    "batch_size": 16,
    "train_freq": 4,
    "policy_kwargs": TINY_NET,
    "reward_model_batch_size": 32,
}
CASES: dict[str, Case] = {
    "cec": Case("cec", "Pendulum-v1", "CECPolicy", {"capacity": 500, "distance_threshold": 0.1}),
    "mfec": Case("mfec", "CartPole-v1", "MFECPolicy", {"capacity_per_action": 500, "projection_dim": None}),
    "two_memory_dqn": Case(
        "two_memory_dqn",
        "CartPole-v1",
        "MlpPolicy",
        {
            "p_ec_schedule": 0.5,
            "learning_starts": 50,
            "buffer_size": 1_000,
            "batch_size": 16,
            "train_freq": 4,
            "target_update_interval": 50,
            "policy_kwargs": TINY_NET,
        },
    ),
    "two_memory_sac": Case(
        "two_memory_sac",
        "Pendulum-v1",
        "MlpPolicy",
        {
            "p_ec_schedule": 0.5,
            "learning_starts": 50,
            "buffer_size": 1_000,
            "batch_size": 16,
            "train_freq": 4,
            "policy_kwargs": TINY_NET,
        },
    ),
    "emac": Case(
        "emac",
        "Pendulum-v1",
        "MlpPolicy",
        {"learning_starts": 50, "buffer_size": 1_000, "batch_size": 16, "train_freq": 4, "policy_kwargs": TINY_NET},
    ),
    "tabular_q": Case("tabular_q", "FrozenLake-v1", "TabularQPolicy", {"learning_starts": 10}),
    "tabular_ec": Case("tabular_ec", "FrozenLake-v1", "TabularECPolicy"),
    "tabular_2m": Case("tabular_2m", "FrozenLake-v1", "TabularTwoMemoryPolicy", {"p_ec_schedule": 0.5}),
    # a MiniGrid task: its goal tile is the task goal that predict() commands on the plain env's states
    "imgep": Case("imgep", "GCRL/LavaGapTabular-v0", "TabularGoalPolicy", multi_env=False),
    "morefree": Case(
        "morefree",
        "GCRL/GrowingTreeGoal-v0",
        "MultiInputPolicy",
        {
            "learning_starts": 50,
            "batch_size": 4,
            "batch_length": 8,
            "train_ratio": 10,
            "imagination_horizon": 3,
            "imagination_starts": 16,
            "policy_kwargs": MOREFREE_TINY_NET,
        },
    ),
    "medal": Case(
        "medal",
        "GCRLTest/GrowingTreeForwardBackward-v0",
        "MultiInputPolicy",
        {**FORWARD_BACKWARD_KWARGS, "demos": "GCRL/GrowingTreeGoal-v0", "reward_model_kwargs": {"hidden": [16]}},
    ),
    "r3l": Case(
        "r3l",
        "GCRLTest/GrowingTreeForwardBackward-v0",
        "MultiInputPolicy",
        {**FORWARD_BACKWARD_KWARGS, "reward_model_kwargs": {"hidden": [16, 8]}},
    ),
    # a plain goal env (no IBC wrapper: every step is the forward agent's); SB3's default buffer, since a HER buffer
    # needs the env at load time; the IBC phases and HER are in tests/test_ibc.py
    "ibc": Case(
        "ibc",
        "GCRL/GrowingTreeGoal-v0",
        "MultiInputPolicy",
        {"learning_starts": 50, "buffer_size": 1_000, "batch_size": 16, "train_freq": 4, "policy_kwargs": TINY_NET},
    ),
}


def _bit_flipping() -> gym.Env:
    from stable_baselines3.common.envs import BitFlippingEnv

    return BitFlippingEnv(n_bits=4)


gym.register("GCRLTest/BitFlipping-v0", entry_point=_bit_flipping)  # Dict goal observations, Discrete actions
#: extra observation spaces (Dict goal observations) on top of one case per algorithm
EXTRA_CASES: dict[str, Case] = {
    "mfec_dict": Case(
        "mfec", "GCRLTest/BitFlipping-v0", "MultiInputPolicy", {"capacity_per_action": 500, "projection_dim": None}
    ),
    "two_memory_dqn_dict": Case(
        "two_memory_dqn",
        "GCRLTest/BitFlipping-v0",
        "MultiInputPolicy",
        {**CASES["two_memory_dqn"].kwargs, "ec_projection_dim": None},
    ),
    "cec_dict": Case("cec", "GCRL/GrowingTreeGoal-v0", "MultiInputPolicy", {"capacity": 500}),
    "emac_dict": Case(
        "emac",
        "GCRL/GrowingTreeGoal-v0",
        "MultiInputPolicy",
        {"learning_starts": 50, "buffer_size": 1_000, "batch_size": 16, "policy_kwargs": TINY_NET},
    ),
    "two_memory_sac_dict": Case(
        "two_memory_sac",
        "GCRL/GrowingTreeGoal-v0",
        "MultiInputPolicy",
        {
            "p_ec_schedule": 0.5,
            "learning_starts": 50,
            "buffer_size": 1_000,
            "batch_size": 16,
            "policy_kwargs": TINY_NET,
        },
    ),
}
ALL_CASES = {**CASES, **EXTRA_CASES}
#: algorithms without a gradient optimizer (their policy *is* a table or an episodic memory)
NO_OPTIMIZER = {"cec", "mfec", "tabular_q", "tabular_ec", "tabular_2m", "imgep"}

algo_names = pytest.mark.parametrize("name", sorted(CASES))
case_names = pytest.mark.parametrize("name", sorted(ALL_CASES))


def test_every_registered_algorithm_has_a_contract_case():
    assert set(CASES) == set(ALGORITHMS), "add a Case for each new algorithm in sb3_gcrl.algorithms.ALGORITHMS"
    for name, case in CASES.items():
        assert case.algo == name


def observation_batch(model: BaseAlgorithm, n_steps: int = 20, seed: int = 123) -> Any:
    """A batch of observations the model's own VecEnv produces (random actions), stacked along axis 0."""
    env = model.get_env()
    assert env is not None
    env.seed(seed)
    env.action_space.seed(seed)
    obs = env.reset()
    collected = [obs]
    for _ in range(n_steps - 1):
        obs, _, _, _ = env.step(np.array([env.action_space.sample() for _ in range(env.num_envs)]))
        collected.append(obs)
    if isinstance(obs, dict):
        return {key: np.concatenate([o[key] for o in collected]) for key in obs}
    return np.concatenate(collected)


def assert_same_state(first: Any, second: Any, where: str = "") -> None:
    """Recursive exact equality of parameters: tensors, arrays, scalars, dicts, lists."""
    if isinstance(first, dict):
        assert isinstance(second, dict) and set(first) == set(second), f"{where}: keys {set(first) ^ set(second)}"
        for key in first:
            assert_same_state(first[key], second[key], f"{where}/{key}")
    elif isinstance(first, (list, tuple)):
        assert len(first) == len(second), where
        for i, (a, b) in enumerate(zip(first, second)):
            assert_same_state(a, b, f"{where}[{i}]")
    elif isinstance(first, th.Tensor):
        assert th.equal(first.cpu(), th.as_tensor(second).cpu()), where
    elif isinstance(first, np.ndarray):
        np.testing.assert_array_equal(first, second, err_msg=where)
    else:
        assert first == second, where


# ---------------------------------------------------------------------------------------------------- constructor
#: SB3's public algorithms: one built on one of them takes all of its arguments
SB3_ALGORITHMS: tuple[type[BaseAlgorithm], ...] = (A2C, DDPG, DQN, PPO, SAC, TD3)


def sb3_arguments_with_defaults(cls: type[BaseAlgorithm]) -> tuple[str, dict[str, Any]]:
    """The SB3 algorithm ``cls`` builds on and its arguments that have a default, with that default.

    On SB3's abstract bases (``BaseAlgorithm``, ``OffPolicyAlgorithm``: their other arguments are each algorithm's
    own settings), the arguments that every SB3 algorithm takes with the same default.
    """
    base = next((c for c in cls.__mro__ if c in SB3_ALGORITHMS), None)
    signatures = [inspect.signature(c.__init__).parameters for c in ([base] if base else SB3_ALGORITHMS)]
    defaults = {
        name: parameter.default
        for name, parameter in signatures[0].items()
        if parameter.default is not inspect.Parameter.empty
        and all(name in other and other[name].default == parameter.default for other in signatures)
    }
    return (base.__name__ if base else "every SB3 algorithm"), defaults


@algo_names
def test_constructor_takes_every_argument_of_its_sb3_base_at_the_default(name: str):
    case = CASES[name]
    base, defaults = sb3_arguments_with_defaults(case.cls)
    # the case's own settings (small buffers and networks) stay; seed is set by Case.make
    arguments = {k: v for k, v in defaults.items() if k not in case.kwargs and k != "seed"}
    try:
        case.make(**arguments)
    except TypeError as error:
        pytest.fail(f"{case.cls.__name__} does not take an argument of {base} at its default: {error}")


#: SB3's policy aliases and the observations each stands for (SB3's algorithms map them to their policies)
SB3_POLICY_ALIASES = ("MlpPolicy", "CnnPolicy", "MultiInputPolicy")


def sb3_alias_of(space: gym.spaces.Space) -> str | None:
    """SB3's policy alias for observations of ``space``; None where SB3 has none (Discrete: tables)."""
    if isinstance(space, gym.spaces.Dict):
        return "MultiInputPolicy"
    if is_image_space(space):
        return "CnnPolicy"
    return "MlpPolicy" if isinstance(space, gym.spaces.Box) else None


@algo_names
def test_policy_aliases_are_sb3s_names_for_the_observations_the_algorithm_supports(name: str):
    """An observation kind a contract case trains on has SB3's alias for it, and every SB3 alias has such a case."""
    cls = CASES[name].cls
    cases = [case for case in ALL_CASES.values() if case.algo == name]
    covered: set[str] = set()
    for case in cases:
        model = case.make()
        alias = sb3_alias_of(model.observation_space)
        if alias is None:
            continue
        covered.add(alias)
        assert alias in cls.policy_aliases, f"{cls.__name__} trains on {model.observation_space} but lacks {alias!r}"
        assert type(case.cls(alias, case.make_env(), **case.kwargs).policy) is type(model.policy)
    aliased = {alias for alias in cls.policy_aliases if alias in SB3_POLICY_ALIASES}
    assert aliased <= covered, (
        f"{cls.__name__} has the aliases {sorted(aliased - covered)} but no contract case with those observations: "
        "add one, or remove the alias if the algorithm does not support them"
    )


# ---------------------------------------------------------------------------------------------------- predict
@case_names
@pytest.mark.parametrize("deterministic", [True, False])
def test_predict_single_and_batched_shapes(name: str, deterministic: bool):
    case = ALL_CASES[name]
    vec_env = case.make_env(n_envs=case.n_envs)
    model = case.make(vec_env)
    action_space = model.action_space
    batch = vec_env.reset()
    if not case.multi_env:  # a batch of two observations of the one env
        batch = (
            {k: np.concatenate([v, v]) for k, v in batch.items()}
            if isinstance(batch, dict)
            else np.concatenate([batch, batch])
        )
    actions, state = model.predict(batch, deterministic=deterministic)
    assert state is None
    assert isinstance(actions, np.ndarray)
    assert actions.shape == (2, *action_space.shape)
    assert all(action_space.contains(np.asarray(a, dtype=action_space.dtype)) for a in actions)

    single = {k: v[0] for k, v in batch.items()} if isinstance(batch, dict) else batch[0]
    action, state = model.predict(single, deterministic=deterministic)
    assert state is None
    assert isinstance(action, np.ndarray), f"predict on one observation returned {type(action)}"
    assert action.shape == action_space.shape
    assert action_space.contains(action.astype(action_space.dtype))
    # the recurrent-policy arguments of SB3's signature are accepted and passed through
    _, state = model.predict(batch, state=None, episode_start=np.ones(2, dtype=bool), deterministic=deterministic)
    assert state is None


@algo_names
def test_predict_rejects_a_wrong_observation_shape(name: str):
    model = CASES[name].make()
    space = model.observation_space
    wrong: Any
    if isinstance(space, gym.spaces.Dict):
        wrong = {k: np.zeros((3, 3, 7)) for k in space.spaces}
    elif isinstance(space, gym.spaces.Discrete):
        wrong = np.zeros((2, 3, 4), dtype=np.int64)
    else:
        wrong = np.zeros((*space.shape, 7), dtype=np.float32)
    with pytest.raises(ValueError):
        model.predict(wrong)


@algo_names
def test_predict_on_the_users_own_env_and_evaluate_policy(name: str):
    case = CASES[name]
    model = case.make()
    env = Monitor(gym.make(case.env_id))
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert env.action_space.contains(np.asarray(action).astype(env.action_space.dtype))
    mean, std = evaluate_policy(model, env, n_eval_episodes=2, deterministic=True)
    assert np.isfinite(mean) and np.isfinite(std)


def float64_actions(env: gym.Env) -> gym.Env:
    """``env`` with its Box action space declared float64 (the actions are cast back to the env's dtype)."""
    space = env.action_space
    assert isinstance(space, gym.spaces.Box)
    wide = gym.spaces.Box(space.low.astype(np.float64), space.high.astype(np.float64), space.shape, np.float64)
    return gym.wrappers.TransformAction(env, lambda action: np.asarray(action, dtype=space.dtype), wide)


@case_names
def test_predict_returns_the_action_spaces_dtype(name: str):
    case = ALL_CASES[name]
    box_actions = isinstance(gym.make(case.env_id).action_space, gym.spaces.Box)
    # a float64 Box where the actions are a Box (float32 is SB3's default, so a float32 cast would go unseen)
    env = make_vec_env(case.env_id, n_envs=1, seed=0, wrapper_class=float64_actions if box_actions else None)
    model = case.make(env)
    assert not box_actions or model.action_space.dtype == np.float64
    obs = env.reset()
    single = {k: v[0] for k, v in obs.items()} if isinstance(obs, dict) else obs[0]
    for observation in (obs, single):
        for deterministic in (True, False):
            action, _ = model.predict(observation, deterministic=deterministic)
            assert action.dtype == model.action_space.dtype, f"{name} predicts {action.dtype}"


# ---------------------------------------------------------------------------------------------------- save/load
@case_names
def test_save_load_restores_predictions_and_parameters(name: str, tmp_path: Path):
    case = ALL_CASES[name]
    model = case.make()
    model.learn(N_STEPS)
    observations = observation_batch(model)
    expected, _ = model.predict(observations, deterministic=True)
    params = model.get_parameters()

    model.save(tmp_path / "model.zip")
    for env in (None, case.make_env()):
        loaded = case.cls.load(tmp_path / "model.zip", env=env)
        actions, _ = loaded.predict(observations, deterministic=True)
        np.testing.assert_array_equal(actions, expected)
        assert_same_state(loaded.get_parameters(), params, "parameters")
        assert loaded.num_timesteps == model.num_timesteps
    # the loaded model keeps learning where it stopped
    loaded.learn(100, reset_num_timesteps=False)
    assert loaded.num_timesteps >= model.num_timesteps + 100


def numpy_generators(model: BaseAlgorithm) -> dict[str, np.random.Generator]:
    """The numpy generators a model draws from: the algorithm's own (``_rng``) and its policy's (``rng``)."""
    owners = {"algorithm": model, "policy": model.policy}
    return {
        f"{owner}.{attribute}": value
        for owner, obj in owners.items()
        for attribute in ("_rng", "rng")
        if isinstance(value := getattr(obj, attribute, None), np.random.Generator)
    }


@case_names
def test_a_loaded_model_continues_the_saved_ones_random_draws(name: str, tmp_path: Path):
    """Nothing lost on save/load: every numpy generator of the algorithm and its policy continues where the saved
    model's stopped (SB3's load would otherwise reseed them as built)."""
    case = ALL_CASES[name]
    model = case.make()
    model.learn(N_STEPS)
    generators = numpy_generators(model)
    model.save(tmp_path / "model.zip")
    loaded = case.cls.load(tmp_path / "model.zip", env=case.make_env())
    restored = numpy_generators(loaded)
    assert restored.keys() == generators.keys()
    for where, generator in generators.items():
        assert restored[where].bit_generator.state == generator.bit_generator.state, where


@algo_names
def test_save_to_a_file_object_and_without_extension(name: str, tmp_path: Path):
    case = CASES[name]
    model = case.make()
    model.learn(100)
    observations = observation_batch(model)
    expected, _ = model.predict(observations, deterministic=True)
    buffer = io.BytesIO()
    model.save(buffer)
    buffer.seek(0)
    np.testing.assert_array_equal(case.cls.load(buffer).predict(observations, deterministic=True)[0], expected)
    model.save(tmp_path / "no_extension")  # SB3 appends .zip
    loaded = case.cls.load(tmp_path / "no_extension")
    np.testing.assert_array_equal(loaded.predict(observations, deterministic=True)[0], expected)


def _rewrite_zip(source: Path, target: Path, data: Callable[[bytes], bytes | None]) -> None:
    """Copy the model archive ``source`` to ``target`` with its ``data`` entry passed through ``data`` (None: left
    out)."""
    with zipfile.ZipFile(source) as archive, zipfile.ZipFile(target, "w") as copy:
        for entry in archive.namelist():
            content = archive.read(entry)
            content = data(content) if entry == "data" else content
            if content is not None:
                copy.writestr(entry, content)


@algo_names
def test_load_of_a_damaged_or_foreign_file_says_what_the_file_is_and_what_to_do(name: str, tmp_path: Path):
    case = CASES[name]
    case.make().save(tmp_path / "model.zip")
    content = (tmp_path / "model.zip").read_bytes()
    (tmp_path / "truncated.zip").write_bytes(content[: len(content) // 2])
    _rewrite_zip(tmp_path / "model.zip", tmp_path / "no_data.zip", lambda data: None)
    _rewrite_zip(tmp_path / "model.zip", tmp_path / "damaged_data.zip", lambda data: data[: len(data) // 2])
    expected = {
        "truncated": "not a zip archive, or a truncated one.*re-save the model, or restore",
        "no_data": "without a 'data' entry, so it is not a Stable-Baselines3 model file",
        "damaged_data": "damaged data section.*re-save the model, or restore",
    }
    for file, message in expected.items():
        with pytest.raises(ModelFileError, match=message):
            case.cls.load(tmp_path / f"{file}.zip")
    # a file saved by another of our algorithms names the class to load it with
    other = CASES["cec" if name != "cec" else "mfec"]
    other.make().save(tmp_path / "other.zip")
    with pytest.raises(
        ModelFileError,
        match=rf"a model of {other.cls.__name__}, not of {case.cls.__name__}.*load it with {other.cls.__name__}\.load",
    ):
        case.cls.load(tmp_path / "other.zip")
    # a file without the class entry (SB3's own save writes none) loads as SB3 loads it
    with zipfile.ZipFile(tmp_path / "model.zip") as archive:
        assert archive.read(SAVED_BY_ENTRY).decode() == case.cls.__name__
    with zipfile.ZipFile(tmp_path / "model.zip") as archive, zipfile.ZipFile(tmp_path / "plain.zip", "w") as copy:
        for entry in archive.namelist():
            if entry != SAVED_BY_ENTRY:
                copy.writestr(entry, archive.read(entry))
    assert case.cls.load(tmp_path / "plain.zip").num_timesteps == 0


@algo_names
def test_a_failure_during_save_leaves_the_previous_file_intact(
    name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    case = CASES[name]
    model = case.make()
    model.save(tmp_path / "model.zip")
    before = (tmp_path / "model.zip").read_bytes()
    model.learn(100)

    def killed(*args: Any, **kwargs: Any) -> Any:
        raise KeyboardInterrupt  # as a kill in the middle of the archive (after the data and the parameters)

    monkeypatch.setattr(save_util, "get_system_info", killed)
    with pytest.raises(KeyboardInterrupt):
        model.save(tmp_path / "model.zip")
    assert (tmp_path / "model.zip").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.zip"]  # no temporary file left behind
    assert case.cls.load(tmp_path / "model.zip").num_timesteps == 0


def test_sb3s_own_load_of_an_episodic_control_file_names_the_algorithm(tmp_path: Path):
    for name, base in (("cec", SAC), ("mfec", DQN)):
        CASES[name].make().save(tmp_path / f"{name}.zip")
        algorithm = CASES[name].cls.__name__
        with pytest.raises(TypeError, match=rf"policy of {algorithm}: load {algorithm} models with {algorithm}.load"):
            base.load(tmp_path / f"{name}.zip")


@case_names
def test_policy_save_load(name: str, tmp_path: Path):
    case = ALL_CASES[name]
    model = case.make()
    model.learn(N_STEPS)
    observations = observation_batch(model)
    expected, _ = model.predict(observations, deterministic=True)
    model.policy.save(tmp_path / "policy.pth")
    policy = type(model.policy).load(tmp_path / "policy.pth")
    actions, _ = policy.predict(observations, deterministic=True)
    np.testing.assert_array_equal(actions, expected)


@algo_names
def test_set_parameters_copies_the_learned_state(name: str):
    case = CASES[name]
    trained = case.make(seed=0)
    trained.learn(N_STEPS)
    observations = observation_batch(trained)
    expected, _ = trained.predict(observations, deterministic=True)
    fresh = case.make(seed=1)
    fresh.set_parameters(trained.get_parameters(), exact_match=True)
    np.testing.assert_array_equal(fresh.predict(observations, deterministic=True)[0], expected)
    with pytest.raises(ValueError):
        fresh.set_parameters({"not_a_module": {}}, exact_match=True)


@algo_names
def test_optimizer_state_is_saved_where_there_is_one(name: str):
    model = CASES[name].make()
    state_dicts, _ = model._get_torch_save_params()
    optimizers = [n for n in state_dicts if "optimizer" in n]
    if name in NO_OPTIMIZER:
        # an episodic/tabular agent has no gradient step: nothing to save, and nothing claims otherwise
        assert optimizers == [], f"{name} has no optimizer but lists {optimizers}"
    else:
        assert optimizers, f"{name} trains a network: its optimizer state must be saved"
        params = model.get_parameters()
        assert all(n in params for n in optimizers)


# ---------------------------------------------------------------------------------------------------- bad data
class NanRewardAt(gym.Wrapper):
    """Return a NaN reward at the given step of the env's life (counted over episodes)."""

    def __init__(self, env: gym.Env, step: int = 5) -> None:
        super().__init__(env)
        self.nan_step, self.steps = step, 0

    def step(self, action: Any) -> Any:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.steps += 1
        return obs, float("nan") if self.steps == self.nan_step else reward, terminated, truncated, info


#: agents that do not learn from the env's reward: MoReFree learns its own distance reward (the env's reward is not
#: stored), IMGEP rewards reaching its own commanded goals
IGNORE_ENV_REWARD = {"morefree", "imgep"}


@algo_names
@pytest.mark.filterwarnings("ignore:.*so this call trains nothing")
def test_a_nan_reward_fails_at_the_step_that_returned_it(name: str):
    case = CASES[name]
    model = case.make(make_vec_env(case.env_id, n_envs=1, seed=0, wrapper_class=NanRewardAt))
    if name in IGNORE_ENV_REWARD:
        model.learn(20)
        return
    with pytest.raises(ValueError, match=r"^Env 0 returned the reward nan at timestep [45]: .*VecCheckNan"):
        model.learn(20)


# ---------------------------------------------------------------------------------------------------- determinism
def rollout_actions(model: BaseAlgorithm, n_steps: int = 50) -> tuple[np.ndarray, np.ndarray]:
    env = model.get_env()
    assert env is not None
    obs = env.reset()
    actions, rewards = [], []
    for _ in range(n_steps):
        action, _ = model.predict(obs, deterministic=False)
        obs, reward, _, _ = env.step(action)
        actions.append(np.asarray(action, dtype=np.float64).copy())
        rewards.append(reward.copy())
    return np.array(actions), np.array(rewards)


@algo_names
def test_seeded_training_is_deterministic(name: str):
    case = CASES[name]
    runs = []
    for _ in range(2):
        model = case.make(seed=3)
        model.learn(N_STEPS)
        runs.append((rollout_actions(model), model.get_parameters()))
    np.testing.assert_array_equal(runs[0][0][0], runs[1][0][0])
    np.testing.assert_array_equal(runs[0][0][1], runs[1][0][1])
    assert_same_state(runs[0][1], runs[1][1], "parameters")


@algo_names
def test_seeding_after_load_makes_sampling_and_learning_reproducible(name: str, tmp_path: Path):
    case = CASES[name]
    model = case.make()
    model.learn(N_STEPS)
    model.save(tmp_path / "model.zip")
    observations = observation_batch(model)
    results = []
    for copy in range(2):
        loaded = case.cls.load(tmp_path / "model.zip", env=case.make_env(seed=5))
        if copy == 0:  # this copy draws random numbers before it is seeded: seeding must make that irrelevant
            loaded.predict(observations, deterministic=False)
        loaded.set_random_seed(7)
        sampled = [loaded.predict(observations, deterministic=False)[0] for _ in range(5)]
        loaded.learn(100, reset_num_timesteps=False)
        results.append((sampled, loaded.get_parameters()))
    for a, b in zip(results[0][0], results[1][0]):
        np.testing.assert_array_equal(a, b)
    assert_same_state(results[0][1], results[1][1], "parameters after learn")


# ---------------------------------------------------------------------------------------------------- callbacks
class LocalsRecorder(BaseCallback):
    """Checks the hooks SB3 promises and the locals its stock callbacks read."""

    def __init__(self) -> None:
        super().__init__()
        self.events: list[str] = []
        self.missing: set[str] = set()

    def _on_training_start(self) -> None:
        self.events.append("training_start")

    def _on_rollout_start(self) -> None:
        self.events.append("rollout_start")

    def _on_step(self) -> bool:
        for key in ("dones", "infos", "new_obs", "rewards"):
            if key not in self.locals:
                self.missing.add(key)
        if "dones" in self.locals:
            assert len(self.locals["dones"]) == self.training_env.num_envs
        return True

    def _on_rollout_end(self) -> None:
        self.events.append("rollout_end")

    def _on_training_end(self) -> None:
        self.events.append("training_end")


@algo_names
def test_callbacks_see_sb3s_hooks_and_locals(name: str, tmp_path: Path):
    case = CASES[name]
    model = case.make(env=case.make_env(n_envs=case.n_envs))
    recorder = LocalsRecorder()
    eval_env = case.make_env()
    callbacks = CallbackList(
        [
            recorder,
            CheckpointCallback(save_freq=50, save_path=str(tmp_path / "checkpoints"), name_prefix="model"),
            EvalCallback(
                eval_env,
                eval_freq=50,
                n_eval_episodes=2,
                best_model_save_path=str(tmp_path / "best"),
                callback_after_eval=StopTrainingOnNoModelImprovement(max_no_improvement_evals=100),
                warn=False,
            ),
            EveryNTimesteps(n_steps=40, callback=CheckpointCallback(save_freq=1, save_path=str(tmp_path / "every"))),
        ]
    )
    model.learn(N_STEPS, callback=callbacks)
    assert recorder.missing == set(), f"{name} does not put {recorder.missing} into the callback locals"
    assert recorder.events[0] == "training_start" and recorder.events[-1] == "training_end"
    assert recorder.events.count("training_start") == 1 and recorder.events.count("training_end") == 1
    assert recorder.events.count("rollout_start") >= 1
    assert recorder.events.count("rollout_start") == recorder.events.count("rollout_end")
    assert recorder.n_calls == pytest.approx(model.num_timesteps / case.n_envs, abs=1)
    assert list((tmp_path / "checkpoints").glob("model_*_steps.zip"))
    assert (tmp_path / "best" / "best_model.zip").exists()
    assert list((tmp_path / "every").glob("*.zip"))
    case.cls.load(tmp_path / "best" / "best_model.zip")  # the checkpoints are loadable models


@algo_names
def test_stop_training_on_max_episodes(name: str):
    case = CASES[name]
    model = case.make()
    model.learn(20_000, callback=StopTrainingOnMaxEpisodes(max_episodes=2))
    assert model.num_timesteps < 20_000


class StopAfter(BaseCallback):
    def __init__(self, n_calls: int) -> None:
        super().__init__()
        self.stop_at = n_calls

    def _on_step(self) -> bool:
        return self.n_calls < self.stop_at


@algo_names
def test_a_callback_returning_false_stops_training(name: str):
    model = CASES[name].make()
    model.learn(5_000, callback=StopAfter(30))
    assert model.num_timesteps <= 30 * model.n_envs + 64  # off-policy SB3 may finish its train_freq chunk


@algo_names
def test_progress_bar_logger_and_tensorboard_run_name(name: str, tmp_path: Path):
    case = CASES[name]
    model = case.make(tensorboard_log=str(tmp_path / "tb"))
    model.learn(N_STEPS, progress_bar=True, log_interval=1)
    runs = sorted(p.name for p in (tmp_path / "tb").iterdir())
    assert runs == [f"{case.cls.__name__}_1"], f"tensorboard run named {runs}, expected the class name"

    model.set_logger(configure(str(tmp_path / "csv"), ["csv"]))
    model.learn(N_STEPS, reset_num_timesteps=False, log_interval=1)
    lines = (tmp_path / "csv" / "progress.csv").read_text().splitlines()
    assert len(lines) >= 2 and "time/total_timesteps" in lines[0]


@algo_names
def test_dump_logs_is_sb3s_public_hook(name: str, tmp_path: Path):
    """``model.dump_logs()`` writes the log (SB3's ``BaseAlgorithm.dump_logs`` only raises NotImplementedError)."""
    model = CASES[name].make()
    model.learn(N_STEPS)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.dump_logs()
    lines = (tmp_path / "progress.csv").read_text().splitlines()
    assert len(lines) == 2 and "time/total_timesteps" in lines[0]


@pytest.mark.parametrize(
    "name",
    sorted(
        n for n, case in CASES.items() if issubclass(case.cls, OffPolicyAlgorithm) or "learning_starts" in case.kwargs
    ),
)
def test_a_budget_within_learning_starts_warns_that_nothing_is_trained(name: str):
    model = CASES[name].make(learning_starts=40)
    with pytest.warns(UserWarning, match=r"budget of 20 timesteps is <= learning_starts=40") as record:
        model.learn(20)
    assert [w.filename for w in record if "learning_starts" in str(w.message)] == [__file__]  # the caller's line
    done = model.num_timesteps
    with pytest.warns(UserWarning, match=rf"{40 - done} \+ {done} already done = 40 timesteps"):
        model.learn(40 - done, reset_num_timesteps=False)  # SB3 counts the steps already done into the budget
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        model.learn(1, reset_num_timesteps=False)
        model.learn(41)
    assert not [w for w in record if "learning_starts" in str(w.message)]


# ---------------------------------------------------------------------------------------------------- envs
@algo_names
def test_learn_on_several_envs_and_set_env_after_load(name: str, tmp_path: Path):
    case = CASES[name]
    if not case.multi_env:
        with pytest.raises((ValueError, TypeError)):
            case.make(env=case.make_env(n_envs=2))
        return
    model = case.make(env=case.make_env(n_envs=2))
    model.learn(N_STEPS)
    assert model.num_timesteps >= N_STEPS
    model.save(tmp_path / "model.zip")
    loaded = case.cls.load(tmp_path / "model.zip")
    assert loaded.get_env() is None
    loaded.set_env(case.make_env(n_envs=2))
    loaded.learn(100, reset_num_timesteps=False)


@algo_names
def test_set_env_accepts_the_raw_env_that_load_accepts(name: str, tmp_path: Path):
    case = CASES[name]
    case.make().save(tmp_path / "model.zip")
    loaded = case.cls.load(tmp_path / "model.zip", env=gym.make(case.env_id))
    loaded.set_env(gym.make(case.env_id))
    loaded.learn(50, reset_num_timesteps=False)
    assert isinstance(loaded.get_env(), DummyVecEnv)


# ---------------------------------------------------------------------------------------------------- HER buffers
BIT_FLIPPING_VARIANTS = {
    "continuous": {"continuous": True},
    "discrete": {},
    "discrete_obs": {"discrete_obs_space": True},
    "image_obs": {"image_obs_space": True},
}


def her_setup(buffer: str, variant: str) -> tuple[Callable[[], gym.Env], dict[str, Any]]:
    """The env factory and the replay-buffer kwargs of one HER buffer of this package on SB3's BitFlippingEnv."""
    from stable_baselines3.common.envs import BitFlippingEnv

    from sb3_gcrl.her import ExecutedActionHerReplayBuffer, TaskRelevantHerReplayBuffer
    from sb3_gcrl.wrappers import GoalCommandWrapper

    def make_raw() -> gym.Env:
        return BitFlippingEnv(n_bits=4, **BIT_FLIPPING_VARIANTS[variant])

    kwargs: dict[str, Any] = {"n_sampled_goal": 2, "goal_selection_strategy": "future"}
    if buffer == "executed_action":
        return make_raw, {"replay_buffer_class": ExecutedActionHerReplayBuffer, "replay_buffer_kwargs": kwargs}
    return (
        lambda: GoalCommandWrapper(make_raw()),
        {
            "replay_buffer_class": TaskRelevantHerReplayBuffer,
            "replay_buffer_kwargs": {**kwargs, "task_goal_ratio": 0.5},
        },
    )


def her_model(
    env_fn: Callable[[], gym.Env], variant: str, her_kwargs: dict[str, Any], n_envs: int, buffer_size: int = 2_000
) -> BaseAlgorithm:
    from stable_baselines3 import DQN, SAC

    model_class = SAC if variant == "continuous" else DQN
    return model_class(
        "MultiInputPolicy",
        make_vec_env(env_fn, n_envs=n_envs, seed=0),
        train_freq=4,
        gradient_steps=n_envs,
        learning_starts=60,
        buffer_size=buffer_size,
        batch_size=16,
        policy_kwargs={"net_arch": [16]},
        seed=0,
        **her_kwargs,
    )


her_buffers = pytest.mark.parametrize("buffer", ["executed_action", "task_relevant"])


@her_buffers
@pytest.mark.parametrize("variant", sorted(BIT_FLIPPING_VARIANTS))
@pytest.mark.parametrize("n_envs", [1, 2])
def test_her_buffers_learn_on_bit_flipping(buffer: str, variant: str, n_envs: int):
    env_fn, her_kwargs = her_setup(buffer, variant)
    model = her_model(env_fn, variant, her_kwargs, n_envs)
    model.learn(150)
    assert model.replay_buffer.size() > 0
    mean, _ = evaluate_policy(model, Monitor(env_fn()), n_eval_episodes=2)
    assert np.isfinite(mean)


@her_buffers
@pytest.mark.parametrize("variant", ["continuous", "discrete"])
def test_her_buffer_save_load_keeps_its_content_and_keeps_learning(buffer: str, variant: str, tmp_path: Path):
    env_fn, her_kwargs = her_setup(buffer, variant)
    model = her_model(env_fn, variant, her_kwargs, n_envs=1)
    model.learn(150)
    old = model.replay_buffer
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    model.replay_buffer = None
    model.load_replay_buffer(tmp_path / "buffer.pkl")
    new = model.replay_buffer
    assert type(new) is type(old) and new.size() == old.size()
    for key in old.observations:
        np.testing.assert_array_equal(new.observations[key], old.observations[key])
    np.testing.assert_array_equal(new.actions, old.actions)
    np.testing.assert_array_equal(new.ep_start, old.ep_start)
    assert new.env is model.get_env()  # SB3 re-attaches the env for compute_reward
    new.sample(8, env=None)  # relabeling works after load (rewards recomputed through the env)
    model.learn(60, reset_num_timesteps=False)


@her_buffers
def test_her_buffer_wraps_around_when_full(buffer: str):
    env_fn, her_kwargs = her_setup(buffer, "discrete")
    model = her_model(env_fn, "discrete", her_kwargs, n_envs=2, buffer_size=40)  # 20 transitions per env
    model.learn(200)
    assert model.replay_buffer.full
    samples = model.replay_buffer.sample(32, env=None)
    assert np.isfinite(samples.rewards.numpy()).all()
