"""Analysis: bootstrap bands, per-run scores, rliable aggregates, entropy, figures (hand-computed values)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy.stats import trim_mean

from sb3_gcrl.analysis import (
    aggregate_curves,
    aggregate_scores,
    bootstrap_mean_ci,
    choose_metric,
    iqm_with_ci,
    load_curves,
    plot_coverage_map,
    plot_learning_curves,
    plot_memory_choice,
    plot_visitation_heatmap,
    probability_of_improvement,
    run_scores,
    visitation_counts,
    visitation_entropy,
)


def curves_table(values: dict[tuple[str, int], list[float]], steps: list[int], metric: str = "success_rate"):
    rows = [
        {"env": "E", "method": method, "seed": seed, "timesteps": step, metric: value}
        for (method, seed), series in values.items()
        for step, value in zip(steps, series)
    ]
    return pd.DataFrame(rows)


def test_bootstrap_band_of_a_single_run_or_constant_runs_collapses_to_the_mean():
    mean, low, high = bootstrap_mean_ci(np.array([[1.0, 2.0, 3.0]]))
    np.testing.assert_array_equal(mean, [1, 2, 3])
    np.testing.assert_array_equal(low, mean)
    np.testing.assert_array_equal(high, mean)
    mean, low, high = bootstrap_mean_ci(np.full((5, 2), 0.5))
    np.testing.assert_allclose([mean, low, high], 0.5)


def test_bootstrap_band_brackets_the_mean_within_the_range_and_is_reproducible():
    values = np.array([[0.0, 1.0], [1.0, 1.0], [0.0, 0.0], [1.0, 0.0]])
    mean, low, high = bootstrap_mean_ci(values, n_resamples=4000)
    np.testing.assert_allclose(mean, [0.5, 0.5])
    assert np.all(low <= mean) and np.all(mean <= high)
    assert np.all(low >= 0.0) and np.all(high <= 1.0) and np.all(high - low > 0.3)
    again = bootstrap_mean_ci(values, n_resamples=4000)
    np.testing.assert_array_equal(again[1], low)
    with pytest.raises(ValueError, match="n_runs >= 1"):
        bootstrap_mean_ci(np.zeros((0, 3)))


def test_aggregate_curves_counts_the_runs_that_reached_each_step():
    table = curves_table({("a", 0): [0.0, 1.0, 1.0], ("a", 1): [0.0, 0.0, 1.0], ("a", 2): [1.0, 1.0]}, [0, 10, 20])
    aggregated = aggregate_curves(table, "success_rate")
    assert aggregated["timesteps"].tolist() == [0, 10, 20]
    assert aggregated["n_runs"].tolist() == [3, 3, 2]
    np.testing.assert_allclose(aggregated["mean"], [1 / 3, 2 / 3, 1.0])
    assert (aggregated["low"] <= aggregated["mean"]).all() and (aggregated["mean"] <= aggregated["high"]).all()


def test_choose_metric_prefers_success_only_when_every_evaluation_reports_it():
    table = curves_table({("a", 0): [0.0, 1.0]}, [0, 10])
    table["mean_return"] = [1.0, 2.0]
    assert choose_metric(table) == "success_rate"
    table.loc[0, "success_rate"] = math.nan
    assert choose_metric(table) == "mean_return"


def test_run_scores_hand_computed():
    table = curves_table({("a", 0): [0.0, 0.5, 1.0, 1.0], ("b", 0): [0.0, 0.0, 0.0, 0.5]}, [0, 10, 20, 40])
    scores = run_scores(table, "success_rate", final_window=2, solve_threshold=0.9).set_index("method")
    # trapezoid: (0 + .5)/2*10 + (.5 + 1)/2*10 + (1 + 1)/2*20 = 2.5 + 7.5 + 20 = 30 over 40 steps
    assert scores.loc["a", "auc"] == pytest.approx(30 / 40)
    assert scores.loc["a", "final"] == pytest.approx(1.0)
    assert scores.loc["a", "solved_at"] == 20
    assert scores.loc["b", "auc"] == pytest.approx(0.25 * 20 / 40)
    assert scores.loc["b", "final"] == pytest.approx(0.25)
    assert math.isnan(scores.loc["b", "solved_at"])
    # solved = reached and kept: an early success that is lost again does not count
    table = curves_table({("c", 0): [1.0, 0.0, 1.0, 1.0], ("d", 0): [1.0, 1.0, 1.0, 0.0]}, [0, 10, 20, 40])
    scores = run_scores(table, "success_rate", solve_threshold=0.9).set_index("method")
    assert scores.loc["c", "solved_at"] == 20
    assert math.isnan(scores.loc["d", "solved_at"])
    # reached: the first evaluation at the level, kept or not
    assert scores.loc["c", "reached_at"] == 0 and scores.loc["d", "reached_at"] == 0
    table = curves_table({("e", 0): [0.0, 0.95, 0.5, 0.0], ("f", 0): [0.0, 0.0, 0.0, 0.5]}, [0, 10, 20, 40])
    scores = run_scores(table, "success_rate", solve_threshold=0.9).set_index("method")
    assert scores.loc["e", "reached_at"] == 10 and math.isnan(scores.loc["e", "solved_at"])
    assert math.isnan(scores.loc["f", "reached_at"])
    assert run_scores(table, "success_rate")["reached_at"].isna().all()  # no threshold
    with pytest.raises(ValueError, match="final_window"):
        run_scores(table, "success_rate", final_window=0)


def test_iqm_matches_the_trimmed_mean_and_its_interval_contains_it():
    scores = np.array([0.0, 0.1, 0.5, 0.6, 0.7, 10.0, 0.4, 0.3])
    iqm, low, high = iqm_with_ci(scores, reps=500)
    assert iqm == pytest.approx(trim_mean(scores, 0.25))
    assert low <= iqm <= high
    np.random.seed(1)
    expected_draw = np.random.rand()
    np.random.seed(1)
    assert iqm_with_ci(scores, reps=500) == (iqm, low, high)  # seeded bootstrap
    assert np.random.rand() == expected_draw  # the caller's global RNG state is left alone


def test_aggregate_scores_uses_iqm_from_three_runs_and_mean_range_below():
    values = {("a", s): [0.0, v] for s, v in enumerate([0.2, 0.4, 0.9])} | {("b", 0): [0.0, 1.0], ("b", 1): [0, 0.5]}
    scores = run_scores(curves_table(values, [0, 10]), "success_rate", solve_threshold=0.9)
    summary = aggregate_scores(scores, reps=500, planned_runs={("E", "b"): 3}).set_index("method")
    assert summary.loc["a", "estimator"] == "IQM"
    assert summary.loc["a", "final"] == pytest.approx(trim_mean([0.2, 0.4, 0.9], 0.25))
    assert summary.loc["b", "estimator"] == "mean"
    assert summary.loc["b", ["final", "final_low", "final_high"]].tolist() == [0.75, 0.5, 1.0]
    assert (summary.loc["b", "n_runs"], summary.loc["b", "n_planned"]) == (2, 3)
    assert (summary.loc["a", "n_solved"], summary.loc["a", "median_solved_at"]) == (1, 10)
    assert (summary.loc["a", "n_reached"], summary.loc["a", "median_reached_at"]) == (1, 10)
    assert (summary.loc["b", "n_reached"], summary.loc["b", "median_reached_at"]) == (1, 10)


def test_probability_of_improvement_hand_computed():
    # pairs: (1>0) (1>1 tie) (2>0) (2>1) -> (1 + .5 + 1 + 1) / 4
    assert probability_of_improvement(np.array([1.0, 2.0]), np.array([0.0, 1.0])) == pytest.approx(0.875)
    assert probability_of_improvement(np.ones(3), np.ones(2)) == pytest.approx(0.5)


def test_visitation_entropy_eq_6_7():
    assert visitation_entropy(np.ones((4, 4))) == pytest.approx(math.log(16))
    assert visitation_entropy(np.array([5, 0, 0])) == 0.0
    assert visitation_entropy(np.zeros(3)) == 0.0
    assert visitation_entropy(np.array([1, 3])) == pytest.approx(-(0.25 * math.log(0.25) + 0.75 * math.log(0.75)))
    with pytest.raises(ValueError, match="non-negative"):
        visitation_entropy(np.array([-1.0, 2.0]))


def test_load_curves_and_learning_curve_figure(tmp_path):
    for method, offset in (("cec", 0.5), ("sac", 0.0)):
        for seed in range(2):
            frame = pd.DataFrame({"timesteps": [0, 100, 200], "success_rate": [0.0, offset, offset + 0.5]})
            frame.to_csv(tmp_path / f"{method}_{seed}.csv", index=False)
    runs = [("E", m, s, tmp_path / f"{m}_{s}.csv") for m in ("cec", "sac") for s in range(2)]
    curves = load_curves(runs)
    assert len(curves) == 12 and list(curves.columns[:3]) == ["env", "method", "seed"]
    figure = plot_learning_curves(aggregate_curves(curves, "success_rate"), "success_rate", tmp_path / "c.png")
    assert (tmp_path / "c.png").stat().st_size > 1000
    assert [line.get_label() for line in figure.axes[0].get_lines()] == ["cec (n=2)", "sac (n=2)"]
    with pytest.raises(ValueError, match="No curves"):
        plot_learning_curves(aggregate_curves(curves.iloc[:0], "success_rate"), "success_rate")


def test_visitation_heatmap_and_coverage_map(tmp_path):
    positions = np.array([[0.1, 0.1], [0.1, 0.2], [0.9, 0.9]])
    counts = visitation_counts(positions, bins=2, bounds=((0, 1), (0, 1)))
    np.testing.assert_array_equal(counts, [[2, 0], [0, 1]])
    relevant = np.array([[True, False], [False, False]])
    figure = plot_visitation_heatmap(counts, ((0, 1), (0, 1)), relevant=relevant, path=tmp_path / "h.png")
    assert "task-relevant: 66.7%" in [text.get_text() for text in figure.axes[0].texts]
    walls = np.array([[True, False], [False, False]])
    figure = plot_coverage_map(np.array([[0, 3], [0, 0]]), walls=walls, goal=(1, 1), path=tmp_path / "cov.png")
    assert figure.axes[0].get_title() == "33% of free cells visited"
    assert (tmp_path / "h.png").is_file() and (tmp_path / "cov.png").is_file()
    with pytest.raises(ValueError, match="shape"):
        visitation_counts(np.zeros(3), bins=2, bounds=((0, 1), (0, 1)))
    with pytest.raises(ValueError, match="relevant mask shape"):
        plot_visitation_heatmap(counts, relevant=np.ones((3, 3), bool))


def test_memory_choice_figure(tmp_path):
    uses_ec = np.array([[True, True, False], [True, False, False]])
    figure = plot_memory_choice([0, 10, 20], uses_ec, curve=np.ones((2, 3)), path=tmp_path / "m.png")
    heights = [patch.get_height() for patch in figure.axes[0].patches]
    assert heights == pytest.approx([1.0, 0.5, 0.0, 0.0, 0.5, 1.0])  # EC share, then RL share
    with pytest.raises(ValueError, match="3 points but timesteps has 2"):
        plot_memory_choice([0, 10], uses_ec)
