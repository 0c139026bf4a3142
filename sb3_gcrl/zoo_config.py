"""Reading RL-Zoo hyperparameter files (``zoo_configs/*.yml`` or ``.py`` files exposing ``hyperparams``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml


def read_zoo_config(config: Path) -> dict[str, Any]:
    """All sections of an RL-Zoo hyperparameter file, keyed by env id (``default``/``atari`` included).

    :param config: ``.yml`` file, or ``.py`` file defining a ``hyperparams`` dict (RL-Zoo accepts both).
    :return: the sections.
    """
    if config.suffix == ".py":
        namespace: dict[str, Any] = {}
        exec(config.read_text(), namespace)
        return dict(namespace["hyperparams"])
    with open(config) as file:
        return dict(yaml.safe_load(file) or {})


def zoo_config_section(config: Path, env_id: str) -> dict[str, Any] | None:
    """The section RL-Zoo would use for ``env_id`` (its own, else ``default``), or None if there is none.

    :param config: hyperparameter file.
    :param env_id: environment id.
    :return: the section's hyperparameters.
    """
    sections = read_zoo_config(config)
    section = sections.get(env_id, sections.get("default"))
    return None if section is None else dict(section)
