"""Tabular IMGEP (thesis Ch. 6, Algorithm 3): Q-learning updates, relabeling, post-exploration, save/load."""

from __future__ import annotations

import warnings
from functools import partial

import gymnasium as gym
import numpy as np
import pytest
from envs import ChainEnv as Chain
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, EvalCallback, StopTrainingOnMaxEpisodes
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from stable_baselines3.common.evaluation import evaluate_policy

import sb3_gcrl  # noqa: F401
from sb3_gcrl.imgep import TabularGoalEnv, TabularGoalPolicy, TabularIMGEP, minigrid_reachable_cells
from sb3_gcrl.post_exploration import AllGoalsEvalCallback, FixedSteps, ProportionalSteps, evaluate_all_goals

#: states 0..5 on a line, start 0; action 1 moves right, 0 left; no reward, truncation after 20 steps
ChainEnv = partial(Chain, n=6, horizon=20, goal_reward=0.0, terminal_goal=False)
#: ChainEnv whose own task is to reach the last state (reward 1, terminated there)
ChainTaskEnv = partial(Chain, n=6, horizon=20)


def make_model(**kwargs) -> TabularIMGEP:
    kwargs.setdefault("seed", 0)
    return TabularIMGEP("TabularGoalPolicy", ChainEnv(), **kwargs)


def test_q_update_matches_eq_6_2_by_hand() -> None:
    model = make_model(learning_rate=0.5, gamma=0.9)
    q = model.policy.q
    q[2, 3, 1] = 0.8  # from state 2, going right is worth 0.8 for goal 3
    # one trajectory 0 -(1)-> 1 -(1)-> 2, learned for goals 2 and 3
    model._states[:2], model._actions[:2], model._next_states[:2] = [0, 1], [1, 1], [1, 2]
    model._next_goals[:2], model._terminals[:2] = [1, 2], [False, False]
    model._update(2, np.array([2, 3]))
    # backwards: t=1 (1 -> 2): goal 2 hit: target 1 -> 0.5; goal 3: target 0.9 * 0.8 = 0.72 -> 0.36
    assert q[1, 2, 1] == pytest.approx(0.5)
    assert q[1, 3, 1] == pytest.approx(0.36)
    # t=0 (0 -> 1): goal 2: 0.9 * max Q[1, 2] = 0.45 -> 0.225; goal 3: 0.9 * 0.36 * 0.5 = 0.162
    assert q[0, 2, 1] == pytest.approx(0.225)
    assert q[0, 3, 1] == pytest.approx(0.162)
    assert q[0, :, 0].sum() == 0 and q[1, :, 0].sum() == 0


def test_env_termination_is_terminal_for_every_goal() -> None:
    model = make_model(learning_rate=1.0, gamma=0.9)
    model.policy.q[1, 4, :] = 1.0
    model._states[0], model._actions[0], model._next_states[0] = 0, 1, 1
    model._next_goals[0], model._terminals[0] = 1, True  # e.g. stepped into lava
    model._update(1, np.array([4]))
    assert model.policy.q[0, 4, 1] == 0.0


def test_hindsight_goals_relabel_half_and_the_whole_post_exploration_part() -> None:
    model = make_model(relabel_fraction=0.5)
    model._next_goals[:10] = np.arange(10) + 100  # all distinct, so the count of goals is the count of states
    goals = model._hindsight_goals(10, reached_at=5, goal=7)
    assert set(range(106, 110)) <= set(goals)  # post-exploration part (t = 6..9) always relabeled
    assert len(goals) == 5 + 1  # ceil(0.5 * 10) states + the commanded goal
    assert 7 in goals
    goals = model._hindsight_goals(10, reached_at=1, goal=3)  # post part (8) larger than the budget (5)
    assert set(range(102, 110)) <= set(goals)


class RecordPostExploration(BaseCallback):
    def __init__(self) -> None:
        super().__init__()
        self.flags: list[bool] = []

    def _on_step(self) -> bool:
        self.flags.append(bool(self.locals["post_exploring"]))
        return True


def test_post_exploration_starts_only_on_success_and_lasts_n_pe_steps() -> None:
    model = make_model(epsilon=0.0, post_exploration_rule=FixedSteps(3))
    model.policy.q[:, :, 1] = 1.0  # greedy: always right, reaches goal 4 after 4 steps
    model._sample_goal = lambda: 4  # type: ignore[method-assign]
    model.goal_space.add(np.array([[0.0]]))
    recorder = RecordPostExploration()
    model.learn(70, callback=recorder, log_interval=0)
    first = recorder.flags[:7]
    assert first == [False] * 4 + [True] * 3  # goal reached on step 4, then exactly n_pe = 3 random steps
    assert model._n_reached == model._n_episodes
    assert model._n_post_exploration_steps == 3 * model._n_episodes


def test_no_post_exploration_without_success_or_when_switched_off() -> None:
    model = make_model(epsilon=0.0, post_exploration_rule=FixedSteps(3))
    model.policy.q[:, :, 0] = 1.0  # greedy: always left, never reaches goal 4
    model._sample_goal = lambda: 4  # type: ignore[method-assign]
    model.goal_space.add(np.array([[0.0]]))
    recorder = RecordPostExploration()
    model.learn(40, callback=recorder, log_interval=0)
    assert not any(recorder.flags) and model._n_post_exploration_steps == 0
    assert len(recorder.flags) == 40  # two full 20-step episodes
    off = make_model(epsilon=0.0, post_exploration=False)
    off.policy.q[:, :, 1] = 1.0
    off._sample_goal = lambda: 4  # type: ignore[method-assign]
    off.goal_space.add(np.array([[0.0]]))
    off.learn(40, log_interval=0)
    assert off._n_post_exploration_steps == 0 and off._n_episodes == 10  # every episode ends at the goal


def test_proportional_post_exploration_length_and_executed_actions_are_stored() -> None:
    model = make_model(epsilon=0.0, post_exploration_rule=ProportionalSteps(0.5))
    model.policy.q[:, :, 1] = 1.0
    model._sample_goal = lambda: 4  # type: ignore[method-assign]
    model.goal_space.add(np.array([[0.0]]))
    env = model.goal_env.env
    env.executed.clear()
    model.learn(6, log_interval=0)
    assert model._n_episodes == 1 and model._n_post_exploration_steps == 2  # ceil(0.5 * 4) post-exploration steps
    np.testing.assert_array_equal(model._actions[:6], env.executed[:6])
    assert model._actions[:4].tolist() == [1, 1, 1, 1]


def test_goal_sampling_follows_eq_6_5() -> None:
    model = make_model(tau=1.0)
    model.goal_space.counts[[1, 2, 5]] = [1, 2, 4]
    samples = np.array([model._sample_goal() for _ in range(20_000)])
    freq = np.array([(samples == g).mean() for g in (1, 2, 5)])
    np.testing.assert_allclose(freq, np.array([1, 0.5, 0.25]) / 1.75, atol=0.015)
    model.tau = 0.0
    samples = np.array([model._sample_goal() for _ in range(6_000)])
    np.testing.assert_allclose([(samples == g).mean() for g in (1, 2, 5)], 1 / 3, atol=0.03)


def test_first_episode_is_random_and_initialises_the_goal_space() -> None:
    model = make_model()
    assert model.goal_space.n_visited == 0
    model.learn(20, log_interval=0)
    assert model.goal_space.counts.sum() == 21  # 20 visited states + the start
    assert model.goal_space.n_visited >= 2


def test_seeding_determinism_and_save_load_round_trip(tmp_path) -> None:
    a = make_model(seed=3)
    b = make_model(seed=3)
    a.learn(500, log_interval=0)
    b.learn(500, log_interval=0)
    np.testing.assert_array_equal(a.policy.q, b.policy.q)
    assert a.policy.q.any()
    a.save(tmp_path / "imgep")
    loaded = TabularIMGEP.load(tmp_path / "imgep", env=ChainEnv())
    np.testing.assert_array_equal(loaded.policy.q, a.policy.q)
    obs = {"observation": np.arange(6), "desired_goal": np.full(6, 5), "achieved_goal": np.arange(6)}
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], a.predict(obs, deterministic=True)[0])
    assert loaded.epsilon == a.epsilon and loaded.post_exploration_rule.p_pe == 0.5
    loaded.learn(100, log_interval=0)  # runtime state rebuilt on load


def test_bad_input_raises_clear_errors() -> None:
    with pytest.raises(TypeError, match="Discrete observation"):
        TabularIMGEP("TabularGoalPolicy", "CartPole-v1")
    with pytest.raises(ValueError, match="learning_rate"):
        make_model(learning_rate=1.5)
    with pytest.raises(ValueError, match=r"learning_rate \(schedule at progress_remaining=1.0\) must be a number in"):
        make_model(learning_rate=lambda progress_remaining: 5.0)  # a schedule is checked as a constant is
    with pytest.raises(ValueError, match="stats_window_size must be >= 1"):
        make_model(stats_window_size=0)
    with pytest.raises(ValueError, match="tau"):
        make_model(tau=float("nan"))
    with pytest.raises(TypeError, match="post_exploration_rule"):
        make_model(post_exploration_rule=0.5)
    with pytest.raises(ValueError, match="goal_of_state"):
        TabularGoalEnv(ChainEnv(), goal_of_state=np.zeros(3, dtype=int))
    with pytest.raises(TypeError, match="Dict observation space"):
        TabularGoalPolicy(spaces.Discrete(4), spaces.Discrete(2))


def test_tabular_goal_env_passes_env_checkers_and_rewards_eq_6_6() -> None:
    env = TabularGoalEnv(gym.make("GCRL/FourRoomsTabular-v0"))
    gym_check_env(env, skip_render_check=True)
    sb3_check_env(TabularGoalEnv(gym.make("GCRL/FourRoomsTabular-v0")), warn=False)
    np.testing.assert_array_equal(env.compute_reward(np.array([3, 4, 5]), np.array([3, 3, 5]), None), [1, 0, 1])
    obs, _ = env.reset(options={"goal": 42})
    assert obs["desired_goal"] == 42 and obs["achieved_goal"] == obs["observation"] // 4


def test_minigrid_reachable_cells_exclude_walls_and_lava() -> None:
    four_rooms = gym.make("GCRL/FourRoomsTabular-v0")
    cells = minigrid_reachable_cells(four_rooms)
    grid = four_rooms.unwrapped.grid
    width = four_rooms.unwrapped.width
    assert all(grid.get(c % width, c // width) is None or grid.get(c % width, c // width).type == "goal" for c in cells)
    assert 200 < cells.size < 17 * 17  # four rooms minus walls
    lava = gym.make("GCRL/LavaGapTabular-v0")
    lava_cells = minigrid_reachable_cells(lava)
    w = lava.unwrapped.width
    types = [getattr(lava.unwrapped.grid.get(c % w, c // w), "type", "empty") for c in lava_cells]
    assert "lava" not in types and "wall" not in types and "goal" in types


def test_all_goals_evaluation_with_a_hand_made_table() -> None:
    model = make_model()
    q = model.policy.q
    q[:, 3:, 1] = 1.0  # goals 3..5: go right (reached); goals 0..2 keep all-zero rows -> action 0 (left)
    env = TabularGoalEnv(ChainEnv())
    success = evaluate_all_goals(model, env, goals=np.arange(6))
    # goal 0: "left" at the start stays on 0, which reaches it; goals 1, 2: the agent sits at 0 in a loop, stopped
    np.testing.assert_array_equal(success, [True, False, False, True, True, True])


def test_imgep_learns_four_rooms_and_logs_metrics() -> None:
    env = gym.make("GCRL/FourRoomsTabular-v0")
    model = TabularIMGEP("TabularGoalPolicy", env, seed=0)
    callback = AllGoalsEvalCallback(TabularGoalEnv(gym.make("GCRL/FourRoomsTabular-v0")), eval_freq=10_000)
    model.learn(20_000, callback=callback, log_interval=50)
    assert callback.success_rates[0] < 0.01  # untrained greedy policy only "reaches" its start cell
    assert callback.success_rates[-1] > 0.5
    assert model.coverage() > 0.5 and model.visitation_entropy() > 3.0


def test_evaluate_policy_on_random_reachable_goals() -> None:
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.monitor import Monitor

    model = TabularIMGEP("TabularGoalPolicy", "GCRL/LavaGapTabular-v0", seed=0)
    model.learn(10_000, log_interval=0)
    env = Monitor(TabularGoalEnv(gym.make("GCRL/LavaGapTabular-v0")))  # goals drawn from the reachable cells
    mean_reward, _ = evaluate_policy(model, env, n_eval_episodes=20)
    assert mean_reward > 0.8  # reward 1 exactly when the commanded cell is reached (Eq. 6.6)


def test_all_goals_eval_callback_keeps_its_schedule_when_steps_skip_multiples() -> None:
    """With n_envs=3 the step count goes 3, 6, 9, 12...: an eval_freq of 10 must still evaluate about every 10
    steps (at the first count at or past each multiple), not only at multiples of 30."""
    callback = AllGoalsEvalCallback(eval_env=None, eval_freq=10)  # type: ignore[arg-type]
    evaluated_at: list[int] = []
    callback._evaluate = lambda: evaluated_at.append(callback.num_timesteps)  # type: ignore[method-assign]

    class Model:
        num_timesteps = 0

    callback.model = Model()  # type: ignore[assignment]
    callback.on_training_start({}, {})
    for steps in range(3, 61, 3):
        Model.num_timesteps = steps
        callback.on_step()
    assert evaluated_at == [0, 12, 21, 30, 42, 51, 60]


def test_predict_evaluate_policy_and_eval_callback_take_the_plain_envs_states() -> None:
    """A bare state of the plain env commands the env's own task goal (here given; MiniGrid: the goal tile)."""
    model = TabularIMGEP("TabularGoalPolicy", TabularGoalEnv(ChainTaskEnv(), terminate_at_goal=False, task_goal=5))
    assert model.task_goal == 5
    model.policy.q[:, 5, 1] = 1.0  # towards the task goal: always right; any other goal: all-zero rows -> left
    assert model.predict(np.int64(2))[0] == 1
    np.testing.assert_array_equal(model.predict(np.arange(6))[0], np.ones(6))
    mean_reward, _ = evaluate_policy(model, ChainTaskEnv(), n_eval_episodes=2)
    assert mean_reward == 1.0
    evaluation = EvalCallback(ChainTaskEnv(), eval_freq=1, n_eval_episodes=2, verbose=0)
    model.learn(1, callback=evaluation, log_interval=0)  # evaluates after step 1, before the first update
    assert evaluation.last_mean_reward == 1.0
    four_rooms = TabularGoalEnv(gym.make("GCRL/FourRoomsTabular-v0"))
    base = four_rooms.unwrapped
    assert base.grid.get(four_rooms.task_goal % base.width, four_rooms.task_goal // base.width).type == "goal"


def test_predict_on_a_bare_state_without_a_task_goal_refuses_clearly() -> None:
    model = make_model()  # ChainEnv: no task goal known
    assert model.task_goal is None
    with pytest.raises(ValueError, match="task_goal=g"):
        model.predict(np.int64(0))
    obs = {"observation": np.arange(6), "desired_goal": np.full(6, 5)}
    assert model.predict(obs)[0].shape == (6,)  # goal-conditioned observations always work
    with_goal = TabularIMGEP("TabularGoalPolicy", TabularGoalEnv(ChainEnv(), task_goal=3))
    with pytest.raises(ValueError, match=r"integers in \[0, 6\)"):
        with_goal.predict(np.array([7]))
    with pytest.raises(ValueError, match="task_goal"):
        TabularGoalEnv(ChainEnv(), task_goal=6)


def test_the_policy_refuses_a_bare_state_naming_the_models_predict() -> None:
    model = TabularIMGEP("TabularGoalPolicy", TabularGoalEnv(ChainTaskEnv(), terminate_at_goal=False, task_goal=5))
    model.policy.q[:, 5, 1] = 1.0
    for bare in (np.int64(2), np.arange(6)):
        with pytest.raises(ValueError, match=r"goal-conditioned.*TabularIMGEP\.predict"):
            model.policy.predict(bare)
    goal_obs = {"observation": np.arange(6), "desired_goal": np.full(6, 5)}
    np.testing.assert_array_equal(model.policy.predict(goal_obs)[0], model.predict(np.arange(6))[0])


def test_the_env_is_wrapped_in_a_monitor_as_sb3_does() -> None:
    from stable_baselines3.common.monitor import Monitor

    model = TabularIMGEP("TabularGoalPolicy", TabularGoalEnv(ChainTaskEnv(), terminate_at_goal=False, task_goal=5))
    env = model.get_env()
    assert env is not None and env.env_is_wrapped(Monitor) == [True]
    model.policy.q[:, 5, 1] = 1.0  # always right, towards the task goal
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # evaluate_policy warns on an env without a Monitor
        rewards, lengths = evaluate_policy(model, env, n_eval_episodes=2, return_episode_rewards=True)
    assert len(rewards) == len(lengths) == 2 and all(0 < length <= 20 for length in lengths)
    model.learn(30, log_interval=0)  # learning goes on beside the Monitor
    already = TabularIMGEP("TabularGoalPolicy", Monitor(ChainTaskEnv()))
    assert already.get_env().env_is_wrapped(Monitor) == [True]  # not wrapped twice: SB3's check of the chain
    assert isinstance(already.get_env().envs[0], TabularGoalEnv)


class RecordLocals(BaseCallback):
    def __init__(self) -> None:
        super().__init__()
        self.steps: list[dict] = []

    def _on_step(self) -> bool:
        self.steps.append({key: self.locals[key] for key in ("new_obs", "rewards", "dones", "infos", "actions")})
        return True


def test_callbacks_get_sb3s_step_locals_and_stop_training_on_max_episodes_works() -> None:
    model = make_model(epsilon=0.0, post_exploration=False)
    model.policy.q[:, :, 1] = 1.0  # greedy: always right
    model._sample_goal = lambda: 3  # type: ignore[method-assign]
    model.goal_space.add(np.array([[0.0]]))
    recorder = RecordLocals()
    model.learn(10_000, callback=CallbackList([recorder, StopTrainingOnMaxEpisodes(max_episodes=2)]), log_interval=0)
    assert model.num_timesteps == 6  # two episodes of 3 steps (each ends at goal 3 without post-exploration)
    dones = [bool(step["dones"][0]) for step in recorder.steps]
    assert dones == [False, False, True, False, False, True]
    first = recorder.steps[0]
    assert first["new_obs"]["observation"].tolist() == [1] and first["new_obs"]["desired_goal"].tolist() == [3]
    assert first["actions"].tolist() == [1] and first["rewards"].shape == (1,)
    assert [float(step["rewards"][0]) for step in recorder.steps[:3]] == [0.0, 0.0, 1.0]  # Eq. 6.6 at the goal
    assert isinstance(first["infos"], list) and first["infos"][0]["is_success"] is False


def test_dones_mark_the_end_of_post_exploration_and_truncation() -> None:
    model = make_model(epsilon=0.0, post_exploration_rule=FixedSteps(2))
    model.policy.q[:, :, 1] = 1.0
    model._sample_goal = lambda: 3  # type: ignore[method-assign]
    model.goal_space.add(np.array([[0.0]]))
    recorder = RecordLocals()
    model.learn(5, callback=recorder, log_interval=0)
    assert [bool(step["dones"][0]) for step in recorder.steps] == [False] * 4 + [True]  # 3 to the goal + 2 random
    never = make_model(epsilon=0.0)
    never.policy.q[:, :, 0] = 1.0  # always left: never reaches goal 3, the episode is truncated after 20 steps
    never._sample_goal = lambda: 3  # type: ignore[method-assign]
    never.goal_space.add(np.array([[0.0]]))
    recorder = RecordLocals()
    never.learn(20, callback=recorder, log_interval=0)
    assert [bool(step["dones"][0]) for step in recorder.steps] == [False] * 19 + [True]


def test_set_random_seed_reseeds_the_agents_generator() -> None:
    reseeded = make_model(seed=0)
    reseeded.set_random_seed(7)
    reseeded.learn(300, log_interval=0)
    fresh = make_model(seed=7)
    fresh.learn(300, log_interval=0)
    np.testing.assert_array_equal(reseeded.policy.q, fresh.policy.q)
    np.testing.assert_array_equal(reseeded.goal_space.counts, fresh.goal_space.counts)


def test_a_loaded_model_continues_exactly_as_the_saved_one(tmp_path) -> None:
    model = make_model(seed=3)
    model.learn(300, log_interval=0)
    model.save(tmp_path / "imgep")
    model.learn(300, log_interval=0)
    loaded = TabularIMGEP.load(tmp_path / "imgep", env=ChainEnv())
    loaded.learn(300, log_interval=0)
    np.testing.assert_array_equal(loaded.policy.q, model.policy.q)
    np.testing.assert_array_equal(loaded.goal_space.counts, model.goal_space.counts)


def test_set_env_takes_the_plain_env_that_load_takes(tmp_path) -> None:
    model = make_model(seed=0)
    model.set_env(ChainEnv())
    assert isinstance(model.goal_env, TabularGoalEnv) and model.goal_env.terminate_at_goal is False
    model.learn(50, log_interval=0)
    model.set_env(TabularGoalEnv(ChainEnv(), terminate_at_goal=False, task_goal=2))
    assert model.task_goal == 2
    with pytest.raises(TypeError, match="Discrete observation"):
        model.set_env(gym.make("CartPole-v1"))
