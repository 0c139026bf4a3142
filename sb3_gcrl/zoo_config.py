"""Reading and checking RL-Zoo hyperparameter files (``zoo_configs/*.yml``, or ``.py`` files with ``hyperparams``)."""

from __future__ import annotations

import difflib
import inspect
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

#: config keys RL-Zoo's ``ExperimentManager`` consumes itself instead of passing them to the algorithm
ZOO_KEYS = frozenset(
    {
        "n_timesteps",
        "n_envs",
        "normalize",
        "env_wrapper",
        "vec_env_wrapper",
        "frame_stack",
        "callback",
        "monitor_kwargs",
        "env_kwargs",
        "noise_type",
        "noise_std",
    }
)
#: constructor arguments that the run itself sets (RL-Zoo passes them), so a config may not set them
RUN_SET_ARGUMENTS = frozenset({"env", "seed", "verbose", "device", "tensorboard_log"})


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


def constructor_arguments(algo_class: type) -> set[str] | None:
    """Keyword arguments ``algo_class(...)`` accepts: its ``__init__``'s, and where that takes ``**kwargs``
    (handed to ``super().__init__``), those of the base classes' ``__init__`` too; None when unbounded."""
    names: set[str] = set()
    for cls in algo_class.__mro__:
        if "__init__" not in vars(cls) or cls is object:
            continue
        parameters = inspect.signature(vars(cls)["__init__"]).parameters.values()
        names |= {p.name for p in parameters if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)} - {"self"}
        if not any(p.kind is p.VAR_KEYWORD for p in parameters):
            return names
    return None


def check_hyperparameters(
    algo: str,
    section: Mapping[str, Any],
    where: str,
    overrides: Sequence[str] = (),
    run_set_hint: str = "seed: --seed; env: --env",
) -> None:
    """Raise before any run starts when a hyperparameter is not an argument of the algorithm's constructor.

    The one check of ``sb3-gcrl train`` and ``sb3-gcrl compare``.

    Keys that RL-Zoo consumes itself (:data:`ZOO_KEYS`) are allowed; an algorithm whose ``**kwargs`` reach no
    base-class constructor without ``**kwargs`` is not checked.

    :param algo: key of ``rl_zoo3.utils.ALGOS`` or of :data:`sb3_gcrl.algorithms.ALGORITHMS`.
    :param section: the hyperparameters a run would get (config section + overrides).
    :param where: where the config's come from (named in the message).
    :param overrides: keys given as overrides (``--hyperparams``), named as such in the message.
    :param run_set_hint: how the command sets the :data:`RUN_SET_ARGUMENTS` instead (named in the message).
    :raises ValueError: naming each unknown key, its close matches and where it comes from.
    """
    from rl_zoo3.utils import ALGOS

    from sb3_gcrl.algorithms import ALGORITHMS, load_algorithm

    algo_class = load_algorithm(algo) if algo in ALGORITHMS else ALGOS[algo]
    arguments = constructor_arguments(algo_class)
    if arguments is None:
        return
    public = sorted(key for key in arguments - RUN_SET_ARGUMENTS if not key.startswith("_"))
    accepted = (arguments - RUN_SET_ARGUMENTS) | ZOO_KEYS
    problems = []
    for key in sorted(set(section) - accepted):
        origin = "--hyperparams" if key in overrides else where
        if key in RUN_SET_ARGUMENTS:
            problems.append(f"{key!r} (from {origin}) is set by the run itself ({run_set_hint})")
            continue
        close = difflib.get_close_matches(key, public + sorted(ZOO_KEYS), n=3)
        hint = f" (did you mean {', '.join(repr(c) for c in close)}?)" if close else ""
        problems.append(f"{key!r}{hint} from {origin}")
    if problems:
        raise ValueError(
            f"Unknown hyperparameter(s) for {algo} ({algo_class.__name__}): {'; '.join(problems)}. "
            f"{algo_class.__name__} takes: {public}; RL-Zoo also reads: {sorted(ZOO_KEYS)}."
        )
