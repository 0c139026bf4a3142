"""The reset-free agents in subprocess envs: they read and answer the Go/Explore wrapper through the VecEnv API only.

The world-model agent (PEG goals planned on the wrapper's request, pi_E acting where ``acting_policy`` says
``"explorer"``) and MoReFree-SAC (stock SAC, the wrapper's own explorer) train in a ``SubprocVecEnv`` with the
wrappers of their configs, in Python and through RL-Zoo's ``--vec-env subproc``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rl_zoo3.utils import get_wrapper_class
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv
from test_morefree import TINY_ALGO, ExplorerCheck, reset_free_env

import sb3_gcrl  # noqa: F401  (registers the GCRL/ envs)
from sb3_gcrl.callbacks import ResetFreeCallback
from sb3_gcrl.her import TaskRelevantHerReplayBuffer
from sb3_gcrl.morefree import MoReFree

REPO = Path(__file__).resolve().parents[1]
ENV_ID = "GCRL/PointUMazeGoal-v0"


def config(name: str) -> dict[str, Any]:
    """The hyperparameters of ``zoo_configs/<name>.yml`` for PointUMaze (the env's default section)."""
    return yaml.safe_load((REPO / "zoo_configs" / f"{name}.yml").read_text())[ENV_ID]


def subprocess_env(hyperparams: dict[str, Any], n_envs: int = 2) -> VecEnv:
    """PointUMaze in a ``SubprocVecEnv``, wrapped by the config's ``env_wrapper`` as RL-Zoo wraps it."""
    return make_vec_env(
        ENV_ID, n_envs=n_envs, seed=0, wrapper_class=get_wrapper_class(hyperparams), vec_env_cls=SubprocVecEnv
    )


class Trace(BaseCallback):
    """The actions, rewards and observations of every step."""

    def __init__(self) -> None:
        super().__init__()
        self.steps: list[tuple[np.ndarray, ...]] = []

    def _on_step(self) -> bool:
        obs = self.locals["new_obs"]
        self.steps.append(
            (self.locals["actions"].copy(), self.locals["rewards"].copy(), *(obs[k] for k in sorted(obs)))
        )
        return True


class WrapperExplorerCheck(BaseCallback):
    """Reads ``acting_policy`` through the VecEnv before each step; checks that every step the wrapper announced as
    its explorer's executed the wrapper's action (reported in ``info["executed_action"]``), not the agent's."""

    def __init__(self) -> None:
        super().__init__()
        self.acting: list[str] = []
        self.seen: set[str] = set()
        self.explore_steps = 0

    def _on_training_start(self) -> None:
        self.acting = self.training_env.get_attr("acting_policy")

    def _on_step(self) -> bool:
        for i, info in enumerate(self.locals["infos"]):
            assert ("executed_action" in info) == (self.acting[i] == "wrapper")
            if "executed_action" in info:
                self.explore_steps += 1
                assert not np.array_equal(info["executed_action"], self.locals["actions"][i])
        self.acting = self.training_env.get_attr("acting_policy")
        self.seen.update(self.acting)
        return True


def test_morefree_trains_in_subprocess_envs_with_peg_goals_and_its_explorer() -> None:
    hyperparams = config("morefree")
    env = subprocess_env(hyperparams)
    try:
        model = MoReFree("MultiInputPolicy", env, seed=0, **{**TINY_ALGO, "learning_starts": 100})
        explorer = ExplorerCheck()
        model.learn(900, callback=[ResetFreeCallback(), explorer])
        assert explorer.explorer_steps > 0  # pi_E's actions executed in Explore phases, after learning started
        counts = env.get_attr("planned_goal_counts")
        assert sum(c["planned"] for c in counts) > 0  # PEG goals planned in this process, commanded in the workers
        assert all(p["explore"] > 0 for p in env.get_attr("phase_steps_total"))
        assert env.env_method("goal_request") == [None, None]  # every request answered; planning off after learn
        assert env.get_attr("agent_explores") == [True, True]
    finally:
        env.close()


def test_morefree_runs_alike_in_dummy_and_subprocess_envs() -> None:
    """The planner draws from each wrapper's generator: the VecEnv class changes nothing, step for step."""
    traces = []
    for vec_env_cls in (DummyVecEnv, SubprocVecEnv):
        env = make_vec_env(
            "GCRL/GrowingTreeGoal-v0", n_envs=2, seed=0, wrapper_class=reset_free_env(eval_horizon=20),
            vec_env_cls=vec_env_cls,
        )  # fmt: skip
        try:
            trace = Trace()
            MoReFree("MultiInputPolicy", env, seed=0, **TINY_ALGO).learn(300, callback=[ResetFreeCallback(), trace])
            assert sum(c["planned"] for c in env.get_attr("planned_goal_counts")) > 0
            traces.append(trace.steps)
        finally:
            env.close()
    dummy, subprocess = traces
    assert len(dummy) == len(subprocess) == 150
    for step_dummy, step_subprocess in zip(dummy, subprocess):
        for a, b in zip(step_dummy, step_subprocess):
            np.testing.assert_array_equal(a, b)


def test_sac_port_trains_in_subprocess_envs_with_the_wrappers_explorer() -> None:
    hyperparams = config("sac")  # MoReFree-SAC
    assert "TaskRelevantHerReplayBuffer" in hyperparams["replay_buffer_class"]
    env = subprocess_env(hyperparams)
    try:
        model = SAC(
            "MultiInputPolicy",
            env,
            replay_buffer_class=TaskRelevantHerReplayBuffer,
            replay_buffer_kwargs=eval(hyperparams["replay_buffer_kwargs"]),  # noqa: S307 (as RL-Zoo reads it)
            learning_starts=700,  # after each env's first Go-Explore segment (<= 300 steps): HER can sample
            batch_size=32,
            train_freq=hyperparams["train_freq"],
            policy_kwargs={"net_arch": [16]},
            seed=0,
        )
        explorer = WrapperExplorerCheck()
        model.learn(1000, callback=[ResetFreeCallback(), explorer])
        assert explorer.explore_steps > 0 and explorer.seen == {"goal", "wrapper"}
        assert explorer.explore_steps == sum(p["explore"] for p in env.get_attr("phase_steps_total"))
        assert env.get_attr("agent_explores") == [False, False]
        assert model.replay_buffer.size() > 0 and model.num_timesteps == 1000
    finally:
        env.close()


def test_zoo_trains_morefree_with_subprocess_envs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``sb3-gcrl train --algo morefree ... --vec-env subproc`` with the CPU config's wrappers, tiny networks."""
    from sb3_gcrl.cli import main

    hyperparams = config("morefree")
    tiny = {key: hyperparams[key] for key in ("policy", "env_wrapper", "callback")}
    tiny.update(n_timesteps=800, n_envs=2, buffer_size=10_000, **{**TINY_ALGO, "learning_starts": 100})
    tiny["policy_kwargs"] = repr(TINY_ALGO["policy_kwargs"])
    for callback in tiny["callback"]:  # diagnostics at 400 steps (path distances computed in the workers)
        if "sb3_gcrl.morefree.MoReFreeDiagnosticsCallback" in callback:
            callback["sb3_gcrl.morefree.MoReFreeDiagnosticsCallback"].update(diagnose_freq=400, n=16)
    path = tmp_path / "tiny.yml"
    path.write_text(yaml.safe_dump({ENV_ID: tiny}))
    logs = tmp_path / "logs"
    argv = ["train", "--algo", "morefree", "--env", ENV_ID, "-conf", str(path), "--vec-env", "subproc"]
    argv += ["-f", str(logs), "--eval-freq", "-1", "--seed", "0", "--log-interval", "1"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "peg_goals_planned" in out and "diagnostics at 400" in out
    (run,) = (logs / "morefree").glob("GCRL-PointUMazeGoal-v0_*")
    assert (run / "GCRL-PointUMazeGoal-v0.zip").exists()
