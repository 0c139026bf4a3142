"""Optuna samplers for this package's algorithms, so that ``sb3-gcrl train --algo <ours> -optimize`` works.

RL-Zoo looks a sampler up in ``rl_zoo3.hyperparams_opt.HYPERPARAMS_SAMPLER[algo]`` and calls it as
``sampler(trial, n_actions, n_envs, additional_args)``; the returned dict updates the config's hyperparameters
before the model is built, so every key is a constructor argument of the algorithm (a test checks that).
:func:`register_zoo_samplers` adds :data:`SAMPLERS` to that table; ``sb3-gcrl train`` calls it.

The search spaces are the thesis's tuned values where it gives them:

- CEC, Table 4.4 (k, tau, sigma, n, d over the four navigation tasks);
- MFEC and the 2M agents, Table 5.1 (epsilon 0.1 / 0.9, k 1 / 3 / 10, p_ec schedules 0.9->0.1, 0.1->0.1,
  0.1->0.9, learning rate 1e-3 / 1e-4);
- tabular IMGEP, Table 6.2 (learning rate 0.1, tau 0, epsilon 0 / 0.1 / 0.3, p_pe 0.5), widened around the
  table's single values so that a search has something to find;
- tabular Q / EC: the authors' tabular 2M settings (learning rate 0.01, epsilon 0.1 -> 0.05), widened likewise.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import optuna

Sampler = Callable[[optuna.Trial, int, int, dict[str, Any]], dict[str, Any]]

#: Table 5.1's switching schedules p^s -> p^e (Eq. 5.5), by name for optuna's categorical distributions
P_EC_SCHEDULES: dict[str, tuple[float, float]] = {"0.9-0.1": (0.9, 0.1), "0.1-0.1": (0.1, 0.1), "0.1-0.9": (0.1, 0.9)}


def _p_ec_schedule(trial: optuna.Trial, decay: float) -> dict[str, Any]:
    start, end = P_EC_SCHEDULES[trial.suggest_categorical("p_ec", list(P_EC_SCHEDULES))]
    return {"type": "decayed" if start >= end else "increasing", "start": start, "end": end, "decay": decay}


def sample_cec_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict[str, Any]) -> dict:
    """CEC (thesis Ch. 4, Table 4.4: k, tau, sigma, n, d).

    :param trial: the optuna trial.
    :param n_actions: action dimension (unused).
    :param n_envs: number of envs (unused).
    :param additional_args: RL-Zoo's extra arguments (unused).
    :return: CEC constructor arguments.
    """
    return {
        "n_neighbors": trial.suggest_categorical("n_neighbors", [1, 3, 5]),
        "temperature": trial.suggest_categorical("temperature", [0.1, 1.0, 10.0]),
        "noise_std": trial.suggest_categorical("noise_std", [0.1, 0.3]),
        "filter_factor": trial.suggest_categorical("filter_factor", [1.0, 3.0]),
        "distance_threshold": trial.suggest_float("distance_threshold", 0.01, 0.5, log=True),
        "exploration_fraction": trial.suggest_float("exploration_fraction", 0.1, 1.0),
    }


def sample_mfec_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict[str, Any]) -> dict:
    """MFEC (thesis Sec. 5.2.3; Table 5.1: epsilon and k).

    :param trial: the optuna trial.
    :param n_actions: number of actions (unused).
    :param n_envs: number of envs (unused).
    :param additional_args: RL-Zoo's extra arguments (unused).
    :return: MFEC constructor arguments.
    """
    return {
        "n_neighbors": trial.suggest_categorical("n_neighbors", [1, 3, 10]),
        "exploration_initial_eps": trial.suggest_categorical("exploration_initial_eps", [0.1, 0.9]),
        "exploration_fraction": trial.suggest_float("exploration_fraction", 0.05, 0.5),
    }


def sample_two_memory_dqn_params(
    trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict[str, Any]
) -> dict:
    """TwoMemoryDQN (thesis Ch. 5, Table 5.1: epsilon, p_ec schedule, learning rate, MFEC's k).

    :param trial: the optuna trial.
    :param n_actions: number of actions (unused).
    :param n_envs: number of envs (unused).
    :param additional_args: RL-Zoo's extra arguments (unused).
    :return: TwoMemoryDQN constructor arguments.
    """
    return {
        "learning_rate": trial.suggest_categorical("learning_rate", [1e-3, 1e-4]),
        "exploration_initial_eps": trial.suggest_categorical("exploration_initial_eps", [0.1, 0.9]),
        "p_ec_schedule": _p_ec_schedule(trial, decay=trial.suggest_float("p_ec_decay", 1e4, 1e6, log=True)),
        "ec_n_neighbors": trial.suggest_categorical("ec_n_neighbors", [1, 3, 10]),
    }


def sample_two_memory_sac_params(
    trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict[str, Any]
) -> dict:
    """TwoMemorySAC (CEC + SAC, ours): Table 5.1's switching schedules, SAC's learning rate, and CEC's k and softmax
    temperature (Table 4.4).

    :param trial: the optuna trial.
    :param n_actions: action dimension (unused).
    :param n_envs: number of envs (unused).
    :param additional_args: RL-Zoo's extra arguments (unused).
    :return: TwoMemorySAC constructor arguments.
    """
    return {
        "learning_rate": trial.suggest_categorical("learning_rate", [3e-4, 1e-3, 1e-4]),
        "p_ec_schedule": _p_ec_schedule(trial, decay=trial.suggest_float("p_ec_decay", 1e4, 1e6, log=True)),
        "ec_n_neighbors": trial.suggest_categorical("ec_n_neighbors", [1, 3, 5]),
        "ec_temperature": trial.suggest_categorical("ec_temperature", [0.1, 1.0, 10.0]),
    }


def _sample_tabular_q(trial: optuna.Trial) -> dict[str, Any]:
    return {
        "learning_rate": trial.suggest_float("learning_rate", 0.005, 0.5, log=True),
        "exploration_final_eps": trial.suggest_categorical("exploration_final_eps", [0.01, 0.05, 0.1]),
    }


def sample_tabular_q_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict[str, Any]) -> dict:
    """Tabular Q-learning (thesis Sec. 5.5.1; authors' tabular settings: learning rate 0.01, epsilon 0.1 -> 0.05).

    :param trial: the optuna trial.
    :param n_actions: number of actions (unused).
    :param n_envs: number of envs (unused).
    :param additional_args: RL-Zoo's extra arguments (unused).
    :return: TabularQLearning constructor arguments.
    """
    return _sample_tabular_q(trial)


def sample_tabular_ec_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict[str, Any]) -> dict:
    """Tabular episodic control (thesis Sec. 5.5.1): exploration only (the max-return update has no rate).

    :param trial: the optuna trial.
    :param n_actions: number of actions (unused).
    :param n_envs: number of envs (unused).
    :param additional_args: RL-Zoo's extra arguments (unused).
    :return: TabularEpisodicControl constructor arguments.
    """
    return {
        "exploration_initial_eps": trial.suggest_categorical("exploration_initial_eps", [0.1, 0.5, 0.9]),
        "exploration_final_eps": trial.suggest_categorical("exploration_final_eps", [0.01, 0.05, 0.1]),
    }


def sample_tabular_2m_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict[str, Any]) -> dict:
    """Tabular 2M (thesis Sec. 5.5.1): Q-learning's rate and exploration, Table 5.1's switching schedules.

    :param trial: the optuna trial.
    :param n_actions: number of actions (unused).
    :param n_envs: number of envs (unused).
    :param additional_args: RL-Zoo's extra arguments (unused).
    :return: TabularTwoMemory constructor arguments.
    """
    return {
        **_sample_tabular_q(trial),
        "p_ec_schedule": _p_ec_schedule(trial, decay=trial.suggest_float("p_ec_decay", 1e3, 1e5, log=True)),
    }


def sample_imgep_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict[str, Any]) -> dict:
    """Tabular IMGEP with post-exploration (thesis Ch. 6, Table 6.2: learning rate, tau, epsilon, p_pe).

    :param trial: the optuna trial.
    :param n_actions: number of actions (unused).
    :param n_envs: number of envs (unused).
    :param additional_args: RL-Zoo's extra arguments (unused).
    :return: TabularIMGEP constructor arguments.
    """
    return {
        "learning_rate": trial.suggest_float("learning_rate", 0.02, 0.5, log=True),
        "epsilon": trial.suggest_categorical("epsilon", [0.0, 0.1, 0.3]),
        "tau": trial.suggest_categorical("tau", [0.0, 0.5, 1.0, 2.0]),
        "post_exploration_rule": {"p_pe": trial.suggest_categorical("p_pe", [0.25, 0.5, 1.0])},
    }


#: ``--algo`` name -> sampler (every key of :data:`sb3_gcrl.algorithms.ALGORITHMS` has one; a test checks it)
SAMPLERS: dict[str, Sampler] = {
    "cec": sample_cec_params,
    "mfec": sample_mfec_params,
    "two_memory_dqn": sample_two_memory_dqn_params,
    "two_memory_sac": sample_two_memory_sac_params,
    "tabular_q": sample_tabular_q_params,
    "tabular_ec": sample_tabular_ec_params,
    "tabular_2m": sample_tabular_2m_params,
    "imgep": sample_imgep_params,
}


def register_zoo_samplers() -> None:
    """Insert :data:`SAMPLERS` into ``rl_zoo3.hyperparams_opt.HYPERPARAMS_SAMPLER`` (what ``-optimize`` reads)."""
    from rl_zoo3.hyperparams_opt import HYPERPARAMS_SAMPLER

    for name, sampler in SAMPLERS.items():
        HYPERPARAMS_SAMPLER.setdefault(name, sampler)
