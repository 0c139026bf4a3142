"""The reset-free configs under RL-Zoo: evaluation stays episodic, every config runs, each setting is stated once."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
CONFIGS = sorted((REPO / "zoo_configs").glob("reset_free_pointumaze_*.yml"))
ENV_ID = "GCRL/PointUMazeGoal-v0"
# tiny budget: small nets, updates start after the first 300-step segment, evaluation after 300 and 600 steps
FAST = ["learning_starts:400", "batch_size:32", "policy_kwargs:dict(net_arch=[16])"]


def zoo_train(config: Path, folder: Path, steps: int, eval_freq: int) -> tuple[Path, str]:
    """Run ``python -m rl_zoo3.train`` (what ``sb3-gcrl train`` wraps) with a tiny budget; the run folder, stdout."""
    cmd = [
        sys.executable, "-m", "rl_zoo3.train", "--algo", "sac", "--env", ENV_ID, "-conf", str(config),
        "--gym-packages", "sb3_gcrl", "-n", str(steps), "--eval-freq", str(eval_freq), "--eval-episodes", "1",
        "--seed", "0", "--num-threads", "1", "--log-interval", "1", "-f", str(folder), "-params", *FAST,
    ]  # fmt: skip
    result = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=900)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    runs = sorted(folder.glob(f"sac/{ENV_ID.replace('/', '-')}_*"))
    assert runs, result.stdout[-2000:]
    return runs[-1], result.stdout


def test_configs_cover_the_methods_of_chapter_3() -> None:
    names = {path.stem.removeprefix("reset_free_pointumaze_") for path in CONFIGS}
    assert {"oracle", "naive", "goexplore", "morefree", "wo_bf", "wo_relabel", "alpha1"} <= names
    morefree = yaml.safe_load((REPO / "zoo_configs" / "reset_free_pointumaze_morefree.yml").read_text())[ENV_ID]
    assert "TaskRelevantHerReplayBuffer" in morefree["replay_buffer_class"]
    wrapper = morefree["env_wrapper"][1]["sb3_gcrl.wrappers.GoExploreWrapper"]
    assert wrapper["scheduler"] == "back_and_forth" and wrapper["scheduler_kwargs"]["alpha"] == 0.2


@pytest.mark.parametrize("config", sorted((REPO / "zoo_configs").glob("reset_free_*.yml")), ids=lambda p: p.stem)
def test_every_config_states_alpha_and_each_horizon_once(config: Path) -> None:
    text = config.read_text()
    assert text.count("eval_horizon:") <= 1  # ResetFreeWrapper's; GoExploreWrapper reads it
    assert text.count("alpha:") + text.count("task_goal_ratio=") <= 1  # the buffer reads the scheduler's alpha
    assert text.count("hard_reset_every:") <= 1


SUITE = ("pointumaze", "fetch_push", "fetch_pick_and_place", "fetch_push_hard", "fetch_pick_and_place_hard", "ant")
SUITE += ("tabletop", "sawyer_door")


@pytest.mark.parametrize("task", SUITE)
def test_every_task_has_a_smaller_cpu_preset_of_the_same_method(task: str) -> None:
    """``reset_free_<task>_morefree_cpu.yml``: the thesis-scale MoReFree config, with a smaller SAC updated less.

    The other keys (the method) are equal.
    """
    from sb3_gcrl.zoo_config import read_zoo_config

    ((env_id, thesis),) = read_zoo_config(REPO / "zoo_configs" / f"reset_free_{task}_morefree.yml").items()
    ((cpu_env_id, cpu),) = read_zoo_config(REPO / "zoo_configs" / f"reset_free_{task}_morefree_cpu.yml").items()
    assert cpu_env_id == env_id
    smaller = {"policy_kwargs", "batch_size", "train_freq", "n_timesteps", "monitor_kwargs"}
    assert {key: value for key, value in cpu.items() if key not in smaller} == {
        key: value for key, value in thesis.items() if key not in smaller
    }  # same method: wrappers, horizons, alpha, bins, buffer, callback, gamma, learning rate
    net = eval(cpu["policy_kwargs"])["net_arch"]  # noqa: S307 (RL-Zoo eval()s this key too)
    assert max(net) <= 128 and len(net) == 2 and sum(net) < sum(eval(thesis["policy_kwargs"])["net_arch"])  # noqa: S307
    assert cpu["batch_size"] < thesis["batch_size"] and cpu["train_freq"] >= 2 * thesis["train_freq"]
    assert cpu["gradient_steps"] == 1 and "is_success" in cpu["monitor_kwargs"]


def test_zoo_evaluation_is_episodic_while_training_is_reset_free(tmp_path: Path, monkeypatch) -> None:
    run, stdout = zoo_train(REPO / "zoo_configs" / "reset_free_pointumaze_morefree.yml", tmp_path, 600, 300)
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
@pytest.mark.parametrize("config", CONFIGS, ids=[path.stem for path in CONFIGS])
def test_every_config_trains_briefly(config: Path, tmp_path: Path) -> None:
    run, _ = zoo_train(config, tmp_path, steps=1200, eval_freq=600)
    evaluations = np.load(run / "evaluations.npz")
    assert np.all(evaluations["ep_lengths"] == 300)
    assert (run / f"{ENV_ID.replace('/', '-')}.zip").exists()


ALL_CONFIGS = sorted((REPO / "zoo_configs").glob("reset_free_*.yml"))


@pytest.mark.slow
@pytest.mark.parametrize("config", ALL_CONFIGS, ids=[path.stem for path in ALL_CONFIGS])
def test_every_config_builds_its_wrapped_env(config: Path) -> None:
    """Each task's config: the env_wrapper chain RL-Zoo builds accepts its kwargs and runs reset-free."""
    import gymnasium as gym
    from rl_zoo3.utils import get_wrapper_class

    import sb3_gcrl  # noqa: F401 (registers GCRL/ envs)

    ((env_id, hyperparams),) = yaml.safe_load(config.read_text()).items()
    wrapper = get_wrapper_class(hyperparams)
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
    from sb3_gcrl.zoo_config import check_mode_switching_callbacks, read_zoo_config

    for env_id, section in read_zoo_config(config).items():
        check_mode_switching_callbacks(section, f"{config.name} ({env_id})")


def test_wrappers_without_their_switching_callback_are_refused(tmp_path: Path) -> None:
    from sb3_gcrl.cli import main
    from sb3_gcrl.zoo_config import check_mode_switching_callbacks

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
