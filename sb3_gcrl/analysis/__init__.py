"""Analysis of results: learning curves, aggregate statistics (IQM + bootstrap CIs via rliable) and figures."""

from sb3_gcrl.analysis.curves import aggregate_curves, bootstrap_mean_ci, choose_metric, load_curves
from sb3_gcrl.analysis.plots import (
    plot_coverage_map,
    plot_learning_curves,
    plot_memory_choice,
    plot_visitation_heatmap,
    visitation_counts,
)
from sb3_gcrl.analysis.statistics import (
    aggregate_scores,
    iqm_with_ci,
    probability_of_improvement,
    run_scores,
    visitation_entropy,
)

__all__ = [
    "aggregate_curves",
    "aggregate_scores",
    "bootstrap_mean_ci",
    "choose_metric",
    "iqm_with_ci",
    "load_curves",
    "plot_coverage_map",
    "plot_learning_curves",
    "plot_memory_choice",
    "plot_visitation_heatmap",
    "probability_of_improvement",
    "run_scores",
    "visitation_counts",
    "visitation_entropy",
]
