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
    assert NoveltyAdaptive(n_pe=30).length(5, goal_visits=2, typical_visits=4) == 60  # deep RL: n_pe * scale
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


# --- deep RL: wrapper, callback, executed actions in HER, RL-Zoo ------------------------------------------------

import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import gymnasium as gym  # noqa: E402
from stable_baselines3 import SAC, HerReplayBuffer  # noqa: E402
from stable_baselines3.common.callbacks import BaseCallback  # noqa: E402

import sb3_gcrl  # noqa: E402,F401
from sb3_gcrl.her import ExecutedActionHerReplayBuffer  # noqa: E402
from sb3_gcrl.post_exploration import PostExplorationCallback, PostExplorationWrapper  # noqa: E402

TREE_GOALS = {"tau": 0.0, "goal_low": [-2.0], "goal_high": [2.0], "n_bins": 40, "within_bin": "uniform"}


class ActionRecorder(gym.Wrapper):
    """Records the actions the base env really executes."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.executed: list[np.ndarray] = []

    def step(self, action):
        self.executed.append(np.array(action, dtype=np.float64).copy())
        return self.env.step(action)


def make_tree(post_exploration: bool = True, n_pe: int = 3, **kwargs) -> PostExplorationWrapper:
    env = ActionRecorder(gym.make("GCRL/GrowingTreeGoal-v0"))
    return PostExplorationWrapper(
        env, post_exploration=post_exploration, n_pe=n_pe, scheduler_kwargs=TREE_GOALS, **kwargs
    )


def test_post_exploration_starts_on_success_lasts_n_pe_steps_and_reports_executed_actions() -> None:
    env = make_tree(n_pe=3)
    env.set_training_mode(True)
    obs, _ = env.reset(seed=0, options={"goal": [0.5]})
    zero = np.zeros(1, dtype=np.float32)
    flags, executed = [], []
    for _ in range(3):  # height stays 0: goal 0.5 not reached, no post-exploration
        obs, reward, terminated, truncated, info = env.step(zero)
        assert not info["post_exploration"] and not info["is_success"] and "executed_action" not in info
        assert reward == 0.0 and not truncated
    obs, _ = env.reset(options={"goal": [0.0]})  # already at the goal: reached on the first step
    for _ in range(10):
        obs, reward, terminated, truncated, info = env.step(zero)
        flags.append(info["post_exploration"])
        if info["post_exploration"]:
            executed.append(info["executed_action"])
        assert info["is_success"]  # sticky once reached: SB3's success rate is the goal-reaching rate
        if truncated:
            break
    assert flags == [False, True, True, True] and truncated and not terminated
    np.testing.assert_allclose(env.env.executed[-3:], executed)  # the base env ran the random actions
    assert any(np.abs(a).sum() > 0 for a in executed)  # not the agent's zero action
    assert env.post_exploration_steps == 3 and env.goals_reached == 1
    # visit counts of the shared binned goal space: 2 resets + 7 steps, heights binned 0.1 wide over [-2, 2]
    assert env.goal_space.counts.sum() == 9
    assert env.goal_space.counts[env.goal_space.bin_index(np.array([0.0]))] >= 5  # 2 resets + 3 zero steps + 1


def test_without_post_exploration_the_episode_ends_at_the_goal() -> None:
    env = make_tree(post_exploration=False)
    env.set_training_mode(True)
    env.reset(seed=0, options={"goal": [0.0]})
    *_, truncated, info = env.step(np.zeros(1, dtype=np.float32))
    assert truncated and info["is_success"] and not info["post_exploration"]
    assert env.post_exploration_steps == 0


def test_episodic_mode_keeps_the_env_goal_and_never_post_explores() -> None:
    env = make_tree(n_pe=3)
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(obs["desired_goal"], [1.0])  # GrowingTree's own goal
    successes = []
    for _ in range(12):  # +0.1 per step reaches 1.0 on step 10; the env does not end, nothing is replaced
        obs, reward, terminated, truncated, info = env.step(np.full(1, 0.1, dtype=np.float32))
        assert "executed_action" not in info and not truncated
        successes.append(info["is_success"])
    assert successes.index(True) == 9 and env.post_exploration_steps == 0


@pytest.mark.parametrize("mode", ["episodic", "post_exploration"])
def test_requested_goal_is_the_goal_the_agent_sees_and_is_judged_on(mode: str) -> None:
    # all-goals evaluation commands each goal through reset(options={"goal": g}); the observation must carry g
    env = make_tree(n_pe=3)
    if mode == "post_exploration":
        env.set_training_mode(True)
    for goal, reached in (([0.5], False), ([0.0], True), ([-0.3], False)):
        obs, _ = env.reset(seed=0, options={"goal": goal})
        np.testing.assert_allclose(obs["desired_goal"], goal)
        obs, reward, _, _, info = env.step(np.zeros(1, dtype=np.float32))  # height stays 0.0
        np.testing.assert_allclose(obs["desired_goal"], goal)
        assert info["is_success"] == reached and reward == float(reached)


def test_wrapper_bad_input_names_the_fix() -> None:
    with pytest.raises(TypeError, match="goal env"):
        PostExplorationWrapper(gym.make("Pendulum-v1"), n_pe=3)
    with pytest.raises(ValueError, match="exactly one"):
        PostExplorationWrapper(gym.make("GCRL/GrowingTreeGoal-v0"), scheduler_kwargs=TREE_GOALS)
    with pytest.raises(ValueError, match="visit counts"):
        PostExplorationWrapper(gym.make("GCRL/GrowingTreeGoal-v0"), adaptive=True, scheduler="env_default")


class RecordPostExplorationFlags(BaseCallback):
    def __init__(self) -> None:
        super().__init__()
        self.flags: list[bool] = []

    def _on_step(self) -> bool:
        self.flags.append(bool(self.locals["infos"][0].get("post_exploration", False)))
        return True


def test_her_buffer_stores_executed_actions_and_relabels_with_post_exploration_states() -> None:
    env = make_tree(n_pe=5)
    model = SAC(
        "MultiInputPolicy",
        env,
        learning_starts=250,
        batch_size=32,
        policy_kwargs={"net_arch": [16]},
        replay_buffer_class=ExecutedActionHerReplayBuffer,
        replay_buffer_kwargs={"n_sampled_goal": 4, "goal_selection_strategy": "future"},
        seed=0,
    )
    flags = RecordPostExplorationFlags()
    model.learn(400, callback=[PostExplorationCallback(log_freq=100), flags])
    wrapper = model.get_env().envs[0].env  # Monitor -> PostExplorationWrapper
    assert wrapper.post_exploration_steps > 0 and wrapper.goals_reached > 0
    buffer = model.replay_buffer
    n = buffer.pos
    assert n == 400 and len(flags.flags) == 400
    # stored actions are the executed ones (Box(-0.1, 0.1) is stored scaled to [-1, 1])
    executed = np.array(wrapper.env.executed[-n:])  # the recorder sits below the wrapper
    np.testing.assert_allclose(buffer.actions[:n, 0], executed / 0.1, atol=1e-5)
    # post-exploration steps are inside their HER episode, and 'future' relabels earlier steps with their states
    post = np.flatnonzero(flags.flags)
    i = int(post[-1])
    start, length = int(buffer.ep_start[i, 0]), int(buffer.ep_length[i, 0])
    assert start <= i < start + length and flags.flags[start + length - 1]  # the episode ends post-exploring
    first_post = start + int(np.argmax(flags.flags[start : start + length]))
    post_goals = buffer.next_observations["achieved_goal"][first_post : start + length, 0]
    goals = buffer._sample_goals(np.full(2000, start), np.zeros(2000, dtype=int))
    share = np.isin(goals, post_goals).mean()  # 'future' draws uniformly over the rest of the episode
    assert share > 0 and share == pytest.approx(len(post_goals) / length, abs=0.03)
    assert model.logger.name_to_value["post_exploration/steps"] == wrapper.post_exploration_steps
    stock = SAC(
        "MultiInputPolicy",
        make_tree(),
        learning_starts=250,
        replay_buffer_class=HerReplayBuffer,
        policy_kwargs={"net_arch": [8]},
    )
    with pytest.raises(TypeError, match="ExecutedActionHerReplayBuffer"):
        stock.learn(10, callback=PostExplorationCallback())


@pytest.mark.slow  # a stock rl_zoo3 subprocess with all-goals evaluations: over a minute on 2 loaded cores
def test_rl_zoo3_train_with_the_post_exploration_yaml(tmp_path: Path) -> None:
    """Stock `rl_zoo3 train` with our FetchReach config (a few hundred steps): the env's section of ddpg.yml."""
    config = Path(__file__).parents[1] / "zoo_configs" / "ddpg.yml"
    zoo = Path(sys.executable).with_name("rl_zoo3")
    result = subprocess.run(
        [str(zoo), "train", "--algo", "ddpg", "--env", "FetchReach-v4", "--gym-packages", "sb3_gcrl", "-conf",
         str(config), "-f", str(tmp_path / "logs"), "--eval-freq", "200", "--eval-episodes", "2", "-params",
         "n_timesteps:300", "learning_starts:120", "batch_size:32", "policy_kwargs:dict(net_arch=[32])",
         "--tensorboard-log", str(tmp_path / "tb")],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    assert (tmp_path / "logs" / "ddpg" / "FetchReach-v4_1" / "FetchReach-v4.zip").is_file()
    assert "IMGEP training mode on for 1 training env(s)" in result.stdout  # the callback switched the wrapper on
    assert "goals_reached_rate=" in result.stdout and "visitation_entropy=" in result.stdout


def test_wrapper_passes_env_checkers_in_both_modes() -> None:
    from gymnasium.utils.env_checker import check_env as gym_check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    def make() -> PostExplorationWrapper:
        return PostExplorationWrapper(gym.make("GCRL/GrowingTreeGoal-v0"), n_pe=3, scheduler_kwargs=TREE_GOALS)

    for training in (False, True):
        env = make()
        if training:
            env.set_training_mode(True)
        gym_check_env(env, skip_render_check=True)
        sb3_check_env(make(), warn=False)


def test_episodes_that_end_at_the_goal_reach_the_monitor_csv_and_sb3(tmp_path: Path) -> None:
    """The Monitor below the wrapper sees only time-limit episodes; the wrapper reports every IMGEP episode."""
    from stable_baselines3.common.monitor import Monitor, load_results

    monitor = Monitor(gym.make("GCRL/GrowingTreeGoal-v0"), str(tmp_path / "0"), info_keywords=("is_success",))
    env = PostExplorationWrapper(monitor, n_pe=3, scheduler_kwargs=TREE_GOALS)
    env.set_training_mode(True)
    zero = np.zeros(1, dtype=np.float32)
    env.reset(seed=0, options={"goal": [0.0]})  # reached at the first step, then 3 post-exploration steps
    for _ in range(4):
        *_, truncated, info = env.step(zero)
    assert truncated and info["episode"]["l"] == 4 and info["is_success"] and info["goal_kind"] == "explore"
    env.reset(options={"goal": [1.5]})
    for _ in range(2):
        *_, truncated, info = env.step(zero)
    assert not truncated and "episode" not in info
    env.close()
    rows = load_results(str(tmp_path))
    assert list(rows.l) == [4] and list(rows.is_success) == [True]


# ------------------------------------------------------------------------- all-goals evaluation (evaluation.py)


def test_all_goals_callback_builds_the_tabular_eval_env_from_the_training_env_and_records_metrics() -> None:
    """Without an eval env, a TabularIMGEP run is evaluated on TabularGoalEnv(gym.make(id, **kwargs)): the same
    layout (env kwargs) as training; each row has the scheduled step, finite success, entropy and coverage."""
    from sb3_gcrl.imgep import TabularGoalEnv, TabularIMGEP
    from sb3_gcrl.post_exploration import AllGoalsEvalCallback
    from sb3_gcrl.post_exploration.evaluation import ALL_GOALS_COLUMNS

    model = TabularIMGEP("TabularGoalPolicy", gym.make("GCRL/LavaGapTabular-v0", layout_seed=3), seed=0)
    callback = AllGoalsEvalCallback(eval_freq=500)
    model.learn(1_000, callback=callback, log_interval=0)
    assert isinstance(callback.eval_env, TabularGoalEnv)
    assert callback.eval_env.unwrapped.spec.kwargs["layout_seed"] == 3
    np.testing.assert_array_equal(callback.eval_env.reachable_goals, model.goal_env.reachable_goals)
    assert [row["timesteps"] for row in callback.records] == [0, 500, 1_000]
    for row in callback.records:
        assert list(row) == list(ALL_GOALS_COLUMNS)
        assert 0 <= row["all_goals_success"] <= 1 and row["n_goals"] == len(model.goal_env.reachable_goals)
    first, last = callback.records[0], callback.records[-1]
    assert first["visitation_entropy"] == 0.0 and first["coverage"] == 0.0  # nothing visited yet
    # counts at the last evaluation (the agent updates them at the end of each episode)
    assert 0 < last["visitation_entropy"] <= model.visitation_entropy() + 0.1
    assert 0 < last["coverage"] <= model.coverage()


def test_all_goals_callback_rebuilds_the_run_wrapper_for_deep_agents_and_names_its_goal_grid() -> None:
    """Deep agents: the eval env is the registered env with the training env's recreatable wrappers (the
    PostExplorationWrapper, episodic); ``goals="maze_cells"`` is 4 goals per free cell; entropy and coverage come
    from the training envs' visit counts."""
    from stable_baselines3 import SAC
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_gcrl.post_exploration import AllGoalsEvalCallback
    from sb3_gcrl.post_exploration.metrics import training_visit_counts

    kwargs = {"tau": 0.01, "goal_low": [-1.5, -1.5], "goal_high": [1.5, 1.5], "n_bins": 10}
    env = make_vec_env(
        "GCRL/PointUMazeGoal-v0",
        wrapper_class=PostExplorationWrapper,
        wrapper_kwargs={"n_pe": 5, "scheduler_kwargs": kwargs},
    )
    model = SAC("MultiInputPolicy", env, learning_starts=1_000, policy_kwargs={"net_arch": [8]}, seed=0)
    callback = AllGoalsEvalCallback(eval_freq=100, goals="maze_cells", max_steps=5)
    model.learn(200, callback=[PostExplorationCallback(require_executed_actions=False), callback])
    assert isinstance(callback.eval_env, PostExplorationWrapper) and not callback.eval_env.training
    assert callback.goals.shape == (28, 2)  # the U-maze has 7 free cells
    assert [row["timesteps"] for row in callback.records] == [0, 100, 200]
    counts = training_visit_counts(model.get_env())
    assert counts is not None and counts.sum() > 0
    assert callback.records[-1]["visitation_entropy"] == pytest.approx(visitation_entropy(counts))
    assert callback.records[-1]["coverage"] == pytest.approx(coverage(counts))


def test_all_goals_callback_refuses_unknown_goal_grids_and_grids_of_other_envs() -> None:
    from sb3_gcrl.post_exploration import AllGoalsEvalCallback
    from sb3_gcrl.post_exploration.evaluation import GOAL_GRIDS

    with pytest.raises(ValueError, match="Unknown goal grid 'maze'.*maze_cells"):
        AllGoalsEvalCallback(goals="maze")
    with pytest.raises(ValueError, match="max_steps must be >= 1"):
        AllGoalsEvalCallback(max_steps=0)
    with pytest.raises(TypeError, match="needs a Fetch env"):
        GOAL_GRIDS["fetch_target_grid"](gym.make("GCRL/PointUMazeGoal-v0"))
    with pytest.raises(TypeError, match="needs a maze env"):
        GOAL_GRIDS["maze_cells"](gym.make("GCRL/GrowingTreeGoal-v0"))
