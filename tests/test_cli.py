"""The ``sb3-gcrl`` command line and its RL-Zoo integration."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import pytest

import sb3_gcrl
from sb3_gcrl.algorithms import ALGORITHMS, load_algorithm
from sb3_gcrl.cli import ZOO_CONFIGS_DIR, main

REPO = Path(__file__).resolve().parent.parent


def test_help_and_unknown_command(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--help"]) == 0
    assert "train" in capsys.readouterr().out
    assert main(["trian"]) == 2
    err = capsys.readouterr().err
    assert "unknown command 'trian'" in err and "compare" in err


def test_list_algos_lists_ours_and_stock(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["list-algos"]) == 0
    out = capsys.readouterr().out
    assert "sac " in out and "dqn " in out
    for name in ALGORITHMS:
        assert name in out


def test_every_registered_algorithm_imports() -> None:
    from stable_baselines3.common.base_class import BaseAlgorithm

    for name in ALGORITHMS:
        assert issubclass(load_algorithm(name), BaseAlgorithm)
    with pytest.raises(KeyError, match="choose one of"):
        load_algorithm("not-an-algo")


def test_import_registers_third_party_envs() -> None:
    assert sb3_gcrl.__version__
    for env_id in ("MinAtar/Breakout-v1", "FetchReach-v4", "PointMaze_UMaze-v3"):
        assert env_id in gym.registry


def test_our_algorithm_without_config_names_the_fix(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(ALGORITHMS, "fake_algo", "stable_baselines3:SAC")
    with pytest.raises(SystemExit, match="pass `-conf"):
        main(["train", "--algo", "fake_algo", "--env", "Pendulum-v1", "-f", str(tmp_path)])


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=300)


def test_plain_rl_zoo3_train_with_gym_packages(tmp_path: Path) -> None:
    """Stock `rl_zoo3 train` (console command) on one of our envs with a stock algorithm's YAML."""
    config = tmp_path / "sac.yml"
    config.write_text(
        "Pendulum-v1:\n  n_timesteps: 200\n  policy: MlpPolicy\n  learning_starts: 100\n"
        "  policy_kwargs: 'dict(net_arch=[8])'\n"
    )
    zoo = Path(sys.executable).with_name("rl_zoo3")
    result = _run(
        [str(zoo), "train", "--algo", "sac", "--env", "Pendulum-v1", "--gym-packages", "sb3_gcrl",
         "-conf", str(config), "-f", str(tmp_path / "logs"), "--eval-freq", "-1"],
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert (tmp_path / "logs" / "sac" / "Pendulum-v1_1" / "Pendulum-v1.zip").is_file()
