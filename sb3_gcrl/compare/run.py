"""One run of a comparison (method x env x seed), built by RL-Zoo's own ``ExperimentManager``; the comparison that
plans and schedules the runs is :mod:`sb3_gcrl.compare.comparison`.

A run is exactly what ``rl_zoo3 train --algo ALGO --env ENV -conf CONFIG --seed SEED -n BUDGET`` builds
(hyperparameters, ``env_wrapper``, ``normalize``, YAML ``callback``s...), except that the zoo's
``EvalCallback`` is replaced by :class:`~sb3_gcrl.compare.evaluation.EvaluationRecorder` (evaluation
schedule in env steps, success rate, rows kept in memory for the per-run CSV). A YAML ``callback`` that is an
:class:`~sb3_gcrl.post_exploration.AllGoalsEvalCallback` (thesis Ch. 6) is evaluated at the run's evaluation points
too, and its rows (all-goals success, visitation entropy, coverage) are returned for ``all_goals.csv``.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import math
import traceback
from collections.abc import Callable
from dataclasses import MISSING, asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from huggingface_sb3 import EnvironmentName

#: the evaluation env is seeded away from the training env (RL-Zoo seeds both with the run seed)
EVAL_SEED_OFFSET = 10_000


@dataclass(frozen=True)
class RunSpec:
    """Everything that defines a run; two runs with equal specs give identical results (same machine).

    :param method: method label (tables, plots, folder name).
    :param algo: algorithm name (key of ``rl_zoo3.utils.ALGOS`` once our algorithms are registered).
    :param config: path of the RL-Zoo hyperparameter file.
    :param config_digest: hash of that file's content (a changed file invalidates finished runs).
    :param env_id: gymnasium id.
    :param seed: run seed (model, training env; evaluation env gets ``seed + EVAL_SEED_OFFSET``).
    :param n_timesteps: training budget in env steps.
    :param eval_freq: env steps between evaluations.
    :param n_eval_episodes: deterministic episodes per evaluation.
    :param hyperparams: overrides applied on top of the config (like ``rl_zoo3 train --hyperparams``).
    :param env_kwargs: keyword arguments of the env constructor, training and evaluation (``--env-kwargs``).
    :param gym_packages: modules imported before building envs (they register extra envs).
    :param save_model: also save the trained model (``zoo/`` folder of the run).
    :param save_freq: env steps between resumable checkpoints (0: none); a run killed after one continues from it
        when the comparison is run again (:func:`execute_run`).
    """

    method: str
    algo: str
    config: str
    config_digest: str
    env_id: str
    seed: int
    n_timesteps: int
    eval_freq: int
    n_eval_episodes: int = 5
    hyperparams: dict[str, Any] = field(default_factory=dict)
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    gym_packages: tuple[str, ...] = ()
    save_model: bool = False
    save_freq: int = 0

    @property
    def env_slug(self) -> str:
        """Env id usable as a folder name (``GCRL/GrowingTree-v0`` -> ``GCRL-GrowingTree-v0``)."""
        return str(EnvironmentName(self.env_id))

    @property
    def relative_dir(self) -> Path:
        """Folder of the run inside the comparison's ``runs/`` folder."""
        return Path(self.env_slug) / self.method / f"seed_{self.seed}"

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form (stored in ``run.json``; compared on resume)."""
        data = asdict(self)
        data["gym_packages"] = list(self.gym_packages)
        return data

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """JSON-friendly default value of every optional field."""
        values: dict[str, Any] = {}
        for spec_field in fields(cls):
            if spec_field.default is not MISSING:
                values[spec_field.name] = spec_field.default
            elif spec_field.default_factory is not MISSING:
                values[spec_field.name] = spec_field.default_factory()
        values["gym_packages"] = list(values["gym_packages"])
        return values

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunSpec:
        """Inverse of :meth:`to_dict`."""
        return cls(**{**data, "gym_packages": tuple(data.get("gym_packages", ()))})


@dataclass
class RunResult:
    """Outcome of a run: ``status`` is ``"finished"`` or ``"failed"`` (then ``error`` holds the traceback).

    ``wall_time_s`` and ``cpu_time_s`` are the run's wall and CPU time (its process's, all threads) as the worker
    measured them (a run continued from a checkpoint adds what its steps before it cost:
    :class:`~sb3_gcrl.compare.costs.RunTimer`); ``cpu_split_s`` splits the CPU time into the phases of
    :data:`~sb3_gcrl.compare.costs.ALL_PHASES` (gradient updates, data collection, evaluations, probes, checkpoints).
    ``visited_goals`` holds up to :data:`MAX_VISITED_POINTS` achieved goals of the training data (off-policy agents
    of goal envs only, else None), for state-visitation heatmaps and task-relevant shares.
    ``all_goals`` holds the rows of the run's :class:`~sb3_gcrl.post_exploration.AllGoalsEvalCallback` (None when
    its config has none).
    """

    spec: RunSpec
    status: str
    evaluations: list[dict[str, float]] = field(default_factory=list)
    wall_time_s: float = math.nan
    cpu_time_s: float = math.nan
    cpu_split_s: dict[str, float] | None = None
    error: str = ""
    log: str = ""
    visited_goals: np.ndarray | None = None
    all_goals: list[dict[str, float]] | None = None


#: cap on the achieved goals kept per run (evenly spaced over the replay buffer)
MAX_VISITED_POINTS = 20_000


def visited_goals(model: Any, max_points: int = MAX_VISITED_POINTS) -> np.ndarray | None:
    """Achieved goals in an off-policy agent's replay buffer (what training visited).

    :param model: a trained SB3 algorithm.
    :param max_points: keep at most this many, evenly spaced in storage order (i.e. over training time).
    :return: float32 array ``(n, goal_dim)``, or None (no replay buffer, no ``achieved_goal``, empty).
    """
    buffer = getattr(model, "replay_buffer", None)
    if callable(getattr(buffer, "achieved_goals", None)):  # sequence buffers (MoReFree) list their goals
        goals = buffer.achieved_goals()
    else:
        observations = getattr(buffer, "observations", None)
        if not isinstance(observations, dict) or "achieved_goal" not in observations:
            return None
        stored = observations["achieved_goal"]
        n_rows = buffer.buffer_size if buffer.full else buffer.pos
        goals = stored[:n_rows].reshape(-1, stored.shape[-1])
    if len(goals) == 0:
        return None
    keep = np.unique(np.linspace(0, len(goals) - 1, min(len(goals), max_points)).astype(np.int64))
    return goals[keep].astype(np.float32)


def all_goals_callback(callbacks: list[Any], eval_freq: int) -> Any | None:
    """The :class:`~sb3_gcrl.post_exploration.AllGoalsEvalCallback` among a run's callbacks, put on the run's schedule.

    Its ``eval_freq`` is set to the run's, so that its rows have the ``timesteps`` of ``evaluations.csv``; a
    different value of the config is replaced, which is printed (to the run's log).

    :param callbacks: the run's callbacks (RL-Zoo's ``exp_manager.callbacks``; ``CallbackList``s are searched).
    :param eval_freq: the run's env steps between evaluations.
    :return: the callback, or None when there is none.
    :raises ValueError: more than one (their rows would compete for one ``all_goals.csv``).
    """
    from sb3_gcrl.compare.costs import flat_callbacks
    from sb3_gcrl.post_exploration import AllGoalsEvalCallback

    found = [callback for callback in flat_callbacks(callbacks) if isinstance(callback, AllGoalsEvalCallback)]
    if len(found) > 1:
        raise ValueError(f"The config lists {len(found)} AllGoalsEvalCallback callbacks; keep one")
    if not found:
        return None
    if found[0].eval_freq != eval_freq:
        print(
            f"AllGoalsEvalCallback: eval_freq {found[0].eval_freq} of the config replaced by the run's eval_freq "
            f"{eval_freq} (all-goals rows at the run's evaluation points)"
        )
        found[0].eval_freq = eval_freq
    return found[0]


def prepare_process(gym_packages: tuple[str, ...] = (), single_thread: bool = True) -> None:
    """Set up a process: our envs and algorithms registered, extra gym packages imported, one torch thread.

    :param gym_packages: modules to import (they register their envs on import).
    :param single_thread: limit torch to one thread (workers; the parent of a comparison keeps its setting).
    """
    if single_thread:
        import torch

        torch.set_num_threads(1)
    import sb3_gcrl  # noqa: F401  (registers the GCRL/ envs)
    from sb3_gcrl.algorithms import register_zoo_algorithms

    register_zoo_algorithms()
    for module in gym_packages:
        importlib.import_module(module)


def _zoo_args(spec: RunSpec, log_folder: Path) -> argparse.Namespace:
    """The ``args`` RL-Zoo stores in ``args.yml``: the equivalent ``rl_zoo3 train`` command line."""
    return argparse.Namespace(
        algo=spec.algo,
        env=spec.env_id,
        conf_file=spec.config,
        seed=spec.seed,
        n_timesteps=spec.n_timesteps,
        hyperparams=spec.hyperparams,
        env_kwargs=spec.env_kwargs,
        gym_packages=list(spec.gym_packages),
        log_folder=str(log_folder),
        eval_freq=-1,
    )


def _settings(spec: dict[str, Any]) -> dict[str, Any]:
    """A run's settings as a checkpoint of it must match them: the spec in its JSON form, without ``save_freq``."""
    return {key: value for key, value in json.loads(json.dumps(spec)).items() if key != "save_freq"}


def resumable_checkpoint(run_dir: Path, spec: RunSpec) -> tuple[Path, dict[str, Any]] | None:
    """The checkpoint an unfinished run continues from: the newest one in ``run_dir``, whole
    (:func:`~sb3_gcrl.common.checkpoints.check_checkpoint`), made with the settings of ``spec``.

    :param run_dir: the run's folder.
    :param spec: the run as planned now.
    :return: the checkpoint and what the run saved with it (its settings and evaluations), or None (a note says
        why a checkpoint that is there is not used).
    """
    from sb3_gcrl.common.checkpoints import (
        CHECKPOINTS_DIR,
        CheckpointError,
        check_checkpoint,
        checkpoint_extra,
        latest_checkpoint,
    )
    from sb3_gcrl.zoo_checks import algorithm_class

    if not (run_dir / CHECKPOINTS_DIR).is_dir():
        return None
    try:
        checkpoint = latest_checkpoint(run_dir)
        check_checkpoint(checkpoint, algorithm_class(spec.algo))
        extra = checkpoint_extra(checkpoint)
    except (CheckpointError, ValueError) as error:
        print(f"The run starts from zero: its checkpoint cannot be used ({error})")
        return None
    if extra is None or _settings(extra.get("spec", {})) != _settings(spec.to_dict()):
        print(f"The run starts from zero: its checkpoint {checkpoint} was made with other settings")
        return None
    return checkpoint, extra


def execute_run(
    spec: RunSpec,
    run_dir: Path,
    log_file: TextIO,
    report_progress: Callable[[int], None] | None = None,
) -> RunResult:
    """Train and evaluate one run; never raises for a failure of the run itself (it is returned as failed).

    With ``spec.save_freq``, a resumable checkpoint (:mod:`sb3_gcrl.common.checkpoints`, with the run's settings and
    evaluations so far) is saved in ``run_dir/checkpoints`` every ``save_freq`` env steps, after the evaluation due
    at that step; a run that finds such a checkpoint of its own settings (:func:`resumable_checkpoint`) continues
    from it, with the step counter, the replay buffer, the wrappers' state, the generators and the evaluations of the
    checkpoint (``sb3-gcrl train --resume``'s mechanism), and ends with the evaluations of an uninterrupted run.

    :param spec: the run.
    :param run_dir: folder for RL-Zoo's own outputs (``zoo/``: config.yml, monitor.csv, model).
    :param log_file: receives the run's stdout/stderr.
    :param report_progress: called with env-step increments (progress bars).
    :return: the run's result with its evaluation rows (and all-goals rows).
    """
    from sb3_gcrl.compare.costs import RunTimer, time_callbacks

    timer = RunTimer()
    clock = timer.clock
    recorder = all_goals = None
    try:
        with contextlib.redirect_stdout(log_file), contextlib.redirect_stderr(log_file):
            prepare_process(spec.gym_packages)
            from rl_zoo3.exp_manager import ExperimentManager

            from sb3_gcrl.common.checkpoints import MODEL_FILE, RunCheckpointCallback, checkpoint_steps
            from sb3_gcrl.compare.evaluation import EvaluationRecorder
            from sb3_gcrl.zoo_train import ResumableExperimentManager

            log_folder = run_dir / "zoo"
            resumed = resumable_checkpoint(run_dir, spec)
            manager_class: type[ExperimentManager] = ExperimentManager
            resuming: dict[str, Any] = {}
            if resumed is not None or spec.save_freq:  # sb3-gcrl train's manager: it resumes from a checkpoint
                manager_class, resuming = ResumableExperimentManager, {"save_arguments": False}
            if resumed is not None:
                print(f"Continuing the run from its checkpoint at {checkpoint_steps(resumed[0])} steps")
                timer.resume(resumed[1].get("costs"))  # a checkpoint saved before runs recorded it: none
                resuming["trained_agent"] = str(resumed[0] / MODEL_FILE)  # RL-Zoo's -i: model, replay buffer
                resuming["resume_from"] = log_folder / spec.algo / f"{spec.env_slug}_1"  # the folder RL-Zoo picks
            exp_manager = manager_class(
                _zoo_args(spec, log_folder),
                spec.algo,
                spec.env_id,
                str(log_folder),
                n_timesteps=spec.n_timesteps,
                eval_freq=-1,  # replaced by the EvaluationRecorder below
                hyperparams=dict(spec.hyperparams),
                env_kwargs=dict(spec.env_kwargs) or None,
                seed=spec.seed,
                verbose=0,
                log_interval=-1,  # rl_zoo3 train's default (0 would mean "log every 0 episodes")
                config=spec.config,
                device="cpu",
                **resuming,
            )
            setup = exp_manager.setup_experiment()
            assert setup is not None  # None only in hyperparameter-optimisation mode
            model, _ = setup
            if getattr(model, "compile_train_step", False) and model.verbose < 1:  # verbose models say it themselves
                from sb3_gcrl.morefree.acceleration import COMPILE_NOTICE

                print(COMPILE_NOTICE)  # the run's log says why its first training step takes minutes
            all_goals = all_goals_callback(exp_manager.callbacks, spec.eval_freq)
            eval_env = exp_manager.create_envs(1, eval_env=True)
            eval_env.seed(spec.seed + EVAL_SEED_OFFSET)
            recorder = EvaluationRecorder(
                eval_env,
                eval_freq=spec.eval_freq,
                n_eval_episodes=spec.n_eval_episodes,
                report_progress=report_progress,
                progress_every=max(1, spec.n_timesteps // 100),
                verbose=1,
            )
            if resumed is not None:
                recorder.resume(resumed[1]["evaluations"])
            exp_manager.callbacks.append(recorder)
            if spec.save_freq:  # after the recorder: a checkpoint holds the evaluation due at its step
                exp_manager.callbacks.append(
                    RunCheckpointCallback(
                        max(1, spec.save_freq // exp_manager.n_envs),
                        run_dir,
                        spec.env_slug,
                        extra=lambda: {"spec": spec.to_dict(), "evaluations": recorder.records, "costs": timer.state()},
                    )
                )
            time_callbacks(clock, exp_manager.callbacks)
            with clock.timing_method(type(model), "train", "train"):
                exp_manager.learn(model)
            if model.num_timesteps < spec.n_timesteps:
                # RL-Zoo's learn() swallows KeyboardInterrupt: never report a cut run as finished
                raise RuntimeError(f"training stopped at {model.num_timesteps} of {spec.n_timesteps} steps")
            clock.timed("evaluate", recorder.evaluate_final)()
            eval_env.close()
            if spec.save_model:
                exp_manager.save_trained_model(model)
        wall_time, cpu_time = timer.elapsed()
        return RunResult(
            spec,
            "finished",
            recorder.records,
            wall_time,
            cpu_time,
            cpu_split_s=clock.split(cpu_time),
            visited_goals=visited_goals(model),
            all_goals=all_goals.records if all_goals is not None else None,
        )
    except Exception:
        error = traceback.format_exc()
        print(error, file=log_file)
        records = recorder.records if recorder is not None else []
        all_goals_records = all_goals.records if all_goals is not None else None
        wall_time, cpu_time = timer.elapsed()
        return RunResult(spec, "failed", records, wall_time, cpu_time, error=error, all_goals=all_goals_records)
