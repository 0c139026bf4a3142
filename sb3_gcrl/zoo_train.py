"""``sb3-gcrl train`` on RL-Zoo's experiment manager, with interruption and resume.

RL-Zoo's ``train`` saves the model when interrupted (Ctrl-C) and exits 0; its ``-i`` starts a new run from a saved
model, with the step counter at 0. :class:`ResumableExperimentManager` keeps everything else of RL-Zoo and adds:

* Ctrl-C stops training after the current step (its evaluation and checkpoint done; a second Ctrl-C stops at
  once), saves a resumable checkpoint (:mod:`sb3_gcrl.common.checkpoints`: model, replay buffer, ``VecNormalize``,
  the wrappers' accumulated state, the global generators) before the env closes, and ``sb3-gcrl train`` exits with
  130 (the shell's code for Ctrl-C) after RL-Zoo's own final save;
* ``--save-freq N`` also writes such a checkpoint every N steps (besides RL-Zoo's ``rl_model_<N>_steps.zip``), so a
  killed run loses at most N steps;
* ``sb3-gcrl train --resume <run folder>`` continues the same run, in the same folder, from its newest checkpoint:
  with the run's own arguments, the step counter where it stopped, the remaining budget, and the monitor CSV and
  evaluation history extended rather than overwritten (evaluations after the checkpoint are dropped: they are
  run again);
* a run that fails before training starts (a model file that does not load, an env the algorithm cannot take)
  leaves no run folder behind (``enjoy`` would pick it as the latest run and find no model);
* a variant's section (``--variant NAME``: the key ``<env id>@NAME``, which RL-Zoo does not read) is written, keyed
  by the plain env id, to the run's parameter folder (:data:`CONFIG_FILE`), which RL-Zoo then reads and a resumed
  run reads again.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rl_zoo3.exp_manager import ExperimentManager
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, EvalCallback
from stable_baselines3.common.vec_env import VecEnv

from sb3_gcrl.common.checkpoints import (
    MODEL_FILE,
    RunCheckpointCallback,
    checkpoint_steps,
    latest_checkpoint,
    restore_checkpoint,
    save_checkpoint,
)
from sb3_gcrl.common.saving import atomic_write_text

if TYPE_CHECKING:
    from sb3_gcrl.zoo_config import ResolvedConfig

#: file in the run's parameter folder (``<run>/<env name>/``) holding the ``sb3-gcrl train`` arguments to resume with
ARGUMENTS_FILE = "sb3_gcrl_train_args.json"
#: file in the run's parameter folder holding the section of a variant (``--variant``), keyed by the plain env id
CONFIG_FILE = "sb3_gcrl_config.yml"
#: ``sb3-gcrl train``'s exit code after an interruption (the shell's code for SIGINT)
INTERRUPTED_EXIT_CODE = 130
#: options of ``sb3-gcrl train`` that take a file path (made absolute in the saved arguments)
PATH_OPTIONS = ("-conf", "--conf-file")


class ResumableExperimentManager(ExperimentManager):
    """RL-Zoo's experiment manager, with resumable checkpoints (see the module's docstring).

    :param args: RL-Zoo's ``ExperimentManager`` arguments.
    :param resume_from: the run folder to continue (None: a new run); RL-Zoo's ``trained_agent`` must then be its
        newest checkpoint's model.
    :param section: a section RL-Zoo cannot read from its file (a variant's): written to :data:`CONFIG_FILE` in the
        run's parameter folder, which becomes the run's config (also for ``--resume``).
    :param save_arguments: write the ``sb3-gcrl train`` arguments to :data:`ARGUMENTS_FILE` (``--resume`` reads them;
        ``sb3-gcrl compare``'s runs resume through ``compare`` instead).
    :param kwargs: RL-Zoo's ``ExperimentManager`` keyword arguments.
    """

    def __init__(
        self,
        *args: Any,
        resume_from: Path | None = None,
        section: ResolvedConfig | None = None,
        save_arguments: bool = True,
        **kwargs: Any,
    ) -> None:
        super().__init__(*args, **kwargs)
        self.save_arguments = save_arguments
        #: whether training stopped on KeyboardInterrupt (Ctrl-C)
        self.interrupted = False
        #: whether the run folder is this run's own, made by it (a failed start removes it)
        self.new_folder = resume_from is None and not Path(self.save_path).exists()
        self.resume_from = resume_from
        self._checkpoint: Path | None = None
        self._finished_before = False
        if resume_from is not None:
            self._checkpoint = Path(self.trained_agent).parent
            self.save_path = str(resume_from)
            self.params_path = f"{self.save_path}/{self.env_name}"
        #: the file written for ``section`` (None: RL-Zoo reads the config it was given)
        self.section_file: Path | None = None
        if section is not None and not self.resuming:
            self.section_file = Path(self.params_path) / CONFIG_FILE
            self.section_file.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.section_file, section.to_yaml())
            self.config = self.args.conf_file = str(self.section_file)

    def setup_experiment(self) -> tuple[BaseAlgorithm, dict[str, Any]] | None:
        """RL-Zoo's setup (hyperparameters, envs, model); when it fails, the new run's folder is removed, so that
        no half-made run (a folder without a model) is left for ``enjoy`` to pick as the latest."""
        try:
            return super().setup_experiment()
        except BaseException:
            if self.new_folder:
                shutil.rmtree(self.save_path, ignore_errors=True)
            raise

    def save_trained_model(self, model: BaseAlgorithm) -> None:
        """RL-Zoo's final save, unless a resumed run had nothing left to train (its files stay as they are)."""
        if not self._finished_before:
            super().save_trained_model(model)

    @property
    def resuming(self) -> bool:
        """Whether this manager continues an earlier run."""
        return self._checkpoint is not None

    def _save_config(self, saved_hyperparams: dict[str, Any]) -> None:
        if self.resuming:
            print(f"Resuming the run in {self.save_path} from {self._checkpoint}")
            if (Path(self.params_path) / "config.yml").is_file():  # the run's own config files stay as they were
                return
        super()._save_config(saved_hyperparams)
        if not self.save_arguments:
            return
        arguments = sys.argv[1:]
        if "--seed" not in arguments:  # RL-Zoo drew one: resume with it
            arguments += ["--seed", str(self.seed)]
        if self.section_file is not None:  # a resumed run reads the variant's section from the run's folder
            arguments = with_option(arguments, PATH_OPTIONS, str(self.section_file))
        atomic_write_text(Path(self.params_path) / ARGUMENTS_FILE, json.dumps(absolute_paths(arguments)))

    def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> VecEnv:
        if self.resuming:  # append to the run's monitor CSV instead of overwriting it
            assert self._checkpoint is not None
            self.monitor_kwargs = {**self.monitor_kwargs, "override_existing": False}
            if not eval_env and not no_log:  # n_envs is known now (RL-Zoo reads it with the hyperparameters)
                steps_per_env = checkpoint_steps(self._checkpoint) // self.n_envs
                for monitor_file in Path(self.save_path).glob("*monitor.csv"):
                    truncate_monitor_file(monitor_file, steps_per_env)
        return super().create_envs(n_envs, eval_env=eval_env, no_log=no_log)

    def create_callbacks(self) -> None:
        super().create_callbacks()
        if self.save_freq > 0:  # RL-Zoo divided it by n_envs already
            self.callbacks.append(RunCheckpointCallback(self.save_freq, self.save_path, str(self.env_name)))
        if self.resuming:
            assert self._checkpoint is not None
            for callback in self.callbacks:
                if isinstance(callback, EvalCallback):
                    restore_evaluations(callback, Path(self.save_path), checkpoint_steps(self._checkpoint))

    def _load_pretrained_agent(self, hyperparams: dict[str, Any], env: VecEnv) -> BaseAlgorithm:
        model = super()._load_pretrained_agent(hyperparams, env)
        if self.resuming:
            assert self._checkpoint is not None
            restore_checkpoint(model, self._checkpoint)
            for callback in self.callbacks:  # periodic callbacks (evaluation, checkpoints) keep their rhythm
                callback.n_calls = model.num_timesteps // self.n_envs
        return model

    def learn(self, model: BaseAlgorithm) -> None:
        """RL-Zoo's ``learn``, continuing the step counter when resuming, with a checkpoint at an interruption."""
        kwargs: dict[str, Any] = {}
        if self.log_interval > -1:
            kwargs["log_interval"] = self.log_interval
        elif self.log_interval < -1:
            kwargs["log_interval"] = None
        if self.callbacks:
            kwargs["callback"] = self.callbacks
        n_timesteps = self.n_timesteps
        if self.resuming:
            n_timesteps = self.n_timesteps - model.num_timesteps
            if n_timesteps <= 0:
                print(f"The run in {self.save_path} has its {self.n_timesteps} steps already: nothing to resume")
                self._finished_before = True
                return
            kwargs["reset_num_timesteps"] = False
        stopper = StopOnInterrupt()
        kwargs["callback"] = [*self.callbacks, stopper]  # last: the step's evaluation and checkpoint come first
        try:
            try:
                with interrupts_between_steps(stopper):
                    model.learn(n_timesteps, **kwargs)
            except KeyboardInterrupt:  # a second Ctrl-C: stop at once
                stopper.requested = True
            if stopper.requested:
                self.interrupted = True
                print(f"Interrupted at step {model.num_timesteps}: saving a resumable checkpoint")
                with sigint_handled_by(signal.SIG_IGN):  # a Ctrl-C now would leave the previous checkpoint only
                    path = save_checkpoint(model, self.save_path, str(self.env_name))
                print(f"Resumable checkpoint in {path}: continue with sb3-gcrl train --resume {self.save_path}")
        finally:
            if self.callbacks:
                self.callbacks[0].on_training_end()  # clean the progress bar (as RL-Zoo)
            assert model.env is not None
            with contextlib.suppress(EOFError):
                model.env.close()


class StopOnInterrupt(BaseCallback):
    """Stop training after the step in which Ctrl-C came (:func:`interrupts_between_steps` sets :attr:`requested`),
    once every callback before this one has done its work for that step (an evaluation due at it, a checkpoint), so
    that the checkpoint saved then is consistent with the run's logs."""

    def __init__(self) -> None:
        super().__init__()
        #: whether Ctrl-C asked training to stop
        self.requested = False

    def _on_step(self) -> bool:
        return not self.requested


@contextlib.contextmanager
def interrupts_between_steps(stopper: StopOnInterrupt) -> Iterator[None]:
    """Inside the block, Ctrl-C (SIGINT) asks ``stopper`` to stop training after the current step; a second Ctrl-C
    raises KeyboardInterrupt at once. Outside the main thread nothing changes.

    :param stopper: the callback that stops training.
    """

    def request_stop(signum: int, frame: Any) -> None:
        if stopper.requested:
            raise KeyboardInterrupt
        stopper.requested = True
        print(
            "\nCtrl-C: training stops after this step (its evaluation and checkpoint included) and saves a resumable "
            "checkpoint; Ctrl-C again to stop at once",
            flush=True,
        )

    with sigint_handled_by(request_stop):
        yield


@contextlib.contextmanager
def sigint_handled_by(handler: Any) -> Iterator[None]:
    """Handle SIGINT (Ctrl-C) with ``handler`` (a function or ``signal.SIG_IGN``) inside the block, when called from the
    main thread (elsewhere nothing changes); the previous handler comes back after it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def with_option(arguments: list[str], flags: tuple[str, ...], value: str) -> list[str]:
    """``arguments`` with the value of the first of ``flags`` replaced (``--flag value`` or ``--flag=value``), or
    ``flags[0] value`` added when none is there."""
    out = list(arguments)
    for i, word in enumerate(out):
        if word in flags and i + 1 < len(out):
            out[i + 1] = value
            return out
        if word.startswith(tuple(f"{flag}=" for flag in flags)):
            out[i] = f"{word.split('=', 1)[0]}={value}"
            return out
    return [*out, flags[0], value]


def absolute_paths(arguments: list[str]) -> list[str]:
    """``arguments`` with the files of :data:`PATH_OPTIONS` made absolute (a resume may run from elsewhere)."""
    out = list(arguments)
    for i, word in enumerate(out[:-1]):
        if word in PATH_OPTIONS and Path(out[i + 1]).is_file():
            out[i + 1] = str(Path(out[i + 1]).resolve())
    return out


def truncate_monitor_file(path: Path, steps: int) -> None:
    """Drop the rows of a Monitor CSV whose episodes (segments) end after ``steps`` steps of its env: a run killed
    after its checkpoint logged them, and the resumed run takes those steps again.

    :param path: a Monitor CSV (``*.monitor.csv``: a JSON header line, the column names, one row per episode).
    :param steps: the env's steps at the checkpoint.
    """
    lines = path.read_text().splitlines(keepends=True)
    header, rows = lines[:2], lines[2:]
    kept, total = [], 0
    length_column = header[1].strip().split(",").index("l") if len(header) > 1 else 1
    for row in rows:
        total += int(float(row.split(",")[length_column]))
        if total > steps:
            break
        kept.append(row)
    if len(kept) < len(rows):
        atomic_write_text(path, "".join(header + kept))


def restore_evaluations(callback: EvalCallback, run_dir: Path, steps: int) -> None:
    """Give ``callback`` the evaluations the run logged up to ``steps`` (its ``evaluations.npz``), so that the file
    is extended, not overwritten, and the best model is only replaced by a better one.

    :param callback: the resumed run's evaluation callback.
    :param run_dir: the run's folder.
    :param steps: the checkpoint's step count (later evaluations are dropped: they are run again).
    """
    path = run_dir / "evaluations.npz"
    if not path.is_file():
        return
    with np.load(path) as data:
        keep = data["timesteps"] <= steps
        callback.evaluations_timesteps = data["timesteps"][keep].tolist()
        callback.evaluations_results = data["results"][keep].tolist()
        callback.evaluations_length = data["ep_lengths"][keep].tolist()
        if "successes" in data:
            callback.evaluations_successes = data["successes"][keep].tolist()
    if callback.evaluations_results:
        callback.best_mean_reward = float(np.max(np.mean(callback.evaluations_results, axis=1)))


def resume_arguments(run_dir: Path) -> tuple[list[str], Path]:
    """The ``sb3-gcrl train`` arguments that continue a run, and its newest checkpoint.

    :param run_dir: the run's folder (``logs/<algo>/<env>_<id>``).
    :return: ``(arguments, checkpoint)``: the run's own arguments with ``-i <checkpoint>/model.zip``.
    :raises SystemExit: the folder is not a run of ``sb3-gcrl train`` or has no checkpoint.
    """
    from sb3_gcrl.common.checkpoints import CheckpointError, check_checkpoint
    from sb3_gcrl.common.command_line import option_value
    from sb3_gcrl.zoo_checks import algorithm_class

    saved = sorted(run_dir.glob(f"*/{ARGUMENTS_FILE}"))
    if not saved:
        raise SystemExit(
            f"sb3-gcrl train --resume {run_dir}: not a run folder of sb3-gcrl train (no */{ARGUMENTS_FILE}); "
            "pass the folder the run printed as 'Log path'"
        )
    arguments: list[str] = json.loads(saved[0].read_text())
    try:
        checkpoint = latest_checkpoint(run_dir)
    except CheckpointError as error:
        raise SystemExit(f"sb3-gcrl train --resume: {error}") from None
    try:
        check_checkpoint(checkpoint, algorithm_class(option_value(arguments, "--algo") or "ppo"))
    except CheckpointError as error:
        models = sorted(str(path) for path in run_dir.glob("*.zip"))
        start_from = f" one of the run's saved models ({', '.join(models)}) or" if models else ""
        raise SystemExit(
            f"sb3-gcrl train --resume: {error}. The run cannot continue from this checkpoint, and it keeps no older "
            "one (each checkpoint replaces the previous). Restore the file from a backup and resume again, or start "
            f"a new run from{start_from} scratch (-i MODEL starts from a saved model, with the step counter at 0)"
        ) from None
    final_model = saved[0].parent.parent / f"{saved[0].parent.name}.zip"
    if final_model.is_file():
        from stable_baselines3.common.save_util import load_from_zip_file

        final_steps = int(load_from_zip_file(final_model)[0]["num_timesteps"])
        if final_steps > checkpoint_steps(checkpoint):
            raise SystemExit(
                f"sb3-gcrl train --resume: the run in {run_dir} finished: its final model ({final_model.name}, "
                f"{final_steps} steps) is newer than its newest checkpoint ({checkpoint_steps(checkpoint)} steps), "
                "so there is nothing to resume"
            )
    kept: list[str] = []
    skip = False
    for word in arguments:  # the run's own -i (a fine-tuned start) is replaced by the checkpoint
        if skip:
            skip = False
            continue
        if word in ("-i", "--trained-agent"):
            skip = True
            continue
        kept.append(word)
    return [*kept, "-i", str(checkpoint / MODEL_FILE)], checkpoint
