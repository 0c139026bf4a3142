"""MoReFree-SAC: the reset-free method of thesis Ch. 3 on SAC + HER, built in Python from its ``sac.yml`` section.

MoReFree-SAC is this package's model-free port of MoReFree (thesis Ch. 3): a goal-conditioned SAC + HER agent
trained **without resets**, with MoReFree's two mechanisms and no world model:

1. **Back-and-Forth Go-Explore** (Algorithm 3) collects the data: with probability alpha (0.2) the agent is sent
   to an evaluation goal g* ~ rho_g*, then back to an initial state g0 ~ rho_0; otherwise to an exploratory goal
   (count-based novelty over visited goal bins, Eq. 6.5, where the thesis plans PEG goals with its world model).
   Each Go phase is followed by an Explore phase of random actions.
2. **Task-relevant relabeling** (Sec. 3.4.2): HER relabels sampled transitions toward rho_g* w.p. alpha/2, toward
   rho_0 w.p. alpha/2, and toward future achieved goals otherwise (the thesis trains on those goals in imagination).

It is no algorithm class of its own: stock SB3 ``SAC`` composes the package's pieces, each documented where it lives
(docs/reset_free.md):

- :class:`sb3_gcrl.wrappers.ResetFreeWrapper`: a physical reset only every ``hard_reset_every`` steps (task table,
  :data:`sb3_gcrl.envs.tasks.TASKS`); SB3 sees truncated segments;
- :class:`sb3_gcrl.wrappers.GoExploreWrapper` with the ``back_and_forth`` scheduler of
  :func:`sb3_gcrl.goals.make_scheduler` (:class:`sb3_gcrl.goals.BackAndForthScheduler` over a novelty scheduler on
  :class:`sb3_gcrl.goals.BinnedGoalSpace`; rho_0 and rho_g* from :class:`sb3_gcrl.goals.TaskRelevantGoals`);
- :class:`sb3_gcrl.her.TaskRelevantHerReplayBuffer`: stores the executed action, relabels toward task-relevant
  goals, reads alpha from the env's scheduler;
- :class:`sb3_gcrl.callbacks.ResetFreeCallback`: switches the *training* env to reset-free mode (an env built here
  stays episodic until it does, so the same builder gives the evaluation env) and logs the reset-free statistics.

Its settings live in one place, the env's default section of ``zoo_configs/sac.yml`` (one per reset-free task,
:func:`env_ids`; ``GCRL/PointUMazeGoal-v0`` by default). The builders below read that section and build from it what
``sb3-gcrl train --algo sac --env <env id>`` (RL-Zoo) builds: the same env chain, agent and callbacks, step for step
(``tests/test_morefree_sac.py`` trains both and compares them). Example::

    from sb3_gcrl import morefree_sac

    env = morefree_sac.make_env("GCRL/PointUMazeGoal-v0", seed=0)  # Monitor -> ResetFree -> GoExplore, alpha 0.2
    model = morefree_sac.make_agent(env, seed=0)  # SAC + TaskRelevantHerReplayBuffer, sac.yml's settings
    model.learn(100_000, callback=morefree_sac.make_callback(env))  # ResetFreeCallback: training goes reset-free
    eval_env = morefree_sac.make_env("GCRL/PointUMazeGoal-v0", seed=1)  # never switched: episodic evaluation

``make_env(..., alpha=1.0)`` is the ablation with task goals only; ``make_agent(env, batch_size=128, ...)`` overrides
a setting of the section (as ``--hyperparams`` does). The baselines and the other ablations of Ch. 3 are the
variants ``<env id>@<variant>`` of ``sac.yml`` (``sb3-gcrl train --algo sac --env <env id> --variant naive``). The
world-model agent of the thesis is :class:`sb3_gcrl.MoReFree` (``--algo morefree``).
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_gcrl.zoo_checks import algorithm_class, check_hyperparameters, check_mode_switching_callbacks
from sb3_gcrl.zoo_config import ZOO_KEYS, find_config, read_zoo_config, resolve_config, split_section_key

if TYPE_CHECKING:
    from stable_baselines3 import SAC
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import VecEnv

#: the algorithm and the file MoReFree-SAC's sections are in (``zoo_configs/sac.yml``)
ALGO = "sac"
#: the task built when none is named
ENV_ID = "GCRL/PointUMazeGoal-v0"
#: the wrapper and the scheduler whose settings make a section MoReFree-SAC (with the buffer below)
GO_EXPLORE_WRAPPER = "sb3_gcrl.wrappers.GoExploreWrapper"
SCHEDULER = "back_and_forth"
BUFFER = "TaskRelevantHerReplayBuffer"
#: the env-side keys of a section (RL-Zoo's, see :data:`sb3_gcrl.zoo_config.ZOO_KEYS`) the builders here read
ENV_KEYS = frozenset({"n_envs", "env_wrapper", "monitor_kwargs", "env_kwargs"})


def is_morefree_sac(section: Mapping[str, Any]) -> bool:
    """Whether a section of ``sac.yml`` is MoReFree-SAC: a ``GoExploreWrapper`` with the ``back_and_forth`` scheduler
    and the ``TaskRelevantHerReplayBuffer``."""
    return _go_explore_settings(section) is not None and str(section.get("replay_buffer_class", "")).endswith(BUFFER)


def env_ids() -> list[str]:
    """The tasks whose default section of ``sac.yml`` is MoReFree-SAC, in file order."""
    sections = read_zoo_config(find_config(ALGO))
    return [key for key, section in sections.items() if split_section_key(key)[1] is None and is_morefree_sac(section)]


def config_section(env_id: str = ENV_ID) -> dict[str, Any]:
    """MoReFree-SAC's settings for a task: its default section of ``sac.yml``, as the file states them (a copy).

    :param env_id: a task of :func:`env_ids`.
    :return: the section (YAML anchors and merge keys resolved; ``policy_kwargs`` etc. as the strings RL-Zoo reads).
    :raises ValueError: the task has no MoReFree-SAC section; the message lists those that have one.
    """
    resolved = resolve_config(ALGO, env_id, config=ALGO)
    if not is_morefree_sac(resolved.hyperparams):
        raise ValueError(
            f"{resolved.where} is not MoReFree-SAC (no {GO_EXPLORE_WRAPPER} with scheduler {SCHEDULER!r} and "
            f"{BUFFER}). MoReFree-SAC's tasks: {env_ids()}"
        )
    check_mode_switching_callbacks(resolved.hyperparams, resolved.where)
    unbuilt = sorted(set(resolved.hyperparams) & ZOO_KEYS - ENV_KEYS - {"n_timesteps", "callback"})
    if unbuilt:
        raise ValueError(f"{resolved.where} sets {unbuilt}, which only RL-Zoo builds: train it with sb3-gcrl train")
    return resolved.hyperparams


def make_env(
    env_id: str = ENV_ID,
    n_envs: int | None = None,
    seed: int | None = None,
    *,
    alpha: float | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    monitor_dir: str | Path | None = None,
    vec_env_cls: type[VecEnv] | None = None,
) -> VecEnv:
    """MoReFree-SAC's env: the task in SB3's ``Monitor``, wrapped by the section's ``env_wrapper`` list (innermost
    first: ``ResetFreeWrapper`` -> ``GoExploreWrapper``), vectorized, as RL-Zoo builds it.

    The wrappers start in evaluation mode (episodic); :func:`make_callback`'s callback switches the env that trains
    to reset-free mode, so an env built here and never trained on is an episodic evaluation env.

    :param env_id: a task of :func:`env_ids`.
    :param n_envs: number of envs; the section's ``n_envs`` (else 1) when None.
    :param seed: seed of the first env (SB3's ``make_vec_env``); the agent's seed reseeds the envs again.
    :param alpha: the probability of a forward/back goal pair (Back-and-Forth, thesis Sec. 3.4), which
        ``TaskRelevantHerReplayBuffer`` reads from the env for its relabeling too; the section's (0.2) when None.
    :param env_kwargs: keyword arguments of ``gym.make``, over the section's ``env_kwargs``.
    :param monitor_dir: where ``Monitor`` writes its CSV (the reset-free segments while training), or None.
    :param vec_env_cls: ``DummyVecEnv`` when None, or e.g. ``SubprocVecEnv``.
    :return: the vectorized env.
    """
    import gymnasium as gym
    from rl_zoo3.utils import get_wrapper_class
    from stable_baselines3.common.env_util import make_vec_env

    settings = config_section(env_id)
    if alpha is not None:
        settings["env_wrapper"] = _with_alpha(settings["env_wrapper"], alpha)
    monitor_kwargs = settings.get("monitor_kwargs", {})
    if isinstance(monitor_kwargs, str):
        monitor_kwargs = _evaluate(monitor_kwargs)
    # a callable, as RL-Zoo passes: make_vec_env would add render_mode="rgb_array" to an env id
    return make_vec_env(
        functools.partial(gym.make, env_id),
        n_envs=settings.get("n_envs", 1) if n_envs is None else n_envs,
        seed=seed,
        env_kwargs={**settings.get("env_kwargs", {}), **(env_kwargs or {})},
        monitor_dir=None if monitor_dir is None else str(monitor_dir),
        wrapper_class=get_wrapper_class(settings),
        vec_env_cls=vec_env_cls,
        monitor_kwargs=monitor_kwargs,
    )


def make_agent(
    env: VecEnv,
    seed: int | None = None,
    *,
    env_id: str | None = None,
    verbose: int = 0,
    device: str = "auto",
    tensorboard_log: str | None = None,
    **overrides: Any,
) -> SAC:
    """MoReFree-SAC's agent on ``env`` (from :func:`make_env`): SB3's ``SAC`` with the section's settings
    (``TaskRelevantHerReplayBuffer``, network, batch, train frequency, ...), built as RL-Zoo builds it.

    :param env: the env, from :func:`make_env`.
    :param seed: the agent's seed (torch, numpy, the action space and the envs).
    :param env_id: the task whose section is read; the env's own id when None.
    :param verbose: SB3's verbosity.
    :param device: torch device.
    :param tensorboard_log: tensorboard folder, or None.
    :param overrides: settings of ``SAC`` over the section's, as the section writes them (``learning_starts=2000``,
        ``policy_kwargs=dict(net_arch=[64, 64])`` or its string ``"dict(net_arch=[64, 64])"``), as
        ``--hyperparams`` gives them to RL-Zoo.
    :return: the agent; train it with ``model.learn(n, callback=make_callback(env))``.
    :raises ValueError: an override is no argument of ``SAC``, or an env-side setting (:func:`make_env` builds those).
    """
    from rl_zoo3.exp_manager import ExperimentManager
    from rl_zoo3.utils import get_class_by_name

    env_id = _env_id(env, env_id)
    where = f"make_agent's overrides for {env_id}"
    env_side = sorted(set(overrides) & ZOO_KEYS)
    if env_side:
        raise ValueError(f"{where}: {env_side} set(s) the env or the run, not SAC (make_env builds the env)")
    arguments = "make_agent's keyword arguments"
    check_hyperparameters(ALGO, overrides, where, list(overrides), "make_agent's arguments", override_flag=arguments)
    settings = {**config_section(env_id), **overrides}
    kwargs = ExperimentManager._preprocess_schedules({k: v for k, v in settings.items() if k not in ZOO_KEYS})
    if isinstance(kwargs.get("train_freq"), list):
        kwargs["train_freq"] = tuple(kwargs["train_freq"])
    for key in ("policy_kwargs", "replay_buffer_class", "replay_buffer_kwargs"):
        if isinstance(kwargs.get(key), str):
            kwargs[key] = _evaluate(kwargs[key])
    if isinstance(kwargs.get("policy"), str) and "." in kwargs["policy"]:
        kwargs["policy"] = get_class_by_name(kwargs["policy"])
    return algorithm_class(ALGO)(
        env=env, tensorboard_log=tensorboard_log, seed=seed, verbose=verbose, device=device, **kwargs
    )


def make_callback(env: VecEnv, env_id: str | None = None) -> list[BaseCallback]:
    """The callbacks of the section (``ResetFreeCallback``), to pass to ``model.learn``: without them the wrappers
    stay episodic and a warning says so at the first training step.

    :param env: the training env (from :func:`make_env`).
    :param env_id: the task whose section is read; the env's own id when None.
    :return: fresh callbacks (one list per ``learn`` call).
    """
    from rl_zoo3.utils import get_callback_list

    return get_callback_list(config_section(_env_id(env, env_id)))


def _go_explore_settings(section: Mapping[str, Any]) -> dict[str, Any] | None:
    """The ``GoExploreWrapper`` entry of a section's ``env_wrapper`` list when its scheduler is Back-and-Forth."""
    wrappers = section.get("env_wrapper") or []
    for entry in wrappers if isinstance(wrappers, list) else [wrappers]:
        if isinstance(entry, Mapping) and GO_EXPLORE_WRAPPER in entry:
            settings = entry[GO_EXPLORE_WRAPPER] or {}
            return dict(settings) if settings.get("scheduler") == SCHEDULER else None
    return None


def _with_alpha(env_wrapper: list[Any], alpha: float) -> list[Any]:
    """The ``env_wrapper`` list with alpha set in the Back-and-Forth scheduler's options (the one place it is stated:
    the buffer reads it from the env)."""
    wrappers = copy.deepcopy(env_wrapper)
    for entry in wrappers:
        if isinstance(entry, dict) and GO_EXPLORE_WRAPPER in entry:
            options = entry[GO_EXPLORE_WRAPPER]
            options["scheduler_kwargs"] = {**options["scheduler_kwargs"], "alpha": alpha}
    return wrappers


def _evaluate(text: str) -> Any:
    """A setting written as Python (``"dict(net_arch=[256, 256])"``), evaluated where RL-Zoo evaluates it (the
    namespace of ``rl_zoo3.exp_manager``), so that both read a section alike."""
    from rl_zoo3 import exp_manager

    return eval(text, dict(vars(exp_manager)))


def _env_id(env: VecEnv, env_id: str | None) -> str:
    """The task id given, else the one of the env's first sub-env."""
    if env_id is not None:
        return env_id
    spec = env.get_attr("spec", [0])[0]
    if spec is None:
        raise ValueError("the env has no gymnasium spec to read its id from: pass env_id=")
    return str(spec.id)
