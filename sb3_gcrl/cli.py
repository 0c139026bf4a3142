"""Command line: ``sb3-gcrl train|enjoy|compare|list-envs|list-algos`` (also ``python -m sb3_gcrl``).

``train`` and ``enjoy`` are RL-Zoo's own ``rl_zoo3.train.train`` / ``rl_zoo3.enjoy.enjoy``: every
``rl_zoo3 train`` flag works. Before handing over, this launcher adds the package's algorithms to the
zoo's algorithm table (``rl_zoo3.utils.ALGOS``, the dict that both scripts read), because a package
imported through ``--gym-packages`` comes too late: the zoo fixes ``--algo`` choices when it builds its
parser. ``train`` finds the hyperparameters as ``sb3-gcrl compare`` does (:func:`~sb3_gcrl.zoo_config.resolve_config`):
the ``-conf`` file (a path or a shipped config's name, ``sb3-gcrl list-configs``), else the shipped
``zoo_configs/<algo>.yml``, then ``<algo>_thesis.yml``, then RL-Zoo's own ``hyperparams/<algo>.yml``; ``--variant NAME``
picks the section ``<env id>@NAME`` instead of the env's own. Before RL-Zoo starts, ``train`` runs the checks of
``sb3-gcrl compare`` (the same functions, :mod:`sb3_gcrl.zoo_config`): algorithm and env names (with close
matches), the section's keys with the ``-params`` overrides (with close matches), a budget of at least one step, the
model of ``-i``, and a writable log folder.
"""

from __future__ import annotations

import contextlib
import importlib
import itertools
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_gcrl.common.command_line import option_value
from sb3_gcrl.zoo_config import ZOO_CONFIGS_DIR, shipped_config

if TYPE_CHECKING:
    from sb3_gcrl.zoo_config import ResolvedConfig

__all__ = ["ZOO_CONFIGS_DIR", "main", "shipped_config"]

#: sub-command -> ``"module:function"`` taking ``argv`` (list of strings) and returning an exit code
COMMANDS: dict[str, str] = {
    "train": "sb3_gcrl.cli:train",
    "enjoy": "sb3_gcrl.cli:enjoy",
    "compare": "sb3_gcrl.compare.cli:main",
    "list-envs": "sb3_gcrl.cli:list_envs",
    "list-algos": "sb3_gcrl.cli:list_algos",
    "list-configs": "sb3_gcrl.cli:list_configs",
}

USAGE = """usage: sb3-gcrl <command> [options]

commands:
  train       train with RL-Zoo (every `rl_zoo3 train` flag), our algorithms included; torch runs on one
              thread unless --num-threads N is given
  enjoy       run a trained agent with RL-Zoo's `enjoy` (every `rl_zoo3 enjoy` flag)
  compare     compare methods x envs x seeds and write curves, plots, a table and a report
  list-envs   print the registered GCRL/ environments with their spaces
  list-algos  print the algorithms `--algo` accepts
  list-configs  print the zoo configs this package ships, their env sections and variants (`-conf NAME` takes
              these names, `--variant NAME` the variants)

`sb3-gcrl <command> --help` shows the options of a command.
"""


def _take_option(argv: Sequence[str], *flags: str) -> tuple[list[str], str | None]:
    """``argv`` without the first of ``flags`` and its value (``--flag value`` or ``--flag=value``), and the value."""
    for i, arg in enumerate(argv):
        for flag in flags:
            if arg == flag and i + 1 < len(argv):
                return [*argv[:i], *argv[i + 2 :]], argv[i + 1]
            if arg.startswith(flag + "="):
                return [*argv[:i], *argv[i + 1 :]], arg.split("=", 1)[1]
    return list(argv), None


def resolve_train_config(argv: Sequence[str]) -> tuple[list[str], ResolvedConfig]:
    """The hyperparameters of ``sb3-gcrl train``, found as ``sb3-gcrl compare`` finds them
    (:func:`~sb3_gcrl.zoo_config.resolve_config`: ``-conf``, else ``zoo_configs/<algo>.yml``, ``<algo>_thesis.yml``,
    RL-Zoo's own), with ``--variant NAME`` picking the section ``<env id>@NAME``.

    :param argv: ``sb3-gcrl train`` arguments.
    :return: the arguments for RL-Zoo (``--variant`` taken out, ``-conf`` naming the file found) and the section
        the run uses (a variant's section is written to the run's folder by
        :class:`~sb3_gcrl.zoo_train.ResumableExperimentManager`: RL-Zoo reads only plain env-id keys).
    :raises SystemExit: no such config, env section or variant; the message names the files searched, the envs
        they cover and the variants of the env.
    """
    from sb3_gcrl.zoo_config import ConfigNotFoundError, resolve_config

    rest, variant = _take_option(argv, "--variant")
    rest, config = _take_option(rest, "-conf", "--conf-file")
    algo = option_value(rest, "--algo") or "ppo"  # RL-Zoo's defaults
    env_id = option_value(rest, "--env") or "CartPole-v1"
    try:
        resolved = resolve_config(algo, env_id, variant, config)
    except ConfigNotFoundError as error:
        raise SystemExit(f"sb3-gcrl train: {error}") from None
    return [*rest, "-conf", str(resolved.path)], resolved


def list_configs(argv: list[str]) -> int:
    """``sb3-gcrl list-configs``: print the shipped zoo configs (names usable as ``-conf NAME``), each with its env
    sections and their variants (``--variant NAME``).

    :param argv: unused (no options).
    :return: exit code.
    """
    from sb3_gcrl.zoo_config import config_sections

    if argv:
        raise SystemExit(f"sb3-gcrl list-configs takes no arguments, got {argv}")
    print(f"# {ZOO_CONFIGS_DIR}: NAME, then each env section with its variants (--variant)")
    for path in sorted(ZOO_CONFIGS_DIR.glob("*.yml")):
        print(path.stem)
        for env_id, variants in config_sections(path).items():
            print(f"  {env_id}" + (f"  variants: {' '.join(variants)}" if variants else ""))
    return 0


def _run_zoo_script(script: Callable[[], None], prog: str, argv: list[str]) -> int:
    import sb3_gcrl  # noqa: F401  (registers the environments)
    from sb3_gcrl.algorithms import register_zoo_algorithms

    register_zoo_algorithms()
    saved_argv = sys.argv
    sys.argv = [prog, *argv]
    try:
        script()
    finally:
        sys.argv = saved_argv
    return 0


#: torch threads of ``sb3-gcrl train`` without ``--num-threads`` (RL-Zoo's default, -1, leaves torch's own count: one
#: per core, much slower than one thread for the small networks of these agents)
DEFAULT_NUM_THREADS = 1
NUM_THREADS_NOTE = (
    f"sb3-gcrl train: torch runs on {DEFAULT_NUM_THREADS} thread unless --num-threads N is given (N = -1: torch's "
    "default count, as in rl_zoo3 train)"
)


VARIANT_NOTE = (
    "sb3-gcrl train: without -conf the hyperparameters come from the shipped zoo_configs/<algo>.yml (then "
    "<algo>_thesis.yml, then RL-Zoo's own); -conf also takes a shipped config's name; --variant NAME trains the "
    "section <env id>@NAME (sb3-gcrl list-configs prints them)"
)
RESUME_NOTE = (
    "sb3-gcrl train: Ctrl-C saves a resumable checkpoint (model, replay buffer, wrapper state, generators) and exits "
    "with 130; --save-freq N also saves one every N steps. `sb3-gcrl train --resume RUN_FOLDER` (the 'Log path' a "
    "run prints) continues that run in its folder, from its newest checkpoint, with its own arguments"
)


@contextlib.contextmanager
def _train_options_in_help() -> Iterator[None]:
    """Inside the block, RL-Zoo's ``train`` parser also lists the options that ``sb3-gcrl train`` takes out of the
    command line before RL-Zoo parses it (``--variant``, ``--resume``), in its usage and help."""
    import argparse
    import types

    import rl_zoo3.train

    class TrainParser(argparse.ArgumentParser):
        def parse_args(self, *args: Any, **kwargs: Any) -> Any:  # type: ignore[override]
            ours = self.add_argument_group("options of sb3-gcrl train (not of rl_zoo3 train)")
            ours.add_argument("--variant", metavar="NAME", help="train the section <env id>@NAME of the config")
            ours.add_argument(
                "--resume",
                metavar="RUN_FOLDER",
                help="continue the run in RUN_FOLDER (the 'Log path' it printed) from its newest checkpoint, with its "
                "own arguments (no other option)",
            )
            return super().parse_args(*args, **kwargs)

    zoo_argparse = rl_zoo3.train.argparse
    rl_zoo3.train.argparse = types.SimpleNamespace(**{**vars(argparse), "ArgumentParser": TrainParser})  # type: ignore[assignment]
    try:
        yield
    finally:
        rl_zoo3.train.argparse = zoo_argparse


def _with_default_num_threads(argv: list[str]) -> list[str]:
    """``argv`` with ``--num-threads 1`` (:data:`DEFAULT_NUM_THREADS`) added when it sets no thread count."""
    if option_value(argv, "--num-threads") is not None:
        return argv
    return [*argv, "--num-threads", str(DEFAULT_NUM_THREADS)]


def train(argv: list[str]) -> int:
    """``sb3-gcrl train``: RL-Zoo's ``train`` with this package's algorithms and configs available.

    Unlike ``rl_zoo3 train``, torch runs on one thread unless ``--num-threads`` is given (:data:`DEFAULT_NUM_THREADS`),
    an interruption (Ctrl-C) saves a resumable checkpoint and exits with 130, and ``--resume RUN_FOLDER`` continues
    a run (:mod:`sb3_gcrl.zoo_train`).

    :param argv: ``rl_zoo3 train`` arguments, or ``--resume RUN_FOLDER``.
    :return: exit code.
    """
    import rl_zoo3.train

    from sb3_gcrl.zoo_train import INTERRUPTED_EXIT_CODE, ResumableExperimentManager, resume_arguments

    if "-h" in argv or "--help" in argv:
        print(NUM_THREADS_NOTE + "\n" + VARIANT_NOTE + "\n" + RESUME_NOTE + "\n")
        with _train_options_in_help():
            return _run_zoo_script(rl_zoo3.train.train, "sb3-gcrl train", argv)
    resume_from = None
    if "--resume" in argv:
        if len(argv) != 2 or argv[0] != "--resume":
            raise SystemExit(
                "sb3-gcrl train --resume RUN_FOLDER takes no other arguments: the run continues with its own"
            )
        resume_from = Path(argv[1]).resolve()
        argv, _ = resume_arguments(resume_from)
    _check_names(argv)
    argv, resolved = resolve_train_config(argv)
    argv = _with_default_num_threads(argv)
    _check_config(argv, resolved)
    section = None if resolved.rl_zoo_reads_it else resolved  # a variant: the run writes its section to its folder
    managers: list[ResumableExperimentManager] = []

    def manager(*args: Any, **kwargs: Any) -> ResumableExperimentManager:
        managers.append(ResumableExperimentManager(*args, resume_from=resume_from, section=section, **kwargs))
        return managers[-1]

    zoo_manager = rl_zoo3.train.ExperimentManager  # type: ignore[attr-defined]
    rl_zoo3.train.ExperimentManager = manager  # type: ignore[attr-defined,assignment]
    try:
        code = _run_zoo_script(rl_zoo3.train.train, "sb3-gcrl train", argv)
    finally:
        rl_zoo3.train.ExperimentManager = zoo_manager  # type: ignore[attr-defined]
    return INTERRUPTED_EXIT_CODE if any(m.interrupted for m in managers) else code


def _overrides(argv: Sequence[str]) -> tuple[dict[str, Any], str]:
    """The ``-params`` / ``--hyperparams`` overrides (``key:value`` words after the flag) in ``argv``, values read as
    :func:`~sb3_gcrl.zoo_config.parse_override` reads them, and the flag they came with."""
    import yaml

    from sb3_gcrl.zoo_config import parse_override

    overrides: dict[str, Any] = {}
    flag = "-params"
    for i, arg in enumerate(argv):
        if arg not in ("-params", "--hyperparams"):
            continue
        flag = arg
        for word in itertools.takewhile(lambda word: not word.startswith("-"), argv[i + 1 :]):
            try:
                key, value = parse_override(word)
            except (ValueError, yaml.YAMLError):  # RL-Zoo's parser names what it cannot read
                key, value = word.split(":", 1)[0], None
            overrides[key] = value
    return overrides, flag


def _check_names(argv: Sequence[str]) -> None:
    """Stop before the hyperparameters are looked up when ``--algo`` or ``--env`` names nothing that exists, with
    close matches (:func:`~sb3_gcrl.zoo_checks.check_algorithm`, :func:`~sb3_gcrl.zoo_checks.check_env_id`: the
    checks of ``sb3-gcrl compare``); the modules of ``--gym-packages`` are imported first (they register envs)."""
    from sb3_gcrl.compare.run import prepare_process
    from sb3_gcrl.zoo_checks import check_algorithm, check_env_id

    prepare_process(tuple(_option_values(argv, "--gym-packages")), single_thread=False)
    try:
        check_algorithm(option_value(argv, "--algo") or "ppo")  # RL-Zoo's defaults
        check_env_id(option_value(argv, "--env") or "CartPole-v1")
    except ValueError as error:
        raise SystemExit(f"sb3-gcrl train: {error}") from None


def _check_config(argv: list[str], resolved: ResolvedConfig) -> None:
    """Stop before training when the section (with the ``-params`` overrides) has a key that the algorithm does not
    take (:func:`~sb3_gcrl.zoo_checks.check_hyperparameters`, with close matches), uses a mode-switched wrapper
    without its callback (:func:`~sb3_gcrl.zoo_checks.check_mode_switching_callbacks`), or has no budget of at least
    one step (:func:`~sb3_gcrl.zoo_checks.run_budget`: ``-n``, else the section's ``n_timesteps``), when the model of
    ``-i`` is not one that the algorithm loads (:func:`~sb3_gcrl.common.saving.check_model_file`, the check of our
    algorithms' ``load``), or when the log folder (``-f``) cannot be written
    (:func:`~sb3_gcrl.common.validation.check_writable_folder`): the checks of ``sb3-gcrl compare``."""
    from rl_zoo3.utils import ALGOS

    from sb3_gcrl.algorithms import ALGORITHMS
    from sb3_gcrl.common.saving import check_model_file
    from sb3_gcrl.common.validation import check_writable_folder
    from sb3_gcrl.zoo_checks import algorithm_class, check_hyperparameters, check_mode_switching_callbacks, run_budget

    overrides, flag = _overrides(argv)
    algo = option_value(argv, "--algo")
    section = {**resolved.hyperparams, **overrides}
    try:
        if algo in ALGORITHMS or algo in ALGOS:
            check_hyperparameters(algo, section, resolved.where, list(overrides), override_flag=flag)
        if not {"callback", "env_wrapper"} & set(overrides):  # else RL-Zoo's merged values are not known here
            check_mode_switching_callbacks(resolved.hyperparams, resolved.where)
        n_timesteps = option_value(argv, "-n", "--n-timesteps")
        if n_timesteps is None or n_timesteps.lstrip("-").isdigit():  # else RL-Zoo's parser names the mistake
            where = f"{flag} n_timesteps" if "n_timesteps" in overrides else resolved.where
            run_budget(section, where, None if n_timesteps is None else int(n_timesteps))
        trained_agent = option_value(argv, "-i", "--trained-agent")
        if algo is not None and trained_agent and Path(trained_agent).is_file():  # else RL-Zoo names the mistake
            check_model_file(trained_agent, algorithm_class(algo))
        check_writable_folder("the log folder (-f)", option_value(argv, "-f", "--log-folder") or "logs")
    except ValueError as error:
        raise SystemExit(f"sb3-gcrl train: {error}") from None


def _option_values(argv: Sequence[str], flag: str) -> list[str]:
    """Values of a ``nargs="+"`` option (``--gym-packages a b``) in ``argv``: the words after ``flag`` up to the next
    option."""
    values: list[str] = []
    for i, arg in enumerate(argv):
        if arg == flag:
            values.extend(itertools.takewhile(lambda word: not word.startswith("-"), argv[i + 1 :]))
    return values


def display_missing() -> bool:
    """Whether this is a Linux machine without a display (neither ``DISPLAY`` nor ``WAYLAND_DISPLAY`` set), where a
    window cannot open: MuJoCo's GLFW viewer then aborts the process (exit code 134)."""
    return sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


#: render modes for which ``render_mode="human"`` opens a window: the env's own (MuJoCo's viewer, pygame), or
#: gymnasium's ``HumanRendering`` wrapper (pygame), which ``gym.make`` applies to an env that only draws images
WINDOW_RENDER_MODES = frozenset({"human", "rgb_array", "rgb_array_list"})


def renders_to_a_window(env_id: str, gym_packages: Sequence[str] = ()) -> bool:
    """Whether RL-Zoo's ``enjoy`` (``render_mode="human"`` unless ``--no-render``) opens a window for ``env_id``: the
    env renders to one itself, or draws images that gymnasium shows in a pygame window (:data:`WINDOW_RENDER_MODES`).

    :param env_id: the env of ``--env``.
    :param gym_packages: the modules of ``--gym-packages`` (they register ``env_id``).
    :return: False also for an env that cannot be made here (RL-Zoo then reports it).
    """
    import gymnasium as gym

    import sb3_gcrl  # noqa: F401  (registers the environments)

    for package in gym_packages:
        importlib.import_module(package)
    try:
        env = gym.make(env_id)
    except gym.error.Error:
        return False
    try:
        return bool(WINDOW_RENDER_MODES & set(env.metadata.get("render_modes") or []))
    finally:
        env.close()


def enjoy(argv: list[str]) -> int:
    """``sb3-gcrl enjoy``: RL-Zoo's ``enjoy`` with this package's algorithms available.

    On a Linux machine without a display (:func:`display_missing`), an env that renders to a window
    (:func:`renders_to_a_window`) runs without rendering (RL-Zoo's ``--no-render``, with a note), instead of aborting
    in MuJoCo's GLFW viewer or failing in pygame's (``XDG_RUNTIME_DIR is invalid``).

    :param argv: ``rl_zoo3 enjoy`` arguments.
    :return: exit code.
    """
    from rl_zoo3.enjoy import enjoy as zoo_enjoy

    asks_for_help = "-h" in argv or "--help" in argv
    if "--no-render" not in argv and not asks_for_help and display_missing():
        env_id = option_value(argv, "--env") or "CartPole-v1"  # RL-Zoo's default env
        if renders_to_a_window(env_id, _option_values(argv, "--gym-packages")):
            print(
                f"sb3-gcrl enjoy: no display (DISPLAY and WAYLAND_DISPLAY unset), so {env_id} runs without rendering "
                "(--no-render); to watch it, run under a display (e.g. `xvfb-run -a sb3-gcrl enjoy ...`)",
                file=sys.stderr,
            )
            argv = [*argv, "--no-render"]
    return _run_zoo_script(zoo_enjoy, "sb3-gcrl enjoy", argv)


def list_envs(argv: list[str]) -> int:
    """``sb3-gcrl list-envs``: print every ``GCRL/`` environment id with its spaces (or, for a task whose optional
    extra is not installed, the install command its error names).

    :param argv: unused (no options).
    :return: exit code.
    """
    import gymnasium as gym

    import sb3_gcrl  # noqa: F401

    if argv:
        raise SystemExit(f"sb3-gcrl list-envs takes no arguments, got {argv}")
    for env_id in sorted(k for k in gym.registry if k.startswith("GCRL/")):
        try:
            env = gym.make(env_id)
        except ImportError as error:  # an optional extra (metaworld for GCRL/SawyerDoor-v0) is not installed
            print(f"{env_id}\n  not available: {error}")
            continue
        try:
            print(f"{env_id}\n  observation: {env.observation_space}\n  action:      {env.action_space}")
        finally:
            env.close()
    return 0


def list_algos(argv: list[str]) -> int:
    """``sb3-gcrl list-algos``: print the algorithms that ``--algo`` accepts (ours, then the zoo's).

    :param argv: unused (no options).
    :return: exit code.
    """
    from rl_zoo3.utils import ALGOS

    from sb3_gcrl.algorithms import ALGORITHMS

    if argv:
        raise SystemExit(f"sb3-gcrl list-algos takes no arguments, got {argv}")
    for name, target in sorted(ALGORITHMS.items()):
        print(f"{name:20s} {target}")
    for name, cls in sorted(ALGOS.items()):
        if name not in ALGORITHMS:
            print(f"{name:20s} {cls.__module__}:{cls.__name__}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``sb3-gcrl`` console script.

    :param argv: command line without the program name (defaults to ``sys.argv[1:]``).
    :return: exit code.
    """
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        code = _dispatch(args)
        sys.stdout.flush()  # inside the try: a reader gone before the last buffered lines is a broken pipe too
    except BrokenPipeError:
        # the reader stopped reading (`sb3-gcrl list-configs | head -1`): stop quietly, as Unix tools do, and point
        # stdout at /dev/null so that the interpreter's own flush at exit does not fail again
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    return code


def _dispatch(args: list[str]) -> int:
    """Run the command of ``args`` (``main`` without the broken-pipe handling)."""
    if not args or args[0] in ("-h", "--help"):
        print(USAGE)
        return 0 if args else 2
    command, rest = args[0], args[1:]
    if command not in COMMANDS:
        print(f"sb3-gcrl: unknown command {command!r}; choose one of {', '.join(COMMANDS)}\n", file=sys.stderr)
        print(USAGE, file=sys.stderr)
        return 2
    module_name, function_name = COMMANDS[command].split(":")
    function: Callable[[list[str]], int] = getattr(importlib.import_module(module_name), function_name)
    return int(function(rest) or 0)


if __name__ == "__main__":
    sys.exit(main())
