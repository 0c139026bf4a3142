"""Table of this package's algorithms, as the RL-Zoo launcher (``sb3-gcrl train|enjoy``) sees them.

Entries are ``"module:Class"`` strings so that the table can be read without importing every
algorithm. An algorithm is off-policy for ``rl_zoo3.enjoy`` when it derives from
``OffPolicyAlgorithm`` (decided after import).
"""

from __future__ import annotations

import importlib

from stable_baselines3.common.base_class import BaseAlgorithm

#: name used with ``--algo`` -> ``"module:Class"``
ALGORITHMS: dict[str, str] = {
    "two_memory_dqn": "sb3_gcrl.two_memory:TwoMemoryDQN",
    "two_memory_sac": "sb3_gcrl.two_memory:TwoMemorySAC",
    "cec": "sb3_gcrl.cec:CEC",
    "mfec": "sb3_gcrl.mfec:MFEC",
    "tabular_q": "sb3_gcrl.tabular:TabularQLearning",
    "tabular_ec": "sb3_gcrl.tabular:TabularEpisodicControl",
    "tabular_2m": "sb3_gcrl.tabular:TabularTwoMemory",
    "imgep": "sb3_gcrl.imgep:TabularIMGEP",
    "morefree": "sb3_gcrl.morefree:MoReFree",
    "emac": "sb3_gcrl.emac:EMAC",
    "medal": "sb3_gcrl.reset_free_baselines:MEDAL",
    "r3l": "sb3_gcrl.reset_free_baselines:R3L",
    "ibc": "sb3_gcrl.reset_free_baselines:IBC",
}


def load_algorithm(name: str) -> type[BaseAlgorithm]:
    """Import and return the class registered under ``name``.

    :param name: key of :data:`ALGORITHMS` (e.g. ``"cec"``).
    :return: the algorithm class.
    """
    if name not in ALGORITHMS:
        raise KeyError(f"Unknown sb3-gcrl algorithm {name!r}; choose one of {sorted(ALGORITHMS)}")
    module_name, class_name = ALGORITHMS[name].split(":")
    return getattr(importlib.import_module(module_name), class_name)


def register_zoo_algorithms() -> None:
    """Insert every algorithm of :data:`ALGORITHMS` into ``rl_zoo3.utils.ALGOS``, and their optuna samplers into
    RL-Zoo's sampler table (``-optimize``)."""
    from rl_zoo3.utils import ALGOS

    from sb3_gcrl.hyperparams_opt import register_zoo_samplers

    for name in ALGORITHMS:
        ALGOS.setdefault(name, load_algorithm(name))
    register_zoo_samplers()
