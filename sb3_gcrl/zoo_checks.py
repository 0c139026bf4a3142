"""The checks every run of ``sb3-gcrl train`` and ``sb3-gcrl compare`` passes before it starts: algorithm and env
names, the hyperparameters of a config section (:mod:`sb3_gcrl.zoo_config`) against the algorithm's constructor, the
callbacks its mode-switched wrappers need, the training budget.
"""

from __future__ import annotations

import difflib
import inspect
from collections.abc import Mapping, Sequence
from typing import Any

from sb3_gcrl.common.validation import check_int
from sb3_gcrl.zoo_config import ZOO_KEYS

#: constructor arguments that the run itself sets (RL-Zoo passes them), so a config may not set them
RUN_SET_ARGUMENTS = frozenset({"env", "seed", "verbose", "device", "tensorboard_log"})


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


def algorithm_class(algo: str) -> type:
    """The class of an algorithm name: this package's (:data:`sb3_gcrl.algorithms.ALGORITHMS`) or RL-Zoo's.

    :param algo: the name (``--algo``).
    :return: the class.
    """
    from rl_zoo3.utils import ALGOS

    from sb3_gcrl.algorithms import ALGORITHMS, load_algorithm

    return load_algorithm(algo) if algo in ALGORITHMS else ALGOS[algo]


def check_hyperparameters(
    algo: str,
    section: Mapping[str, Any],
    where: str,
    overrides: Sequence[str] = (),
    run_set_hint: str = "seed: --seed; env: --env",
    override_flag: str = "--hyperparams",
) -> None:
    """Raise before any run starts when a hyperparameter is not an argument of the algorithm's constructor.

    The one check of ``sb3-gcrl train`` and ``sb3-gcrl compare``.

    Keys that RL-Zoo consumes itself (:data:`~sb3_gcrl.zoo_config.ZOO_KEYS`) are allowed; an algorithm whose
    ``**kwargs`` reach no base-class constructor without ``**kwargs`` is not checked.

    :param algo: key of ``rl_zoo3.utils.ALGOS`` or of :data:`sb3_gcrl.algorithms.ALGORITHMS`.
    :param section: the hyperparameters a run would get (config section + overrides).
    :param where: where the config's come from (named in the message).
    :param overrides: keys given as overrides (``--hyperparams``), named as such in the message.
    :param run_set_hint: how the command sets the :data:`RUN_SET_ARGUMENTS` instead (named in the message).
    :param override_flag: the option the overrides came with (``-params`` or ``--hyperparams``).
    :raises ValueError: naming each unknown key, its close matches and where it comes from.
    """
    algo_class = algorithm_class(algo)
    arguments = constructor_arguments(algo_class)
    if arguments is None:
        return
    public = sorted(key for key in arguments - RUN_SET_ARGUMENTS if not key.startswith("_"))
    accepted = (arguments - RUN_SET_ARGUMENTS) | ZOO_KEYS
    problems = []
    for key in sorted(set(section) - accepted):
        origin = override_flag if key in overrides else where
        if key in RUN_SET_ARGUMENTS:
            problems.append(f"{key!r} (from {origin}) is set by the run itself ({run_set_hint})")
            continue
        close = difflib.get_close_matches(key, sorted(set(public) | ZOO_KEYS), n=3)
        hint = f" (did you mean {', '.join(repr(c) for c in close)}?)" if close else ""
        problems.append(f"{key!r}{hint} from {origin}")
    if problems:
        raise ValueError(
            f"Unknown hyperparameter(s) for {algo} ({algo_class.__name__}): {'; '.join(problems)}. "
            f"{algo_class.__name__} takes: {public}; RL-Zoo also reads: {sorted(ZOO_KEYS)}."
        )


def available_algorithms() -> list[str]:
    """Algorithm names ``--algo`` and a compare method may use: this package's and RL-Zoo's (sorted)."""
    from rl_zoo3.utils import ALGOS

    from sb3_gcrl.algorithms import ALGORITHMS

    return sorted(set(ALGORITHMS) | set(ALGOS))


def check_algorithm(algo: str) -> None:
    """Raise a clear error when ``algo`` is not an algorithm name (:func:`available_algorithms`).

    :param algo: the name given (``--algo``, a compare method's ``ALGO``).
    :raises ValueError: with close matches and the valid names.
    """
    algos = available_algorithms()
    if algo in algos:
        return
    close = difflib.get_close_matches(algo, algos, n=3)
    hint = f" Did you mean {close}?" if close else ""
    raise ValueError(f"{algo!r} is not an algorithm.{hint} Valid algorithms: {algos}.")


def check_env_id(env_id: str) -> None:
    """Raise a clear error when ``env_id`` is not registered with gymnasium.

    :param env_id: gymnasium id, e.g. ``GCRL/GrowingTree-v0``.
    :raises ValueError: listing close matches and this package's ``GCRL/`` ids.
    """
    import gymnasium as gym

    if env_id in gym.registry:
        return
    close = difflib.get_close_matches(env_id, list(gym.registry), n=5)
    ours = sorted(key for key in gym.registry if key.startswith("GCRL/"))
    raise ValueError(
        f"Unknown env {env_id!r}. Close matches: {close}. This package's envs: {ours}. "
        "Envs of another package need `--gym-packages <module>` (the module must register them on import)."
    )


def run_budget(section: Mapping[str, Any], where: str, n_timesteps: Any = None) -> int:
    """The training budget of a run (env steps), checked before it starts: ``n_timesteps`` when given (the command
    line's ``-n``), else the section's ``n_timesteps``.

    :param section: the hyperparameters the run gets (config section and overrides).
    :param where: where the section comes from (named in the message).
    :param n_timesteps: the budget given explicitly, or None.
    :return: the budget.
    :raises ValueError: ``n_timesteps must be >= 1`` (naming the section when the value comes from it), or the
        section gives no budget.
    """
    if n_timesteps is not None:
        return check_int("n_timesteps", n_timesteps)
    if "n_timesteps" not in section:
        raise ValueError(f"{where} gives no n_timesteps: pass a budget (--n-timesteps)")
    value = section["n_timesteps"]
    try:  # PyYAML reads 1e6 (no dot) as a string
        return check_int("n_timesteps", float(value) if isinstance(value, str) else value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{error}, from {where}: set a budget of at least 1 step there, or pass -n N") from None
