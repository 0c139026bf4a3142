"""Interrupted runs lose nothing that was saved: ``sb3-gcrl train`` checkpoints, exits 130 on Ctrl-C, resumes."""

from __future__ import annotations

import json
import os
import pickle
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from stable_baselines3.common.monitor import load_results

from sb3_gcrl.common.checkpoints import (
    CheckpointError,
    checkpoint_steps,
    latest_checkpoint,
    restore_checkpoint,
    save_checkpoint,
)
from sb3_gcrl.zoo_train import INTERRUPTED_EXIT_CODE

ENV = "GCRL/PointUMazeGoal-v0"
ENV_NAME = "GCRL-PointUMazeGoal-v0"
#: MoReFree-SAC (SAC; Back-and-Forth Go-Explore wrappers, task-relevant HER), the default section of
#: zoo_configs/sac.yml: a tiny, cheap version of it
TRAIN = [
    "train", "--algo", "sac", "--env", ENV, "-n", "3000",
    "--save-freq", "1000", "--eval-freq", "1000", "--eval-episodes", "1", "-f", "logs", "--seed", "1",
    "-params", "learning_starts:2500", "batch_size:8", "policy_kwargs:dict(net_arch=[8])", "gradient_steps:1",
    "train_freq:4",
]  # fmt: skip


def _start(cwd: Path, arguments: list[str]) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "sb3_gcrl", *arguments],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )


def _stop_after_first_checkpoint(process: subprocess.Popen[str], run_dir: Path, sig: signal.Signals) -> str:
    latest = run_dir / "checkpoints" / "latest"
    deadline = time.monotonic() + 300
    while not latest.is_file() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert process.poll() is None, "the run ended before its first checkpoint"
    process.send_signal(sig)
    output, _ = process.communicate(timeout=300)
    return output


def _wrapper_state(checkpoint: Path) -> dict:
    (state,) = pickle.loads((checkpoint / "env_state.pkl").read_bytes())
    return {name: attributes for name, attributes in pickle.loads(state)}


@pytest.mark.parametrize(
    ("sig", "variant"), [(signal.SIGINT, None), (signal.SIGKILL, "wo_relabel")], ids=["sigint", "sigkill-variant"]
)
def test_interrupted_run_resumes_with_everything_saved(
    tmp_path: Path, sig: signal.Signals, variant: str | None
) -> None:
    """A killed run resumes; one of a variant (``--variant``) with the section written to its folder."""
    run_dir = tmp_path / "logs" / "sac" / f"{ENV_NAME}_1"
    train = TRAIN if variant is None else [*TRAIN, "--variant", variant]
    output = _stop_after_first_checkpoint(_start(tmp_path, train), run_dir, sig)
    if sig == signal.SIGINT:
        # RL-Zoo's own final save, then the shell's exit code for Ctrl-C, and a checkpoint at the interruption
        assert "Interrupted at step" in output and "sb3-gcrl train --resume" in output, output[-3000:]
        assert (run_dir / f"{ENV_NAME}.zip").is_file()
    checkpoint = latest_checkpoint(run_dir)
    steps = checkpoint_steps(checkpoint)
    assert 1000 <= steps < 3000
    saved_state = _wrapper_state(checkpoint)["GoExploreWrapper"]
    assert sum(saved_state["goal_counts"].values()) > 0
    with np.load(run_dir / "evaluations.npz") as data:
        evaluations_before = data["timesteps"][data["timesteps"] <= steps].tolist()
    monitor_rows_before = len(load_results(str(run_dir)))

    resumed = _start(tmp_path, ["train", "--resume", str(run_dir)])
    output = resumed.communicate(timeout=600)[0]
    assert resumed.returncode == 0, output[-3000:]
    assert "Resuming the run" in output
    if variant is not None:  # the variant's section, read back from the run's folder
        from sb3_gcrl.zoo_train import CONFIG_FILE

        section_file = run_dir / ENV_NAME / CONFIG_FILE
        assert f"Loading hyperparameters from: {section_file}" in output
        assert "ExecutedActionHerReplayBuffer" in section_file.read_text()
    assert [path.name for path in (tmp_path / "logs" / "sac").iterdir()] == [run_dir.name]  # the same run folder
    final = latest_checkpoint(run_dir)
    assert checkpoint_steps(final) == 3000  # the counter continued to the run's own budget
    from stable_baselines3.common.save_util import load_from_zip_file

    # SB3 collects train_freq (4) steps per chunk: a run resumed from a step that is not a multiple of 4 ends within
    # one chunk past its budget, as SB3's own learn does for a budget that is not a multiple of train_freq
    assert 3000 <= load_from_zip_file(run_dir / f"{ENV_NAME}.zip")[0]["num_timesteps"] < 3004
    with np.load(run_dir / "evaluations.npz") as data:
        timesteps = data["timesteps"].tolist()
    assert timesteps[: len(evaluations_before)] == evaluations_before  # kept, not overwritten
    assert timesteps == sorted(set(timesteps)) and timesteps[-1] == 3000  # every evaluation once, on its rhythm
    monitor = load_results(str(run_dir))
    assert len(monitor) > monitor_rows_before  # the monitor CSV was extended
    assert monitor["l"].sum() <= 3000  # rows of steps taken again after a kill are not there twice
    final_state = _wrapper_state(final)["GoExploreWrapper"]
    for kind, count in saved_state["goal_counts"].items():  # the wrappers went on from their saved counts
        assert final_state["goal_counts"][kind] >= count
    assert sum(final_state["goal_counts"].values()) > sum(saved_state["goal_counts"].values())
    assert not [path for path in (run_dir / "checkpoints").iterdir() if path.name.startswith(".")]


def test_checkpoint_round_trip_restores_wrapper_state_and_generators(tmp_path: Path) -> None:
    import gymnasium as gym
    import torch as th
    from stable_baselines3 import SAC
    from stable_baselines3.common.env_util import make_vec_env

    import sb3_gcrl  # noqa: F401
    from sb3_gcrl.wrappers import GoExploreWrapper, ResetFreeWrapper

    def wrap(env: gym.Env) -> gym.Env:
        env = ResetFreeWrapper(env, eval_horizon=100)
        return GoExploreWrapper(env, scheduler="back_and_forth", scheduler_kwargs={"alpha": 0.2})

    def model() -> SAC:
        env = make_vec_env(ENV, n_envs=1, seed=0, wrapper_class=wrap)
        env.env_method("set_training_mode", True)
        return SAC("MultiInputPolicy", env, learning_starts=1000, policy_kwargs={"net_arch": [8]}, seed=0)

    trained = model()
    trained.learn(300)
    checkpoint = save_checkpoint(trained, tmp_path, ENV_NAME)
    expected_draw = (np.random.rand(), th.rand(1).item())
    state = trained.get_env().env_method("run_state")[0]
    scheduler = trained.get_env().get_attr("scheduler")[0]

    fresh = SAC.load(checkpoint / "model.zip", env=model().get_env())
    fresh.load_replay_buffer(checkpoint / "replay_buffer.pkl")
    restore_checkpoint(fresh, checkpoint)
    assert (np.random.rand(), th.rand(1).item()) == expected_draw
    assert fresh.num_timesteps == 300 and fresh.replay_buffer.size() == trained.replay_buffer.size()
    restored = fresh.get_env().get_attr("scheduler")[0]
    assert restored is not scheduler
    assert np.array_equal(restored.exploratory.goal_space._counts, scheduler.exploratory.goal_space._counts)
    assert restored.task_goals is fresh.get_env().get_attr("task_goals")[0]  # shared objects stay shared
    assert fresh.get_env().env_method("run_state")[0] == state
    # declared task goals sample from the new env again
    assert fresh.get_env().env_method("sample_task_goals", "evaluation", 2)[0].shape == (2, 2)


def test_a_chain_of_other_wrappers_refuses_the_saved_state() -> None:
    import gymnasium as gym

    import sb3_gcrl  # noqa: F401
    from sb3_gcrl.wrappers import GoExploreWrapper, ResetFreeWrapper

    saved = GoExploreWrapper(ResetFreeWrapper(gym.make(ENV), eval_horizon=100)).run_state()
    with pytest.raises(ValueError, match="resume with the env_wrapper of the run"):
        ResetFreeWrapper(gym.make(ENV), eval_horizon=100).load_run_state(saved)


def test_resume_of_a_folder_without_checkpoint_names_what_is_missing(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError, match="no checkpoint"):
        latest_checkpoint(tmp_path)
    from sb3_gcrl.cli import main

    with pytest.raises(SystemExit, match="not a run folder of sb3-gcrl train"):
        main(["train", "--resume", str(tmp_path)])
    (tmp_path / ENV_NAME).mkdir()
    (tmp_path / ENV_NAME / "sb3_gcrl_train_args.json").write_text(json.dumps(["--algo", "sac"]))
    with pytest.raises(SystemExit, match="Ctrl-C"):
        main(["train", "--resume", str(tmp_path)])
    with pytest.raises(SystemExit, match="takes no other arguments"):
        main(["train", "--resume", str(tmp_path), "-n", "10"])


def test_exit_code_of_an_interruption_is_the_shells() -> None:
    assert INTERRUPTED_EXIT_CODE == 128 + signal.SIGINT


def test_monitor_rows_after_the_checkpoint_are_dropped(tmp_path: Path) -> None:
    from sb3_gcrl.zoo_train import truncate_monitor_file

    path = tmp_path / "0.monitor.csv"
    header = '#{"t_start": 0.0, "env_id": "E"}\nr,l,t,is_success\n'
    path.write_text(header + "0.0,300,1.0,False\n1.0,300,2.0,True\n0.0,300,3.0,False\n")
    truncate_monitor_file(path, 700)  # episodes ending at 300 and 600 steps stay; the one ending at 900 goes
    assert path.read_text() == header + "0.0,300,1.0,False\n1.0,300,2.0,True\n"
    truncate_monitor_file(path, 600)
    assert path.read_text().count("\n") == 4


def test_ctrl_c_stops_after_the_step_with_its_evaluation_and_twice_stops_at_once() -> None:
    from sb3_gcrl.zoo_train import StopOnInterrupt, interrupts_between_steps

    stopper = StopOnInterrupt()
    # Python's own Ctrl-C handler before the run, whatever this process inherited (nohup, CI runners: SIG_IGN)
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with interrupts_between_steps(stopper):
            os.kill(os.getpid(), signal.SIGINT)  # the first Ctrl-C only asks
            assert stopper.requested
            with pytest.raises(KeyboardInterrupt):
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(1)  # the handler runs between bytecodes; give it the chance
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, inherited)


def test_an_interruption_during_an_evaluation_keeps_that_evaluation(tmp_path: Path) -> None:
    from stable_baselines3 import SAC
    from stable_baselines3.common.callbacks import BaseCallback, EvalCallback

    from sb3_gcrl.zoo_train import StopOnInterrupt

    stopper = StopOnInterrupt()

    class CtrlCAt(BaseCallback):  # Ctrl-C arrives while step 60 is being processed (before its evaluation)
        def _on_step(self) -> bool:
            stopper.requested = stopper.requested or self.num_timesteps == 60
            return True

    model = SAC("MlpPolicy", "Pendulum-v1", learning_starts=1000, policy_kwargs={"net_arch": [8]}, seed=0)
    evaluation = EvalCallback(model.get_env(), eval_freq=30, n_eval_episodes=1, log_path=str(tmp_path))
    model.learn(300, callback=[CtrlCAt(), evaluation, stopper])
    assert model.num_timesteps == 60 and evaluation.evaluations_timesteps == [30, 60]


def test_resume_of_a_finished_run_changes_nothing(tmp_path: Path) -> None:
    """A run that ended normally after its last checkpoint is not trained again from that checkpoint."""
    run = subprocess.run(
        [sys.executable, "-m", "sb3_gcrl", *TRAIN[: TRAIN.index("-n")], "-n", "1100", *TRAIN[TRAIN.index("-n") + 2 :]],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    run_dir = tmp_path / "logs" / "sac" / f"{ENV_NAME}_1"
    assert checkpoint_steps(latest_checkpoint(run_dir)) == 1000
    from sb3_gcrl.cli import main

    final = (run_dir / f"{ENV_NAME}.zip").read_bytes()
    with pytest.raises(SystemExit, match="finished: its final model"):
        main(["train", "--resume", str(run_dir)])
    assert (run_dir / f"{ENV_NAME}.zip").read_bytes() == final


def test_a_damaged_checkpoint_is_named_before_the_run_resumes(tmp_path: Path) -> None:
    from stable_baselines3 import SAC

    from sb3_gcrl.cli import main
    from sb3_gcrl.common.checkpoints import check_checkpoint

    model = SAC("MlpPolicy", "Pendulum-v1", learning_starts=50, policy_kwargs={"net_arch": [8]}, seed=0)
    model.learn(60)
    checkpoint = save_checkpoint(model, tmp_path, "Pendulum-v1")
    check_checkpoint(checkpoint, SAC)  # a whole one passes
    (tmp_path / "Pendulum-v1").mkdir()
    (tmp_path / "Pendulum-v1" / "sb3_gcrl_train_args.json").write_text(json.dumps(["--algo", "sac"]))
    (tmp_path / "best_model.zip").write_bytes((checkpoint / "model.zip").read_bytes())
    whole = {path.name: path.read_bytes() for path in checkpoint.iterdir()}

    def refusal() -> str:
        with pytest.raises(SystemExit) as refused:
            main(["train", "--resume", str(tmp_path)])
        message = str(refused.value.code)
        assert "Restore the file from a backup" in message and str(tmp_path / "best_model.zip") in message
        for name, data in whole.items():
            (checkpoint / name).write_bytes(data)
        return message

    buffer = checkpoint / "replay_buffer.pkl"
    buffer.write_bytes(whole["replay_buffer.pkl"][:1000])
    assert re.search(
        r"replay_buffer\.pkl is damaged: 1,000 bytes where the checkpoint wrote [\d,]+ \(cut off", refusal()
    )
    (checkpoint / "model.zip").unlink()  # e.g. a copy that skipped *.zip files
    assert "model.zip is damaged: the file is missing" in refusal()
    manifest = json.loads(whole["checkpoint.json"])
    del manifest["sizes"]  # a checkpoint that recorded no sizes
    (checkpoint / "checkpoint.json").write_text(json.dumps(manifest))
    buffer.write_bytes(whole["replay_buffer.pkl"][:1000])
    assert "replay_buffer.pkl is damaged: its 1,000 bytes end before the end of the pickle" in refusal()
    (checkpoint / "checkpoint.json").write_text(json.dumps(manifest))
    (checkpoint / "env_state.pkl").write_bytes(b"")
    assert re.search(r"env_state\.pkl is damaged: it does not load \(EOFError", refusal())
    (checkpoint / "model.zip").write_bytes(whole["model.zip"][: len(whole["model.zip"]) // 2])
    assert re.search(r"model\.zip is damaged: [\d,]+ bytes where the checkpoint wrote [\d,]+ \(cut off", refusal())
    (checkpoint / "checkpoint.json").write_text(json.dumps(manifest))
    (checkpoint / "model.zip").write_bytes(whole["model.zip"][: len(whole["model.zip"]) // 2])
    assert "model.zip is not a zip archive, or a truncated one" in refusal()
