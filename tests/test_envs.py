"""Tests of the registered thesis tasks (``sb3_gcrl.envs``)."""

from __future__ import annotations

import warnings
from collections import deque

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_gcrl  # noqa: F401  (registers the envs)
from sb3_gcrl.envs import (
    GCRL_ENV_IDS,
    MINATAR_ENV_IDS,
    GrowingTreeGoalEnv,
    PointMazeGoalTaskEnv,
    PointMazeTaskEnv,
    TabularMiniGridObservation,
    WindyGridEnv,
    decode_state,
    encode_state,
    make_tabular_minigrid,
    windy_grid_optimal_value,
    windy_grid_policy_value,
    windy_grid_value_iteration,
)
from sb3_gcrl.envs.point_maze import FOUR_ROOMS_GOAL_CELL, FOUR_ROOMS_MAP, FOUR_ROOMS_START_CELL
from sb3_gcrl.envs.windy_grid import START_CELL, encode_cell

# Safety-Gym's task names PointGoal / CarGoal are episodic Box tasks, not goal-env variants.
GOAL_ENV_IDS = tuple(
    env_id for env_id in GCRL_ENV_IDS if "Goal-v" in env_id and env_id not in ("GCRL/PointGoal-v0", "GCRL/CarGoal-v0")
)


def _checked_env(env: gym.Env) -> gym.Env:
    """The object the checkers should see: our class itself, or the wrapper stack for wrapper-built envs."""
    return env if isinstance(env, TabularMiniGridObservation) or "Tabular" in env.spec.id else env.unwrapped


# ---------------------------------------------------------------------------------------------------------------
# Registry and API conformance
# ---------------------------------------------------------------------------------------------------------------
def test_ids_are_registered_under_the_namespace() -> None:
    assert len(GCRL_ENV_IDS) == len(set(GCRL_ENV_IDS)) == 14
    for env_id in GCRL_ENV_IDS + MINATAR_ENV_IDS:
        assert env_id in gym.registry, env_id
    assert all(env_id.startswith("GCRL/") for env_id in GCRL_ENV_IDS)


@pytest.mark.parametrize("env_id", GCRL_ENV_IDS)
def test_gymnasium_and_sb3_env_checkers(env_id: str) -> None:
    env = gym.make(env_id)
    target = _checked_env(env)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # infinite velocity bounds, non-normalised GrowingTree actions
        # "human" rendering needs a display; MuJoCo envs are render-checked nowhere on a headless CI machine.
        gym_check_env(target, skip_render_check="Point" in env_id)
        sb3_check_env(target, warn=False)
    env.close()


@pytest.mark.parametrize("env_id", GCRL_ENV_IDS)
def test_seeding_is_deterministic(env_id: str) -> None:
    def rollout(seed: int) -> list:
        env = gym.make(env_id)
        env.action_space.seed(seed)
        obs, _ = env.reset(seed=seed)
        trace = [obs]
        for _ in range(30):
            obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            trace.append((obs, reward, terminated, truncated))
            if terminated or truncated:
                obs, _ = env.reset()
        env.close()
        return trace

    first, second = rollout(3), rollout(3)
    assert repr(first) == repr(second)


@pytest.mark.parametrize("env_id", MINATAR_ENV_IDS)
def test_minatar_games_are_available(env_id: str) -> None:
    env = gym.make(env_id)
    obs, _ = env.reset(seed=0)
    assert obs.shape[:2] == (10, 10)
    env.step(env.action_space.sample())


def test_minatar_envs_are_registered_as_minatar_registers_them(monkeypatch: pytest.MonkeyPatch) -> None:
    import minatar.gym

    registered: dict[str, tuple[str, dict]] = {}
    monkeypatch.setattr(
        minatar.gym, "register", lambda id, entry_point, kwargs: registered.update({id: (entry_point, kwargs)})
    )
    minatar.gym.register_envs()
    assert set(MINATAR_ENV_IDS) <= set(registered)
    for env_id, (entry_point, kwargs) in registered.items():
        assert (gym.spec(env_id).entry_point, gym.spec(env_id).kwargs) == (entry_point, kwargs), env_id


@pytest.mark.parametrize("env_id", GOAL_ENV_IDS)
def test_goal_envs_declare_task_relevant_goals(env_id: str) -> None:
    env = gym.make(env_id)
    base = env.unwrapped
    rng = np.random.default_rng(0)
    goal_space = env.observation_space["desired_goal"]
    for sample in (base.sample_initial_goal, base.sample_evaluation_goal):
        goal = sample(rng)
        assert goal.shape == goal_space.shape
        assert goal_space.contains(goal.astype(goal_space.dtype))
    obs, info = env.reset(seed=1)
    assert "is_success" in info
    # vectorised compute_reward: a batch of 5 returns shape (5,) and agrees with the single call
    achieved = np.repeat(obs["achieved_goal"][None], 5, axis=0)
    desired = np.stack([base.sample_evaluation_goal(rng) for _ in range(4)] + [obs["achieved_goal"]])
    rewards = base.compute_reward(achieved, desired, [{}] * 5)
    assert rewards.shape == (5,)
    assert rewards[-1] > 0
    single = base.compute_reward(obs["achieved_goal"], obs["desired_goal"], {})
    assert float(single) == float(base.compute_reward(achieved[:1], obs["desired_goal"][None], [{}])[0])


@pytest.mark.parametrize("env_id", ["GCRL/GrowingTreeGoal-v0", "GCRL/PointUMazeGoal-v0"])
def test_goal_envs_work_with_sb3_her_relabelling(env_id: str) -> None:
    from stable_baselines3 import SAC, HerReplayBuffer

    env = gym.make(env_id, max_episode_steps=20)
    model = SAC(
        "MultiInputPolicy",
        env,
        replay_buffer_class=HerReplayBuffer,
        learning_starts=1_000,  # collect only: no gradient step is needed to exercise relabelling
        policy_kwargs={"net_arch": [8]},
        seed=0,
    )
    model.learn(100)
    batch = model.replay_buffer.sample(64)
    # HER recomputed the rewards of relabelled goals through the env's vectorised compute_reward
    expected = env.unwrapped.compute_reward(
        batch.next_observations["achieved_goal"].numpy(), batch.observations["desired_goal"].numpy(), {}
    )
    np.testing.assert_allclose(batch.rewards.numpy().ravel(), expected)
    assert 0 < expected.sum() < 64  # some relabelled goals are reached (future strategy), some are not


# ---------------------------------------------------------------------------------------------------------------
# GrowingTree
# ---------------------------------------------------------------------------------------------------------------
def test_growing_tree_optimal_policy_reaches_goal_in_ten_steps() -> None:
    env = gym.make("GCRL/GrowingTree-v0")
    obs, _ = env.reset(seed=0)
    assert obs.dtype == np.float32 and obs[0] == 0.0
    for step in range(1, 11):
        obs, reward, terminated, truncated, info = env.step(np.array([0.1], dtype=np.float32))
        if step < 10:  # after 9 steps the height is 0.9: exactly on the tolerance boundary, not reached
            assert (reward, terminated, info["is_success"]) == (0.0, False, False), step
    assert (reward, terminated, info["is_success"]) == (1.0, True, True)
    assert obs[0] == pytest.approx(1.0, abs=1e-5)


def test_growing_tree_clips_actions_and_height_and_truncates() -> None:
    env = gym.make("GCRL/GrowingTree-v0")
    env.reset(seed=0)
    obs, *_ = env.step(np.array([5.0]))  # clipped to 0.1
    assert obs[0] == pytest.approx(0.1)
    for _ in range(60):
        obs, reward, terminated, truncated, _ = env.step(np.array([-0.1]))
    assert obs[0] == pytest.approx(-2.0) and reward == 0.0
    steps = 61
    while not truncated:
        _, _, terminated, truncated, _ = env.step(np.array([-0.1]))
        steps += 1
    assert steps == 200 and not terminated


def test_growing_tree_goal_variant() -> None:
    env = GrowingTreeGoalEnv()
    obs, _ = env.reset(seed=0, options={"goal": -0.5})
    assert obs["desired_goal"][0] == pytest.approx(-0.5)
    for _ in range(5):
        obs, reward, terminated, _, info = env.step(np.array([-0.1]))
    assert reward == 1.0 and info["is_success"] and not terminated  # the goal variant does not terminate
    assert reward == env.compute_reward(obs["achieved_goal"], obs["desired_goal"], info)


def test_growing_tree_bad_input() -> None:
    with pytest.raises(ValueError, match=r"goal must lie in \[-2, 2\]"):
        gym.make("GCRL/GrowingTree-v0", goal=3.0)
    env = gym.make("GCRL/GrowingTree-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="non-finite action"):
        env.unwrapped.step(np.array([np.nan]))
    with pytest.raises(ValueError, match="Unknown reset options"):
        env.reset(options={"goal": 0.5})  # only the goal variant takes a goal


# ---------------------------------------------------------------------------------------------------------------
# WindyGrid
# ---------------------------------------------------------------------------------------------------------------
def _walk(env: gym.Env, actions: list[int]) -> tuple[int, float, bool, dict]:
    total = 0.0
    for action in actions:
        obs, reward, terminated, _, info = env.step(action)
        total += reward
        if terminated:
            break
    return int(obs), total, terminated, info


RIGHT, UP, DOWN = 1, 0, 2


def test_windy_grid_goal_without_wind_and_trap_with_wind() -> None:
    calm = gym.make("GCRL/WindyGrid-v0", wind_probability=0.0)
    obs, _ = calm.reset(seed=0)
    assert obs == encode_cell(*START_CELL) == 30
    state, total, terminated, info = _walk(calm, [RIGHT] * 7)
    assert (state, total, terminated, info["is_success"]) == (37, -7.0, True, True)

    stormy = gym.make("GCRL/WindyGrid-v0", wind_probability=1.0)
    stormy.reset(seed=0)
    state, total, terminated, info = _walk(stormy, [RIGHT] * 7)
    assert (state, total, terminated, info["is_success"]) == (27, -106.0, True, False)  # trap (2, 7)


def test_windy_grid_wind_only_in_column_six_and_can_push_onto_goal() -> None:
    env = gym.make("GCRL/WindyGrid-v0", wind_probability=1.0)
    env.reset(seed=0)
    state, total, terminated, _ = _walk(env, [DOWN] + [RIGHT] * 6)  # row 4, columns 0..6: no gust before 6
    assert (state, total, terminated) == (46, -7.0, False)
    state, reward, terminated, _, info = env.step(RIGHT)  # from (4, 6) the gust lifts the agent onto the goal
    assert (state, reward, terminated, info["gust"], info["is_success"]) == (37, -1.0, True, True, True)


def test_windy_grid_transition_model_matches_sampled_dynamics() -> None:
    env = WindyGridEnv()
    P, R, terminal = env.transition_model()
    assert P.shape == (70, 4, 70) and np.allclose(P.sum(axis=2), 1.0)
    assert terminal.sum() == 2
    assert P[36, RIGHT, 27] == pytest.approx(0.2) and P[36, RIGHT, 37] == pytest.approx(0.8)
    assert R[36, RIGHT] == pytest.approx(0.8 * -1 + 0.2 * -100)
    # empirical frequencies from (3, 6)
    counts = np.zeros(70)
    env.reset(seed=0)
    for _ in range(4000):
        env._cell[:] = (3, 6)
        state, *_ = env.step(RIGHT)
        counts[state] += 1
    assert counts[27] / 4000 == pytest.approx(0.2, abs=0.03)


def test_windy_grid_value_iteration_optimum_and_episodic_control_trap() -> None:
    assert windy_grid_optimal_value() == pytest.approx(-8.8)
    V, policy = windy_grid_value_iteration(gamma=1.0)
    # the policy episodic control prefers: straight right along row 3 (best-ever return -7, the highest possible)
    risky = policy.copy()
    risky[30:37] = RIGHT
    risky_value = windy_grid_policy_value(risky)[30]
    assert risky_value == pytest.approx(0.8 * -7 + 0.2 * -106)
    assert risky_value < V[30] < -7.0
    for gamma in (0.9, 0.99):
        assert windy_grid_policy_value(risky, gamma=gamma)[30] < windy_grid_optimal_value(gamma=gamma)


def test_windy_grid_optimum_matches_monte_carlo_rollouts_of_the_optimal_policy() -> None:
    _, policy = windy_grid_value_iteration(gamma=1.0)
    env = gym.make("GCRL/WindyGrid-v0")
    returns = []
    for episode in range(3000):
        state, _ = env.reset(seed=episode)
        total, done = 0.0, False
        while not done:
            state, reward, terminated, truncated, _ = env.step(int(policy[state]))
            total += reward
            done = terminated or truncated
        returns.append(total)
    assert np.mean(returns) == pytest.approx(windy_grid_optimal_value(), abs=0.05)
    assert set(returns) == {-8.0, -9.0}


def test_windy_grid_bad_input() -> None:
    with pytest.raises(ValueError, match=r"wind_probability must lie in \[0, 1\]"):
        WindyGridEnv(wind_probability=1.5)
    env = WindyGridEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="Invalid action"):
        env.step(4)
    with pytest.raises(ValueError, match="never terminates"):
        windy_grid_policy_value(np.full(70, 3))  # always "left": never reaches a terminal state


# ---------------------------------------------------------------------------------------------------------------
# Sparse MountainCarContinuous
# ---------------------------------------------------------------------------------------------------------------
def test_sparse_mountain_car_pays_only_at_the_flag() -> None:
    env = gym.make("GCRL/SparseMountainCarContinuous-v0")
    assert env.spec.max_episode_steps == 999
    obs, _ = env.reset(seed=0)
    rewards = []
    for _ in range(999):  # bang-bang energy pumping reaches the flag
        obs, reward, terminated, truncated, info = env.step(np.array([1.0 if obs[1] >= 0 else -1.0]))
        rewards.append(reward)
        if terminated or truncated:
            break
    assert terminated and info["is_success"]
    assert rewards[-1] == 100.0 and all(r == 0.0 for r in rewards[:-1])


# ---------------------------------------------------------------------------------------------------------------
# PointUMaze / Point4Rooms
# ---------------------------------------------------------------------------------------------------------------
def _drive(env: gym.Env, waypoints: list[tuple[int, int]], max_steps: int) -> tuple[int, float, bool, bool, dict]:
    """Waypoint P-controller through cell centres; returns (steps, last reward, terminated, truncated, info)."""
    base = env.unwrapped
    obs, _ = env.reset(seed=0)
    targets = [base.maze.cell_rowcol_to_xy(np.array(cell)) for cell in waypoints] + [base.goal]
    k = steps = 0
    while steps < max_steps:
        steps += 1
        state = obs["observation"] if isinstance(obs, dict) else obs
        if k < len(targets) - 1 and np.linalg.norm(targets[k] - state[:2]) < 0.3:
            k += 1
        obs, reward, terminated, truncated, info = env.step(np.clip(4 * (targets[k] - state[:2]) - state[2:], -1, 1))
        if terminated or truncated:
            break
    return steps, reward, terminated, truncated, info


U_WAYPOINTS = [(3, 3), (1, 3), (1, 1)]
FOUR_ROOMS_WAYPOINTS = [(8, 1), (8, 5), (8, 8), (5, 8), (3, 8), (1, 9)]


@pytest.mark.parametrize(
    ("env_id", "waypoints"),
    [("GCRL/PointUMaze-v0", U_WAYPOINTS), ("GCRL/Point4Rooms-v0", FOUR_ROOMS_WAYPOINTS)],
)
def test_point_maze_episodic_terminates_at_goal(env_id: str, waypoints: list) -> None:
    env = gym.make(env_id)
    steps, reward, terminated, truncated, info = _drive(env, waypoints, env.spec.max_episode_steps)
    assert terminated and not truncated and reward == 1.0 and info["is_success"]
    assert steps < env.spec.max_episode_steps / 2


def test_point_maze_random_policy_does_not_succeed_and_pays_nothing() -> None:
    env = gym.make("GCRL/PointUMaze-v0")
    env.action_space.seed(0)
    env.reset(seed=0)
    for _ in range(300):
        _, reward, terminated, _, info = env.step(env.action_space.sample())
        assert reward == 0.0 and not terminated and not info["is_success"]


@pytest.mark.parametrize(
    ("env_id", "waypoints"),
    [("GCRL/PointUMazeGoal-v0", U_WAYPOINTS), ("GCRL/Point4RoomsGoal-v0", FOUR_ROOMS_WAYPOINTS)],
)
def test_point_maze_goal_variant_reaches_goal_within_horizon_without_terminating(env_id: str, waypoints: list) -> None:
    env = gym.make(env_id)
    horizon = env.spec.max_episode_steps
    steps, reward, terminated, truncated, info = _drive(env, waypoints, horizon)
    assert steps == horizon and truncated and not terminated  # reached but not terminated
    assert reward == 1.0 and info["is_success"] and info["success"]


def test_point_maze_start_and_goal_regions() -> None:
    env = PointMazeGoalTaskEnv(
        maze_map=FOUR_ROOMS_MAP, start_cell=FOUR_ROOMS_START_CELL, goal_cell=FOUR_ROOMS_GOAL_CELL
    )
    start_xy = env.maze.cell_rowcol_to_xy(np.array(FOUR_ROOMS_START_CELL))
    goal_xy = env.maze.cell_rowcol_to_xy(np.array(FOUR_ROOMS_GOAL_CELL))
    assert start_xy[0] < 0 and start_xy[1] < 0 and goal_xy[0] > 0 and goal_xy[1] > 0  # bottom-left -> top-right
    starts, goals = [], []
    for seed in range(30):
        obs, info = env.reset(seed=seed)
        starts.append(obs["achieved_goal"])
        goals.append(obs["desired_goal"])
        assert not info["is_success"]
    assert np.abs(np.array(starts) - start_xy).max() <= 0.1
    assert np.abs(np.array(goals) - goal_xy).max() <= 0.1
    assert np.unique(np.array(starts)[:, 0]).size == 30  # the noise is there
    obs, _ = env.reset(seed=0, options={"reset_pos": goal_xy + 0.2, "goal": goal_xy})
    np.testing.assert_allclose(obs["achieved_goal"], goal_xy + 0.2)
    np.testing.assert_allclose(obs["desired_goal"], goal_xy)
    _, reward, terminated, _, info = env.step(np.zeros(2))
    assert reward == 1.0 and info["is_success"] and not terminated


def test_point_maze_terminal_flag_configurable_and_non_goal_env_has_no_compute_reward() -> None:
    episodic = gym.make("GCRL/PointUMaze-v0")
    assert not hasattr(episodic.unwrapped, "compute_reward")  # SB3 would mistake it for a goal env
    goal_xy = episodic.unwrapped.maze.cell_rowcol_to_xy(np.array((1, 1)))
    episodic.reset(seed=0, options={"reset_pos": goal_xy})
    assert episodic.step(np.zeros(2))[2] is True
    terminating_goal_env = gym.make("GCRL/PointUMazeGoal-v0", terminate_at_goal=True)
    terminating_goal_env.reset(seed=0, options={"reset_pos": goal_xy})
    assert terminating_goal_env.step(np.zeros(2))[2] is True


def test_point_maze_bad_input() -> None:
    with pytest.raises(ValueError, match="is a wall cell"):
        PointMazeTaskEnv(start_cell=(2, 1))
    with pytest.raises(ValueError, match="outside the 5x5 maze map"):
        PointMazeTaskEnv(goal_cell=(7, 1))
    with pytest.raises(ValueError, match=r"start_noise must lie in \[0, 0.5\)"):
        PointMazeTaskEnv(start_noise=0.7)
    env = PointMazeTaskEnv()
    with pytest.raises(ValueError, match="Unknown reset options"):
        env.reset(options={"goal_position": (0, 0)})
    with pytest.raises(ValueError, match="lies outside the maze"):
        env.reset(options={"goal": (10.0, 0.0)})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="non-finite action"):
        env.step(np.array([np.nan, 0.0]))


# ---------------------------------------------------------------------------------------------------------------
# Tabular MiniGrid
# ---------------------------------------------------------------------------------------------------------------
TABULAR_IDS = ("GCRL/FourRoomsTabular-v0", "GCRL/LavaCrossingTabular-v0", "GCRL/LavaGapTabular-v0")


def test_tabular_encode_decode_round_trip() -> None:
    width, height = 9, 7
    indices = [encode_state(x, y, d, width) for y in range(height) for x in range(width) for d in range(4)]
    assert indices == list(range(width * height * 4))
    assert all(encode_state(*decode_state(i, width), width) == i for i in indices)
    assert decode_state(encode_state(3, 5, 2, width), width) == (3, 5, 2)


@pytest.mark.parametrize("env_id", TABULAR_IDS)
def test_tabular_observation_is_agent_pose_and_layout_is_fixed(env_id: str) -> None:
    env = gym.make(env_id)
    wrapper = env.get_wrapper_attr("decode")
    base = env.unwrapped
    assert env.action_space == gym.spaces.Discrete(3)
    assert env.observation_space.n == base.width * base.height * 4
    first, _ = env.reset(seed=0)
    grid = base.grid.encode().copy()
    assert wrapper(first) == (*map(int, base.agent_pos), base.agent_dir)
    env.action_space.seed(0)
    for _ in range(20):
        obs, *_ = env.step(env.action_space.sample())
        assert wrapper(obs) == (*map(int, base.agent_pos), base.agent_dir)
    second, _ = env.reset(seed=123)  # a different episode seed: same layout, same start pose
    assert second == first and np.array_equal(base.grid.encode(), grid)


@pytest.mark.parametrize("env_id", TABULAR_IDS)
def test_tabular_cached_layout_reset_equals_regenerated_reset(env_id: str) -> None:
    minigrid_id = gym.spec(env_id).kwargs["minigrid_id"]
    cached = make_tabular_minigrid(minigrid_id, layout_seed=2, cache_layout=True)
    regenerated = make_tabular_minigrid(minigrid_id, layout_seed=2, cache_layout=False)
    for env in (cached, regenerated):
        env.action_space.seed(0)
    for episode in range(3):
        first = [env.reset(seed=episode)[0] for env in (cached, regenerated)]
        assert first[0] == first[1]
        for _ in range(40):
            action = cached.action_space.sample()
            outcomes = [env.step(action)[:4] for env in (cached, regenerated)]
            assert outcomes[0] == outcomes[1]
            if outcomes[0][2] or outcomes[0][3]:
                break
        assert cached.unwrapped.step_count == regenerated.unwrapped.step_count
        assert np.array_equal(cached.unwrapped.grid.encode(), regenerated.unwrapped.grid.encode())


def test_tabular_layout_seed_selects_the_layout() -> None:
    layouts = set()
    for layout_seed in range(4):
        env = gym.make("GCRL/LavaCrossingTabular-v0", layout_seed=layout_seed)
        env.reset(seed=0)
        layouts.add(env.unwrapped.grid.encode().tobytes())
    assert len(layouts) > 1


def _plan(env: gym.Env, target: str) -> list[int]:
    """BFS over (x, y, dir) on the fixed layout to a pose from which 'forward' enters a cell of type target."""
    base = env.unwrapped
    moves = [(1, 0), (0, 1), (-1, 0), (0, -1)]  # MiniGrid directions 0 right, 1 down, 2 left, 3 up

    def cell_type(x: int, y: int) -> str | None:
        cell = base.grid.get(x, y)
        return None if cell is None else cell.type

    start = (*map(int, base.agent_pos), int(base.agent_dir))
    parents: dict[tuple, tuple | None] = {start: None}
    queue = deque([start])
    while queue:
        pose = queue.popleft()
        x, y, d = pose
        ahead = (x + moves[d][0], y + moves[d][1])
        if cell_type(*ahead) == target:
            actions = [2]
            while parents[pose] is not None:
                pose, action = parents[pose]
                actions.append(action)
            return actions[::-1]
        successors = [((x, y, (d - 1) % 4), 0), ((x, y, (d + 1) % 4), 1)]
        if cell_type(*ahead) is None:
            successors.append(((*ahead, d), 2))
        for nxt, action in successors:
            if nxt not in parents:
                parents[nxt] = (pose, action)
                queue.append(nxt)
    raise AssertionError(f"no path to {target}")


@pytest.mark.parametrize("env_id", TABULAR_IDS)
def test_tabular_goal_gives_minigrid_reward_and_success(env_id: str) -> None:
    env = gym.make(env_id, layout_seed=1)
    env.reset(seed=0)
    plan = _plan(env, "goal")
    for action in plan:
        _, reward, terminated, _, info = env.step(action)
    max_steps = env.unwrapped.max_steps
    assert terminated and info["is_success"]
    assert reward == pytest.approx(1 - 0.9 * len(plan) / max_steps)


@pytest.mark.parametrize("env_id", ["GCRL/LavaCrossingTabular-v0", "GCRL/LavaGapTabular-v0"])
def test_tabular_lava_terminates_without_reward(env_id: str) -> None:
    env = gym.make(env_id)
    env.reset(seed=0)
    for action in _plan(env, "lava"):
        _, reward, terminated, _, info = env.step(action)
    assert terminated and reward == 0.0 and not info["is_success"]


def test_tabular_wrapper_bad_input() -> None:
    with pytest.raises(TypeError, match="needs a MiniGrid environment"):
        TabularMiniGridObservation(gym.make("CartPole-v1"))
    env = gym.make("GCRL/LavaGapTabular-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="Invalid action 5"):
        env.step(5)
    with pytest.raises(ValueError, match="layout_seed must be a non-negative integer"):
        gym.make("GCRL/LavaGapTabular-v0", layout_seed=-1)


@pytest.mark.parametrize("env_id", ["GCRL/GrowingTree-v0", "GCRL/GrowingTreeGoal-v0", "GCRL/WindyGrid-v0"])
def test_rgb_array_rendering_so_sb3_accepts_the_env_id(env_id: str) -> None:
    """SB3 makes string env ids with render_mode="rgb_array" (falling back only on TypeError)."""
    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    space = env.action_space
    env.step(space.high if isinstance(space, gym.spaces.Box) else space.sample())  # a full step moves a pixel
    assert not np.array_equal(frame, env.render()) or env_id == "GCRL/WindyGrid-v0"
    with pytest.raises(ValueError, match="render_mode must be None, 'ansi' or 'rgb_array'"):
        gym.make(env_id, render_mode="sketch")


def test_minatar_ids_without_minatar_installed_name_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib.util

    from sb3_gcrl import envs

    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "minatar" else real_find_spec(name, *a)
    )
    for env_id in [env_id for env_id in gym.registry if env_id.startswith("MinAtar/")]:
        monkeypatch.delitem(gym.registry, env_id)
    envs._register_minatar()
    with pytest.raises(ModuleNotFoundError, match=r"pip install 'sb3-gcrl\[minatar\]'"):
        gym.make(MINATAR_ENV_IDS[0])
