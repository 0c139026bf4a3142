"""The reproduction scripts (``scripts/reproduce_ch*.py``, ``scripts/bench_two_memory.py``) and the compare presets.

The scripts run through ``sb3-gcrl compare`` presets and take every setting from ``zoo_configs/``; the slow tests run
each chapter's quick preset end to end through its script.
"""

from __future__ import annotations

import importlib.util
import json
import math
import re
from pathlib import Path
from types import ModuleType

import numpy as np
import pandas as pd
import pytest

from sb3_gcrl.cli import ZOO_CONFIGS_DIR
from sb3_gcrl.compare.methods import method_label, parse_method
from sb3_gcrl.compare.presets import (
    PRESETS,
    get_preset,
    minatar_env_kwargs,
    preset_labels,
    select_methods,
)
from sb3_gcrl.zoo_config import zoo_config_section

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"
REPRODUCE_SCRIPTS = sorted(SCRIPTS.glob("reproduce_ch*.py"))
#: keys of a zoo config (model constructor arguments) that a script must never set itself
MODEL_KEYS = (
    "learning_rate",
    "buffer_size",
    "batch_size",
    "target_update_interval",
    "train_freq",
    "gradient_steps",
    "exploration_fraction",
    "exploration_initial_eps",
    "exploration_final_eps",
    "learning_starts",
    "net_arch",
    "n_pe",
    "noise_std",
    "gamma",
)


def load_script(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# ----------------------------------------------------------------------------------------------- settings only in zoo


@pytest.mark.parametrize("script", [*REPRODUCE_SCRIPTS, SCRIPTS / "bench_two_memory.py"], ids=lambda p: p.name)
def test_scripts_set_no_hyperparameters(script: Path) -> None:
    code = script.read_text()
    for key in MODEL_KEYS:
        assert not re.search(rf"\b{key}\s*[=:]", code.replace('"', " ").replace("'", " ")), (
            f"{script.name} sets {key}: settings belong in zoo_configs/"
        )


@pytest.mark.parametrize("script", REPRODUCE_SCRIPTS, ids=lambda p: p.name)
def test_reproduce_scripts_run_through_compare(script: Path) -> None:
    code = script.read_text()
    assert "run_preset(" in code
    for own_runner in ("ThreadPoolExecutor", "ProcessPoolExecutor", "subprocess", "yaml.safe_load", ".learn("):
        assert own_runner not in code, f"{script.name} has its own runner ({own_runner})"


@pytest.mark.parametrize("game", ["Breakout", "Asterix", "Seaquest", "SpaceInvaders", "Freeway"])
def test_minatar_configs_agree(game: str) -> None:
    """2M's RL half and the DQN baseline share the authors' DQN settings (one update every 10 steps, target
    copied every 1000 updates = 10,000 env steps, RMSprop 1e-4, batch 16, buffer 5e4)."""
    env_id = f"MinAtar/{game}-v1"
    two_memory = zoo_config_section(ZOO_CONFIGS_DIR / "two_memory_dqn.yml", env_id)
    dqn = zoo_config_section(ZOO_CONFIGS_DIR / "dqn.yml", env_id)
    assert two_memory is not None and dqn is not None
    shared = set(dqn) - {"policy", "policy_kwargs"}
    assert {key: two_memory[key] for key in shared} == {key: dqn[key] for key in shared}
    assert dqn["target_update_interval"] == 1000 * dqn["train_freq"] == 10_000
    assert float(dqn["learning_rate"]) == 1e-4 and dqn["batch_size"] == 16 and dqn["buffer_size"] == 50_000


def test_bench_two_memory_builds_the_zoo_config_agents(tmp_path: Path) -> None:
    """The benchmark's agents are the zoo configs' (it used to copy them, with target_update_interval 2000)."""
    bench = load_script("bench_two_memory")
    section = zoo_config_section(ZOO_CONFIGS_DIR / "two_memory_dqn.yml", "MinAtar/Breakout-v1")
    assert section is not None
    for kind in ("dqn", "2m", "2m_pec1"):
        model = bench.make(kind, seed=0, game="Breakout", log_folder=tmp_path)
        assert model.target_update_interval == section["target_update_interval"] == 10_000
        assert model.batch_size == section["batch_size"]
        assert model.train_freq.frequency == section["train_freq"]
        assert model.buffer_size == section["buffer_size"]
    assert type(model).__name__ == "TwoMemoryDQN"
    # the one setting the benchmark chooses itself is what it measures: 2M with every episode acted by MFEC
    assert {kind: overrides for kind, (_, _, overrides) in bench.KINDS.items() if overrides} == {
        "2m_pec1": {"p_ec_schedule": 1.0}
    }


# ------------------------------------------------------------------------------------------------------- presets


def test_every_preset_resolves() -> None:
    for name, preset in PRESETS.items():
        labels = preset_labels(name)
        assert len(set(labels)) == len(labels), name
        for spec in preset.methods:
            method = parse_method(spec)
            assert method.label == method_label(spec)
            for env_id in preset.envs:
                assert method.config_for(env_id).is_file()


def test_compare_kwargs_overrides() -> None:
    preset = get_preset("ch5-minatar")
    kwargs = preset.compare_kwargs(seeds=[7], n_timesteps=None, env_kwargs={"sticky_action_prob": 0.1}, output="x")
    assert kwargs["seeds"] == [7]
    assert kwargs["n_timesteps"] == preset.n_timesteps  # None keeps the preset's value
    assert kwargs["env_kwargs"] == {**preset.env_kwargs, "sticky_action_prob": 0.1}
    assert preset.env_kwargs["sticky_action_prob"] == 0.2  # the preset itself is untouched
    assert kwargs["output"] == "x" and kwargs["methods"] == list(preset.methods)


def test_select_methods() -> None:
    assert select_methods(["ch3", "ch3-ablations"], ["alpha1", "oracle"]) == ["alpha1=sac@alpha1", "oracle=sac@oracle"]
    assert select_methods(["ch5"]) == list(get_preset("ch5").methods)
    # a label two presets share (one per algorithm) resolves to the first preset's spec
    assert select_methods(["ch6-deep", "ch6"], ["off"]) == ["off=ddpg@off"]
    assert select_methods(["ch6", "ch6-deep"], ["off"]) == ["off=imgep@off"]
    with pytest.raises(ValueError, match="choose from"):
        select_methods(["ch3"], ["morefre"])
    with pytest.raises(ValueError, match="Unknown preset"):
        get_preset("ch7")


def test_minatar_env_kwargs() -> None:
    assert minatar_env_kwargs("Breakout")["sticky_action_prob"] == 0.2
    assert minatar_env_kwargs("Freeway")["sticky_action_prob"] == 0.01
    assert minatar_env_kwargs("Asterix")["max_episode_steps"] == 10_000
    with pytest.raises(ValueError, match="Breakout"):
        minatar_env_kwargs("Pong")


def test_quick_preset_single_evaluation_episode_is_exact() -> None:
    """The quick preset evaluates one episode: GrowingTree is deterministic, so a greedy policy repeats it."""
    import gymnasium as gym

    import sb3_gcrl  # noqa: F401

    preset = get_preset("quick")
    assert preset.n_eval_episodes == 1 and preset.envs == ("GCRL/GrowingTree-v0",)
    env = gym.make(preset.envs[0])
    episodes = []
    for seed in (0, 1):
        observations = [env.reset(seed=seed)[0]]
        for _ in range(20):
            observations.append(env.step(np.array([0.05], dtype=np.float32))[0])
        episodes.append(np.concatenate(observations))
    np.testing.assert_array_equal(episodes[0], episodes[1])


# ------------------------------------------------------------------------------------- quick presets, end to end


def _assert_comparison(folder: Path, n_runs: int) -> pd.DataFrame:
    for name in ("report.md", "curves.png", "summary.csv", "scores.csv", "curves.csv"):
        assert (folder / name).is_file(), name
    curves = pd.read_csv(folder / "curves.csv")
    assert curves.groupby(["env", "method", "seed"]).ngroups == n_runs
    assert np.isfinite(curves["mean_return"]).all()
    scores = pd.read_csv(folder / "scores.csv")
    assert len(scores) == n_runs and np.isfinite(scores[["final", "auc"]].to_numpy()).all()
    return curves


def test_reproduce_ch3_reads_the_probes_of_plain_continued_and_restarted_runs() -> None:
    run_probes = load_script("reproduce_ch3").run_probes

    def parse(text: str) -> list[tuple[int, dict[str, float]]]:  # "probe@STEP VALUE" lines
        return [(int(step), {"x": float(value)}) for step, value in re.findall(r"^probe@(\d+) (\S+)$", text, re.M)]

    plain = "eval@0\nprobe@10 1\nprobe@20 2\n"
    assert run_probes(plain, parse) == [(10, {"x": 1.0}), (20, {"x": 2.0})]  # never continued
    assert run_probes("", parse) == []
    continued = plain + "Continuing the run from its checkpoint at 10 steps\nprobe@20 3\nprobe@30 4\n"
    assert run_probes(continued, parse) == [(10, {"x": 1.0}), (20, {"x": 3.0}), (30, {"x": 4.0})]
    # earlier versions probed a continued run at its first step and then one step off the grid
    off_grid = plain + "Continuing the run from its checkpoint at 10 steps\nprobe@11 9\nprobe@21 3\n"
    assert run_probes(off_grid, parse) == [(10, {"x": 1.0}), (20, {"x": 3.0})]
    restarted = continued + "The run starts from zero: its checkpoint cannot be used (...)\nprobe@10 5\n"
    assert run_probes(restarted, parse) == [(10, {"x": 5.0})]


@pytest.mark.slow
def test_reproduce_ch3_quick(tmp_path: Path) -> None:
    assert load_script("reproduce_ch3").main(["--quick", "--out", str(tmp_path)]) == 0
    _assert_comparison(tmp_path, len(get_preset("ch3-quick").methods))
    table = pd.read_csv(tmp_path / "ch3_summary.csv")
    assert np.isfinite(table[["final_success", "mean_success", "task_relevant_pct"]].to_numpy()).all()
    assert ((table["task_relevant_pct"] >= 0) & (table["task_relevant_pct"] <= 100)).all()
    assert (table["closest_to_goal"] >= 0).all() and (table["success_radius"] == 0.45).all()
    assert (tmp_path / "visitation_GCRL-PointUMazeGoal-v0.png").is_file()


@pytest.mark.slow
def test_ch3_baselines_preset_runs_every_method(tmp_path: Path) -> None:
    """IBC, MEDAL, R3L, world-model MoReFree, reset-free PEG and MoReFree-SAC train and evaluate side by side."""
    from sb3_gcrl.compare.presets import run_preset

    result = run_preset("ch3-baselines-quick", tmp_path, n_workers=1, progress=False)
    assert not result.summary.failed, result.summary.failed
    curves = _assert_comparison(tmp_path, 6)
    assert set(curves["method"]) == {
        "ibc",
        "medal",
        "r3l",
        "morefree_world_model",
        "peg_world_model",
        "morefree_sac_port",
    }


@pytest.mark.slow
def test_reproduce_ch4_quick(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert load_script("reproduce_ch4").main(["--quick", "--out", str(tmp_path)]) == 0
    curves = _assert_comparison(tmp_path, 2)
    assert np.isfinite(curves["success_rate"]).all()
    assert "| PointUMaze | cec | 1 |" in capsys.readouterr().out


@pytest.mark.slow
def test_reproduce_ch4_navigation_quick(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Fig. 4.3's three-way comparison runs end to end: CEC, SAC and EMAC on PointGoal and CarGoal."""
    assert load_script("reproduce_ch4").main(["--preset", "ch4-navigation", "--quick", "--out", str(tmp_path)]) == 0
    curves = _assert_comparison(tmp_path, 6)
    assert set(curves["method"]) == {"cec", "sac", "emac"}
    out = capsys.readouterr().out
    assert "| CarGoal | emac | 1 |" in out and "| PointGoal | cec | 1 |" in out


@pytest.mark.slow
def test_reproduce_ch5_windygrid_quick(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    script = load_script("reproduce_ch5")
    assert script.main(["windygrid", "--quick", "--out", str(tmp_path)]) == 0
    curves = _assert_comparison(tmp_path / "windygrid", 3)
    assert curves.loc[curves["method"] == "tabular_2m", "eval_memory_is_ec"].isin([0.0, 1.0]).all()
    assert (tmp_path / "windygrid" / "memory_GCRL-WindyGrid-v0_tabular_2m.png").is_file()
    assert script.main(["report", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "windygrid.png").is_file()
    assert "evaluates with EC" in capsys.readouterr().out


@pytest.mark.slow
def test_reproduce_ch5_minatar_quick(tmp_path: Path) -> None:
    script = load_script("reproduce_ch5")
    assert script.main(["minatar", "--quick", "--out", str(tmp_path)]) == 0
    _assert_comparison(tmp_path / "Breakout", 3)
    spec = json.loads((tmp_path / "Breakout" / "comparison.json").read_text())["specs"][0]
    assert spec["env_kwargs"] == minatar_env_kwargs("Breakout")


@pytest.mark.slow
def test_reproduce_ch6_quick(tmp_path: Path) -> None:
    assert load_script("reproduce_ch6").main(["--quick", "--out", str(tmp_path)]) == 0
    _assert_comparison(tmp_path / "FourRooms", 3)
    rows = json.loads((tmp_path / "ch6_results.json").read_text())
    assert [row["variant"] for row in rows] == ["off", "on", "adaptive"]
    for row in rows:
        for key in ("success_all_goals", "auc", "entropy", "coverage"):
            assert math.isfinite(row[key]) and 0 <= row[key] <= (10 if key == "entropy" else 1), key
        assert row["n_goals"] > 1
        # the all-goals curve over training, at the comparison's evaluation points (all_goals.csv)
        assert row["timesteps"] == [0, 1_000, 2_000] and np.isfinite(row["success"] + row["entropy_curve"]).all()
    assert "| AUC mean |" in (tmp_path / "summary.md").read_text()
    for name in ("heatmap_FourRooms.png", "curves.png", "entropy.png", "FourRooms/all_goals.png"):
        assert (tmp_path / name).is_file(), name
