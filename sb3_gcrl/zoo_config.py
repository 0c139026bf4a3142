"""Reading and checking RL-Zoo hyperparameter files (``zoo_configs/*.yml``, or ``.py`` files with ``hyperparams``)."""

from __future__ import annotations

from collections.abc import Mapping
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


def mode_switching_callbacks() -> dict[str, str]:
    """Wrapper class name -> the callback that switches it to training mode for the training env only.

    Read from the wrappers' own ``switching_callback`` (the eval env, which RL-Zoo wraps with the same
    ``env_wrapper``, must stay episodic).

    :return: the mapping.
    """
    from sb3_gcrl.post_exploration.wrapper import PostExplorationWrapper
    from sb3_gcrl.wrappers import GoalCommandWrapper, GoExploreWrapper, ResetFreeWrapper

    wrappers = (ResetFreeWrapper, GoalCommandWrapper, GoExploreWrapper, PostExplorationWrapper)
    return {wrapper.__name__: wrapper.switching_callback for wrapper in wrappers}


def _class_paths(value: Any) -> list[str]:
    """Class paths named in an ``env_wrapper``/``callback`` entry (a string, a dict, or a list of them)."""
    if value is None:
        return []
    if isinstance(value, str):
        return [value]
    if isinstance(value, Mapping):
        return [str(key) for key in value]
    return [name for item in value for name in _class_paths(item)]


def check_mode_switching_callbacks(section: Mapping[str, Any], where: str = "the config") -> None:
    """Raise if a section uses our episodic-until-switched wrappers without the callback that switches them.

    Without :class:`~sb3_gcrl.callbacks.ResetFreeCallback` the reset-free wrappers stay episodic, and without
    :class:`~sb3_gcrl.post_exploration.PostExplorationCallback` no goal is ever commanded: the run would quietly be
    plain episodic training.

    :param section: the hyperparameters of one env (``env_wrapper``, ``callback``, ...).
    :param where: the config's name for the error message.
    :raises ValueError: naming the callback to add.
    """
    callbacks = {path.rsplit(".", 1)[-1] for path in _class_paths(section.get("callback"))}
    switching = mode_switching_callbacks()
    for wrapper in _class_paths(section.get("env_wrapper")):
        callback = switching.get(wrapper.rsplit(".", 1)[-1])
        if callback is not None and callback.rsplit(".", 1)[-1] not in callbacks:
            raise ValueError(
                f"{where} wraps the env in {wrapper} but has no {callback.rsplit('.', 1)[-1]}, so training would "
                "stay episodic (the wrapper leaves its episodic mode only when the callback switches the training "
                f"env): add\n  callback:\n    - {callback}\n(in Python: model.learn(..., callback=...))"
            )
