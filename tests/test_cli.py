"""The ``sb3-gcrl`` command line and its RL-Zoo integration."""

from __future__ import annotations

import argparse
import os
import re
import shutil
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


def test_a_closed_pipe_ends_the_command_quietly() -> None:
    read, write = os.pipe()
    os.close(read)  # the reader is gone before anything is written (`sb3-gcrl list-configs | head -1`)
    try:
        result = subprocess.run(
            [sys.executable, "-m", "sb3_gcrl", "list-configs"],
            stdout=write,
            stderr=subprocess.PIPE,
            text=True,
            timeout=120,
        )
    finally:
        os.close(write)
    assert result.stderr == "" and result.returncode == 1  # no BrokenPipeError traceback


def test_list_algos_lists_ours_and_stock(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["list-algos"]) == 0
    out = capsys.readouterr().out
    assert "sac " in out and "dqn " in out
    for name in ALGORITHMS:
        assert name in out


def test_list_envs_goes_on_past_a_task_whose_optional_extra_is_missing(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without metaworld, GCRL/SawyerDoor-v0 cannot be made; list-envs names the fix and lists the rest."""

    class Spaces:
        observation_space = gym.spaces.Box(0.0, 1.0, (2,))
        action_space = gym.spaces.Discrete(3)

        def close(self) -> None:
            pass

    def make(env_id: str, **kwargs: object) -> Spaces:
        if env_id == "GCRL/SawyerDoor-v0":
            raise ImportError("GCRL/SawyerDoor-v0 needs metaworld 3.0.0: pip install -e '.[door]'")
        return Spaces()

    monkeypatch.setattr(gym, "make", make)
    assert main(["list-envs"]) == 0
    out = capsys.readouterr().out
    assert "GCRL/SawyerDoor-v0\n  not available: GCRL/SawyerDoor-v0 needs metaworld" in out
    ids = sorted(k for k in gym.registry if k.startswith("GCRL/"))
    assert ids[-1] != "GCRL/SawyerDoor-v0" and f"{ids[-1]}\n  observation: Box" in out
    assert out.count("  action:      Discrete(3)") == len(ids) - 1


def test_every_registered_algorithm_imports() -> None:
    from stable_baselines3.common.base_class import BaseAlgorithm

    for name in ALGORITHMS:
        assert issubclass(load_algorithm(name), BaseAlgorithm)
    with pytest.raises(KeyError, match="choose one of"):
        load_algorithm("not-an-algo")


def test_import_registers_third_party_envs() -> None:
    assert sb3_gcrl.__version__
    assert sb3_gcrl.CEC.__name__ == "CEC" and sb3_gcrl.wrappers.GoExploreWrapper  # imported on first access
    assert set(sb3_gcrl.__all__) <= set(dir(sb3_gcrl))
    with pytest.raises(AttributeError, match="no attribute 'CECC'"):
        sb3_gcrl.CECC  # noqa: B018
    for env_id in ("MinAtar/Breakout-v1", "FetchReach-v4", "PointMaze_UMaze-v3"):
        assert env_id in gym.registry


def test_help_and_import_load_no_torch_sb3_or_rl_zoo() -> None:
    code = (
        "import sys; from sb3_gcrl.cli import main; main(['--help']); import gymnasium as gym; "
        "assert 'GCRL/GrowingTree-v0' in gym.registry and 'MinAtar/Breakout-v1' in gym.registry; "
        "print(sorted(m for m in ('torch', 'stable_baselines3', 'rl_zoo3', 'minatar') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.splitlines()[-1] == "[]"  # the heavy imports wait for a command (or class) that needs them


def test_import_is_quiet() -> None:
    # gymnasium-robotics 1.4.x prints an Adroit notice on import; every `import sb3_gcrl` used to show it
    result = subprocess.run([sys.executable, "-c", "import sb3_gcrl"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stderr == "" and result.stdout == ""


def test_our_algorithm_without_config_names_the_fix(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(ALGORITHMS, "fake_algo", "stable_baselines3:SAC")
    with pytest.raises(SystemExit, match="pass `-conf"):
        main(["train", "--algo", "fake_algo", "--env", "Pendulum-v1", "-f", str(tmp_path)])


def test_train_refuses_unknown_hyperparameters_before_training_with_close_matches(tmp_path: Path) -> None:
    config = tmp_path / "typo.yml"
    config.write_text("Pendulum-v1:\n  n_timesteps: 100\n  policy: MlpPolicy\n  lerning_rate: 0.001\n")
    logs = tmp_path / "logs"
    argv = ["train", "--algo", "sac", "--env", "Pendulum-v1", "-conf", str(config), "-f", str(logs)]
    with pytest.raises(SystemExit, match=rf"'lerning_rate' \(did you mean 'learning_rate'.*\) from {config}"):
        main(argv)
    with pytest.raises(SystemExit, match=r"'gama' \(did you mean 'gamma'\?\) from -params"):
        main([*argv, "-params", "gama:0.9", "learning_rate:0.01"])
    config.write_text("default:\n  n_timesteps: 100\n  gama: 0.9\n")
    with pytest.raises(SystemExit, match=r"for cec \(CEC\): 'gama' \(did you mean 'gamma'"):
        main(["train", "--algo", "cec", "--env", "Pendulum-v1", "-conf", str(config), "-f", str(logs)])
    assert not logs.exists()  # refused before RL-Zoo set anything up


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=600)


def test_plain_rl_zoo3_train_with_gym_packages(tmp_path: Path) -> None:
    """Stock `rl_zoo3 train` (console command) on one of our envs with a stock algorithm's zoo config."""
    beside = Path(sys.executable).with_name("rl_zoo3")  # the console script of this interpreter's install
    zoo = beside if beside.exists() else Path(shutil.which("rl_zoo3") or beside)
    result = _run(
        [
            str(zoo),
            "train",
            "--algo",
            "sac",
            "--env",
            "GCRL/GrowingTree-v0",
            "--gym-packages",
            "sb3_gcrl",
            "-conf",
            str(ZOO_CONFIGS_DIR / "sac.yml"),
            "-n",
            "150",
            "--hyperparams",
            "learning_starts:50",
            "policy_kwargs:dict(net_arch=[8])",
            "-f",
            str(tmp_path / "logs"),
            "--eval-freq",
            "-1",
        ],
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert (tmp_path / "logs" / "sac" / "GCRL-GrowingTree-v0_1" / "GCRL-GrowingTree-v0.zip").is_file()


def test_sb3_gcrl_train_then_enjoy_our_algorithm(tmp_path: Path) -> None:
    """`sb3-gcrl train --algo cec` reads zoo_configs/cec.yml by default; `sb3-gcrl enjoy` loads the result."""
    logs = tmp_path / "logs"
    result = _run(
        [
            sys.executable,
            "-m",
            "sb3_gcrl",
            "train",
            "--algo",
            "cec",
            "--env",
            "GCRL/GrowingTree-v0",
            "-n",
            "400",
            "-f",
            str(logs),
            "--eval-freq",
            "-1",
            "--seed",
            "3",
        ],
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    run_dir = logs / "cec" / "GCRL-GrowingTree-v0_1"
    assert (run_dir / "GCRL-GrowingTree-v0.zip").is_file()
    assert "distance_threshold" in (run_dir / "GCRL-GrowingTree-v0" / "config.yml").read_text()
    result = _run(
        [
            sys.executable,
            "-m",
            "sb3_gcrl",
            "enjoy",
            "--algo",
            "cec",
            "--env",
            "GCRL/GrowingTree-v0",
            "-f",
            str(logs),
            "--no-render",
            "-n",
            "50",
        ],
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr[-3000:]


@pytest.mark.parametrize(
    ("env_id", "display", "no_render"),
    [
        ("GCRL/PointUMaze-v0", None, True),
        ("GCRL/PointUMaze-v0", ":0", False),
        ("GCRL/GrowingTree-v0", None, True),  # images, which gymnasium shows in a pygame window
        ("GCRL/GrowingTree-v0", ":0", False),
    ],
)
def test_enjoy_without_a_display_runs_window_envs_without_rendering(
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    env_id: str,
    display: str | None,
    no_render: bool,
) -> None:
    import rl_zoo3.enjoy

    seen: list[list[str]] = []
    monkeypatch.setattr(rl_zoo3.enjoy, "enjoy", lambda: seen.append(list(sys.argv)))
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if display is None:
        monkeypatch.delenv("DISPLAY", raising=False)
    else:
        monkeypatch.setenv("DISPLAY", display)
    assert main(["enjoy", "--algo", "cec", "--env", env_id, "-f", "logs"]) == 0
    assert ("--no-render" in seen[0]) is no_render
    assert ("no display" in capsys.readouterr().err) is no_render
    monkeypatch.setattr(rl_zoo3.enjoy, "enjoy", lambda: None)
    assert main(["enjoy", "--help"]) == 0 and "no display" not in capsys.readouterr().err  # a note of no env


@pytest.mark.parametrize("env_id", ["GCRL/PointUMaze-v0", "GCRL/GrowingTree-v0"])  # MuJoCo's viewer, pygame
def test_enjoy_on_a_machine_without_a_display_runs_without_rendering(tmp_path: Path, env_id: str) -> None:
    logs = tmp_path / "logs"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    train = ["train", "--algo", "cec", "--env", env_id, "-n", "200", "--eval-freq", "-1"]
    result = subprocess.run(
        [sys.executable, "-m", "sb3_gcrl", *train, "-f", str(logs)], capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr[-3000:]
    enjoy = ["enjoy", "--algo", "cec", "--env", env_id, "-f", str(logs), "-n", "20"]
    result = subprocess.run(
        [sys.executable, "-m", "sb3_gcrl", *enjoy], capture_output=True, text=True, timeout=300, env=env
    )
    assert result.returncode == 0, result.stderr[-3000:]  # 134 (SIGABRT in GLFW) before
    assert "runs without rendering (--no-render)" in result.stderr
    assert "XDG_RUNTIME_DIR" not in result.stderr  # pygame's window, before


def test_train_runs_torch_on_one_thread_unless_num_threads_is_given(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import torch

    threads: list[int] = []
    monkeypatch.setattr(torch, "set_num_threads", threads.append)
    run = ["train", "--algo", "cec", "--env", "GCRL/GrowingTree-v0", "-n", "50", "--eval-freq", "-1"]
    assert main([*run, "-f", str(tmp_path / "logs")]) == 0  # a tiny run through RL-Zoo's own train
    assert threads == [1]

    import rl_zoo3.train

    seen: list[list[str]] = []
    monkeypatch.setattr(rl_zoo3.train, "train", lambda: seen.append(list(sys.argv)))
    for given in (["--num-threads", "4"], ["--num-threads=-1"]):  # the user's count, -1 included, is kept
        main([*run, *given])
        assert sum(arg.startswith("--num-threads") for arg in seen[-1]) == 1 and given[-1] in seen[-1]
    main(["train", "--help"])  # printed before RL-Zoo's own help
    assert "torch runs on 1 thread unless --num-threads N is given" in capsys.readouterr().out


def test_conf_takes_the_name_of_a_shipped_config(tmp_path, capsys):
    from sb3_gcrl.cli import resolve_train_config, shipped_config

    argv, resolved = resolve_train_config(["--algo", "sac", "-conf", "sac", "--env", "GCRL/PointUMazeGoal-v0"])
    assert argv == ["--algo", "sac", "--env", "GCRL/PointUMazeGoal-v0", "-conf", str(ZOO_CONFIGS_DIR / "sac.yml")]
    assert resolved.key == "GCRL/PointUMazeGoal-v0"
    argv, _ = resolve_train_config(["--algo", "cec", "--conf-file=cec.yml", "--env", "GCRL/GrowingTree-v0"])
    assert argv[-1] == str(ZOO_CONFIGS_DIR / "cec.yml")
    own = tmp_path / "cec.yml"
    own.write_text("GCRL/GrowingTree-v0: {policy: CECPolicy}\n")
    argv, resolved = resolve_train_config(["--algo", "cec", "--env", "GCRL/GrowingTree-v0", "-conf", str(own)])
    assert argv[-1] == str(own) and resolved.hyperparams == {"policy": "CECPolicy"}  # a user's file wins
    argv, _ = resolve_train_config(["--algo", "cec", "--env", "GCRL/GrowingTree-v0"])
    assert argv[-2:] == ["-conf", str(ZOO_CONFIGS_DIR / "cec.yml")]  # our algorithm's default file
    assert shipped_config("../pyproject.toml") is None  # names only, no paths out of the folder
    with pytest.raises(SystemExit, match="list-configs"):
        resolve_train_config(["--algo", "sac", "-conf", "no_such_config"])
    assert main(["list-configs"]) == 0
    out = capsys.readouterr().out
    names = out.split()
    assert "cec" in names and "sac" in names and "morefree_thesis" in names
    sac = out.split("\nsac\n")[1]  # the env sections of sac.yml, each with its variants
    assert (
        "  GCRL/PointUMazeGoal-v0  variants: oracle naive goexplore wo_bf wo_relabel alpha1 post_exploration_on" in sac
    )


def _refused_everywhere(
    tmp_path: Path, train_argv: list[str], compare_argv: list[str], capsys: pytest.CaptureFixture[str]
) -> tuple[str, str]:
    """The messages of ``sb3-gcrl train`` and ``sb3-gcrl compare`` refusing a mistake before any work (nothing
    written in their output folders)."""
    from sb3_gcrl.compare.cli import EXIT_USAGE
    from sb3_gcrl.compare.cli import main as compare_main

    logs, output = tmp_path / "logs", tmp_path / "out"
    with pytest.raises(SystemExit) as refused:
        main(["train", *train_argv, "-f", str(logs)])
    capsys.readouterr()
    assert compare_main([*compare_argv, "--output", str(output), "--no-progress"]) == EXIT_USAGE
    compare_message = capsys.readouterr().err
    assert not (logs.exists() and any(logs.iterdir())) and not (output / "runs").exists()
    return str(refused.value.code), compare_message


def test_budgets_below_one_step_are_refused_by_train_compare_and_the_python_api(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from sb3_gcrl.compare import compare

    config = tmp_path / "budget.yml"
    config.write_text("Pendulum-v1:\n  n_timesteps: -5\n  policy: MlpPolicy\n")
    expected = r"n_timesteps must be >= 1, got -5\.?0?, from .*budget\.yml \(section Pendulum-v1\)"
    train_message, compare_message = _refused_everywhere(
        tmp_path, ["--algo", "sac", "--env", "Pendulum-v1", "-conf", str(config)],
        ["-m", f"sac:{config}", "-e", "Pendulum-v1"], capsys,
    )  # fmt: skip
    assert re.search(expected, train_message) and re.search(expected, compare_message)
    with pytest.raises(ValueError, match=expected):
        compare([f"sac:{config}"], ["Pendulum-v1"], output=tmp_path / "api", progress=False)
    config.write_text("Pendulum-v1:\n  n_timesteps: 100\n  policy: MlpPolicy\n")
    for budget in ("0", "-100"):
        train_message, compare_message = _refused_everywhere(
            tmp_path, ["--algo", "sac", "--env", "Pendulum-v1", "-conf", str(config), "-n", budget],
            ["-m", f"sac:{config}", "-e", "Pendulum-v1", "-n", budget], capsys,
        )  # fmt: skip
        assert f"n_timesteps must be >= 1, got {budget}" in train_message
        assert f"n_timesteps must be >= 1, got {budget}" in compare_message
    with pytest.raises(SystemExit, match=r"got -3\.?0?, from -params n_timesteps"):
        main(["train", "--algo", "sac", "--env", "Pendulum-v1", "-conf", str(config), "-params", "n_timesteps:-3"])


def test_misspelled_names_get_the_same_close_matches_on_train_and_compare(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    train_message, compare_message = _refused_everywhere(
        tmp_path, ["--algo", "cec", "--env", "GCRL/PointUmaze-v0"], ["-m", "cec", "-e", "GCRL/PointUmaze-v0"], capsys
    )
    expected = "Unknown env 'GCRL/PointUmaze-v0'. Close matches: ['GCRL/PointUMaze-v0'"
    assert expected in train_message and expected in compare_message
    env = "GCRL/GrowingTree-v0"
    train_message, compare_message = _refused_everywhere(
        tmp_path, ["--algo", "cecc", "--env", env], ["-m", "cecc", "-e", env], capsys
    )
    expected = "'cecc' is not an algorithm. Did you mean ['cec'"
    assert expected in train_message and expected in compare_message


def test_a_close_match_is_suggested_once_and_overrides_are_named_by_their_flag(tmp_path: Path) -> None:
    config = tmp_path / "typo.yml"
    config.write_text("default:\n  n_timesteps: 100\n  noise_sdt: 0.1\n")
    argv = ["train", "--algo", "cec", "--env", "Pendulum-v1", "-conf", str(config), "-f", str(tmp_path / "logs")]
    with pytest.raises(SystemExit) as refused:
        main(argv)
    assert str(refused.value.code).count("did you mean 'noise_std'") == 1
    config.write_text("default:\n  n_timesteps: 100\n")
    with pytest.raises(SystemExit, match=r"'gama' \(did you mean 'gamma'\?\) from -params"):
        main([*argv, "-params", "gama:0.9"])
    with pytest.raises(SystemExit, match=r"'gama' \(did you mean 'gamma'\?\) from --hyperparams"):
        main([*argv, "--hyperparams", "gama:0.9"])


def test_a_read_only_or_full_output_folder_is_refused_before_work_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import errno
    import tempfile
    from collections import namedtuple

    from sb3_gcrl.common import validation

    config = tmp_path / "sac.yml"
    config.write_text("Pendulum-v1:\n  n_timesteps: 100\n  policy: MlpPolicy\n")
    argvs = (
        ["--algo", "sac", "--env", "Pendulum-v1", "-conf", str(config)],
        ["-m", f"sac:{config}", "-e", "Pendulum-v1"],
    )

    def read_only(*args: object, **kwargs: object) -> None:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    with monkeypatch.context() as patch:  # a read-only mount (root writes through permission bits)
        patch.setattr(tempfile, "TemporaryFile", read_only)
        train_message, compare_message = _refused_everywhere(tmp_path, *argvs, capsys)
    assert re.search(
        r"Cannot write in the log folder \(-f\) .*logs \(Read-only file system\): pass another", train_message
    )
    assert re.search(r"Cannot write in the output folder \(--output\) .*out \(Read-only file system\)", compare_message)
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(validation.shutil, "disk_usage", lambda path: usage(10**9, 10**9 - 4096, 4096))
    train_message, compare_message = _refused_everywhere(tmp_path, *argvs, capsys)
    assert re.search(r"The log folder \(-f\) .*logs is on a full disk \(4,096 bytes free\): free some", train_message)
    assert "The output folder (--output)" in compare_message and "full disk (4,096 bytes free)" in compare_message


def test_a_train_that_fails_at_start_leaves_no_run_folder(tmp_path: Path) -> None:
    config = tmp_path / "her.yml"  # HER needs Dict observations: the model cannot be built on Pendulum
    config.write_text(
        "Pendulum-v1:\n  n_timesteps: 100\n  policy: MlpPolicy\n  replay_buffer_class: HerReplayBuffer\n"
        "  learning_starts: 10\n"
    )
    logs = tmp_path / "logs"
    argv = ["train", "--algo", "sac", "--env", "Pendulum-v1", "-conf", str(config), "-f", str(logs)]
    with pytest.raises(Exception) as failed:
        main(argv)
    assert not isinstance(failed.value, SystemExit)  # RL-Zoo's own setup failed, after it made the run folder
    assert (logs / "sac").is_dir() and not list((logs / "sac").iterdir())
    damaged = tmp_path / "damaged.zip"  # a model file that does not load is refused before RL-Zoo starts
    damaged.write_bytes(b"PK\x03\x04 not a whole archive")
    config.write_text("Pendulum-v1:\n  n_timesteps: 100\n  policy: MlpPolicy\n")
    with pytest.raises(SystemExit, match=r"damaged\.zip is not a zip archive, or a truncated one"):
        main([*argv, "-i", str(damaged)])
    assert not list((logs / "sac").iterdir())


def test_train_help_lists_the_options_of_sb3_gcrl_train(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(["train", "--help"])
    assert done.value.code == 0
    help_text = capsys.readouterr().out
    usage = help_text[help_text.index("usage: sb3-gcrl train") :].split("\n\n")[0]
    assert "[--variant NAME]" in usage and "[--resume RUN_FOLDER]" in usage
    assert "--resume RUN_FOLDER   continue the run in RUN_FOLDER" in help_text
    import rl_zoo3.train

    assert rl_zoo3.train.argparse is argparse  # put back
