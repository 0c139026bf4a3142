"""Goal spaces, task-relevant goals and schedulers (thesis Sec. 3.4, Alg. 3, Eq. 6.5 and 6.7)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import sb3_gcrl  # noqa: F401 (registers GCRL/ envs)
from sb3_gcrl.goals import (
    BackAndForthScheduler,
    BinnedGoalSpace,
    EnvDefaultScheduler,
    NoveltyScheduler,
    TaskRelevantGoals,
    declared_task_goals,
    declares_task_goals,
    make_scheduler,
)


# --- binned goal space ----------------------------------------------------------------------------------------------
def test_bin_index_and_counts_by_hand() -> None:
    space = BinnedGoalSpace([0.0, 0.0], [1.0, 2.0], n_bins=[2, 4])  # bin widths 0.5 and 0.5
    # (0.1, 0.1) -> (0, 0) -> 0; (0.6, 1.9) -> (1, 3) -> 1 * 4 + 3 = 7; out of range is clipped
    np.testing.assert_array_equal(space.bin_index(np.array([[0.1, 0.1], [0.6, 1.9], [-5.0, 9.0]])), [0, 7, 3])
    space.add(np.array([0.1, 0.1]))
    space.add(np.array([[0.6, 1.9], [0.7, 1.6], [0.2, 0.2]]))  # batch with a repeated bin
    assert space.counts[0] == 2 and space.counts[7] == 2 and space.n_visited == 2


def test_novelty_distribution_is_eq_6_5() -> None:
    space = BinnedGoalSpace([0.0], [3.0], n_bins=3)
    space.add(np.array([[0.5]] * 1 + [[1.5]] * 4))  # n = (1, 4, 0)
    visited, p = space.novelty_probabilities(tau=1.0)
    np.testing.assert_array_equal(visited, [0, 1])
    np.testing.assert_allclose(p, [1.0 / 1.25, 0.25 / 1.25])  # (1/n)^tau normalised
    _, p2 = space.novelty_probabilities(tau=2.0)
    np.testing.assert_allclose(p2, [1.0 / 1.0625, 0.0625 / 1.0625])
    _, p0 = space.novelty_probabilities(tau=0.0)
    np.testing.assert_allclose(p0, [0.5, 0.5])  # tau = 0: uniform over visited bins
    space.counts[1] = 10**12  # huge counts stay finite
    assert np.isfinite(space.novelty_probabilities(tau=10.0)[1]).all()


def test_novelty_sampling_frequencies_match_eq_6_5() -> None:
    space = BinnedGoalSpace([0.0], [3.0], n_bins=3)
    space.add(np.array([[0.5]] * 1 + [[1.5]] * 4))
    goals = space.sample_novel(tau=1.0, rng=np.random.default_rng(0), n=20_000)
    frequency_bin0 = float(np.mean(goals[:, 0] < 1.0))
    assert abs(frequency_bin0 - 0.8) < 4 * np.sqrt(0.8 * 0.2 / 20_000)
    assert np.all((goals >= 0.0) & (goals < 2.0))  # never the unvisited bin


def test_goals_lie_inside_their_bin() -> None:
    uniform = BinnedGoalSpace([0.0, 0.0], [1.0, 1.0], n_bins=2, within_bin="uniform")
    uniform.add(np.array([0.9, 0.1]))
    goals = uniform.sample_uniform(np.random.default_rng(0), n=500)
    assert np.all((goals[:, 0] >= 0.5) & (goals[:, 0] <= 1.0) & (goals[:, 1] >= 0.0) & (goals[:, 1] <= 0.5))
    assert goals[:, 0].std() > 0.1  # spread over the bin
    visited = BinnedGoalSpace([0.0, 0.0], [1.0, 1.0], n_bins=2, within_bin="visited")
    visited.add(np.array([0.9, 0.1]))
    np.testing.assert_array_equal(visited.sample_uniform(np.random.default_rng(0), n=3), [[0.9, 0.1]] * 3)


def test_entropy_eq_6_7() -> None:
    space = BinnedGoalSpace([0.0], [4.0], n_bins=4)
    space.add(np.array([[0.5], [1.5], [2.5], [3.5]]))
    assert space.entropy() == pytest.approx(np.log(4))


def test_goal_space_errors_name_the_fix() -> None:
    with pytest.raises(ValueError, match="pass finite goal_low/goal_high, or leave both out"):
        BinnedGoalSpace([-np.inf], [np.inf])
    with pytest.raises(ValueError, match="high must exceed low"):
        BinnedGoalSpace([1.0], [0.0])
    with pytest.raises(ValueError, match="use fewer n_bins"):
        BinnedGoalSpace([0.0] * 4, [1.0] * 4, n_bins=1000)
    with pytest.raises(RuntimeError, match="add"):
        BinnedGoalSpace([0.0], [1.0]).sample_uniform(np.random.default_rng(0))


# --- task-relevant goals ----------------------------------------------------------------------------------------------
def test_declared_task_goals_come_from_the_env() -> None:
    env = gym.make("GCRL/PointUMazeGoal-v0")
    assert declares_task_goals(env)
    goals = TaskRelevantGoals(env, goal_dim=2)
    rng = np.random.default_rng(0)
    np.testing.assert_allclose(goals.sample("initial", rng, 50), np.tile([-1.0, -1.0], (50, 1)), atol=0.1)
    np.testing.assert_allclose(goals.sample("evaluation", rng, 50), np.tile([-1.0, 1.0], (50, 1)), atol=0.1)
    initial, evaluation = declared_task_goals(env, 20, seed=3)
    assert initial.shape == evaluation.shape == (20, 2)
    np.testing.assert_allclose(evaluation, np.tile([-1.0, 1.0], (20, 1)), atol=0.1)
    np.testing.assert_array_equal(declared_task_goals(env, 20, seed=3)[1], evaluation)  # seeded
    with pytest.raises(ValueError, match="does not declare sample_initial_goal"):
        declared_task_goals(gym.make("PointMaze_UMaze-v3"), 5)


def test_task_goals_are_learned_from_resets_of_any_goal_env() -> None:
    env = gym.make("PointMaze_UMaze-v3")  # a goal env that declares nothing
    assert not declares_task_goals(env)
    goals = TaskRelevantGoals(env, goal_dim=2, capacity=4)
    with pytest.raises(RuntimeError, match="call reset"):
        goals.sample("initial", np.random.default_rng(0))
    seen_initial, seen_eval = [], []
    for seed in range(6):
        obs, _ = env.reset(seed=seed)
        goals.record_reset(obs)
        seen_initial.append(obs["achieved_goal"])
        seen_eval.append(obs["desired_goal"])
    assert goals.n_recorded == 6
    sample = goals.sample("initial", np.random.default_rng(0), 200)
    kept = np.array(seen_initial[2:])  # ring buffer of capacity 4 keeps the last 4 resets
    assert all(np.any(np.all(np.isclose(row, kept), axis=1)) for row in sample)
    assert len(np.unique(sample, axis=0)) == 4
    evaluation = goals.sample("evaluation", np.random.default_rng(0), 50)
    assert all(np.any(np.all(np.isclose(row, np.array(seen_eval[2:])), axis=1)) for row in evaluation)
    with pytest.raises(ValueError, match="'initial' or 'evaluation'"):
        goals.sample("start", np.random.default_rng(0))  # type: ignore[arg-type]


# --- schedulers ----------------------------------------------------------------------------------------------------
class FixedTaskGoals(TaskRelevantGoals):
    """rho_0 = {-1}, rho_g* = {+1} in a 1-D goal space."""

    def __init__(self) -> None:
        self.declared, self.goal_dim = True, 1

    def sample(self, kind, rng, n=1):
        return np.full((n, 1), -1.0 if kind == "initial" else 1.0)


def obs_at(x: float) -> dict[str, np.ndarray]:
    return {"observation": np.array([x]), "achieved_goal": np.array([x]), "desired_goal": np.array([7.0])}


def test_env_default_scheduler_keeps_the_env_goal() -> None:
    assert EnvDefaultScheduler().next_goal(obs_at(0.0), np.random.default_rng(0))[0] == 7.0


def test_back_and_forth_sequence_is_algorithm_3() -> None:
    space = BinnedGoalSpace([-5.0], [5.0], n_bins=10, within_bin="visited")
    scheduler = BackAndForthScheduler(FixedTaskGoals(), NoveltyScheduler(space), alpha=1.0)
    rng = np.random.default_rng(0)
    sequence = [(scheduler.next_goal(obs_at(3.3), rng)[0], scheduler.kind) for _ in range(6)]
    assert sequence == [(1.0, "forward"), (-1.0, "back")] * 3
    scheduler = BackAndForthScheduler(FixedTaskGoals(), NoveltyScheduler(space), alpha=0.0)
    assert {(scheduler.next_goal(obs_at(3.3), rng)[0], scheduler.kind) for _ in range(5)} == {(3.3, "explore")}


def test_back_and_forth_pair_probability_is_alpha() -> None:
    space = BinnedGoalSpace([-5.0], [5.0], n_bins=10)
    space.add(np.array([0.0]))
    scheduler = BackAndForthScheduler(FixedTaskGoals(), NoveltyScheduler(space), alpha=0.3)
    rng = np.random.default_rng(1)
    kinds = []
    for _ in range(6000):
        scheduler.next_goal(obs_at(0.0), rng)
        kinds.append(scheduler.kind)
    kinds_arr = np.array(kinds)
    n_forward, n_back, n_explore = (np.sum(kinds_arr == k) for k in ("forward", "back", "explore"))
    assert n_forward == n_back  # every forward goal is followed by its back goal
    pair_rate = n_forward / (n_forward + n_explore)  # decisions taken = pairs + exploratory goals
    assert abs(pair_rate - 0.3) < 4 * np.sqrt(0.3 * 0.7 / (n_forward + n_explore))
    assert all(kinds[i + 1] == "back" for i in np.flatnonzero(kinds_arr[:-1] == "forward"))


def test_pending_back_goal_is_dropped_after_a_physical_reset() -> None:
    space = BinnedGoalSpace([-5.0], [5.0], n_bins=10, within_bin="visited")
    scheduler = BackAndForthScheduler(FixedTaskGoals(), NoveltyScheduler(space), alpha=1.0)
    rng = np.random.default_rng(0)
    scheduler.next_goal(obs_at(0.0), rng)
    scheduler.reset_pending()
    scheduler.next_goal(obs_at(0.0), rng)
    assert scheduler.kind == "forward"


def test_make_scheduler_errors_list_the_choices() -> None:
    with pytest.raises(ValueError, match="choose one of"):
        make_scheduler("peg", FixedTaskGoals())
    with pytest.raises(ValueError, match="alpha must be in"):
        make_scheduler("back_and_forth", FixedTaskGoals(), [-1.0], [1.0], alpha=1.5)
    with pytest.raises(ValueError, match="tau must be"):
        make_scheduler("novelty", FixedTaskGoals(), [-1.0], [1.0], tau=-1.0)
    with pytest.raises(
        ValueError, match=r"option\(s\) \['temperature'\] of goal scheduler 'novelty'; it takes .*'tau'"
    ):
        make_scheduler("novelty", FixedTaskGoals(), [-1.0], [1.0], temperature=1.0)  # a YAML scheduler_kwargs typo
    with pytest.raises(
        ValueError, match=r"'back_and_forth'; it takes \['achieved_goal_space', 'alpha', 'exploratory'\]"
    ):
        make_scheduler("back_and_forth", FixedTaskGoals(), exploratory="evaluation", tau=1.0, beta=0.5)
    with pytest.raises(
        ValueError, match=r"does not use \['tau'\]: remove them; it takes \['achieved_goal_space', 'goal_high'"
    ):
        make_scheduler("uniform_visited", FixedTaskGoals(), [-1.0], [1.0], tau=1.0)
    scheduler = make_scheduler(
        "back_and_forth", FixedTaskGoals(), [-1.0], [1.0], alpha=0.2, exploratory="uniform_visited"
    )
    assert isinstance(scheduler, BackAndForthScheduler) and scheduler.alpha == 0.2


def test_recorded_goals_are_visible_in_counts_before_a_block_fills() -> None:
    space = BinnedGoalSpace([0.0], [1.0], n_bins=2)
    for x in (0.1, 0.2, 0.9):
        space.record(np.array([x]))
    np.testing.assert_array_equal(space.counts, [2, 1])  # reading counts bins the buffered goals
    for _ in range(3000):  # more than one block
        space.record(np.array([0.7]))
    assert space.counts[1] == 3001 and space.n_visited == 2


# --- bounds inferred from the goals the env shows ---------------------------------------------------------------------
class WideBoundsGoalEnv(gym.Env):
    """A goal env whose spaces say +-10 (like panda-gym's) while every goal lives in +-0.15."""

    def __init__(self) -> None:
        box = gym.spaces.Box(-10.0, 10.0, (2,), np.float64)
        self.observation_space = gym.spaces.Dict({"observation": box, "achieved_goal": box, "desired_goal": box})
        self.action_space = gym.spaces.Box(-0.02, 0.02, (2,), np.float32)
        self.x = np.zeros(2)
        self.goal = np.zeros(2)

    def _obs(self) -> dict[str, np.ndarray]:
        return {"observation": self.x.copy(), "achieved_goal": self.x.copy(), "desired_goal": self.goal.copy()}

    def compute_reward(self, achieved_goal, desired_goal, info) -> np.ndarray:
        return -(np.linalg.norm(achieved_goal - desired_goal, axis=-1) > 0.02).astype(np.float64)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = self.np_random.uniform(-0.05, 0.05, 2)
        self.goal = self.np_random.uniform(-0.15, 0.15, 2)
        return self._obs(), {}

    def step(self, action):
        self.x = np.clip(self.x + np.asarray(action, dtype=np.float64), -0.15, 0.15)
        obs = self._obs()
        reward = float(self.compute_reward(obs["achieved_goal"], obs["desired_goal"], {}))
        return obs, reward, False, False, {"is_success": reward == 0.0}


def test_novelty_bins_follow_the_goals_not_the_nominal_space_bounds() -> None:
    from sb3_gcrl.wrappers import GoExploreWrapper, ResetFreeWrapper

    env = ResetFreeWrapper(gym.wrappers.TimeLimit(WideBoundsGoalEnv(), 100), eval_horizon=100)
    env = GoExploreWrapper(env, "back_and_forth", {"n_bins": 10})  # no goal_low / goal_high given
    env.set_training_mode(True)
    env.reset(seed=0)
    env.action_space.seed(0)
    commanded = []
    for _ in range(3000):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
            commanded.append(env.goal)
    space = env.scheduler.exploratory.goal_space
    assert np.all(space.high - space.low <= 1.2)  # within a factor 4 of the goals' extent (0.3), not 20
    assert np.all(space.low <= -0.05) and np.all(space.high >= 0.05)
    assert space.n_visited >= 10  # novelty has bins to choose from (nominal bounds: 1-4 bins)
    assert np.all(np.abs(commanded) <= 0.15 + 1e-9)


def test_inferred_bounds_grow_by_merging_bins_with_exact_counts() -> None:
    rng = np.random.default_rng(0)
    space = BinnedGoalSpace(n_bins=[4, 5], within_bin="visited", dim=2)
    with pytest.raises(RuntimeError, match="No goal seen yet"):
        space.bin_index(np.zeros(2))
    first = rng.uniform(0.0, 0.1, (50, 2))
    space.add(first)
    np.testing.assert_allclose([space.low, space.high], [first.min(0), first.max(0)], rtol=1e-12)
    space.add(np.array([[-3.0, 0.05], [0.05, 7.0]]))  # far outside, below in x and above in y
    more = rng.uniform(-3.0, 7.0, (200, 2))
    space.add(more)
    assert space.counts.sum() == 252  # no visit lost while the box grew
    assert np.all(space.low <= -3.0) and np.all(space.high >= 7.0)
    assert np.all(space.high - space.low <= 4 * (10.0 + 0.1))
    everything = np.concatenate([first, [[-3.0, 0.05], [0.05, 7.0]], more])
    expected = np.bincount(space.bin_index(everything), minlength=space.n_cells)
    # merged counts = counts binned afresh in the final box, up to goals within rounding of a bin edge (the first
    # batch's maximum sits on the initial box's upper edge)
    position = (everything - space.low) / space.bin_width
    on_edge = int(np.any(np.abs(position - np.round(position)) < 1e-9, axis=1).sum())
    assert on_edge <= 2 and np.abs(space.counts - expected).sum() <= 2 * on_edge
    visited = np.flatnonzero(space.counts)
    np.testing.assert_array_equal(space.bin_index(space.goals_in_bins(visited, rng)), visited)  # real visited goals
    space.extend(np.array([20.0, 20.0]))  # a task goal widens the box without counting a visit
    assert space.counts.sum() == 252 and np.all(space.high >= 20.0)
