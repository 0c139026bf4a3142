"""`sb3-gcrl compare`: method/env resolution, evaluation schedule, resume, crash isolation, Ray backend.

The end-to-end test runs a tiny comparison (2 methods x 2 seeds x 200 steps on Pendulum, 8-unit
nets) once and checks it in phases (one test function, so that pytest-xdist never runs it twice).
"""

from __future__ import annotations

import io
import json
import math
import os
import stat
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
import yaml
from gymnasium import spaces
from stable_baselines3 import A2C, SAC
from stable_baselines3.common.env_util import make_vec_env

from sb3_gcrl.cli import ZOO_CONFIGS_DIR
from sb3_gcrl.common.checkpoints import checkpoint_extra, latest_checkpoint
from sb3_gcrl.compare import PRESETS, EvaluationRecorder, LocalProcessBackend, compare, parse_method
from sb3_gcrl.compare.cli import EXIT_USAGE, build_parser
from sb3_gcrl.compare.cli import main as compare_main
from sb3_gcrl.compare.comparison import _config_label, compile_note, plan_runs
from sb3_gcrl.compare.costs import ALL_PHASES, PhaseClock, RunTimer
from sb3_gcrl.compare.methods import check_env_id
from sb3_gcrl.compare.report import summarize, write_outputs
from sb3_gcrl.compare.run import RunResult, RunSpec, execute_run, visited_goals
from sb3_gcrl.compare.storage import (
    atomic_write_text,
    is_finished,
    lock_output,
    read_run_record,
    write_run_result,
)

TINY_CONFIG = """
Pendulum-v1:
  n_timesteps: 200
  policy: 'MlpPolicy'
  learning_starts: 100
  buffer_size: 1000
  batch_size: 16
  policy_kwargs: "dict(net_arch=[8])"
"""
TINY_TD3_EXTRA = """
  noise_type: 'normal'
  noise_std: 0.1
"""
BROKEN_CONFIG = """
Pendulum-v1:
  n_timesteps: 200
  policy: 'MlpPolicy'
  learning_rate: not-a-schedule
"""
# an env wrapper that kills its own process, as a segfault or the out-of-memory killer would
KILLED_CONFIG = (
    TINY_CONFIG
    + """
  env_wrapper: killing_wrapper.kill_process
"""
)
KILLING_WRAPPER = """
import os, signal

def kill_process(env):
    os.kill(os.getpid(), signal.SIGKILL)
"""


def write_configs(folder: Path) -> dict[str, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    texts = {"sac": TINY_CONFIG, "td3": TINY_CONFIG + TINY_TD3_EXTRA, "broken": BROKEN_CONFIG, "killed": KILLED_CONFIG}
    paths = {name: folder / f"tiny_{name}.yml" for name in texts}
    for name, text in texts.items():
        paths[name].write_text(text)
    return paths


TINY_OPTIONS = dict(seeds=[0, 1], eval_freq=100, n_eval_episodes=1, progress=False, n_workers=2)


def tiny_methods(configs: dict[str, Path]) -> list[str]:
    """The tiny comparison: sac vs td3 (x 2 seeds x 200 steps, 8-unit nets)."""
    return [f"sac:{configs['sac']}", f"td3:{configs['td3']}"]


class InterruptAfterFirstRun:
    """Events receiver that raises KeyboardInterrupt (as Ctrl-C would) once the first run has ended."""

    def __init__(self, events) -> None:
        self.events = events

    def on_start(self, spec):
        self.events.on_start(spec)

    def on_progress(self, spec, steps):
        self.events.on_progress(spec, steps)

    def on_end(self, spec, status, **details):
        self.events.on_end(spec, status, **details)
        raise KeyboardInterrupt


class InterruptingBackend(LocalProcessBackend):
    def run(self, jobs, events):
        super().run(jobs, InterruptAfterFirstRun(events))


def finished_runs(output: Path) -> dict[Path, int]:
    """Run folders whose run.json says finished -> modification time of that file."""
    return {
        path.parent: path.stat().st_mtime_ns
        for path in output.glob("runs/*/*/*/run.json")
        if json.loads(path.read_text())["status"] == "finished"
    }


def test_tiny_comparison_end_to_end(tmp_path, monkeypatch, capsys):
    """Interrupted -> resumed without redoing finished runs -> files and table -> re-run skips all -> crash."""
    configs = write_configs(tmp_path / "configs")
    output = tmp_path / "out"

    # 1. Ctrl-C after the first run ended: runs in flight are stopped, finished ones stay on disk
    with pytest.raises(KeyboardInterrupt):
        compare(tiny_methods(configs), ["Pendulum-v1"], output=output, backend=InterruptingBackend(2), **TINY_OPTIONS)
    done_before = finished_runs(output)
    assert len(done_before) >= 1

    # 2. the same command resumes: finished runs are skipped and not rewritten, the others are redone
    result = compare(tiny_methods(configs), ["Pendulum-v1"], output=output, **TINY_OPTIONS)
    assert result.n_skipped == len(done_before)
    assert {run_dir: finished_runs(output)[run_dir] for run_dir in done_before} == done_before
    assert len(finished_runs(output)) == 4 and not result.summary.failed

    # 3. what the comparison wrote
    for name in ["curves.csv", "scores.csv", "summary.csv", "curves.png", "report.md", "comparison.json"]:
        assert (output / name).stat().st_size > 0, name
    run_dir = output / "runs" / "Pendulum-v1" / "tiny_sac" / "seed_0"
    evaluations = pd.read_csv(run_dir / "evaluations.csv")
    assert evaluations["timesteps"].tolist() == [0, 100, 200]
    assert evaluations["success_rate"].isna().all()  # Pendulum reports no is_success
    assert (evaluations["mean_length"] == 200).all()
    assert (run_dir / "zoo" / "sac").is_dir()  # RL-Zoo's own outputs (config.yml, monitor.csv)
    record = read_run_record(run_dir)
    assert 0 < record["cpu_time_s"] < 2 * record["wall_time_s"]  # one torch thread: CPU time about the wall time
    split = record["cpu_split_s"]  # where the CPU time went: the phases add up to it
    assert list(split) == list(ALL_PHASES) and split["train"] > 0 and split["evaluate"] > 0 and split["probe"] == 0
    assert sum(split.values()) == pytest.approx(record["cpu_time_s"])
    assert not hasattr(SAC.train, "__wrapped__")  # the clock's patch of the algorithm's train is gone
    summary = pd.read_csv(output / "summary.csv")
    assert summary["method"].tolist() == ["tiny_sac", "tiny_td3"]
    assert summary["n_runs"].tolist() == [2, 2]
    assert set(summary["estimator"]) == {"mean"}  # 2 runs: mean and [min, max], not IQM
    scores = pd.read_csv(output / "scores.csv")
    returns = evaluations["mean_return"].to_numpy()
    row = scores[(scores["method"] == "tiny_sac") & (scores["seed"] == 0)].iloc[0]
    assert row["final"] == pytest.approx(returns[-1])
    assert row["auc"] == pytest.approx(((returns[0] + returns[1]) / 2 + (returns[1] + returns[2]) / 2) / 2)
    report = (output / "report.md").read_text()
    assert result.summary.table in report and "| tiny_td3" in result.summary.table

    # 4. the CLI on the same folder: everything skipped, nothing rewritten, the table printed
    before = finished_runs(output)
    argv = ["-m", *tiny_methods(configs), "-e", "Pendulum-v1", "--seeds", "0", "1", "--eval-freq", "100"]
    assert compare_main([*argv, "--eval-episodes", "1", "-o", str(output), "--no-progress"]) == 0
    assert finished_runs(output) == before
    assert "4 runs (4 resumed, 0 failed)" in capsys.readouterr().out

    # 4b. a run.json holding a list (not a record) does not crash the resume: that run is redone, and it is said
    broken = output / "runs" / "Pendulum-v1" / "tiny_td3" / "seed_1"
    (broken / "run.json").write_text("[1, 2]")
    assert compare_main([*argv, "--eval-episodes", "1", "-o", str(output), "--no-progress"]) == 0
    out, err = capsys.readouterr()
    assert "4 runs (3 resumed, 0 failed)" in out and f"plot: {output / 'curves.png'}" in out
    assert f"{broken / 'run.json'} holds a JSON list" in err and "redone" in err
    assert read_run_record(broken)["status"] == "finished"
    before = finished_runs(output)

    # 4c. --report-only with a seed more: nothing is trained, the missing run is listed, comparison.json is left
    # alone, and it works while another compare holds the folder (a study still training)
    settings_time = (output / "comparison.json").stat().st_mtime_ns
    more = ["-m", *tiny_methods(configs), "-e", "Pendulum-v1", "--seeds", "0", "1", "2", "--eval-freq", "100"]
    more += ["--eval-episodes", "1", "-o", str(output)]
    with lock_output(output):
        assert compare_main([*more, "--report-only"]) == 0
    out, err = capsys.readouterr()
    assert "report of the 4 finished runs of 6 (nothing trained; the report lists the other 2)" in out
    assert "run failed" not in err
    assert finished_runs(output) == before and not (output / "runs" / "Pendulum-v1" / "tiny_sac" / "seed_2").exists()
    assert (output / "comparison.json").stat().st_mtime_ns == settings_time
    report = (output / "report.md").read_text()
    assert "tiny_sac / seed 2: `not finished (never ran, interrupted or still training)`" in report
    recorded = json.loads((output / "comparison.json").read_text())["command"]
    assert f"Command: `{recorded}`" in report and "--report-only" not in recorded  # the command that trained them
    assert "re-made from the finished runs by: `sb3-gcrl compare " in report and "--report-only`" in report
    assert "| tiny_sac | 2/3 " in report.replace("  ", " ")
    assert compare_main([*more[:-1], str(tmp_path / "empty"), "--report-only"]) == EXIT_USAGE
    assert "holds no runs to report on" in capsys.readouterr().err
    other = [*more[:-6], "--eval-freq", "50", *more[-4:], "--report-only"]  # settings the runs were not made with
    assert compare_main(other) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "eval_freq: 100 -> 50" in err and "--report-only reports runs made with the command's own settings" in err
    assert compare_main([*more, "--report-only", "--overwrite"]) == EXIT_USAGE
    assert "--overwrite has nothing to redo" in capsys.readouterr().err
    assert not (tmp_path / "empty").exists()

    # 5. a worker killed by a signal is recorded as failed; the other runs are kept and the exit code says so
    (tmp_path / "killing_wrapper.py").write_text(KILLING_WRAPPER)
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    argv = ["-m", f"sac:{configs['sac']}", f"killed=sac:{configs['killed']}", "-e", "Pendulum-v1", "--seeds", "0"]
    assert compare_main([*argv, "--eval-freq", "100", "--eval-episodes", "1", "-o", str(output), "--no-progress"]) == 1
    record = read_run_record(output / "runs" / "Pendulum-v1" / "killed" / "seed_0")
    assert record["status"] == "failed" and "killed by signal 9" in record["error"]
    assert finished_runs(output) == before
    assert "killed / seed 0" in (output / "report.md").read_text()
    err = capsys.readouterr().err  # the console names the error and the log, not just "see its train.log"
    assert "run failed: Pendulum-v1 / killed / seed 0" in err and "killed by signal 9" in err
    assert f"log: {output / 'runs' / 'Pendulum-v1' / 'killed' / 'seed_0' / 'train.log'}" in err


def test_changed_settings_are_not_silently_reused(tmp_path):
    configs = write_configs(tmp_path)
    spec = plan_runs([parse_method(f"sac:{configs['sac']}")], ["Pendulum-v1"], [0], 200, 100, 1, {}, (), tmp_path)[0]
    write_run_result(tmp_path / "out" / "runs" / spec.relative_dir, RunResult(spec, "finished"))
    with pytest.raises(FileExistsError, match=r"n_timesteps: 200 -> 300.*--overwrite"):
        compare([f"sac:{configs['sac']}"], ["Pendulum-v1"], seeds=[0], n_timesteps=300, output=tmp_path / "out")


def test_a_run_uses_one_torch_thread(tmp_path, monkeypatch):
    import torch

    threads = []
    monkeypatch.setattr(torch, "set_num_threads", threads.append)
    configs = write_configs(tmp_path)
    spec = plan_runs([parse_method(f"sac:{configs['broken']}")], ["Pendulum-v1"], [0], 200, 100, 1, {}, (), tmp_path)
    execute_run(spec[0], tmp_path / "run", io.StringIO())  # what each worker process runs
    assert threads == [1]


def test_failing_run_returns_its_traceback_instead_of_raising(tmp_path):
    configs = write_configs(tmp_path)
    spec = plan_runs([parse_method(f"sac:{configs['broken']}")], ["Pendulum-v1"], [0], 200, 100, 1, {}, (), tmp_path)
    log = io.StringIO()
    result = execute_run(spec[0], tmp_path / "run", log)
    assert result.status == "failed"
    assert "Traceback" in result.error and "ValueError" in result.error
    assert result.error in log.getvalue()


@pytest.mark.slow  # Ray's own start-up (GCS, raylet, workers) takes ~1 min on a loaded 2-core machine
def test_ray_backend_runs_the_same_tiny_comparison(tmp_path):
    pytest.importorskip("ray")
    configs = write_configs(tmp_path / "configs")
    result = compare(tiny_methods(configs), ["Pendulum-v1"], output=tmp_path / "out", backend="ray", **TINY_OPTIONS)
    assert not result.summary.failed and len(result.specs) == 4
    assert (tmp_path / "out" / "curves.png").is_file() and "| tiny_td3" in result.summary.table
    # same seeds, same run: a run on Ray equals the run executed here
    spec = result.specs[-1]
    local = execute_run(spec, tmp_path / "local", io.StringIO())
    on_ray = pd.read_csv(tmp_path / "out" / "runs" / spec.relative_dir / "evaluations.csv")
    np.testing.assert_allclose(on_ray["mean_return"], [row["mean_return"] for row in local.evaluations])
    assert "eval@200" in (tmp_path / "out" / "runs" / spec.relative_dir / "train.log").read_text()


# --- names and errors -------------------------------------------------------------------------------------


def test_method_spellings(tmp_path):
    configs = write_configs(tmp_path)
    assert parse_method("sac").algo == "sac" and parse_method("sac").config is None
    method = parse_method(f"td3:{configs['td3']}")
    assert (method.label, method.algo, method.config) == ("tiny_td3", "td3", configs["td3"].resolve())
    stem = parse_method("fast=td3:tiny_td3", config_dir=tmp_path)
    assert (stem.label, stem.config) == ("fast", configs["td3"].resolve())
    # a bare algorithm finds RL-Zoo's own hyperparameters when zoo_configs/ has none for the env
    assert parse_method("sac").config_for("Pendulum-v1", tmp_path).name == "sac.yml"


def test_unknown_method_lists_valid_algorithms():
    with pytest.raises(ValueError, match=r"Unknown method 'sax'.*Did you mean \['sac'.*Valid algorithms: \[.*'td3'"):
        parse_method("sax")
    with pytest.raises(ValueError, match="not found at .*Files in"):
        parse_method("sac:no_such_config")
    with pytest.raises(ValueError, match="label"):
        parse_method("a/b=sac")


def test_unknown_env_lists_valid_ones():
    with pytest.raises(ValueError, match=r"Unknown env 'Pendulm-v1'. Close matches: \['Pendulum-v1'.*GCRL/"):
        check_env_id("Pendulm-v1")


def test_method_without_hyperparameters_for_env_lists_covered_envs(tmp_path):
    configs = write_configs(tmp_path)
    method = parse_method(f"sac:{configs['sac']}")
    expected = r"No hyperparameters for sac on CartPole-v1.*covers \['Pendulum-v1'\]"
    with pytest.raises(ValueError, match=expected):
        method.config_for("CartPole-v1")


def test_reset_free_config_without_its_callback_is_refused_before_running(tmp_path):
    config = tmp_path / "forgot.yml"
    section = {"n_timesteps": 100, "policy": "MultiInputPolicy", "env_wrapper": ["sb3_gcrl.wrappers.ResetFreeWrapper"]}
    config.write_text(yaml.safe_dump({"GCRL/PointUMazeGoal-v0": section}))
    plan = dict(seeds=[0], n_timesteps=None, eval_freq=None, n_eval_episodes=1, gym_packages=[], config_dir=tmp_path)
    methods = [parse_method(f"sac:{config}")]
    with pytest.raises(ValueError, match="has no ResetFreeCallback"):
        plan_runs(methods, ["GCRL/PointUMazeGoal-v0"], hyperparams={}, **plan)
    # the same override RL-Zoo would apply (--hyperparams callback:...) makes it valid
    callback = {"callback": ["sb3_gcrl.callbacks.ResetFreeCallback"]}
    assert len(plan_runs(methods, ["GCRL/PointUMazeGoal-v0"], hyperparams=callback, **plan)) == 1


def test_cli_reports_bad_names_before_running_anything(tmp_path, capsys):
    assert compare_main(["-m", "sax", "-e", "Pendulum-v1", "-o", str(tmp_path)]) == EXIT_USAGE
    assert "Valid algorithms" in capsys.readouterr().err
    assert compare_main(["-m", "sac", "-e", "NoSuchEnv-v0", "-o", str(tmp_path)]) == EXIT_USAGE
    assert "Unknown env 'NoSuchEnv-v0'" in capsys.readouterr().err
    assert compare_main(["-m", "sac", "-e", "Pendulum-v1", "-n", "0", "-o", str(tmp_path)]) == EXIT_USAGE
    assert "n_timesteps must be >= 1, got 0" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()
    with pytest.raises(SystemExit):
        compare_main(["--preset", "nope"])


def test_invalid_settings_raise_clear_errors(tmp_path):
    with pytest.raises(ValueError, match="seeds must be distinct"):
        compare(["sac"], ["Pendulum-v1"], seeds=[0, 0], output=tmp_path)
    with pytest.raises(ValueError, match="n_timesteps must be >= 1"):
        compare(["sac"], ["Pendulum-v1"], n_timesteps=0, output=tmp_path)
    with pytest.raises(ValueError, match="labels must be distinct"):
        compare(["sac", "sac"], ["Pendulum-v1"], output=tmp_path)
    with pytest.raises(ValueError, match="n_workers must be >= 1"):
        LocalProcessBackend(n_workers=0)


def test_list_presets_and_methods(capsys):
    assert compare_main(["--list-presets"]) == 0
    assert "quick:" in capsys.readouterr().out


# --- storage ----------------------------------------------------------------------------------------------


def make_spec(**changes) -> RunSpec:
    fields = dict(
        method="m", algo="sac", config="c.yml", config_digest="abc", env_id="GCRL/GrowingTree-v0", seed=0,
        n_timesteps=100, eval_freq=10,
    )  # fmt: skip
    return RunSpec(**{**fields, **changes})


def test_run_result_round_trip_and_changed_spec_detection(tmp_path):
    spec = make_spec()
    assert spec.relative_dir == Path("GCRL-GrowingTree-v0/m/seed_0")
    assert RunSpec.from_dict(json.loads(json.dumps(spec.to_dict()))) == spec
    assert not is_finished(tmp_path, spec)
    row = {"timesteps": 0, "num_timesteps": 0, "mean_return": 1.0, "std_return": 0.0, "mean_length": 3.0}
    write_run_result(tmp_path, RunResult(spec, "finished", [row | {"success_rate": math.nan, "wall_time_s": 0.1}]))
    assert not list(tmp_path.glob(".*.tmp"))  # atomic writes leave no temporary files
    assert is_finished(tmp_path, spec)
    assert is_finished(tmp_path, make_spec(config="moved/c.yml"))  # same content digest, other path: same run
    with pytest.raises(FileExistsError, match=r"n_timesteps: 100 -> 200.*--overwrite"):
        is_finished(tmp_path, make_spec(n_timesteps=200))
    write_run_result(tmp_path, RunResult(spec, "failed", error="boom"))
    assert not is_finished(tmp_path, spec)  # failed runs are redone


def test_finished_run_with_tuples_in_its_spec_is_recognised_on_resume(tmp_path):
    """run.json stores tuples as lists; resuming must still see the run as finished, not as changed settings."""
    spec = make_spec(env_kwargs={"goal": (1.0, 0.5)}, hyperparams={"policy_kwargs": {"net_arch": (8, 8)}})
    write_run_result(tmp_path, RunResult(spec, "finished", [{"timesteps": 0, "mean_return": 0.0}]))
    assert is_finished(tmp_path, spec)


# --- evaluation schedule ----------------------------------------------------------------------------------


class CountToGoal(gym.Env):
    """Reach 3 by pressing action 1 three times (episodes of at most 4 steps); ``is_success`` at the goal."""

    observation_space = spaces.Box(0.0, 4.0, (1,), np.float32)
    action_space = spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.position, self.t = 0, 0
        return np.array([0.0], np.float32), {}

    def step(self, action):
        self.position += int(action)
        self.t += 1
        success = self.position >= 3
        obs = np.array([self.position], np.float32)
        return obs, float(success), success, self.t >= 4 and not success, {"is_success": success}


def test_evaluation_schedule_is_in_env_steps_and_reads_is_success():
    train_env = make_vec_env(CountToGoal, n_envs=2, seed=0)
    eval_env = make_vec_env(CountToGoal, n_envs=1, seed=1)
    model = A2C("MlpPolicy", train_env, n_steps=3, seed=0, policy_kwargs={"net_arch": [4]})
    reported: list[int] = []
    recorder = EvaluationRecorder(eval_env, eval_freq=5, n_eval_episodes=2, report_progress=reported.append)
    model.learn(24, callback=recorder)  # 2 envs: num_timesteps goes 2, 4, 6, ... 24
    recorder.evaluate_final()  # 24 is not a multiple of 5: one last evaluation at the end
    records = pd.DataFrame(recorder.records)
    assert records["timesteps"].tolist() == [0, 5, 10, 15, 20, 24]
    assert records["num_timesteps"].tolist() == [0, 6, 10, 16, 20, 24]
    assert records["success_rate"].isin([0.0, 0.5, 1.0]).all()
    # success iff the episode ends before the 4-step limit
    assert ((records["success_rate"] == 1.0) == (records["mean_length"] == 3.0)).all()
    assert sum(reported) == 24
    with pytest.raises(ValueError, match="eval_freq must be >= 1"):
        EvaluationRecorder(eval_env, eval_freq=0)


TABULAR_2M_CONFIG = """
GCRL/WindyGrid-v0:
  n_timesteps: 400
  policy: TabularTwoMemoryPolicy
  p_ec_schedule: {type: decayed, start: 0.9, end: 0.01, decay: 200}
"""


def test_two_memory_runs_record_the_evaluation_memory_and_get_a_memory_figure(tmp_path):
    """2M agents: `eval_memory_is_ec` per evaluation (Eq. 5.6) and a Fig. 5.6-style panel in the report."""
    config = tmp_path / "two_memory.yml"
    config.write_text(TABULAR_2M_CONFIG)
    method = parse_method(f"2m=tabular_2m:{config}")
    specs = plan_runs([method], ["GCRL/WindyGrid-v0"], [0, 1], None, 100, 1, {}, (), tmp_path)
    output = tmp_path / "out"
    for spec in specs:
        result = execute_run(spec, tmp_path / "zoo", io.StringIO())
        assert result.status == "finished", result.error
        write_run_result(output / "runs" / spec.relative_dir, result)
    evaluations = pd.read_csv(output / "runs" / specs[0].relative_dir / "evaluations.csv")
    assert evaluations["timesteps"].tolist() == [0, 100, 200, 300, 400]
    assert evaluations["eval_memory_is_ec"].isin([0.0, 1.0]).all()

    summary = summarize(output, specs, metric="mean_return")
    assert summary.metrics == {"GCRL/WindyGrid-v0": "mean_return"}
    write_outputs(output, summary, "2M", "", 1.0)
    assert (output / "memory_GCRL-WindyGrid-v0_2m.png").stat().st_size > 0
    assert "memory_GCRL-WindyGrid-v0_2m.png" in (output / "report.md").read_text()
    with pytest.raises(ValueError, match="metric must be"):
        summarize(output, specs, metric="returns")


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_resolves_to_registered_envs_and_existing_configs(name, tmp_path):
    preset = PRESETS[name]
    methods = [parse_method(spec) for spec in preset.methods]
    for env_id in preset.envs:
        check_env_id(env_id)
    specs = plan_runs(
        methods, preset.envs, preset.seeds, preset.n_timesteps, preset.eval_freq, preset.n_eval_episodes,
        preset.hyperparams, (), ZOO_CONFIGS_DIR, config_folder=tmp_path,
    )  # fmt: skip
    assert len(specs) == len(preset.methods) * len(preset.envs) * len(preset.seeds)
    assert all(Path(spec.config).is_file() for spec in specs)


def test_report_names_a_shipped_config_by_its_place_in_the_package_not_this_machines_path(tmp_path):
    """A study's report is kept in git: it must read the same on every clone."""
    assert _config_label(str(ZOO_CONFIGS_DIR / "cec.yml")) == "sb3_gcrl/zoo_configs/cec.yml"
    own = str(tmp_path / "zoo_configs" / "cec.yml")  # a user's file of the same name stays as given
    assert _config_label(own) == own


def test_env_kwargs_reach_the_env_constructor(tmp_path):
    configs = write_configs(tmp_path)
    method = parse_method(f"sac:{configs['sac']}")
    spec = plan_runs([method], ["Pendulum-v1"], [0], 200, 100, 1, {}, (), tmp_path, env_kwargs={"no_such_arg": 1})[0]
    result = execute_run(spec, tmp_path / "run", io.StringIO())
    assert result.status == "failed" and "no_such_arg" in result.error


def test_run_json_of_an_older_version_without_new_fields_still_counts_as_finished(tmp_path):
    spec = make_spec()
    write_run_result(tmp_path, RunResult(spec, "finished", [{"timesteps": 0, "mean_return": 0.0}]))
    record = json.loads((tmp_path / "run.json").read_text())
    del record["spec"]["env_kwargs"]  # a field added later, at its default value
    (tmp_path / "run.json").write_text(json.dumps(record))
    assert is_finished(tmp_path, spec)


def burn(seconds: float) -> None:
    """Spend about ``seconds`` of CPU time."""
    end = time.process_time() + seconds
    while time.process_time() < end:
        pass


def test_phase_clock_counts_each_timed_call_once_and_leaves_classes_as_it_found_them():
    class Agent:
        def train(self) -> None:
            burn(0.05)

        def learn(self) -> None:
            burn(0.05)
            self.train()

    class Evaluator:
        def on_step(self) -> bool:
            burn(0.03)
            Agent().train()  # inside an evaluation: counts to the evaluation only
            return True

    clock, evaluator = PhaseClock(), Evaluator()
    clock.time_callback(evaluator, "evaluate")
    start = time.process_time()
    with clock.timing_method(Agent, "train", "train"):
        Agent().learn()
        evaluator.on_step()
    total = time.process_time() - start
    assert clock.cpu_s["train"] == pytest.approx(0.05, abs=0.02)
    assert clock.cpu_s["evaluate"] == pytest.approx(0.08, abs=0.02)
    split = clock.split(total)
    assert list(split) == list(ALL_PHASES) and split["collect"] == pytest.approx(0.05, abs=0.02)
    assert "train" in vars(Agent) and not hasattr(Agent.train, "__wrapped__")  # its own method is back

    class Child(Agent):
        pass

    with clock.timing_method(Child, "train", "train"):  # inherited: patched on the class, then removed again
        assert "train" in vars(Child) and "train" in vars(Agent)
    assert "train" not in vars(Child) and Child.train is Agent.train
    with clock.timing_method(Evaluator, "train", "train"):  # no train (a tabular agent): nothing to time
        assert not hasattr(Evaluator, "train")
    with pytest.raises(ValueError, match="phase must be one of"):
        clock.timed("learn", burn)


def test_compare_says_before_the_runs_that_compiling_their_training_step_takes_minutes(tmp_path):
    def plan(method: str, **hyperparams: object) -> list:
        return plan_runs(
            [parse_method(method)], ["GCRL/PointUMazeGoal-v0"], [0, 1], 1000, 500, 1, hyperparams, (), ZOO_CONFIGS_DIR,
            config_folder=tmp_path,
        )  # fmt: skip

    note = compile_note(plan("morefree") + plan("peg=morefree@peg") + plan("sac"))
    assert note is not None and note.startswith("morefree, peg: each run compiles its training step")
    assert "minutes on a CPU" in note and "train.log" in note
    assert compile_note(plan("morefree", compile_train_step=False)) is None  # the override wins
    assert compile_note(plan("sac")) is None


def test_a_resumed_run_counts_the_time_its_steps_took_before_the_checkpoint():
    earlier = {"wall_time_s": 100.0, "cpu_time_s": 80.0, "cpu_phase_s": {"train": 50.0, "evaluate": 5.0}}
    timer = RunTimer()
    timer.resume(earlier)
    timer.clock.cpu_s["train"] += 1.0  # this part's own training
    wall, cpu = timer.elapsed()
    assert 100.0 <= wall < 110.0 and 80.0 <= cpu < 90.0
    state = timer.state()
    assert state["cpu_phase_s"]["train"] == 51.0 and state["cpu_phase_s"]["evaluate"] == 5.0
    assert json.loads(json.dumps(state)) == state  # saved with the checkpoint's JSON
    fresh = RunTimer()
    fresh.resume(None)  # a checkpoint that holds no costs
    assert fresh.elapsed()[1] < 5.0 and sum(fresh.clock.cpu_s.values()) == 0.0


def test_report_splits_the_cpu_time_of_the_runs_that_recorded_it_by_phase(tmp_path):
    rows = [{"timesteps": 0, "mean_return": 0.0}, {"timesteps": 10, "mean_return": 1.0}]
    split = {"collect": 20.0, "train": 60.0, "evaluate": 10.0, "probe": 8.0, "checkpoint": 2.0}
    spec = make_spec(seed=0)
    result = RunResult(spec, "finished", rows, 110.0, 100.0, cpu_split_s=split)
    write_run_result(tmp_path / "runs" / spec.relative_dir, result)
    older = make_spec(method="n", seed=0)  # no split recorded: left out of the split table
    write_run_result(tmp_path / "runs" / older.relative_dir, RunResult(older, "finished", rows, 40.0, 30.0))
    summary = summarize(tmp_path, [spec, older])
    write_outputs(tmp_path, summary, "t", "", 1.0)
    report = (tmp_path / "report.md").read_text()
    assert "| method | runs | train | collect | evaluate | probe | checkpoint |" in report
    assert "| m | 1 | 60 s (60%) | 20 s (20%) | 10 s (10%) | 8 s (8%) | 2 s (2%) |" in report
    assert "| n | 1 | 40 s | 30 s | 0.01 h |" in report and report.count("| n | 1 |") == 1


def test_report_gives_wall_and_cpu_time_per_method_and_says_where_an_older_run_did_not_record_cpu(tmp_path):
    rows = [{"timesteps": 0, "mean_return": 0.0}, {"timesteps": 10, "mean_return": 1.0}]
    specs = [make_spec(seed=0), make_spec(seed=1), make_spec(method="n", seed=0)]
    times = [(100.0, 90.0), (300.0, 250.0), (40.0, math.nan)]
    for spec, (wall, cpu) in zip(specs, times):
        write_run_result(tmp_path / "runs" / spec.relative_dir, RunResult(spec, "finished", rows, wall, cpu))
    older = tmp_path / "runs" / specs[2].relative_dir / "run.json"
    record = json.loads(older.read_text())
    assert record["cpu_time_s"] is None  # not measured: null, never NaN
    del record["cpu_time_s"]  # a run of a version that did not record it
    older.write_text(json.dumps(record))
    summary = summarize(tmp_path, specs)
    assert summary.run_times["cpu_time_s"].tolist()[:2] == [90.0, 250.0]
    write_outputs(tmp_path, summary, "t", "", 1.0)
    report = (tmp_path / "report.md").read_text()
    assert "| m | 2 | 200 s (100-300) | 170 s (90-250) | 0.09 h |" in report
    assert "| n | 1 | 40 s | not recorded | not recorded |" in report


def test_report_adds_the_return_where_the_reward_pays_for_more_than_the_success(tmp_path):
    """Sub-goals paying 0.5: a method that always takes one has success 0 but return 0.5, which the report shows."""

    def rows(success: float, ret: float) -> list[dict[str, float]]:
        return [{"timesteps": t, "mean_return": ret, "success_rate": success} for t in (0, 10)]

    specs = [make_spec(method=m, seed=seed) for m in ("subgoal", "goal") for seed in range(3)]
    for spec in specs:
        result = rows(0.0, 0.5) if spec.method == "subgoal" else rows(1.0, 1.0)
        write_run_result(tmp_path / "runs" / spec.relative_dir, RunResult(spec, "finished", result, 1.0))
    summary = summarize(tmp_path, specs)
    assert summary.return_summary.set_index("method")["final"].to_dict() == {"subgoal": 0.5, "goal": 1.0}
    write_outputs(tmp_path, summary, "t", "", 1.0)
    report = (tmp_path / "report.md").read_text()
    assert "### Evaluation return" in report
    assert "| subgoal | 3/3  | evaluation return | 0.50 [0.50, 0.50] |" in report
    # where the return is the success, nothing is added
    for spec in specs:
        write_run_result(tmp_path / "runs" / spec.relative_dir, RunResult(spec, "finished", rows(1.0, 1.0), 1.0))
    summary = summarize(tmp_path, specs)
    assert summary.return_table == "" and summary.return_summary.empty


GOAL_SAC_CONFIG = """
GCRL/PointUMazeGoal-v0:
  n_timesteps: 200
  policy: 'MultiInputPolicy'
  learning_starts: 100
  buffer_size: 1000
  batch_size: 16
  policy_kwargs: "dict(net_arch=[8])"
"""


def test_goal_env_runs_keep_visited_goals_and_get_visitation_heatmaps(tmp_path):
    """2-D goal spaces: achieved goals of the replay buffer are stored per run and drawn per method (Fig. 3.5)."""
    config = tmp_path / "goal_sac.yml"
    config.write_text(GOAL_SAC_CONFIG)
    methods = [parse_method(f"a=sac:{config}"), parse_method(f"b=sac:{config}")]
    specs = plan_runs(methods, ["GCRL/PointUMazeGoal-v0"], [0], None, 100, 1, {}, (), tmp_path)
    output = tmp_path / "out"
    for spec in specs:
        result = execute_run(spec, tmp_path / "zoo", io.StringIO())
        assert result.status == "finished", result.error
        assert result.visited_goals.shape == (200, 2)  # one achieved goal per env step
        write_run_result(output / "runs" / spec.relative_dir, result)
    assert (output / "runs" / specs[0].relative_dir / "visited_goals.npy").is_file()
    summary = summarize(output, specs)
    write_outputs(output, summary, "goal env", "", 1.0)
    assert (output / "visitation_GCRL-PointUMazeGoal-v0.png").stat().st_size > 0
    assert "visitation_GCRL-PointUMazeGoal-v0.png" in (output / "report.md").read_text()


def test_visited_goals_of_any_dimension_are_kept_and_heatmaps_show_two_goal_dimensions(tmp_path, monkeypatch):
    """4-D goals are kept (task-relevant share), in storage order; a heatmap needs two goal dimensions to show."""
    from types import SimpleNamespace

    from stable_baselines3.common.buffers import DictReplayBuffer

    goal = spaces.Box(-1.0, 1.0, (4,), np.float32)
    observation_space = spaces.Dict({"observation": goal, "achieved_goal": goal, "desired_goal": goal})
    buffer = DictReplayBuffer(10, observation_space, spaces.Box(-1.0, 1.0, (1,)), n_envs=2)
    assert visited_goals(SimpleNamespace(replay_buffer=buffer)) is None  # empty
    stored = np.arange(24, dtype=np.float32).reshape(3, 2, 4)  # 3 steps of 2 envs
    for step in stored:
        obs = {key: step for key in observation_space.spaces}
        buffer.add(obs, obs, np.zeros((2, 1)), np.zeros(2), np.zeros(2), [{}, {}])
    np.testing.assert_array_equal(visited_goals(SimpleNamespace(replay_buffer=buffer)), stored.reshape(6, 4))
    assert visited_goals(SimpleNamespace(replay_buffer=buffer), max_points=2).tolist() == [
        stored[0, 0].tolist(),
        stored[2, 1].tolist(),
    ]

    spec = tiny_spec(tmp_path)
    output = tmp_path / "out"
    row = {"timesteps": 0, "num_timesteps": 0, "mean_return": -1.0, "std_return": 0.0, "mean_length": 200}
    result = RunResult(spec, "finished", [row], wall_time_s=1.0, visited_goals=stored.reshape(6, 4))
    write_run_result(output / "runs" / spec.relative_dir, result)
    assert np.load(output / "runs" / spec.relative_dir / "visited_goals.npy").shape == (6, 4)
    write_outputs(output, summarize(output, [spec]), "4-D goals", "", 1.0)
    assert not list(output.glob("visitation_*.png"))
    assert "visitation_" not in (output / "report.md").read_text()

    # Tabletop's goal is (fist xy, mug xy): its heatmap shows the mug (dimensions 2, 3), as the thesis's Fig. 3.9
    from dataclasses import replace

    import sb3_gcrl.compare.report as report

    tabletop = replace(spec, env_id="GCRL/Tabletop-v0")
    write_run_result(output / "runs" / tabletop.relative_dir, replace(result, spec=tabletop))
    drawn = []
    monkeypatch.setattr(report, "visitation_counts", lambda goals, *args: drawn.append(goals) or np.ones((2, 2)))
    write_outputs(output, summarize(output, [tabletop]), "Tabletop", "", 1.0)
    assert (output / "visitation_GCRL-Tabletop-v0.png").is_file()
    np.testing.assert_array_equal(drawn[0], stored.reshape(6, 4)[:, 2:])


def tiny_spec(tmp_path: Path) -> RunSpec:
    configs = write_configs(tmp_path / "configs")
    return plan_runs([parse_method(f"sac:{configs['sac']}")], ["Pendulum-v1"], [0], 200, 100, 1, {}, (), tmp_path)[0]


def write_finished_run(output: Path, spec: RunSpec) -> Path:
    run_dir = output / "runs" / spec.relative_dir
    row = {"timesteps": 0, "num_timesteps": 0, "mean_return": -1.0, "std_return": 0.0, "mean_length": 200}
    write_run_result(run_dir, RunResult(spec, "finished", [row], wall_time_s=1.0))
    return run_dir


@pytest.mark.parametrize(
    ("content", "problem"),
    [("[1, 2]", "holds a JSON list"), ('"finished"', "holds a JSON str"), ("{not json", "is not valid JSON"),
     ('{"status": "done"}', "has status 'done'"), ('{"status": "finished", "spec": []}', "'spec' that is not")],
)  # fmt: skip
def test_unusable_run_json_counts_as_unfinished_and_says_why(tmp_path, content, problem):
    spec = tiny_spec(tmp_path)
    run_dir = write_finished_run(tmp_path / "out", spec)
    assert is_finished(run_dir, spec)
    (run_dir / "run.json").write_text(content)
    notes: list[str] = []
    assert not is_finished(run_dir, spec, notes)
    assert len(notes) == 1 and str(run_dir / "run.json") in notes[0] and problem in notes[0]
    summary = summarize(tmp_path / "out", [spec])  # the report lists the run instead of crashing
    assert len(summary.failed) == 1 and problem in summary.failed[0][1]


@pytest.mark.parametrize(
    ("content", "problem"),
    [("", "cannot be parsed as CSV"), ("timesteps,mean_return\n", "no evaluation rows"),
     ("step,return\n0,1\n", "lacks the column(s) ['timesteps', 'mean_return']"),
     ("timesteps,mean_return\n0,1.0\n100,abc\n", "column 'mean_return' holds non-numeric values (row 2: 'abc')"),
     ("timesteps,mean_return,success_rate\n0,1,yes\n", "column 'success_rate' holds non-numeric"),
     ("timesteps,mean_return\n0,\n", "column 'mean_return' has empty values (row 1)")],
)  # fmt: skip
def test_unusable_evaluations_csv_is_named_with_what_is_wrong(tmp_path, content, problem):
    spec = tiny_spec(tmp_path)
    run_dir = write_finished_run(tmp_path / "out", spec)
    (run_dir / "evaluations.csv").write_text(content)
    summary = summarize(tmp_path / "out", [spec])
    assert len(summary.failed) == 1
    error = summary.failed[0][1]
    assert str(run_dir / "evaluations.csv") in error and problem in error
    notes: list[str] = []
    assert not is_finished(run_dir, spec, notes)  # redone on resume
    assert problem in notes[0]


def test_a_second_compare_on_a_folder_in_use_refuses_and_names_the_pid(tmp_path, capsys):
    import os

    from sb3_gcrl.compare.storage import OutputInUseError

    configs = write_configs(tmp_path / "configs")
    output = tmp_path / "out"
    with lock_output(output) as lock:
        assert lock.read_text() == f"{os.getpid()}\n"
        with pytest.raises(OutputInUseError, match=rf"process {os.getpid()} holds .*compare.lock.*another --output"):
            compare([f"sac:{configs['sac']}"], ["Pendulum-v1"], seeds=[0], output=output, progress=False)
        argv = ["-m", f"sac:{configs['sac']}", "-e", "Pendulum-v1", "--seeds", "0", "-o", str(output)]
        assert compare_main(argv) == EXIT_USAGE
        assert "is in use by another sb3-gcrl compare" in capsys.readouterr().err
    assert not (output / "runs").exists() and not lock.exists()


def test_a_stale_lock_of_a_dead_process_is_taken_over(tmp_path, capsys):
    import os
    import subprocess
    import sys

    dead = subprocess.Popen([sys.executable, "-c", ""])
    dead.wait()
    (tmp_path / "compare.lock").write_text(f"{dead.pid}\n")
    with lock_output(tmp_path) as lock:
        assert lock.read_text() == f"{os.getpid()}\n"
    assert f"taking over the lock of process {dead.pid}" in capsys.readouterr().err


def _process_gone(pid: int) -> bool:
    """True when ``pid`` has exited (a zombie left unreaped by its new parent counts as gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return True
    return stat.rsplit(")", 1)[1].split()[0] in ("Z", "X")


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc to follow the orphan")
def test_workers_die_with_their_sigkilled_parent(tmp_path):
    """A worker started like the local backend starts it must not outlive a SIGKILLed compare process."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from sb3_gcrl.compare.worker import PARENT_PID_ENV, SPEC_FILE

    configs = write_configs(tmp_path / "configs")
    spec = plan_runs([parse_method(f"sac:{configs['sac']}")], ["Pendulum-v1"], [0], 10**7, 10**6, 1, {}, (), tmp_path)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / SPEC_FILE).write_text(json.dumps(spec[0].to_dict()))
    parent_code = (
        "import os, subprocess, sys, time\n"
        f"environment = {{**os.environ, {PARENT_PID_ENV!r}: str(os.getpid())}}\n"
        f"worker = subprocess.Popen([sys.executable, '-m', 'sb3_gcrl.compare.worker', {str(run_dir)!r}], "
        "env=environment, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)\n"
        "print(worker.pid, flush=True)\n"
        "time.sleep(600)\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", parent_code], stdout=subprocess.PIPE, text=True)
    worker_pid = int(parent.stdout.readline())
    try:
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 120  # the worker notices once its imports are done (seconds, more under load)
        while not _process_gone(worker_pid) and time.monotonic() < deadline:
            time.sleep(0.5)
        assert _process_gone(worker_pid), "the worker outlived its SIGKILLed parent"
        assert not (run_dir / "run.json").exists()
    finally:
        if not _process_gone(worker_pid):
            os.kill(worker_pid, signal.SIGKILL)


def test_hyperparameter_typos_are_refused_before_any_run_with_close_matches(tmp_path, capsys):
    configs = write_configs(tmp_path / "configs")
    output = tmp_path / "out"
    with pytest.raises(
        ValueError, match=r"'lerning_rate' \(did you mean 'learning_rate', 'learning_starts'\?\) from --hyperparams"
    ):
        compare([f"sac:{configs['sac']}"], ["Pendulum-v1"], seeds=[0], hyperparams={"lerning_rate": 0.1}, output=output)
    typo = tmp_path / "typo.yml"
    typo.write_text(TINY_CONFIG.replace("buffer_size", "bufer_size"))
    with pytest.raises(
        ValueError, match=rf"SAC\): 'bufer_size' \(did you mean 'buffer_size'.*\) from {typo} \(section Pendulum-v1\)"
    ):
        compare([f"sac:{typo}"], ["Pendulum-v1"], seeds=[0], output=output)
    with pytest.raises(ValueError, match=r"'seed' \(from --hyperparams\) is set by the run itself"):
        compare([f"sac:{configs['sac']}"], ["Pendulum-v1"], seeds=[0], hyperparams={"seed": 3}, output=output)
    argv = ["-m", f"sac:{configs['sac']}", "-e", "Pendulum-v1", "--hyperparams", "lerning_rate:0.1", "-o", str(output)]
    assert compare_main(argv) == EXIT_USAGE
    assert "did you mean 'learning_rate'" in capsys.readouterr().err
    assert not output.exists()  # refused before anything was written or run


def test_zoo_keys_and_inherited_constructor_arguments_pass_the_hyperparameter_check():
    from sb3_gcrl.compare.run import prepare_process
    from sb3_gcrl.zoo_checks import check_hyperparameters

    prepare_process(single_thread=False)
    check_hyperparameters(
        "td3", {"n_timesteps": 1, "noise_type": "normal", "noise_std": 0.1, "policy": "MlpPolicy"}, "x"
    )
    check_hyperparameters("tabular_q", {"learning_rate": 0.1, "gamma": 0.9}, "x")  # via **kwargs to its base
    with pytest.raises(ValueError, match=r"'gama' \(did you mean 'gamma'"):
        check_hyperparameters("tabular_q", {"gama": 0.9}, "x")


def test_cli_prints_failures_and_announces_only_the_plot_it_wrote(tmp_path, monkeypatch, capsys):
    """No run finished: no curves.png, so the console must not point to one; failures show error and log."""
    import sb3_gcrl.compare.comparison as comparison
    from sb3_gcrl.compare.comparison import ComparisonResult
    from sb3_gcrl.compare.report import Summary

    spec = tiny_spec(tmp_path)
    log = tmp_path / "out" / "runs" / "train.log"
    error = "Traceback (most recent call last):\n  File 'x.py', line 1\nValueError: learning_rate is not a schedule"
    summary = Summary(pd.DataFrame(), pd.DataFrame(), pd.DataFrame(), {}, [(spec, error, log)], "(none)", [], {})
    result = ComparisonResult(tmp_path / "out", [spec], 0, summary, 1.0, files=[tmp_path / "out" / "report.md"])
    monkeypatch.setattr(comparison, "compare", lambda *args, **kwargs: result)
    assert compare_main(["-m", "sac", "-e", "Pendulum-v1", "-o", str(tmp_path / "out")]) == 1
    out, err = capsys.readouterr()
    assert "curves.png" not in out and "no plot" in out
    assert "ValueError: learning_rate is not a schedule" in err and f"log: {log}" in err


# ------------------------------------------------------------------------ all-goals evaluations (thesis Ch. 6)

ALL_GOALS_ROW = {"timesteps": 0, "num_timesteps": 0, "all_goals_success": 0.5, "n_goals": 4}


def test_tabular_imgep_run_records_all_goals_rows_at_its_evaluation_points(tmp_path):
    """A ch6-quick-like run (TabularIMGEP, FourRooms config with its AllGoalsEvalCallback): all_goals.csv has finite
    success, entropy and coverage at every step of evaluations.csv, and the report draws and tabulates them."""
    methods = [parse_method("on=imgep@on")]  # a variant: its section is written for RL-Zoo
    specs = plan_runs(
        methods, ["GCRL/FourRoomsTabular-v0"], [0], 1_000, 500, 1, {}, (), ZOO_CONFIGS_DIR, config_folder=tmp_path
    )
    output = tmp_path / "out"
    run_dir = output / "runs" / specs[0].relative_dir
    log = io.StringIO()
    result = execute_run(specs[0], run_dir, log)
    assert result.status == "finished", result.error
    assert "eval_freq 10000 of the config replaced by the run's eval_freq 500" in log.getvalue()
    write_run_result(run_dir, result)
    assert is_finished(run_dir, specs[0])
    evaluations, all_goals = pd.read_csv(run_dir / "evaluations.csv"), pd.read_csv(run_dir / "all_goals.csv")
    assert all_goals["timesteps"].tolist() == evaluations["timesteps"].tolist() == [0, 500, 1_000]
    values = all_goals[["all_goals_success", "visitation_entropy", "coverage"]].to_numpy()
    assert np.isfinite(values).all() and (values[:, [0, 2]] <= 1).all() and values[-1, 1] > 0
    summary = summarize(output, specs)
    assert "success over all goals" in summary.all_goals_table
    assert np.isfinite(summary.all_goals_scores[["final", "auc"]].to_numpy()).all()
    write_outputs(output, summary, "ch6", "", 1.0)
    report = (output / "report.md").read_text()
    for name in ("all_goals.png", "all_goals_entropy.png"):
        assert (output / name).stat().st_size > 0 and name in report
    assert len(pd.read_csv(output / "all_goals_curves.csv")) == 3


def test_runs_without_all_goals_evaluations_expect_no_all_goals_file(tmp_path):
    spec = tiny_spec(tmp_path)
    run_dir = write_finished_run(tmp_path / "out", spec)
    assert json.loads((run_dir / "run.json").read_text())["n_all_goals_evaluations"] is None
    assert not (run_dir / "all_goals.csv").exists() and is_finished(run_dir, spec)
    assert summarize(tmp_path / "out", [spec]).all_goals_table == ""


@pytest.mark.parametrize(
    ("content", "problem"),
    [(None, "is missing"), ("timesteps,all_goals_success\n", "no all-goals evaluation rows"),
     ("timesteps,success\n0,1\n", "lacks the column(s) ['all_goals_success']"),
     ("timesteps,all_goals_success\n0,\n", "column 'all_goals_success' has empty values (row 1)"),
     ("timesteps,all_goals_success,coverage\n0,1,all\n", "column 'coverage' holds non-numeric")],
)  # fmt: skip
def test_unusable_all_goals_csv_makes_the_run_unfinished_and_is_named(tmp_path, content, problem):
    spec = tiny_spec(tmp_path)
    run_dir = tmp_path / "out" / "runs" / spec.relative_dir
    row = {"timesteps": 0, "num_timesteps": 0, "mean_return": -1.0}
    write_run_result(run_dir, RunResult(spec, "finished", [row], wall_time_s=1.0, all_goals=[ALL_GOALS_ROW]))
    assert json.loads((run_dir / "run.json").read_text())["n_all_goals_evaluations"] == 1
    assert is_finished(run_dir, spec)
    if content is None:
        (run_dir / "all_goals.csv").unlink()
    else:
        (run_dir / "all_goals.csv").write_text(content)
    notes: list[str] = []
    assert not is_finished(run_dir, spec, notes)  # redone on resume
    assert len(notes) == 1 and str(run_dir / "all_goals.csv") in notes[0] and problem in notes[0]
    summary = summarize(tmp_path / "out", [spec])
    assert len(summary.failed) == 1 and problem in summary.failed[0][1]


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_written_files_honour_the_umask_like_open(tmp_path: Path, umask: int) -> None:
    previous = os.umask(umask)
    try:
        atomic_write_text(tmp_path / "report.md", "new\n")
        existing = tmp_path / "scores.csv"
        existing.write_text("old\n")
        existing.chmod(0o600)
        atomic_write_text(existing, "replaced\n")
    finally:
        os.umask(previous)
    assert stat.S_IMODE((tmp_path / "report.md").stat().st_mode) == 0o666 & ~umask  # 0o644 under 0o022
    assert stat.S_IMODE(existing.stat().st_mode) == 0o600 and existing.read_text() == "replaced\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.md", "scores.csv"]  # no temporary file left


def test_command_line_overrides_read_as_rl_zoo_writes_them() -> None:
    args = build_parser().parse_args(["--hyperparams", "projection_dim:None", "--env-kwargs", "heading_noise:0.1"])
    assert args.hyperparams == [("projection_dim", None)]
    assert args.env_kwargs == [("heading_noise", 0.1)]
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--hyperparams", "learning_rate"])


def _worker_pid(run_dir: Path) -> int | None:
    """The pid of the compare worker training ``run_dir`` (Linux: read from /proc)."""
    for entry in Path("/proc").iterdir():
        try:
            words = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"sb3_gcrl.compare.worker" in words and str(run_dir).encode() in words:
            return int(entry.name)
    return None


@pytest.mark.skipif(not Path("/proc/self/cmdline").exists(), reason="finds the worker through /proc")
def test_a_killed_run_continues_from_its_checkpoint_when_the_command_is_run_again(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    config = tmp_path / "sac.yml"
    config.write_text(
        "Pendulum-v1:\n  n_timesteps: 4000\n  policy: MlpPolicy\n  learning_starts: 100\n  batch_size: 16\n"
        "  policy_kwargs: dict(net_arch=[8])\n"
    )
    output = tmp_path / "out"
    command = [
        sys.executable, "-m", "sb3_gcrl", "compare", "-m", f"sac:{config}", "-e", "Pendulum-v1", "--seeds", "0",
        "--eval-freq", "1000", "--eval-episodes", "1", "--save-freq", "1000", "-w", "1", "--no-progress",
        "--output", str(output),
    ]  # fmt: skip
    run_dir = output / "runs" / "Pendulum-v1" / "sac" / "seed_0"
    first = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 900  # generous: a loaded machine makes the imports slow
    while not (run_dir / "checkpoints" / "latest").is_file() and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    pid = _worker_pid(run_dir)
    assert pid is not None, f"no worker to kill: compare ended ({first.poll()}) or no checkpoint in 900 s"
    os.kill(pid, signal.SIGKILL)
    output_text, _ = first.communicate(timeout=900)
    assert first.returncode == 1, output_text[-3000:]  # the run failed: its worker was killed
    saved = int((run_dir / "checkpoints" / "latest").read_text().split("_")[0])
    assert 1000 <= saved < 4000
    costs = checkpoint_extra(latest_checkpoint(run_dir))["costs"]  # what the steps up to the checkpoint cost
    assert costs["cpu_time_s"] > 0 and costs["cpu_phase_s"]["train"] > 0
    second = subprocess.run(command, capture_output=True, text=True, timeout=900)
    assert second.returncode == 0, second.stderr[-3000:]
    log = (run_dir / "train.log").read_text()
    assert f"Continuing the run from its checkpoint at {saved} steps" in log
    evaluations = pd.read_csv(run_dir / "evaluations.csv")
    assert evaluations["timesteps"].tolist() == [0, 1000, 2000, 3000, 4000]  # as an uninterrupted run's
    result = json.loads((run_dir / "run.json").read_text())
    assert result["status"] == "finished"
    assert result["cpu_time_s"] > costs["cpu_time_s"] and result["wall_time_s"] > costs["wall_time_s"]
    assert result["cpu_split_s"]["train"] > costs["cpu_phase_s"]["train"]
    assert not (run_dir / "checkpoints").exists()  # a finished run keeps no checkpoint


@pytest.mark.filterwarnings("ignore:MoReFree.learn")  # the budget ends before learning_starts on purpose
def test_the_log_of_a_compiled_run_says_that_its_first_training_step_compiles(tmp_path):
    def run(name: str, **hyperparams: object) -> str:
        spec = plan_runs(
            [parse_method("morefree")], ["GCRL/PointUMazeGoal-v0"], [0], 100, 100, 1, hyperparams, (),
            ZOO_CONFIGS_DIR, config_folder=tmp_path,
        )[0]  # fmt: skip
        log = io.StringIO()  # the worker's train.log; 100 steps end before the first training step
        assert execute_run(spec, tmp_path / name, log).status == "finished"
        return log.getvalue()

    assert "MoReFree: compiling the training step with torch.compile" in run("compiled")
    assert "compiling the training step" not in run("plain", compile_train_step=False)
