"""``-optimize`` for this package's algorithms: each has an optuna sampler whose keys its constructor takes."""

from __future__ import annotations

from pathlib import Path

import optuna
import pytest
from rl_zoo3.hyperparams_opt import HYPERPARAMS_SAMPLER
from test_contracts import CASES

from sb3_gcrl.algorithms import ALGORITHMS, register_zoo_algorithms
from sb3_gcrl.cli import main
from sb3_gcrl.hyperparams_opt import SAMPLERS


def test_every_algorithm_has_a_sampler_registered_for_the_zoo():
    assert set(SAMPLERS) == set(ALGORITHMS)
    register_zoo_algorithms()
    for name, sampler in SAMPLERS.items():
        assert HYPERPARAMS_SAMPLER[name] is sampler


@pytest.mark.parametrize("name", sorted(ALGORITHMS))
def test_sampled_hyperparameters_build_a_model_that_learns(name: str):
    case = CASES[name]
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    for _ in range(3):
        trial = study.ask()
        action_space = case.make_env().action_space
        n_actions = action_space.n if hasattr(action_space, "n") else action_space.shape[0]
        sampled = SAMPLERS[name](trial, n_actions, 1, {"using_her_replay_buffer": False, "her_kwargs": {}})
        assert sampled, f"the {name} sampler samples nothing"
        model = case.make(**sampled)  # every key is a constructor argument, every value valid
        model.learn(50)


def test_optimize_runs_two_trials_from_the_command_line(tmp_path: Path):
    storage = f"sqlite:///{tmp_path / 'study.db'}"
    argv = ["train", "--algo", "tabular_q", "--env", "FrozenLake-v1", "-n", "400", "-optimize", "--n-trials", "2"]
    argv += ["--n-jobs", "1", "--sampler", "random", "--pruner", "median", "--n-evaluations", "2"]
    argv += ["--eval-episodes", "2", "--storage", storage, "--study-name", "t", "-f", str(tmp_path / "logs")]
    argv += ["-conf", str(tmp_path / "q.yml")]
    (tmp_path / "q.yml").write_text("FrozenLake-v1:\n  policy: TabularQPolicy\n  n_timesteps: 400\n")
    assert main(argv) == 0
    study = optuna.load_study(study_name="t", storage=storage)
    assert len(study.trials) == 2
    assert all(t.state in (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED) for t in study.trials)
