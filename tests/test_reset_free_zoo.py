"""The reset-free configs under RL-Zoo: evaluation stays episodic, every config runs, each setting is stated once.

MoReFree-SAC is the default section of each reset-free task in ``zoo_configs/sac.yml``; its baselines and ablations
are the variants ``<env id>@<method>`` of the same file.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from sb3_gcrl.zoo_config import read_zoo_config, resolve_config, split_section_key

REPO = Path(__file__).resolve().parents[1]
SAC = REPO / "zoo_configs" / "sac.yml"
ENV_ID = "GCRL/PointUMazeGoal-v0"
RESET_FREE_TASKS = (
    "GCRL/PointUMazeGoal-v0", "GCRL/AntArena-v0", "GCRL/Tabletop-v0", "GCRL/SawyerDoor-v0", "GCRL/ErgodicFetchPush-v0",
    "GCRL/ErgodicFetchPickAndPlace-v0", "GCRL/FetchPushHard-v0", "GCRL/FetchPickAndPlaceHard-v0",
)  # fmt: skip
#: (env id, variant) of every section of MoReFree-SAC and its baselines and ablations (not the post-exploration ones)
SECTIONS = [
    split_section_key(key)
    for key in read_zoo_config(SAC)
    if split_section_key(key)[0] in RESET_FREE_TASKS and "post_exploration" not in key
]
#: the Ch. 3 methods on PointUMaze: MoReFree-SAC (None: the default section) and its variants
METHODS = [variant for env_id, variant in SECTIONS if env_id == ENV_ID]
# tiny budget: small nets, updates start after the first 300-step segment, evaluation after 300 and 600 steps
FAST = ["learning_starts:400", "batch_size:32", "policy_kwargs:dict(net_arch=[16])"]


def zoo_train(config: Path, folder: Path, steps: int, eval_freq: int, variant: str | None = None) -> tuple[Path, str]:
    """Run ``python -m rl_zoo3.train`` (what ``sb3-gcrl train`` wraps) with a tiny budget, or for a variant (a section
    ``<env id>@<variant>``, which RL-Zoo does not read) ``sb3-gcrl train --variant``; the run folder, stdout."""
    command = ["rl_zoo3.train"] if variant is None else ["sb3_gcrl", "train", "--variant", variant]
    cmd = [
        sys.executable, "-m", *command, "--algo", "sac", "--env", ENV_ID, "-conf", str(config),
        "--gym-packages", "sb3_gcrl", "-n", str(steps), "--eval-freq", str(eval_freq), "--eval-episodes", "1",
        "--seed", "0", "--num-threads", "1", "--log-interval", "1", "-f", str(folder), "-params", *FAST,
    ]  # fmt: skip
    result = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=900)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    runs = sorted(folder.glob(f"sac/{ENV_ID.replace('/', '-')}_*"))
    assert runs, result.stdout[-2000:]
    return runs[-1], result.stdout


def test_configs_cover_the_methods_of_chapter_3() -> None:
    assert {"oracle", "naive", "goexplore", None, "wo_bf", "wo_relabel", "alpha1"} <= set(METHODS)
    morefree = resolve_config("sac", ENV_ID).hyperparams  # MoReFree-SAC: the default section
    assert "TaskRelevantHerReplayBuffer" in morefree["replay_buffer_class"]
    wrapper = morefree["env_wrapper"][1]["sb3_gcrl.wrappers.GoExploreWrapper"]
    assert wrapper["scheduler"] == "back_and_forth" and wrapper["scheduler_kwargs"]["alpha"] == 0.2


@pytest.mark.parametrize(("env_id", "variant"), SECTIONS, ids=[f"{e}@{v}" for e, v in SECTIONS])
def test_every_config_states_alpha_and_each_horizon_once(env_id: str, variant: str | None) -> None:
    text = resolve_config("sac", env_id, variant).to_yaml()
    assert text.count("eval_horizon:") <= 1  # ResetFreeWrapper's; GoExploreWrapper reads it
    assert text.count("alpha:") + text.count("task_goal_ratio=") <= 1  # the buffer reads the scheduler's alpha
    assert text.count("hard_reset_every:") <= 1


def test_zoo_evaluation_is_episodic_while_training_is_reset_free(tmp_path: Path, monkeypatch) -> None:
    # plain `rl_zoo3 train -conf zoo_configs/sac.yml`: RL-Zoo picks the env's own section, MoReFree-SAC
    run, stdout = zoo_train(SAC, tmp_path, 600, 300)
    evaluations = np.load(run / "evaluations.npz")
    assert list(evaluations["timesteps"]) == [300, 600]
    # the eval env got the same env_wrapper, yet its episodes are T_eval long (no Go/Explore segment ends)
    assert np.all(evaluations["ep_lengths"] == 300)
    # training curves: the training Monitor's CSV holds the Go-Explore segments (no physical episode ended in 600
    # reset-free steps), with the success column the config asks for; SB3 logs them as rollout/*
    from stable_baselines3.common.monitor import load_results

    rows = load_results(str(run))
    assert len(rows) >= 2 and rows.l.max() <= 300 and rows.l.sum() <= 600
    assert set(rows.columns) >= {"r", "l", "t", "is_success"}
    for key in ("ep_len_mean ", "ep_rew_mean ", "success_rate ", "goal_success_"):  # goal kinds: seed-dependent
        assert f"|    {key}" in stdout
    # rl_zoo3 plot_train finds and plots them
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from rl_zoo3.plots.plot_train import plot_train

    for y_axis in ("reward", "success", "length"):
        argv = ["plot_train", "-a", "sac", "-e", "PointUMazeGoal", "-f", str(tmp_path), "-w", "1", "-y", y_axis]
        monkeypatch.setattr("sys.argv", argv)
        monkeypatch.setattr(plt, "show", lambda: None)
        plot_train()
        (line,) = plt.gca().get_lines()
        assert len(line.get_xdata()) == len(rows)
        plt.close("all")


@pytest.mark.slow
@pytest.mark.parametrize("variant", METHODS, ids=[str(m) for m in METHODS])
def test_every_config_trains_briefly(variant: str | None, tmp_path: Path) -> None:
    run, _ = zoo_train(SAC, tmp_path, steps=1200, eval_freq=600, variant=variant)
    evaluations = np.load(run / "evaluations.npz")
    assert np.all(evaluations["ep_lengths"] == 300)
    assert (run / f"{ENV_ID.replace('/', '-')}.zip").exists()


@pytest.mark.slow
@pytest.mark.parametrize(("env_id", "variant"), SECTIONS, ids=[f"{e}@{v}" for e, v in SECTIONS])
def test_every_config_builds_its_wrapped_env(env_id: str, variant: str | None) -> None:
    """Each task's sections: the env_wrapper chain RL-Zoo builds accepts its kwargs and runs reset-free."""
    import gymnasium as gym
    from rl_zoo3.utils import get_wrapper_class

    import sb3_gcrl  # noqa: F401 (registers GCRL/ envs)

    wrapper = get_wrapper_class(resolve_config("sac", env_id, variant).hyperparams)
    env = gym.make(env_id)
    env = wrapper(env) if wrapper is not None else env
    env.reset(seed=0)
    if hasattr(env, "set_training_mode"):
        env.set_training_mode(True)
    env.action_space.seed(0)
    for _ in range(60):
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        assert "is_success" in info
        if terminated or truncated:
            env.reset()
    env.close()


@pytest.mark.parametrize("config", sorted((REPO / "zoo_configs").glob("*.yml")), ids=lambda p: p.stem)
def test_every_config_with_a_mode_switched_wrapper_has_its_callback(config: Path) -> None:
    from sb3_gcrl.zoo_checks import check_mode_switching_callbacks

    for key, section in read_zoo_config(config).items():  # variants (<env id>@<variant>) included
        check_mode_switching_callbacks(section, f"{config.name} ({key})")


def test_wrappers_without_their_switching_callback_are_refused(tmp_path: Path) -> None:
    from sb3_gcrl.cli import main
    from sb3_gcrl.zoo_checks import check_mode_switching_callbacks

    wrapper = {"sb3_gcrl.wrappers.ResetFreeWrapper": {"eval_horizon": 300}}
    reset_free = "sb3_gcrl.callbacks.ResetFreeCallback"
    post = "sb3_gcrl.post_exploration.PostExplorationCallback"
    for section, missing in (
        ({"env_wrapper": [wrapper]}, reset_free),
        ({"env_wrapper": "sb3_gcrl.wrappers.GoExploreWrapper"}, reset_free),
        ({"env_wrapper": [wrapper], "callback": ["sb3_gcrl.callbacks.VisitationCallback"]}, reset_free),
        ({"env_wrapper": [{"sb3_gcrl.post_exploration.PostExplorationWrapper": {"n_pe": 3}}]}, post),
        ({"env_wrapper": "sb3_gcrl.post_exploration.PostExplorationWrapper", "callback": reset_free}, post),
    ):
        with pytest.raises(ValueError, match=f"(?s)has no {missing.rsplit('.', 1)[1]}.*- {missing}"):
            check_mode_switching_callbacks(section)
    check_mode_switching_callbacks({"env_wrapper": [wrapper], "callback": reset_free})
    check_mode_switching_callbacks({"env_wrapper": [wrapper], "callback": [{reset_free: {"log_freq": 10}}]})
    check_mode_switching_callbacks(
        {"env_wrapper": "sb3_gcrl.post_exploration.PostExplorationWrapper", "callback": post}
    )
    check_mode_switching_callbacks({"env_wrapper": "sb3_contrib.common.wrappers.TimeFeatureWrapper"})

    # the CLI stops before any training, naming the fix
    config = tmp_path / "forgot_callback.yml"
    config.write_text(
        yaml.safe_dump({ENV_ID: {"n_timesteps": 100, "policy": "MultiInputPolicy", "env_wrapper": [wrapper]}})
    )
    with pytest.raises(SystemExit, match="ResetFreeCallback"):
        main(["train", "--algo", "sac", "--env", ENV_ID, "-conf", str(config), "-f", str(tmp_path / "logs")])
    assert not (tmp_path / "logs").exists()
