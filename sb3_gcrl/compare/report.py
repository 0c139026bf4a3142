"""Turn the finished runs of a comparison into tables, a curves figure and a Markdown report."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from huggingface_sb3 import EnvironmentName
from matplotlib.figure import Figure

from sb3_gcrl.analysis.curves import METRICS, aggregate_curves, choose_metric, load_curves
from sb3_gcrl.analysis.plots import (
    METRIC_LABELS,
    plot_learning_curves,
    plot_memory_choice,
    plot_visitation_heatmap,
    visitation_counts,
)
from sb3_gcrl.analysis.statistics import aggregate_scores, probability_of_improvement, run_scores, visitation_entropy
from sb3_gcrl.compare.costs import ALL_PHASES, cost_section
from sb3_gcrl.compare.run import RunSpec
from sb3_gcrl.compare.storage import (
    ALL_GOALS_FILE,
    EVALUATIONS_FILE,
    LOG_FILE,
    VISITED_FILE,
    atomic_write_text,
    load_run_record,
    result_files_problem,
)

#: default level of ``success_rate`` that counts as solved (for the "solved" columns)
SUCCESS_THRESHOLD = 0.9
#: metric of the all-goals curves (column of ``all_goals.csv``; thesis Sec. 6.5.1)
ALL_GOALS_METRIC = "all_goals_success"
#: metrics that are success rates (two decimals, "solved" columns)
SUCCESS_METRICS = ("success_rate", ALL_GOALS_METRIC)


@dataclass
class Summary:
    """Analysed results of a comparison.

    :param curves: every evaluation of every finished run (tidy).
    :param scores: per-run final score, AUC, step solved.
    :param summary: per (env, method) aggregates (see :func:`~sb3_gcrl.analysis.statistics.aggregate_scores`).
    :param metrics: metric used per env.
    :param failed: ``(spec, error, log path)`` of the runs that failed, never ran, or left unusable files.
    :param run_times: ``env``, ``method``, ``wall_time_s`` and ``cpu_time_s`` (NaN where the run did not record it)
        of every finished run, as its worker measured them.
    :param run_dirs: ``(env, method) -> folders`` of the finished runs.
    :param table: the printed Markdown table.
    :param all_goals_curves: every all-goals evaluation (``all_goals.csv``) of the finished runs that have one
        (tidy; empty when none has).
    :param all_goals_scores: per-run final and AUC of the all-goals success.
    :param all_goals_summary: their aggregates per (env, method).
    :param all_goals_table: ``all_goals_summary`` as Markdown ("" when no run has all-goals evaluations).
    :param return_summary: aggregates of the evaluation return per (env, method), for the envs scored by success rate
        whose return is not the success (e.g. sub-goals that pay part of the reward); empty when there is none.
    :param return_table: ``return_summary`` as Markdown ("" when it is empty).
    """

    curves: pd.DataFrame
    scores: pd.DataFrame
    summary: pd.DataFrame
    metrics: dict[str, str]
    failed: list[tuple[RunSpec, str, Path]]
    table: str
    run_times: pd.DataFrame
    run_dirs: dict[tuple[str, str], list[Path]]
    all_goals_curves: pd.DataFrame = field(default_factory=pd.DataFrame)
    all_goals_scores: pd.DataFrame = field(default_factory=pd.DataFrame)
    all_goals_summary: pd.DataFrame = field(default_factory=pd.DataFrame)
    all_goals_table: str = ""
    return_summary: pd.DataFrame = field(default_factory=pd.DataFrame)
    return_table: str = ""


def _format_interval(value: float, low: float, high: float, digits: int) -> str:
    if math.isnan(value):
        return "n/a"
    return f"{value:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def format_table(summary: pd.DataFrame, metrics: dict[str, str]) -> str:
    """The aggregate table as Markdown (readable in a terminal too).

    :param summary: table from :func:`~sb3_gcrl.analysis.statistics.aggregate_scores`.
    :param metrics: metric per env.
    :return: the table text.
    """
    header = [
        "env", "method", "runs", "metric", "final", "AUC", "estimator", "solved", "median steps to solve",
        "median steps to reach",
    ]  # fmt: skip
    lines = []
    for row in summary.itertuples(index=False):
        metric = metrics[row.env]
        bounds = (row.final_low, row.final_high, row.auc_low, row.auc_high)
        small = all(abs(bound) < 10 for bound in bounds if not math.isnan(bound))
        digits = 2 if metric in SUCCESS_METRICS or small else 1  # returns of 0-1 rewards need the second digit
        solved_at = "-" if math.isnan(row.median_solved_at) else f"{row.median_solved_at:,.0f}"
        reached_at = "-" if math.isnan(row.median_reached_at) else f"{row.median_reached_at:,.0f}"
        lines.append(
            [
                row.env,
                row.method,
                f"{row.n_runs}/{row.n_planned}",
                METRIC_LABELS.get(metric, metric),
                _format_interval(row.final, row.final_low, row.final_high, digits),
                _format_interval(row.auc, row.auc_low, row.auc_high, digits),
                "IQM [95% CI]" if row.estimator == "IQM" else "mean [min, max]",
                f"{row.n_solved}/{row.n_runs}" if metric in SUCCESS_METRICS else "-",
                solved_at,
                f"{reached_at} ({row.n_reached}/{row.n_runs})" if metric in SUCCESS_METRICS else "-",
            ]
        )
    widths = [max(len(str(cell)) for cell in column) for column in zip(header, *lines)]

    def render(cells: list[str]) -> str:
        return "| " + " | ".join(str(cell).ljust(width) for cell, width in zip(cells, widths)) + " |"

    return "\n".join([render(header), render(["-" * width for width in widths]), *map(render, lines)])


def summarize(
    output: Path,
    specs: list[RunSpec],
    final_window: int = 1,
    solve_threshold: float | None = None,
    min_runs_for_iqm: int = 3,
    metric: str = "auto",
) -> Summary:
    """Load the planned runs from ``output`` and compute curves, per-run scores and aggregates (also of the
    all-goals success of the runs that recorded it, with the same final window and solve threshold).

    :param output: comparison folder.
    :param specs: the runs of this comparison (others lying in the folder are ignored).
    :param final_window: evaluations averaged into the final score.
    :param solve_threshold: level counted as solved (default: :data:`SUCCESS_THRESHOLD` for success rates,
        none for returns).
    :param min_runs_for_iqm: below this many runs per method, mean and range replace IQM and CI.
    :param metric: ``success_rate``, ``mean_return``, or ``auto`` (success when every evaluation of the env
        reports it, else return).
    :return: the summary.
    """
    if metric not in ("auto", *METRICS):
        raise ValueError(f"metric must be 'auto' or one of {METRICS}, got {metric!r}")
    metric_choice = metric
    finished, failed, times, run_dirs, all_goals_runs = [], [], [], {}, []
    for spec in specs:
        run_dir = output / "runs" / spec.relative_dir
        record, problem = load_run_record(run_dir)
        if problem is None and record is not None and record["status"] == "finished":
            problem = result_files_problem(run_dir, record)
            if problem is None:
                finished.append((spec.env_id, spec.method, spec.seed, run_dir / EVALUATIONS_FILE))
                if record.get("n_all_goals_evaluations") is not None:
                    all_goals_runs.append((spec.env_id, spec.method, spec.seed, run_dir / ALL_GOALS_FILE))
                cpu_time = record.get("cpu_time_s")  # runs of older versions did not record it
                cpu_time = float(cpu_time) if isinstance(cpu_time, (int, float)) else math.nan
                split = record.get("cpu_split_s") or {}
                phases = [float(split[p]) if isinstance(split.get(p), (int, float)) else math.nan for p in ALL_PHASES]
                times.append((spec.env_id, spec.method, float(record["wall_time_s"]), cpu_time, *phases))
                run_dirs.setdefault((spec.env_id, spec.method), []).append(run_dir)
                continue
        if problem is not None:
            error = f"unusable result: {problem} (run the same command again to redo the run)"
        else:
            unfinished = "not finished (never ran, interrupted or still training)"
            error = unfinished if record is None else str(record.get("error") or "")
        failed.append((spec, error, run_dir / LOG_FILE))
    curves = load_curves(finished)
    planned = pd.Series([(s.env_id, s.method) for s in specs]).value_counts().to_dict()
    scores, summaries, metrics, return_summaries = [], [], {}, []
    for env_id, env_curves in curves.groupby("env", sort=False):
        metric = metrics[env_id] = choose_metric(env_curves) if metric_choice == "auto" else metric_choice
        if env_curves[metric].isna().any():
            raise ValueError(f"{env_id} does not report {metric} in every evaluation: use --metric mean_return or auto")
        threshold = (
            solve_threshold
            if solve_threshold is not None
            else (SUCCESS_THRESHOLD if metric == "success_rate" else None)
        )
        env_scores = run_scores(env_curves, metric, final_window, threshold)
        scores.append(env_scores.assign(metric=metric))
        summaries.append(aggregate_scores(env_scores, min_runs_for_iqm, planned_runs=planned))
        if metric == "success_rate" and not np.allclose(env_curves["mean_return"], env_curves["success_rate"]):
            # the reward pays for more than the success: the return is the other half of the picture
            return_scores = run_scores(env_curves, "mean_return", final_window, None)
            return_summaries.append(aggregate_scores(return_scores, min_runs_for_iqm, planned_runs=planned))
    # tables list envs and methods in the order the user gave them (groupby sorts them alphabetically)
    order = {key: rank for rank, key in enumerate(dict.fromkeys((s.env_id, s.method) for s in specs))}
    curves = _in_order(curves, order)
    scores_table = _in_order(pd.concat(scores, ignore_index=True), order) if scores else pd.DataFrame()
    summary = _in_order(pd.concat(summaries, ignore_index=True), order) if summaries else pd.DataFrame()
    table = format_table(summary, metrics) if len(summary) else "(no finished runs)"
    run_times = pd.DataFrame(
        times, columns=["env", "method", "wall_time_s", "cpu_time_s", *(f"cpu_{p}_s" for p in ALL_PHASES)]
    )
    result = Summary(curves, scores_table, summary, metrics, failed, table, run_times, run_dirs)
    if return_summaries:
        result.return_summary = _in_order(pd.concat(return_summaries, ignore_index=True), order)
        result.return_table = format_table(
            result.return_summary, dict.fromkeys(result.return_summary["env"], "mean_return")
        )
    if all_goals_runs:
        threshold = SUCCESS_THRESHOLD if solve_threshold is None else solve_threshold
        result.all_goals_curves = _in_order(load_curves(all_goals_runs), order)
        result.all_goals_scores = _in_order(
            run_scores(result.all_goals_curves, ALL_GOALS_METRIC, final_window, threshold), order
        )
        result.all_goals_summary = _in_order(
            aggregate_scores(result.all_goals_scores, min_runs_for_iqm, planned_runs=planned), order
        )
        all_goals_metrics = dict.fromkeys(result.all_goals_summary["env"], ALL_GOALS_METRIC)
        result.all_goals_table = format_table(result.all_goals_summary, all_goals_metrics)
    return result


def _in_order(table: pd.DataFrame, order: dict[tuple[str, str], int]) -> pd.DataFrame:
    """Rows sorted (stably) by the planned (env, method) order."""
    if not len(table):
        return table
    rank = [order[key] for key in zip(table["env"], table["method"])]
    return table.iloc[sorted(range(len(table)), key=rank.__getitem__)].reset_index(drop=True)


def _aggregate(curves: pd.DataFrame, metrics: dict[str, str]) -> pd.DataFrame:
    """Mean curves with bootstrap bands per (env, method), methods in the order of ``curves``."""
    methods = {method: rank for rank, method in enumerate(dict.fromkeys(curves["method"]))}
    return pd.concat(
        [
            aggregate_curves(group, metrics[env_id]).sort_values("method", key=lambda m: m.map(methods), kind="stable")
            for env_id, group in curves.groupby("env", sort=False)
        ]
    )


def write_outputs(output: Path, summary: Summary, title: str, settings_md: str, wall_time_s: float) -> list[Path]:
    """Write ``curves.csv``, ``scores.csv``, ``summary.csv``, ``curves.png`` and ``report.md`` into ``output``
    (and the all-goals files of :func:`_all_goals_outputs` when runs recorded all-goals evaluations).

    :param output: comparison folder.
    :param summary: from :func:`summarize`.
    :param title: report title.
    :param settings_md: Markdown describing the settings (methods, configs, budgets).
    :param wall_time_s: wall time of this invocation.
    :return: the files written (``curves.png`` and the other figures only when there were finished runs).
    """
    written = [output / name for name in ("curves.csv", "scores.csv", "summary.csv")]
    atomic_write_text(output / "curves.csv", summary.curves.to_csv(index=False))
    atomic_write_text(output / "scores.csv", summary.scores.to_csv(index=False))
    atomic_write_text(output / "summary.csv", summary.summary.to_csv(index=False))
    figure_md = ""
    if len(summary.curves):
        aggregated = _aggregate(summary.curves, summary.metrics)
        # the figure gets a short title (the report's may be a sentence); panels are titled by env
        methods = dict.fromkeys(summary.curves["method"])
        plot_learning_curves(aggregated, summary.metrics, path=output / "curves.png", title=" vs ".join(methods))
        written.append(output / "curves.png")
        figure_md = "![learning curves](curves.png)\n" + _memory_choice_figures(output, summary)
        figure_md += _visitation_figures(output, summary)
    lines = [
        f"# {title}",
        "",
        settings_md,
        "## Results",
        "",
        summary.table,
        "",
        figure_md,
        "*final*: metric at the last evaluation (mean of the last evaluations when `--final-window` > 1); "
        "*AUC*: average level over training (area under the evaluation curve / steps). With >= 3 runs per method "
        "the table gives the interquartile mean (IQM) and its 95% stratified-bootstrap confidence interval "
        "(rliable, 2000 resamples); with fewer, the mean and the [min, max] of the runs. Curves: mean over runs "
        "with a 95% percentile-bootstrap band. *solved*: runs whose success rate reached "
        f"{SUCCESS_THRESHOLD:g} (or `--solve-threshold`) and stayed there until the end; *median steps to solve*: "
        "median over those runs of the first evaluation from which it stayed there; *median steps to reach*: median "
        "of the first evaluation at that level, kept or not, over the runs that got there (how many of all).",
        "",
    ]
    if summary.return_table:
        lines += [
            "### Evaluation return",
            "",
            "On these envs the reward pays for more than reaching the goal (e.g. sub-goals), so the success rate "
            "above does not tell the whole story: the same table for the evaluation return (*solved* is not "
            "counted for returns).",
            "",
            summary.return_table,
            "",
        ]
    lines += _improvement_section(summary)
    all_goals_files, all_goals_md = _all_goals_outputs(output, summary)
    written += all_goals_files
    lines += all_goals_md
    if summary.failed:
        lines += ["## Failed or missing runs", ""]
        for spec, error, log in summary.failed:
            last = error.strip().splitlines()[-1] if error.strip() else "unknown error"
            lines.append(f"- {spec.env_id} / {spec.method} / seed {spec.seed}: `{last}` (log: `{log}`)")
        lines.append("")
    lines += cost_section(summary.run_times)
    lines.append(f"Wall time of this invocation (resumed runs cost nothing): {wall_time_s:.0f} s.")
    atomic_write_text(output / "report.md", "\n".join(lines) + "\n")
    return [*written, output / "report.md"]


def _all_goals_outputs(output: Path, summary: Summary) -> tuple[list[Path], list[str]]:
    """The all-goals results (thesis Sec. 6.5.1, Fig. 6.3 / 6.5): ``all_goals_curves.csv``, ``all_goals_scores.csv``,
    ``all_goals_summary.csv``, ``all_goals.png`` and, where every evaluation has one, the visitation entropy
    curves ``all_goals_entropy.png`` (Eq. 6.7); with their report section.

    :return: the files written and the report lines (both empty when no run has all-goals evaluations).
    """
    curves = summary.all_goals_curves
    if not len(curves):
        return [], []
    names = ("all_goals_curves.csv", "all_goals_scores.csv", "all_goals_summary.csv")
    for name, table in zip(names, (curves, summary.all_goals_scores, summary.all_goals_summary)):
        atomic_write_text(output / name, table.to_csv(index=False))
    written = [output / name for name in names]
    methods = " vs ".join(dict.fromkeys(curves["method"]))
    metrics = dict.fromkeys(curves["env"], ALL_GOALS_METRIC)
    plot_learning_curves(_aggregate(curves, metrics), metrics, path=output / "all_goals.png", title=methods)
    written.append(output / "all_goals.png")
    lines = [
        "## Success over all goals (thesis Sec. 6.5.1)",
        "",
        "Greedy success at reaching every goal of the task (tabular: every reachable cell; deep: the goal grid of "
        "the run's AllGoalsEvalCallback), at the evaluation points of the curves above; final, AUC and CIs as "
        "in the table above.",
        "",
        summary.all_goals_table,
        "",
        "![success over all goals](all_goals.png)",
    ]
    counted = curves.groupby("env")["visitation_entropy"].transform(lambda values: values.notna().all())
    if counted.any():
        entropy_metrics = dict.fromkeys(curves.loc[counted, "env"], "visitation_entropy")
        aggregated = _aggregate(curves[counted], entropy_metrics)
        plot_learning_curves(aggregated, entropy_metrics, path=output / "all_goals_entropy.png", title=methods)
        written.append(output / "all_goals_entropy.png")
        lines += ["", "![visitation entropy of the training data (Eq. 6.7)](all_goals_entropy.png)"]
    return written, [*lines, ""]


def _memory_choice_figures(output: Path, summary: Summary) -> str:
    """Fig. 5.6 (top row) for every 2M method: which memory each evaluation used, above the curve."""
    curves = summary.curves
    if "eval_memory_is_ec" not in curves or curves["eval_memory_is_ec"].isna().all():
        return ""
    lines = ["", "### Memory used by 2M at evaluation (Fig. 5.6, top row: orange EC, grey RL)", ""]
    for (env_id, method), group in curves.dropna(subset=["eval_memory_is_ec"]).groupby(["env", "method"], sort=False):
        metric = summary.metrics[env_id]
        choice = group.pivot_table(index="seed", columns="timesteps", values="eval_memory_is_ec").dropna(axis=1)
        curve = group.pivot_table(index="seed", columns="timesteps", values=metric)[choice.columns]
        name = f"memory_{EnvironmentName(env_id)}_{method}.png"
        plot_memory_choice(
            choice.columns.to_numpy(),
            choice.to_numpy() > 0.5,
            curve.to_numpy(),
            curve_label=METRIC_LABELS.get(metric, metric),
            title=f"{method} on {env_id}",
            path=output / name,
        )
        lines.append(f"![{method} memory choice on {env_id}]({name})")
    return "\n".join(lines) + "\n"


def _visitation_figures(output: Path, summary: Summary, bins: int = 40) -> str:
    """Fig. 3.5-style state-visitation heatmaps (achieved goals of the training data, all seeds of a method).

    Two goal dimensions are drawn: those the task table names for the env (the mug's XY on Tabletop, as Fig.
    3.9), else a 2-D goal space's; other envs get none (their visited goals still serve ``reproduce_ch3``'s
    task-relevant share). Suite envs are drawn over their whole goal box, with samples of rho_0 and rho_g* as white
    dots (the thesis's circles).
    """
    from sb3_gcrl.envs.tasks import find_task

    lines = []
    for env_id in dict.fromkeys(env for env, _ in summary.run_dirs):
        points = {}
        for (env, method), run_dirs in summary.run_dirs.items():
            files = [run_dir / VISITED_FILE for run_dir in run_dirs if (run_dir / VISITED_FILE).is_file()]
            if env == env_id and files:
                points[method] = np.concatenate([np.load(file) for file in files])
        task = find_task(env_id)
        task = task if task is not None and task.goal_low is not None else None
        dims = task.visitation_dims if task is not None else (0, 1)
        goal_dims = {goals.shape[-1] for goals in points.values()}
        if not points or len(goal_dims) > 1 or (task is None and goal_dims != {2}) or max(dims) >= min(goal_dims):
            continue
        points = {method: goals[:, dims] for method, goals in points.items()}
        if task is not None:  # the task's goal box: the whole table / maze, whatever the agents visited
            low, high = np.asarray(task.goal_low)[list(dims)], np.asarray(task.goal_high)[list(dims)]
        else:
            stacked = np.concatenate(list(points.values()))
            low, high = stacked.min(axis=0), stacked.max(axis=0)
        margin = 0.02 * np.maximum(high - low, 1e-6)
        bounds = tuple(zip(low - margin, high + margin))  # shared by the panels, so they compare
        markers = None if task is None else _task_goal_samples(env_id)[:, dims]
        figure = Figure(figsize=(4.2 * len(points), 3.6), layout="constrained")
        for ax, (method, goals) in zip(figure.subplots(1, len(points), squeeze=False)[0], points.items()):
            counts = visitation_counts(goals, bins, bounds)
            title = f"{method} (entropy {visitation_entropy(counts):.2f})"
            plot_visitation_heatmap(counts, bounds, ax=ax, title=title, points=markers)
        name = f"visitation_{EnvironmentName(env_id)}.png"
        shown = "" if min(goal_dims) == 2 else f" (goal dimensions {dims[0]}, {dims[1]})"
        figure.suptitle(f"{env_id}: achieved goals{shown} in the replay buffer, all seeds")
        figure.savefig(output / name, dpi=150, bbox_inches="tight")
        lines.append(f"![state visitation on {env_id}]({name})")
    if not lines:
        return ""
    header = "### State visitation (Fig. 3.5 style; entropy of Eq. 6.7 over the 40 x 40 bins)"
    return "\n".join(["", header, "", *lines]) + "\n"


def _task_goal_samples(env_id: str, n: int = 32) -> np.ndarray:
    """``n`` samples each of rho_0 and rho_g* that a reset-free suite env declares, stacked ``(2 n, goal_dim)``."""
    import gymnasium as gym

    from sb3_gcrl.goals import declared_task_goals

    env = gym.make(env_id)
    samples = np.concatenate(declared_task_goals(env, n))
    env.close()
    return samples


def _improvement_section(summary: Summary) -> list[str]:
    """Pairwise probability of improvement on the final score (Agarwal et al., 2021), per env."""
    lines = []
    for env_id, env_scores in summary.scores.groupby("env", sort=False) if len(summary.scores) else []:
        methods = list(dict.fromkeys(env_scores["method"]))
        for first, second in itertools.combinations(methods, 2):
            x = env_scores.loc[env_scores["method"] == first, "final"].to_numpy()
            y = env_scores.loc[env_scores["method"] == second, "final"].to_numpy()
            lines.append(f"| {env_id} | {first} > {second} | {probability_of_improvement(x, y):.2f} |")
    if not lines:
        return []
    return [
        "### Probability of improvement (final score)",
        "",
        "P(a run of the first method ends higher than a run of the second; ties count 1/2).",
        "",
        "| env | comparison | P |",
        "| --- | --- | --- |",
        *lines,
        "",
    ]
