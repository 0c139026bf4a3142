"""MoReFree-SAC built in Python (:mod:`sb3_gcrl.morefree_sac`) is its ``sac.yml`` section, not a lookalike: with the
same seed and overrides, RL-Zoo's run of the section and the builders' agent take the same actions, store the same
replay contents and end with the same weights."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch as th

from sb3_gcrl import morefree_sac
from sb3_gcrl.her import TaskRelevantHerReplayBuffer
from sb3_gcrl.zoo_config import ZOO_CONFIGS_DIR, resolve_config

ENV_ID = morefree_sac.ENV_ID
STEPS = 600
#: a tiny learner: updates start after the first 300-step Go-Explore segment (150 updates in 600 steps)
OVERRIDES = {"learning_starts": 300, "batch_size": 32, "buffer_size": 2_000, "policy_kwargs": "dict(net_arch=[16, 16])"}


def rl_zoo_agent(folder: Path, monkeypatch: pytest.MonkeyPatch):
    """Stock ``rl_zoo3 train -conf zoo_configs/sac.yml`` (the env's default section), in this process; its model."""
    import rl_zoo3.train
    from rl_zoo3.exp_manager import ExperimentManager

    trained = []
    monkeypatch.setattr(ExperimentManager, "save_trained_model", lambda self, model: trained.append(model))
    params = [f"{key}:{value!r}" if isinstance(value, str) else f"{key}:{value}" for key, value in OVERRIDES.items()]
    config = str(ZOO_CONFIGS_DIR / "sac.yml")
    monkeypatch.setattr(sys, "argv", [
        "train", "--algo", "sac", "--env", ENV_ID, "--gym-packages", "sb3_gcrl", "-conf", config, "-n", str(STEPS),
        "--seed", "0", "--eval-freq", "-1", "--num-threads", "1", "--verbose", "0", "-f", str(folder),
        "-params", *params,
    ])  # fmt: skip
    rl_zoo3.train.train()
    (model,) = trained
    return model


def python_agent():
    """The module docstring's example, with the same overrides."""
    env = morefree_sac.make_env(ENV_ID, seed=0)
    model = morefree_sac.make_agent(env, seed=0, **OVERRIDES)
    model.learn(STEPS, callback=morefree_sac.make_callback(env))
    return model


def test_the_builders_train_the_agent_rl_zoo_trains_from_the_section(tmp_path: Path, monkeypatch) -> None:
    zoo = rl_zoo_agent(tmp_path, monkeypatch)
    ours = python_agent()
    # the same chain, buffer, learner
    assert repr(ours.env.envs[0]) == repr(zoo.env.envs[0])
    assert type(ours.replay_buffer) is type(zoo.replay_buffer) is TaskRelevantHerReplayBuffer
    assert ours.env.get_attr("task_goal_alpha") == zoo.env.get_attr("task_goal_alpha") == [0.2]
    assert (ours.num_timesteps, ours._n_updates) == (zoo.num_timesteps, zoo._n_updates) == (STEPS, 150)
    # the same actions (the executed ones the buffer stores, Explore phases included) and replay contents
    ours_buffer, zoo_buffer = vars(ours.replay_buffer), vars(zoo.replay_buffer)
    for key in ("actions", "rewards", "dones", "timeouts", "ep_start", "ep_length"):
        np.testing.assert_array_equal(ours_buffer[key], zoo_buffer[key], err_msg=key)
    for key in ("observations", "next_observations"):
        for part in ours_buffer[key]:
            np.testing.assert_array_equal(ours_buffer[key][part], zoo_buffer[key][part], err_msg=f"{key}/{part}")
    assert ours.replay_buffer.pos == STEPS and np.abs(ours_buffer["actions"][:STEPS]).sum() > 0
    # the same losses all the way: equal weights after 150 updates, equal last logged losses
    for (name, value), (zoo_name, zoo_value) in zip(
        ours.policy.state_dict().items(), zoo.policy.state_dict().items(), strict=True
    ):
        assert name == zoo_name and th.equal(value, zoo_value), name
    assert th.equal(ours.log_ent_coef, zoo.log_ent_coef)
    for key in ("train/actor_loss", "train/critic_loss", "train/ent_coef_loss"):
        assert ours.logger.name_to_value[key] == zoo.logger.name_to_value[key], key


def test_alpha_is_the_back_and_forth_schedulers_and_alpha_1_is_the_shipped_ablation() -> None:
    env_wrapper = morefree_sac.config_section(ENV_ID)["env_wrapper"]
    ablation = resolve_config("sac", ENV_ID, "alpha1").hyperparams
    assert morefree_sac._with_alpha(env_wrapper, 1.0) == ablation["env_wrapper"]
    env = morefree_sac.make_env(ENV_ID, seed=0, alpha=1.0)
    assert env.get_attr("task_goal_alpha") == [1.0]  # what TaskRelevantHerReplayBuffer reads


def test_every_reset_free_task_has_its_section_and_other_sections_are_refused() -> None:
    assert morefree_sac.env_ids()[0] == ENV_ID and "GCRL/FetchPushHard-v0" in morefree_sac.env_ids()
    with pytest.raises(ValueError, match="is not MoReFree-SAC"):
        morefree_sac.config_section("GCRL/GrowingTree-v0")


def test_make_agent_refuses_env_settings_and_unknown_ones() -> None:
    env = morefree_sac.make_env(ENV_ID, seed=0)
    with pytest.raises(ValueError, match="make_env builds the env"):
        morefree_sac.make_agent(env, env_wrapper=[])
    with pytest.raises(ValueError, match="did you mean 'learning_starts'"):
        morefree_sac.make_agent(env, learning_start=300)
