"""Post-exploration (thesis Ch. 6): entropy Eq. 6.7, coverage, length rules, the deep-RL wrapper and callback."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_gcrl.post_exploration import (
    FixedSteps,
    NoveltyAdaptive,
    ProportionalSteps,
    coverage,
    make_post_exploration_rule,
    visitation_entropy,
)


def test_visitation_entropy_against_hand_computation() -> None:
    # p = (1/4, 1/4, 1/2): H = -(2 * 0.25 * ln 0.25 + 0.5 * ln 0.5) = 1.5 ln 2
    assert visitation_entropy(np.array([1, 0, 1, 2, 0])) == pytest.approx(1.5 * np.log(2))
    assert visitation_entropy(np.array([1, 0, 1, 2]), base=2) == pytest.approx(1.5)
    assert visitation_entropy(np.full((4, 4), 7)) == pytest.approx(np.log(16))  # uniform: log N
    assert visitation_entropy(np.zeros(3)) == 0.0
    with pytest.raises(ValueError, match="non-negative"):
        visitation_entropy(np.array([1, -1]))


def test_coverage_with_and_without_reachable_mask() -> None:
    counts = np.array([3, 0, 1, 0])
    assert coverage(counts) == 0.5
    assert coverage(counts, reachable=np.array([True, False, True, True])) == pytest.approx(2 / 3)
    with pytest.raises(ValueError, match="one per bin"):
        coverage(counts, reachable=np.array([True, False]))


def test_fixed_and_proportional_rules() -> None:
    assert FixedSteps(30).length(steps_to_goal=7, goal_visits=1, typical_visits=5) == 30
    rule = ProportionalSteps(0.5)
    assert rule.length(7, 1, 5) == 4  # ceil(0.5 * 7)
    assert rule.length(1, 1, 5) == 1
    assert ProportionalSteps(0.5, min_steps=3).length(2, 1, 1) == 3
    with pytest.raises(ValueError, match="n_pe"):
        FixedSteps(-1)
    with pytest.raises(ValueError, match="p_pe"):
        ProportionalSteps(float("nan"))


def test_novelty_adaptive_rule_stretches_novel_goals_and_skips_known_ones() -> None:
    rule = NoveltyAdaptive(p_pe=0.5, beta=1.0, min_scale=0.25, max_scale=4.0)
    assert rule.length(10, goal_visits=10, typical_visits=10) == 5  # typical goal: as ProportionalSteps
    assert rule.length(10, goal_visits=5, typical_visits=10) == 10  # twice as novel: twice as long
    assert rule.length(10, goal_visits=1, typical_visits=100) == 20  # capped at max_scale
    assert rule.length(10, goal_visits=50, typical_visits=10) == 0  # 5x more visited: inside the known region
    assert rule.length(40, goal_visits=10, typical_visits=10) == 20  # far goals get longer post-exploration
    assert NoveltyAdaptive(max_steps=3).length(40, 1, 1) == 3
    with pytest.raises(ValueError, match="min_scale"):
        NoveltyAdaptive(min_scale=2.0, max_scale=1.0)


def test_make_post_exploration_rule_from_yaml_values() -> None:
    assert isinstance(make_post_exploration_rule(n_pe=50), FixedSteps)
    assert isinstance(make_post_exploration_rule(p_pe=0.5), ProportionalSteps)
    adaptive = make_post_exploration_rule(adaptive={"p_pe": 0.3, "beta": 0.5})
    assert isinstance(adaptive, NoveltyAdaptive) and adaptive.beta == 0.5
    with pytest.raises(ValueError, match="exactly one"):
        make_post_exploration_rule(n_pe=10, p_pe=0.5)
    with pytest.raises(ValueError, match="exactly one"):
        make_post_exploration_rule()
