"""Optuna search spaces for this package's algorithms, so that ``sb3-gcrl train --algo <ours> -optimize`` works.

RL-Zoo looks a sampler up in ``rl_zoo3.hyperparams_opt.HYPERPARAMS_SAMPLER[algo]`` and calls it as
``sampler(trial, n_actions, n_envs, additional_args)``; the returned dict updates the config's hyperparameters
before the model is built, so every key is a constructor argument of the algorithm (a test builds a model from
sampled values for every algorithm). The search spaces are data (:data:`SEARCH_SPACES`), turned into samplers by
one function; :func:`register_zoo_samplers` adds them to RL-Zoo's table (``sb3-gcrl train`` calls it).

The ranges are the thesis's tuned values where it gives them:

- CEC, Table 4.4 (k, tau, sigma, n, d over the four navigation tasks);
- MFEC and the 2M agents, Table 5.1 (epsilon 0.1 / 0.9, k 1 / 3 / 10, p_ec schedules 0.9->0.1, 0.1->0.1,
  0.1->0.9, learning rate 1e-3 / 1e-4);
- tabular IMGEP, Table 6.2 (learning rate 0.1, tau 0, epsilon 0 / 0.1 / 0.3, p_pe 0.5), widened around the
  table's single values so that a search has something to find;
- tabular Q / EC: the authors' tabular 2M settings (learning rate 0.01, epsilon 0.1 -> 0.05), widened likewise;
- EMAC (the Ch. 4 baseline): around the paper's alpha, k and projection dimension;
- MoReFree (Ch. 3): the train ratios of Table 3.2, learning rate, imagination horizon and entropy around PEG's
  defaults;
- MEDAL and R3L (Ch. 3 baselines): learning rate and discount around the official MEDAL code's, and the update
  frequency of the backward reward model.

Settings of the env wrappers (MoReFree's alpha, the horizons H_G = H_E, the hard-reset interval) are not
constructor arguments of an algorithm, and RL-Zoo's sampler interface can only return those; tune them by running
one config section per value, e.g. variants ``<env id>@<name>`` of ``zoo_configs/<algo>.yml`` (``sb3-gcrl compare -m
ALGO@NAME ...`` runs them side by side).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import optuna

Sampler = Callable[[optuna.Trial, int, int, dict[str, Any]], dict[str, Any]]


@dataclass(frozen=True)
class Choice:
    """One of ``values`` (optuna's categorical distribution)."""

    values: tuple[Any, ...]

    def sample(self, trial: optuna.Trial, name: str) -> Any:
        return trial.suggest_categorical(name, list(self.values))


@dataclass(frozen=True)
class Range:
    """A float in ``[low, high]``, log-uniform if ``log``."""

    low: float
    high: float
    log: bool = False

    def sample(self, trial: optuna.Trial, name: str) -> float:
        return trial.suggest_float(name, self.low, self.high, log=self.log)


@dataclass(frozen=True)
class SwitchingSchedule:
    """A p_ec schedule of Eq. 5.5: Table 5.1's ``p^s -> p^e`` pairs with a log-uniform decay constant."""

    decay_low: float
    decay_high: float
    #: Table 5.1's switching schedules p^s -> p^e, by name for optuna's categorical distribution
    pairs: tuple[tuple[str, float, float], ...] = (("0.9-0.1", 0.9, 0.1), ("0.1-0.1", 0.1, 0.1), ("0.1-0.9", 0.1, 0.9))

    def sample(self, trial: optuna.Trial, name: str) -> dict[str, Any]:
        pairs = {label: (start, end) for label, start, end in self.pairs}
        start, end = pairs[trial.suggest_categorical(f"{name}_pair", list(pairs))]
        decay = trial.suggest_float(f"{name}_decay", self.decay_low, self.decay_high, log=True)
        return {"type": "decayed" if start >= end else "increasing", "start": start, "end": end, "decay": decay}


@dataclass(frozen=True)
class Nested:
    """A dict ``{key: value}`` with the value drawn from ``space`` (e.g. IMGEP's ``{p_pe: 0.5}`` rule)."""

    key: str
    space: Choice | Range

    def sample(self, trial: optuna.Trial, name: str) -> dict[str, Any]:
        return {self.key: self.space.sample(trial, self.key)}


Space = Choice | Range | SwitchingSchedule | Nested

_TABULAR_Q: dict[str, Space] = {
    "learning_rate": Range(0.005, 0.5, log=True),
    "exploration_final_eps": Choice((0.01, 0.05, 0.1)),
}

#: ``--algo`` name -> constructor argument -> its search space (every algorithm of the package has one; tested)
SEARCH_SPACES: dict[str, dict[str, Space]] = {
    "cec": {  # Table 4.4
        "n_neighbors": Choice((1, 3, 5)),
        "temperature": Choice((0.1, 1.0, 10.0)),
        "noise_std": Choice((0.1, 0.3)),
        "filter_factor": Choice((1.0, 3.0)),
        "distance_threshold": Range(0.01, 0.5, log=True),
        "exploration_fraction": Range(0.1, 1.0),
    },
    "mfec": {  # Table 5.1 (epsilon, k)
        "n_neighbors": Choice((1, 3, 10)),
        "exploration_initial_eps": Choice((0.1, 0.9)),
        "exploration_fraction": Range(0.05, 0.5),
    },
    "two_memory_dqn": {  # Table 5.1
        "learning_rate": Choice((1e-3, 1e-4)),
        "exploration_initial_eps": Choice((0.1, 0.9)),
        "p_ec_schedule": SwitchingSchedule(1e4, 1e6),
        "ec_n_neighbors": Choice((1, 3, 10)),
    },
    "two_memory_sac": {  # Table 5.1's switching, SAC's learning rate, CEC's k and softmax temperature (Table 4.4)
        "learning_rate": Choice((3e-4, 1e-3, 1e-4)),
        "p_ec_schedule": SwitchingSchedule(1e4, 1e6),
        "ec_n_neighbors": Choice((1, 3, 5)),
        "ec_temperature": Choice((0.1, 1.0, 10.0)),
    },
    "tabular_q": _TABULAR_Q,
    "tabular_ec": {  # the max-return update has no rate: exploration only
        "exploration_initial_eps": Choice((0.1, 0.5, 0.9)),
        "exploration_final_eps": Choice((0.01, 0.05, 0.1)),
    },
    "tabular_2m": {**_TABULAR_Q, "p_ec_schedule": SwitchingSchedule(1e3, 1e5)},
    "imgep": {  # Table 6.2
        "learning_rate": Range(0.02, 0.5, log=True),
        "epsilon": Choice((0.0, 0.1, 0.3)),
        "tau": Choice((0.0, 0.5, 1.0, 2.0)),
        "post_exploration_rule": Nested("p_pe", Choice((0.25, 0.5, 1.0))),
    },
    "emac": {  # around the EMAC paper's values (alpha 0.1, k 2, projection to 4 dims, DDPG's learning rate 1e-3)
        "alpha": Choice((0.05, 0.1, 0.3)),
        "n_neighbors": Choice((1, 2, 5)),
        "projection_dim": Choice((4, 8)),
        "learning_rate": Choice((1e-3, 3e-4)),
    },
    "morefree": {  # Table 3.2's train ratios (every n env steps one training round), around PEG's defaults
        "train_ratio": Choice((1, 2, 5)),
        "learning_rate": Range(1e-4, 1e-3, log=True),
        "imagination_horizon": Choice((10, 15, 20)),
        "entropy_coef": Range(1e-5, 1e-3, log=True),
    },
    # MEDAL / R3L (Ch. 3 baselines): SAC's learning rate and discount around the official MEDAL code's 3e-4 / 0.99,
    # and how often the backward reward model (discriminator / RND) is updated (MEDAL: every 10 env steps)
    "medal": {
        "learning_rate": Range(1e-4, 1e-3, log=True),
        "gamma": Choice((0.95, 0.98, 0.99)),
        "reward_model_train_freq": Choice((1, 10, 50)),
    },
    "r3l": {
        "learning_rate": Range(1e-4, 1e-3, log=True),
        "gamma": Choice((0.95, 0.98, 0.99)),
        "reward_model_train_freq": Choice((1, 10, 50)),
    },
    # IBC (Ch. 3 baseline): SAC's learning rate and discount around the official IBC code's 1e-4 / 0.99, and the
    # policy samples of the curriculum's value (official: 10); the curriculum itself is a wrapper setting
    "ibc": {
        "learning_rate": Range(1e-4, 1e-3, log=True),
        "gamma": Choice((0.95, 0.98, 0.99)),
        "value_samples": Choice((1, 10)),
    },
}


def sample_hyperparameters(trial: optuna.Trial, space: dict[str, Space]) -> dict[str, Any]:
    """Draw one value per constructor argument of ``space`` (optuna parameter names are the argument names).

    :param trial: the optuna trial.
    :param space: constructor argument -> search space.
    :return: constructor arguments.
    """
    return {name: distribution.sample(trial, name) for name, distribution in space.items()}


def make_sampler(algo: str) -> Sampler:
    """RL-Zoo sampler (``sampler(trial, n_actions, n_envs, additional_args)``) over ``SEARCH_SPACES[algo]``.

    :param algo: key of :data:`SEARCH_SPACES`.
    :return: the sampler; ``n_actions``, ``n_envs`` and ``additional_args`` are not used by these spaces.
    """
    space = SEARCH_SPACES[algo]

    def sampler(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict[str, Any]) -> dict[str, Any]:
        return sample_hyperparameters(trial, space)

    sampler.__name__ = f"sample_{algo}_params"
    return sampler


#: ``--algo`` name -> RL-Zoo sampler
SAMPLERS: dict[str, Sampler] = {name: make_sampler(name) for name in SEARCH_SPACES}


def register_zoo_samplers() -> None:
    """Insert :data:`SAMPLERS` into ``rl_zoo3.hyperparams_opt.HYPERPARAMS_SAMPLER`` (what ``-optimize`` reads)."""
    from rl_zoo3.hyperparams_opt import HYPERPARAMS_SAMPLER

    for name, sampler in SAMPLERS.items():
        HYPERPARAMS_SAMPLER.setdefault(name, sampler)
