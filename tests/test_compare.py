"""`sb3-gcrl compare`: method/env resolution, evaluation schedule, resume, crash isolation, Ray backend.

The end-to-end tests share one tiny comparison (2 methods x 2 seeds x 200 steps on Pendulum with 8-unit
nets, plus a method whose config is broken) built by a module fixture that is first interrupted after its
first finished run and then resumed.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
from gymnasium import spaces
from stable_baselines3 import A2C
from stable_baselines3.common.env_util import make_vec_env

from sb3_gcrl.compare import EvaluationRecorder, LocalProcessBackend, compare, parse_method
from sb3_gcrl.compare.cli import EXIT_USAGE
from sb3_gcrl.compare.cli import main as compare_main
from sb3_gcrl.compare.methods import check_env_id
from sb3_gcrl.compare.run import RunResult, RunSpec
from sb3_gcrl.compare.storage import is_finished, read_run_record, write_run_result

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


def write_configs(folder: Path) -> dict[str, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = {"sac": folder / "tiny_sac.yml", "td3": folder / "tiny_td3.yml", "broken": folder / "broken.yml"}
    paths["sac"].write_text(TINY_CONFIG)
    paths["td3"].write_text(TINY_CONFIG + TINY_TD3_EXTRA)
    paths["broken"].write_text(BROKEN_CONFIG)
    return paths


def tiny_comparison(configs: dict[str, Path], output: Path, **kwargs):
    """The tiny comparison of the issue: sac vs td3, 2 seeds, 200 steps, + a method that crashes."""
    methods = [f"sac:{configs['sac']}", f"td3:{configs['td3']}", f"broken=sac:{configs['broken']}"]
    options = dict(seeds=[0, 1], eval_freq=100, n_eval_episodes=1, output=output, progress=False, n_workers=2)
    return compare(methods, ["Pendulum-v1"], **{**options, **kwargs})


class InterruptAfterFirstRun:
    """Events receiver that raises KeyboardInterrupt (as Ctrl-C would) once the first run has ended."""

    def __init__(self, events) -> None:
        self.events = events

    def on_start(self, spec):
        self.events.on_start(spec)

    def on_progress(self, spec, steps):
        self.events.on_progress(spec, steps)

    def on_end(self, spec, status):
        self.events.on_end(spec, status)
        raise KeyboardInterrupt


class InterruptingBackend(LocalProcessBackend):
    def run(self, jobs, events):
        super().run(jobs, InterruptAfterFirstRun(events))


@pytest.fixture(scope="module")
def resumed(tmp_path_factory):
    """Interrupt the tiny comparison after its first run, record what was on disk, then resume it."""
    folder = tmp_path_factory.mktemp("compare")
    configs = write_configs(folder / "configs")
    output = folder / "out"
    with pytest.raises(KeyboardInterrupt):
        tiny_comparison(configs, output, backend=InterruptingBackend(n_workers=2))
    ended_before = {
        path.parent: path.stat().st_mtime_ns for path in output.glob("runs/*/*/*/run.json")
    }  # runs that ended (finished or failed) before the interruption
    result = tiny_comparison(configs, output)
    return configs, output, ended_before, result


def test_interrupted_comparison_resumes_without_redoing_finished_runs(resumed):
    _, output, ended_before, result = resumed
    assert len(ended_before) >= 1
    finished_before = [d for d in ended_before if read_run_record(d)["status"] == "finished"]
    # runs that finished before the interruption were skipped, and their files were not rewritten
    assert result.n_skipped == len(finished_before)
    for run_dir in finished_before:
        assert (run_dir / "run.json").stat().st_mtime_ns == ended_before[run_dir]
    # the runs cut by the interruption were redone completely
    for spec in result.specs:
        record = read_run_record(output / "runs" / spec.relative_dir)
        assert record["status"] == ("failed" if spec.method == "broken" else "finished")


def test_comparison_writes_curves_tables_plot_and_report(resumed):
    _, output, _, result = resumed
    for name in ["curves.csv", "scores.csv", "summary.csv", "curves.png", "report.md", "comparison.json"]:
        assert (output / name).stat().st_size > 0, name
    run_dir = output / "runs" / "Pendulum-v1" / "tiny_sac" / "seed_0"
    evaluations = pd.read_csv(run_dir / "evaluations.csv")
    assert evaluations["timesteps"].tolist() == [0, 100, 200]
    assert evaluations["success_rate"].isna().all()  # Pendulum reports no is_success
    assert (evaluations["mean_length"] == 200).all()
    assert (run_dir / "zoo" / "sac").is_dir()  # RL-Zoo's own outputs (config.yml, monitor.csv)

    summary = pd.read_csv(output / "summary.csv")
    assert summary["method"].tolist() == ["tiny_sac", "tiny_td3"]
    assert summary["n_runs"].tolist() == [2, 2]
    assert set(summary["estimator"]) == {"mean"}  # 2 runs: mean and range, not IQM
    scores = pd.read_csv(output / "scores.csv")
    sac = evaluations["mean_return"].to_numpy()
    row = scores[(scores["method"] == "tiny_sac") & (scores["seed"] == 0)].iloc[0]
    assert row["final"] == pytest.approx(sac[-1])
    assert row["auc"] == pytest.approx(((sac[0] + sac[1]) / 2 + (sac[1] + sac[2]) / 2) / 2)

    assert "tiny_sac" in result.summary.table and "tiny_td3" in result.summary.table
    report = (output / "report.md").read_text()
    assert result.summary.table in report
    assert "## Failed or missing runs" in report and "broken / seed 0" in report
    assert [spec.method for spec, _, _ in result.summary.failed] == ["broken", "broken"]


def test_crashed_run_is_recorded_with_its_traceback(resumed):
    _, output, _, _ = resumed
    run_dir = output / "runs" / "Pendulum-v1" / "broken" / "seed_0"
    record = read_run_record(run_dir)
    assert record["status"] == "failed"
    assert "Traceback" in record["error"]
    assert "Traceback" in (run_dir / "train.log").read_text()


def test_rerun_skips_everything_finished_and_retries_failures_only(resumed, capsys):
    configs, output, _, _ = resumed
    before = {p: p.stat().st_mtime_ns for p in output.glob("runs/*/tiny_*/*/run.json")}
    code = compare_main(
        ["-m", f"sac:{configs['sac']}", f"td3:{configs['td3']}", "-e", "Pendulum-v1", "--seeds", "0", "1"]
        + ["--eval-freq", "100", "--eval-episodes", "1", "-o", str(output), "--no-progress"]
    )
    assert code == 0
    assert {p: p.stat().st_mtime_ns for p in before} == before
    out = capsys.readouterr().out
    assert "4 runs (4 resumed, 0 failed)" in out and "| tiny_sac" in out


def test_changed_settings_are_not_silently_reused(resumed):
    configs, output, _, _ = resumed
    with pytest.raises(FileExistsError, match="--overwrite"):
        compare([f"sac:{configs['sac']}"], ["Pendulum-v1"], seeds=[0], n_timesteps=300, output=output, progress=False)


def test_ray_backend_runs_the_same_tiny_comparison(resumed, tmp_path):
    pytest.importorskip("ray")
    configs, local_output, _, _ = resumed
    methods = [f"sac:{configs['sac']}", f"td3:{configs['td3']}"]
    result = compare(
        methods, ["Pendulum-v1"], seeds=[0, 1], eval_freq=100, n_eval_episodes=1, output=tmp_path, backend="ray",
        n_workers=2, progress=False,
    )  # fmt: skip
    assert not result.summary.failed
    for spec in result.specs:  # same seeds -> same runs as with the local process pool
        ray_curve = pd.read_csv(tmp_path / "runs" / spec.relative_dir / "evaluations.csv")
        local_curve = pd.read_csv(local_output / "runs" / spec.relative_dir / "evaluations.csv")
        np.testing.assert_allclose(ray_curve["mean_return"], local_curve["mean_return"])
    assert "Traceback" not in (tmp_path / "runs" / result.specs[0].relative_dir / "train.log").read_text()


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
    expected = r"no hyperparameters for env 'CartPole-v1'.*Envs it covers: \['Pendulum-v1'\]"
    with pytest.raises(ValueError, match=expected):
        method.config_for("CartPole-v1")


def test_cli_reports_bad_names_before_running_anything(tmp_path, capsys):
    assert compare_main(["-m", "sax", "-e", "Pendulum-v1", "-o", str(tmp_path)]) == EXIT_USAGE
    assert "Valid algorithms" in capsys.readouterr().err
    assert compare_main(["-m", "sac", "-e", "NoSuchEnv-v0", "-o", str(tmp_path)]) == EXIT_USAGE
    assert "Unknown env 'NoSuchEnv-v0'" in capsys.readouterr().err
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
