"""``sb3-gcrl compare``: command line of :func:`sb3_gcrl.compare.compare` (also ``python -m sb3_gcrl.compare.cli``).

With no arguments it runs the ``quick`` preset (the README's main command).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

from sb3_gcrl.zoo_config import parse_override

#: exit codes
EXIT_OK, EXIT_RUNS_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130


def _hyperparam(text: str) -> tuple[str, Any]:
    try:
        return parse_override(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (``sb3-gcrl compare --help``)."""
    from sb3_gcrl.compare.presets import DEFAULT_PRESET

    parser = argparse.ArgumentParser(
        prog="sb3-gcrl compare",
        description="Compare methods x envs x seeds: parallel runs, evaluation curves, IQM table, plots, report. "
        f"Without arguments: the '{DEFAULT_PRESET}' preset.",
        epilog="A method is ALGO (hyperparameters found as sb3-gcrl train finds them: zoo_configs/ALGO.yml, then "
        "ALGO_thesis.yml, then RL-Zoo's own), ALGO@VARIANT (the section <env id>@VARIANT), ALGO[@VARIANT]:CONFIG "
        "(a .yml path or a zoo_configs/ file name) or LABEL=ALGO[@VARIANT][:CONFIG]; --list-methods prints the "
        "files with their env sections and variants. Re-running the same command resumes: finished runs are kept "
        "and skipped. Each run is a process with one torch (and OpenMP) thread.",
    )
    parser.add_argument("--preset", help="start from a named comparison (see --list-presets); options override it")
    parser.add_argument("--list-presets", action="store_true", help="print the presets and exit")
    parser.add_argument(
        "--list-methods", action="store_true", help="print algorithms and zoo config files (envs, variants), exit"
    )
    parser.add_argument("-m", "--methods", nargs="+", help="methods to compare")
    parser.add_argument("-e", "--envs", nargs="+", help="gymnasium env ids")
    seeds = parser.add_mutually_exclusive_group()
    seeds.add_argument("--seeds", nargs="+", type=int, help="run seeds (default 0 1 2)")
    seeds.add_argument("--n-seeds", type=int, help="use seeds 0 .. N-1")
    parser.add_argument("-n", "--n-timesteps", type=int, help="training budget per run (default: the config's)")
    parser.add_argument("--eval-freq", type=int, help="env steps between evaluations (default: budget / 20)")
    parser.add_argument("--eval-episodes", type=int, help="deterministic episodes per evaluation (default 5)")
    parser.add_argument("-o", "--output", "--out", type=Path, help="output folder (default results/<preset>)")
    parser.add_argument("--backend", choices=["local", "ray"], default="local", help="where runs execute")
    parser.add_argument("-w", "--workers", "--n-workers", type=int, help="parallel runs (default: cores)")
    parser.add_argument("--ray-address", help="Ray cluster address (default: start a local Ray instance)")
    parser.add_argument(
        "--hyperparams", nargs="+", type=_hyperparam, default=[], metavar="KEY:VALUE",
        help="overrides for every method, values as Python literals or YAML (learning_starts:100 projection_dim:None "
        "'policy_kwargs:dict(net_arch=[64])')",
    )  # fmt: skip
    parser.add_argument(
        "--env-kwargs", nargs="+", type=_hyperparam, default=[], metavar="KEY:VALUE",
        help="env constructor arguments for every env, values as --hyperparams (sticky_action_prob:0.2)",
    )  # fmt: skip
    parser.add_argument("--gym-packages", nargs="+", default=[], help="modules to import (register extra envs)")
    parser.add_argument("--config-dir", type=Path, help="folder of zoo configs for bare method names")
    parser.add_argument("--overwrite", action="store_true", help="redo finished runs whose settings changed")
    parser.add_argument(
        "--report-only", action="store_true",
        help="train nothing: write the report of the runs already finished in --output (also while another "
        "compare trains into it)",
    )  # fmt: skip
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--save-models", action="store_true", help="save each trained model in its run folder")
    parser.add_argument(
        "--save-freq", type=int, default=0, metavar="N",
        help="save a resumable checkpoint of each run every N env steps: a run killed after one continues from it "
        "when the command is run again (default 0: none, a killed run starts from zero)",
    )  # fmt: skip
    parser.add_argument("--final-window", type=int, default=1, help="evaluations averaged into the final score")
    parser.add_argument("--solve-threshold", type=float, help="level counted as solved (default 0.9 success)")
    parser.add_argument(
        "--metric", choices=["auto", "success_rate", "mean_return"],
        help="metric of the table and plots (default auto: success rate where every evaluation reports it)",
    )  # fmt: skip
    parser.add_argument("--title", help="report title")
    return parser


def _print_presets() -> None:
    from sb3_gcrl.compare.presets import PRESETS

    for name, preset in PRESETS.items():
        print(f"{name}: {preset.description}")
        print(
            f"    methods {' '.join(preset.methods)} | envs {' '.join(preset.envs)} | seeds {len(preset.seeds)} | "
            f"{preset.n_timesteps:,} steps, eval every {preset.eval_freq:,}"
        )
        if preset.thesis:
            print(f"    thesis: {preset.thesis}")


def _print_methods(config_dir: Path) -> None:
    from sb3_gcrl.compare.methods import available_algorithms
    from sb3_gcrl.compare.run import prepare_process
    from sb3_gcrl.zoo_config import config_sections

    prepare_process(single_thread=False)
    print("algorithms:", " ".join(available_algorithms()))
    print(f"zoo configs in {config_dir} (env sections, with variants for ALGO@VARIANT):")
    for config in sorted(config_dir.glob("*.yml")):
        sections = config_sections(config)
        envs = ", ".join(env + (f" [{' '.join(variants)}]" if variants else "") for env, variants in sections.items())
        print(f"  {config.stem}: {envs}")


def main(argv: list[str] | None = None) -> int:
    """Run ``sb3-gcrl compare``.

    :param argv: arguments without the program name (default ``sys.argv[1:]``).
    :return: 0 when every run finished, 1 when some failed, 2 on bad arguments, 130 when interrupted.
    """
    from sb3_gcrl.compare.presets import DEFAULT_PRESET, PRESETS
    from sb3_gcrl.zoo_config import ZOO_CONFIGS_DIR

    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    config_dir = args.config_dir or ZOO_CONFIGS_DIR
    if args.list_presets:
        _print_presets()
        return EXIT_OK
    if args.list_methods:
        _print_methods(config_dir)
        return EXIT_OK

    preset_name = args.preset or (DEFAULT_PRESET if not (args.methods or args.envs) else None)
    if preset_name is not None and preset_name not in PRESETS:
        parser.error(f"unknown preset {preset_name!r}; choose one of {sorted(PRESETS)}")
    preset = PRESETS.get(preset_name) if preset_name else None

    def pick(value: Any, preset_field: str, default: Any = None) -> Any:
        """The command-line value if given, else the preset's, else the default."""
        if value is not None:
            return value
        return getattr(preset, preset_field) if preset is not None else default

    methods, envs = pick(args.methods, "methods"), pick(args.envs, "envs")
    if not methods or not envs:
        parser.error("give both --methods and --envs (or a --preset)")
    seeds = pick(args.seeds or (list(range(args.n_seeds)) if args.n_seeds is not None else None), "seeds", (0, 1, 2))
    output = args.output or Path("results") / (preset_name or "comparison")

    from sb3_gcrl.compare.comparison import compare, describe_failure
    from sb3_gcrl.compare.storage import OutputInUseError

    command = "sb3-gcrl compare" + ("" if not argv else " " + shlex.join(argv))
    try:
        result = compare(
            methods,
            envs,
            seeds=seeds,
            n_timesteps=pick(args.n_timesteps, "n_timesteps"),
            eval_freq=pick(args.eval_freq, "eval_freq"),
            n_eval_episodes=pick(args.eval_episodes, "n_eval_episodes", 5),
            output=output,
            backend=args.backend,
            n_workers=args.workers,
            ray_address=args.ray_address,
            hyperparams={**pick(None, "hyperparams", {}), **dict(args.hyperparams)},
            env_kwargs={**pick(None, "env_kwargs", {}), **dict(args.env_kwargs)},
            gym_packages=args.gym_packages,
            config_dir=config_dir,
            overwrite=args.overwrite,
            progress=not args.no_progress,
            save_models=args.save_models,
            final_window=args.final_window,
            solve_threshold=args.solve_threshold,
            metric=pick(args.metric, "metric", "auto"),
            title=pick(args.title, "description"),
            command=command,
            report_only=args.report_only,
            save_freq=args.save_freq,
        )
    except KeyboardInterrupt:
        print(
            f"\ninterrupted: finished runs are kept in {output}; run the same command again to resume", file=sys.stderr
        )
        return EXIT_INTERRUPTED
    except (ValueError, FileExistsError, ImportError, OutputInUseError) as error:
        print(f"sb3-gcrl compare: error: {error}", file=sys.stderr)
        return EXIT_USAGE

    summary = result.summary
    print(summary.table)
    plot = result.output / "curves.png"
    where = f"report: {result.output / 'report.md'}" + (
        f", plot: {plot}" if plot in result.files else " (no plot: no run finished)"
    )
    if args.report_only:  # the unfinished runs are expected here; the report lists them
        print(
            f"\nreport of the {result.n_skipped} finished runs of {len(result.specs)} (nothing trained; the report "
            f"lists the other {len(summary.failed)}); {where}"
        )
        return EXIT_OK
    for spec, error, log_path in summary.failed:
        print(describe_failure(spec, error, log_path), file=sys.stderr)
    print(
        f"\n{len(result.specs)} runs ({result.n_skipped} resumed, {len(summary.failed)} failed) in "
        f"{result.wall_time_s:.0f} s; {where}"
    )
    return EXIT_RUNS_FAILED if summary.failed else EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
