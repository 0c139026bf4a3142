"""A comparison, ``compare()``: methods x envs x seeds planned as runs, run in parallel, resumable, analysed into a
report (each run itself: :mod:`sb3_gcrl.compare.run`)."""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sb3_gcrl.common.validation import check_int, check_optional_int, check_writable_folder
from sb3_gcrl.compare.backends import Backend, Job, LocalProcessBackend, RayBackend
from sb3_gcrl.compare.methods import Method, check_env_id, parse_method
from sb3_gcrl.compare.report import Summary, summarize, write_outputs
from sb3_gcrl.compare.run import RunSpec, prepare_process
from sb3_gcrl.compare.storage import (
    COMPARISON_FILE,
    OtherSettingsError,
    atomic_write_text,
    is_finished,
    lock_output,
)
from sb3_gcrl.zoo_checks import check_hyperparameters, check_mode_switching_callbacks, run_budget
from sb3_gcrl.zoo_config import ZOO_CONFIGS_DIR, resolve_config

#: evaluations per run when ``eval_freq`` is not given
DEFAULT_N_EVALUATIONS = 20
#: how a comparison sets the constructor arguments a config may not set (``RUN_SET_ARGUMENTS`` of zoo_checks)
RUN_SET_HINT = "seed: --seeds; env: --envs"
#: lines of a failed run's error printed on the console
ERROR_LINES_SHOWN = 3


@dataclass
class ComparisonResult:
    """What :func:`compare` did.

    :param output: the comparison folder.
    :param specs: every run of the comparison.
    :param n_skipped: runs already finished before this invocation (resumed).
    :param summary: tables and failures (see :class:`~sb3_gcrl.compare.report.Summary`).
    :param wall_time_s: wall time of this invocation.
    :param files: the analysis files written (``curves.png`` only when some run finished).
    """

    output: Path
    specs: list[RunSpec]
    n_skipped: int
    summary: Summary
    wall_time_s: float
    files: list[Path] = field(default_factory=list)


def error_excerpt(error: str, n_lines: int = ERROR_LINES_SHOWN) -> list[str]:
    """The last ``n_lines`` non-empty lines of a run's error (a traceback's last line names the exception)."""
    lines = [line.rstrip() for line in error.strip().splitlines() if line.strip()]
    return lines[-n_lines:] or ["unknown error"]


def describe_failure(spec: RunSpec, error: str, log_path: Path | None) -> str:
    """Console text for a failed run: which run, the error's last lines, and its log."""
    lines = [f"run failed: {spec.env_id} / {spec.method} / seed {spec.seed}"]
    lines += [f"    {line}" for line in error_excerpt(error)]
    if log_path is not None:
        lines.append(f"    log: {log_path}")
    return "\n".join(lines)


class ProgressDisplay:
    """A tqdm bar over the env steps of all runs to do, with counts of running/finished/failed runs.

    :param total_steps: env steps summed over all runs.
    :param n_runs: number of runs.
    :param enabled: show the bar (False: count silently).
    """

    def __init__(self, total_steps: int, n_runs: int, enabled: bool = True) -> None:
        from tqdm.auto import tqdm

        self.bar = tqdm(
            total=total_steps, unit="step", unit_scale=True, disable=not enabled, dynamic_ncols=True, mininterval=0.5
        )
        self.n_runs = n_runs
        self.running = self.finished = self.failed = 0
        self._refresh()

    def _refresh(self) -> None:
        self.bar.set_description(
            f"runs: {self.finished} done, {self.failed} failed, {self.running} running, of {self.n_runs}"
        )

    def on_start(self, spec: RunSpec) -> None:
        self.running += 1
        self._refresh()

    def on_progress(self, spec: RunSpec, steps: int) -> None:
        self.bar.update(steps)

    def on_end(self, spec: RunSpec, status: str, error: str = "", log_path: Path | None = None) -> None:
        self.running -= 1
        if status == "finished":
            self.finished += 1
        else:
            self.failed += 1
            self.bar.write(describe_failure(spec, error, log_path), file=sys.stderr)
        self._refresh()

    def close(self) -> None:
        self.bar.close()


def make_backend(backend: Backend | str, n_workers: int | None = None, ray_address: str | None = None) -> Backend:
    """Backend from its name (``local`` or ``ray``) or as given.

    :param backend: ``"local"``, ``"ray"`` or a :class:`~sb3_gcrl.compare.backends.Backend`.
    :param n_workers: parallel runs (local) or CPUs of a local Ray instance.
    :param ray_address: address of a Ray cluster (``auto``, ``ray://host:10001``).
    """
    if isinstance(backend, Backend):
        return backend
    if backend == "local":
        return LocalProcessBackend(n_workers)
    if backend == "ray":
        return RayBackend(address=ray_address, num_cpus=n_workers)
    raise ValueError(f"Unknown backend {backend!r}; choose 'local' or 'ray'")


def plan_runs(
    methods: Sequence[Method],
    envs: Sequence[str],
    seeds: Sequence[int],
    n_timesteps: int | None,
    eval_freq: int | None,
    n_eval_episodes: int,
    hyperparams: dict[str, Any],
    gym_packages: Sequence[str],
    config_dir: Path,
    save_models: bool = False,
    env_kwargs: dict[str, Any] | None = None,
    config_folder: Path | None = None,
    save_freq: int = 0,
) -> list[RunSpec]:
    """Every run (env-major, then method, then seed), with its config resolved; raises before anything runs.

    A run's ``config_digest`` is its section's (a changed setting is never silently reused); a variant's section,
    which RL-Zoo does not read from its file, is written to ``config_folder`` (default: a ``sb3_gcrl_configs`` folder
    in the temporary directory) and the run's ``config`` is that file.

    :raises ValueError: a method has no hyperparameters for an env (the message lists what it covers), or a
        hyperparameter (config or override) is not an argument of the algorithm (named with close matches).
    """
    import tempfile

    folder = config_folder if config_folder is not None else Path(tempfile.gettempdir()) / "sb3_gcrl_configs"
    specs = []
    for env_id in envs:
        for method in methods:
            resolved = method.resolve(env_id, config_dir)
            section = {**resolved.hyperparams, **hyperparams}
            check_mode_switching_callbacks(section, resolved.where)
            check_hyperparameters(method.algo, section, resolved.where, list(hyperparams), RUN_SET_HINT)
            budget = run_budget(section, resolved.where, n_timesteps)
            frequency = eval_freq if eval_freq is not None else max(1, budget // DEFAULT_N_EVALUATIONS)
            specs.extend(
                RunSpec(
                    method=method.label,
                    algo=method.algo,
                    config=str(resolved.zoo_file(folder)),
                    config_digest=resolved.digest,
                    env_id=env_id,
                    seed=int(seed),
                    n_timesteps=budget,
                    eval_freq=frequency,
                    n_eval_episodes=n_eval_episodes,
                    hyperparams=dict(hyperparams),
                    env_kwargs=dict(env_kwargs or {}),
                    gym_packages=tuple(gym_packages),
                    save_model=save_models,
                    save_freq=save_freq,
                )
                for seed in seeds
            )
    return specs


def compile_note(specs: Sequence[RunSpec]) -> str | None:
    """The line ``compare`` prints before runs whose algorithm compiles its training step (``compile_train_step``):
    their progress stands still at their first training step while ``torch.compile`` works (None: no such run).

    :param specs: the runs about to start.
    """
    compiling = sorted(
        {
            spec.method
            for spec in specs
            if {**resolve_config(spec.algo, spec.env_id, config=spec.config).hyperparams, **spec.hyperparams}.get(
                "compile_train_step"
            )
        }
    )
    if not compiling:
        return None
    from sb3_gcrl.morefree.acceleration import COMPILE_TIME

    return (
        f"{', '.join(compiling)}: each run compiles its training step with torch.compile first (compile_train_step), "
        f"so its progress waits at its first training step: {COMPILE_TIME}. The run's train.log says when "
        "compiling starts."
    )


def _config_label(config: str) -> str:
    """A config path as the report shows it: a shipped file by its place in the package, not this machine's path."""
    path = Path(config)
    if path.parent.resolve() == ZOO_CONFIGS_DIR:
        return f"{ZOO_CONFIGS_DIR.parent.name}/{ZOO_CONFIGS_DIR.name}/{path.name}"
    return config


def _recorded_command(output: Path) -> str | None:
    """The command recorded in ``output/comparison.json`` by the compare that trained its runs (None if unreadable)."""
    try:
        command = json.loads((output / COMPARISON_FILE).read_text()).get("command")
    except (OSError, ValueError, AttributeError):
        return None
    return command if isinstance(command, str) else None


def _settings_markdown(
    specs: list[RunSpec], backend: str, command: str | None, report_command: str | None = None
) -> str:
    methods = {}
    for spec in specs:
        methods.setdefault(spec.method, (spec.algo, set()))[1].add(_config_label(spec.config))
    lines = ["## Settings", ""]
    if command:
        lines += [f"Command: `{command}`", ""]
    if report_command:
        lines += [f"This report was re-made from the finished runs by: `{report_command}`", ""]
    lines += ["| method | algorithm | RL-Zoo config |", "| --- | --- | --- |"]
    lines += [f"| {name} | {algo} | {', '.join(sorted(configs))} |" for name, (algo, configs) in methods.items()]
    first = specs[0]
    budgets = sorted({spec.n_timesteps for spec in specs})
    frequencies = sorted({spec.eval_freq for spec in specs})
    lines += [
        "",
        f"- envs: {', '.join(dict.fromkeys(spec.env_id for spec in specs))}",
        f"- seeds: {', '.join(str(s) for s in dict.fromkeys(spec.seed for spec in specs))}",
        f"- budget: {', '.join(f'{b:,}' for b in budgets)} env steps per run; evaluation every "
        f"{', '.join(f'{f:,}' for f in frequencies)} steps, {first.n_eval_episodes} deterministic episodes",
        f"- hyperparameter overrides: {first.hyperparams or 'none'}; env kwargs: {first.env_kwargs or 'none'}",
        f"- backend: {backend}",
        "",
    ]
    return "\n".join(lines)


def _unfinished_runs(specs: list[RunSpec], output: Path, overwrite: bool, redone: bool = True) -> list[Job]:
    """The planned runs that ``output`` does not hold finished with the same settings.

    :param specs: the planned runs.
    :param output: the comparison folder.
    :param overwrite: count finished runs whose settings differ as unfinished (else that is an error).
    :param redone: the runs will be trained now (said in the notes printed about runs that are redone).
    :return: ``(spec, run folder)`` of every unfinished run, in plan order.
    :raises OtherSettingsError: a run finished with other settings and ``overwrite`` is off.
    """
    jobs: list[Job] = []
    notes: list[str] = []
    for spec in specs:
        run_dir = output / "runs" / spec.relative_dir
        try:
            if is_finished(run_dir, spec, notes):
                continue
        except OtherSettingsError:
            if not overwrite:
                raise
        jobs.append((spec, run_dir))
    for note in notes:  # said even without a progress bar
        print(f"{note}: the run counts as unfinished" + (" and is redone" if redone else ""), file=sys.stderr)
    return jobs


def compare(
    methods: Sequence[str | Method],
    envs: Sequence[str],
    seeds: Sequence[int] = (0, 1, 2),
    n_timesteps: int | None = None,
    eval_freq: int | None = None,
    n_eval_episodes: int = 5,
    output: str | Path = "results/comparison",
    backend: Backend | str = "local",
    n_workers: int | None = None,
    ray_address: str | None = None,
    hyperparams: dict[str, Any] | None = None,
    env_kwargs: dict[str, Any] | None = None,
    gym_packages: Sequence[str] = (),
    config_dir: str | Path = ZOO_CONFIGS_DIR,
    overwrite: bool = False,
    progress: bool = True,
    save_models: bool = False,
    final_window: int = 1,
    solve_threshold: float | None = None,
    metric: str = "auto",
    title: str | None = None,
    command: str | None = None,
    report_only: bool = False,
    save_freq: int = 0,
) -> ComparisonResult:
    """Run methods x envs x seeds (skipping runs finished earlier in ``output``) and write the analysis.

    Output files (see :mod:`sb3_gcrl.compare.storage`): per-run ``evaluations.csv``, ``curves.csv``,
    ``scores.csv``, ``summary.csv``, ``curves.png`` and ``report.md``.

    :param methods: method specs (``ALGO``, ``ALGO@VARIANT``, ``ALGO[@VARIANT]:CONFIG``,
        ``LABEL=ALGO[@VARIANT][:CONFIG]``) or :class:`Method` objects.
    :param envs: gymnasium ids.
    :param seeds: run seeds.
    :param n_timesteps: budget per run; default: each config's ``n_timesteps`` for the env.
    :param eval_freq: env steps between evaluations; default: budget / 20.
    :param n_eval_episodes: deterministic episodes per evaluation.
    :param output: comparison folder (created; re-using it resumes).
    :param backend: ``"local"`` (process pool), ``"ray"`` or a backend object.
    :param n_workers: parallel runs (default: available cores).
    :param ray_address: Ray cluster address (``--backend ray``); default: a local Ray instance.
    :param hyperparams: overrides for every method (as ``rl_zoo3 train --hyperparams``).
    :param env_kwargs: env constructor keyword arguments for every env (as ``rl_zoo3 train --env-kwargs``).
    :param gym_packages: modules to import in every process (they register extra envs).
    :param config_dir: folder of the zoo configs searched for bare method names.
    :param overwrite: redo finished runs whose settings differ (else that is an error).
    :param progress: show the progress bar.
    :param save_models: save each trained model in its run folder.
    :param final_window: evaluations averaged into the final score.
    :param solve_threshold: level counted as solved (default 0.9 for success rates).
    :param metric: ``success_rate``, ``mean_return`` or ``auto`` (success where every evaluation reports it).
    :param title: report title.
    :param command: command line to quote in the report.
    :param report_only: train nothing: write the analysis of the runs already finished in ``output`` (the others
        are listed as missing). It takes no lock, so it also works while another compare trains into ``output``
        (a snapshot; that compare rewrites the analysis when it ends), and it leaves ``comparison.json`` alone.
    :param save_freq: env steps between resumable checkpoints of each run (0: none): a run killed after one (a lost
        machine, a killed worker) continues from it when the comparison is run again, instead of from zero.
    :return: the result, with the summary tables.
    """
    start = time.perf_counter()
    if not methods or not envs or not seeds:
        raise ValueError("compare needs at least one method, one env and one seed")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be distinct, got {list(seeds)}")
    check_optional_int("n_timesteps", n_timesteps)
    check_optional_int("eval_freq", eval_freq)
    check_int("n_eval_episodes", n_eval_episodes)
    check_int("save_freq", save_freq, minimum=0)
    if metric not in ("auto", "success_rate", "mean_return"):
        raise ValueError(f"metric must be 'auto', 'success_rate' or 'mean_return', got {metric!r}")
    config_dir = Path(config_dir)
    prepare_process(tuple(gym_packages), single_thread=False)  # registers envs and algorithms for the checks
    parsed = [m if isinstance(m, Method) else parse_method(m, config_dir) for m in methods]
    labels = [m.label for m in parsed]
    if len(set(labels)) != len(labels):
        raise ValueError(f"Method labels must be distinct, got {labels}; name them with LABEL=ALGO[@VARIANT][:CONFIG]")
    for env_id in envs:
        check_env_id(env_id)
    output = Path(output)
    if report_only and not (output / "runs").is_dir():
        raise ValueError(f"{output} holds no runs to report on; run the command without --report-only first")
    check_writable_folder("the output folder (--output)", output)
    specs = plan_runs(
        parsed, envs, seeds, n_timesteps, eval_freq, n_eval_episodes, hyperparams or {}, gym_packages, config_dir,
        save_models, env_kwargs, output / "configs", save_freq,
    )  # fmt: skip

    def analyse(
        n_skipped: int, backend_name: str, trained_by: str | None = command, report_command: str | None = None
    ) -> ComparisonResult:
        summary = summarize(output, specs, final_window=final_window, solve_threshold=solve_threshold, metric=metric)
        report_title = title or f"{' vs '.join(labels)} on {', '.join(envs)}"
        wall_time = time.perf_counter() - start
        settings_md = _settings_markdown(specs, backend_name, trained_by, report_command)
        files = write_outputs(output, summary, report_title, settings_md, wall_time)
        return ComparisonResult(output, specs, n_skipped, summary, wall_time, files)

    if report_only:
        if overwrite:
            raise ValueError("--report-only trains nothing, so --overwrite has nothing to redo: drop one of them")
        try:
            jobs = _unfinished_runs(specs, output, overwrite=False, redone=False)
        except OtherSettingsError as error:
            raise ValueError(
                f"{error.run_dir} holds a finished run made with other settings ({error.details}); --report-only "
                f"reports runs made with the command's own settings: give the settings of the command recorded in "
                f"{output / COMPARISON_FILE}"
            ) from None
        # the report quotes the command that trained the runs (recorded by it), and this one as the report's maker
        return analyse(len(specs) - len(jobs), "none (--report-only)", _recorded_command(output) or command, command)

    # one compare per folder at a time: a second one would race this one's workers (its lock names our pid)
    with lock_output(output):
        jobs = _unfinished_runs(specs, output, overwrite)
        n_skipped = len(specs) - len(jobs)
        # seed-major order: every method gets its first runs early (balanced partial results if interrupted, and
        # slow and fast methods interleave instead of the slowest running alone at the end)
        jobs.sort(key=lambda job: job[0].seed)
        backend = make_backend(backend, n_workers, ray_address)
        settings = {"command": command, "specs": [spec.to_dict() for spec in specs]}
        atomic_write_text(output / COMPARISON_FILE, json.dumps(settings, indent=2) + "\n")
        if n_skipped and progress:
            print(f"{n_skipped} of {len(specs)} runs already finished in {output}: skipped", file=sys.stderr)

        note = compile_note([spec for spec, _ in jobs])
        if note is not None:
            print(note, file=sys.stderr)
        if jobs:
            display = ProgressDisplay(sum(spec.n_timesteps for spec, _ in jobs), len(jobs), enabled=progress)
            try:
                backend.run(jobs, display)
            finally:
                display.close()

        return analyse(n_skipped, type(backend).__name__)
