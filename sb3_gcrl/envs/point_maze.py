"""PointUMaze and Point4Rooms: the thesis's point-mass navigation tasks on gymnasium-robotics PointMaze.

Thesis sources: Ch. 4 (CEC, Sec. 4.5.2, Fig. 4.3, Table 4.4: episodic, sparse reward, start bottom-left,
goal top-left of the U / the far room, "small randomness" on both), Ch. 3 (MoReFree, Sec. 3.7.1:
PointUMaze start (0, 0) bottom-left with U(-0.1, 0.1) noise, evaluation goal top-left, 100 evaluation
steps) and Ch. 6 (post-exploration, Fig. 6.5).

Registered ids (cell size 1, origin at the map centre, success radius 0.45 as in gymnasium-robotics):

===============================  ==================  =========  ============================================
id                               observation         horizon    episode end
===============================  ==================  =========  ============================================
``GCRL/PointUMaze-v0``           Box (4,)            1000       terminates at the goal, reward 1
``GCRL/Point4Rooms-v0``          Box (4,)            1000       terminates at the goal, reward 1
``GCRL/Point4RoomsSubgoals-v0``  Box (4,)            1000       terminates at the goal (reward 1) or at a
                                                                sub-goal (reward 0.5)
``GCRL/PointUMazeGoal-v0``       Dict goal env       300        never terminates; reward 1 while in the goal
``GCRL/Point4RoomsGoal-v0``      Dict goal env       600        never terminates; reward 1 while in the goal
===============================  ==================  =========  ============================================

- Observation: PointMaze's ``(x, y, vx, vy)`` (float64). Goal variants: ``Dict(observation (4,),
  achieved_goal (2,) = (x, y), desired_goal (2,))`` with a vectorised ``compute_reward``.
- Action: ``Box(-1, 1, (2,))``, forces on the ball.
- Start: centre of ``start_cell`` + U(-0.1, 0.1) per coordinate; goal: centre of ``goal_cell`` +
  U(-0.1, 0.1). U-maze: start (row 3, col 1) bottom-left, goal (1, 1) top-left of the U. Four rooms
  (11x11, rooms of 4x4 cells, one-cell doorways): start (9, 1) in the bottom-left room, goal (1, 9) in the
  top-right (far) room.
- ``info["is_success"]`` (and PointMaze's ``info["success"]``): ``||(x, y) - goal|| <= 0.45``.
- Task-relevant goals: ``sample_initial_goal`` draws from the start region (rho_0),
  ``sample_evaluation_goal`` from the goal region (rho_g*); ``reset`` draws from exactly these.

Sub-goals (``subgoal_cells``, ``GCRL/Point4RoomsSubgoals-v0``): ``mujoco_maze``'s ``SubGoal4Rooms`` task adds
two sub-goals worth 0.5 that also end the episode, one in each room next to the start room, in line with the
start: in its 9x9 map (start at row 7, col 1; goal at row 1, col 7, i.e. (6, -6) cells from the start) they
lie (0, -6) and (6, 0) cells from the start, at (row 1, col 1) in the top-left room and (row 7, col 7) in the
bottom-right room. On our 11x11 map (start (9, 1), goal (1, 9)) they are the corresponding corners (1, 1)
and (9, 9), without noise, reached within the goal's radius (as in ``mujoco_maze``, where goal and sub-goals
share one radius); ``info["is_success"]`` stays True only at the goal.

Departures from the thesis: the thesis (CEC) used the ``mujoco_maze`` package (cells of 4 units, a point with
an orientation, obs reduced to (x, y, orientation), a -0.0001 reward per step in its goal tasks); we build on
gymnasium-robotics' maintained PointMaze instead: cells of 1 unit, a ball without orientation, reward 0 per
step (the 4-dim observation matches the thesis's Table 4.2). Traversing the U / the four rooms takes a simple
waypoint controller about 160 / 390 steps here (pinned by tests/test_envs.py), so the goal variants use 300
(U) / 600 (four rooms) steps instead of IBC's 100-step evaluation, and the episodic ones keep the thesis's
1000 steps. The goal variants do not terminate at the goal (as IBC's PointUMaze and gymnasium-robotics'
default), which keeps HER relabelling consistent; pass ``terminate_at_goal=True`` to ``gym.make`` to change
that.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from os import path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium_robotics.envs.maze import point as point_module
from gymnasium_robotics.envs.maze.maze_v4 import Maze
from gymnasium_robotics.envs.maze.point import PointEnv
from gymnasium_robotics.utils.mujoco_utils import MujocoModelNames

U_MAZE_MAP: list[list[int]] = [
    [1, 1, 1, 1, 1],
    [1, 0, 0, 0, 1],
    [1, 1, 1, 0, 1],
    [1, 0, 0, 0, 1],
    [1, 1, 1, 1, 1],
]
#: success radius around the goal (gymnasium-robotics' PointMaze)
SUCCESS_RADIUS = 0.45
U_MAZE_START_CELL = (3, 1)  # bottom-left
U_MAZE_GOAL_CELL = (1, 1)  # top-left of the U

FOUR_ROOMS_MAP: list[list[int]] = [
    [1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1],
    [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1],
    [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1],
    [1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1],
    [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1],
    [1, 1, 0, 1, 1, 1, 1, 1, 0, 1, 1],
    [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1],
    [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1],
    [1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1],
    [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1],
    [1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1],
]
FOUR_ROOMS_START_CELL = (9, 1)  # bottom-left room
FOUR_ROOMS_GOAL_CELL = (1, 9)  # top-right room, the far one
# mujoco_maze SubGoal4Rooms: the far corners of the two rooms next to the start room (reward 0.5, terminal)
FOUR_ROOMS_SUBGOAL_CELLS: tuple[tuple[int, int], ...] = ((1, 1), (9, 9))

_RESET_OPTIONS = ("reset_cell", "goal_cell", "reset_pos", "goal")
_MAZE_HEIGHT = 0.4  # as gymnasium-robotics' PointMaze


class PointMazeTaskEnv(gym.Env):
    """Episodic PointMaze with a fixed start region and goal region (the thesis's PointUMaze / Point4Rooms).

    Observation ``Box (4,)`` = ``(x, y, vx, vy)``; reward 1 and termination on reaching the goal. The maze is
    built with gymnasium-robotics' ``Maze`` and driven by its ``PointEnv`` (same physics as
    ``PointMaze_*-v3``). :class:`PointMazeGoalTaskEnv` is the goal-env variant.

    :param maze_map: gymnasium-robotics maze map (1 wall, 0 free); the default is the U-maze.
    :param start_cell: ``(row, col)`` of the start region's centre.
    :param goal_cell: ``(row, col)`` of the goal region's centre.
    :param start_noise: half-width of the uniform noise added to each start coordinate.
    :param goal_noise: half-width of the uniform noise added to each goal coordinate.
    :param distance_threshold: success radius around the goal.
    :param terminate_at_goal: end the episode on success (and at a sub-goal).
    :param subgoal_cells: ``(row, col)`` centres of sub-goals (mujoco_maze's ``SubGoal4Rooms``, thesis
        Sec. 4.5.2's Point4Rooms): within ``distance_threshold`` of one, the step pays ``subgoal_reward`` and
        ends the episode (with ``terminate_at_goal``); ``info["is_success"]`` stays False there and
        ``info["subgoal_reached"]`` is True. ``None``: no sub-goals (and no ``subgoal_reached`` key).
    :param subgoal_reward: reward at a sub-goal (mujoco_maze: 0.5).
    :param render_mode: as PointMaze (``"rgb_array"`` needs ``MUJOCO_GL=egl`` on a headless machine).
    :param kwargs: forwarded to gymnasium-robotics' ``PointEnv`` (e.g. ``width``/``height`` for rendering).
    """

    metadata = {"render_modes": ["human", "rgb_array", "depth_array"], "render_fps": 50}

    def __init__(
        self,
        maze_map: list[list[int]] | None = None,
        start_cell: tuple[int, int] = U_MAZE_START_CELL,
        goal_cell: tuple[int, int] = U_MAZE_GOAL_CELL,
        start_noise: float = 0.1,
        goal_noise: float = 0.1,
        distance_threshold: float = SUCCESS_RADIUS,
        terminate_at_goal: bool = True,
        subgoal_cells: Sequence[tuple[int, int]] | None = None,
        subgoal_reward: float = 0.5,
        render_mode: str | None = None,
        **kwargs: Any,
    ) -> None:
        maze_map = U_MAZE_MAP if maze_map is None else maze_map
        for name, cell in (("start_cell", start_cell), ("goal_cell", goal_cell)):
            _check_free_cell(maze_map, cell, name)
        subgoals = [] if subgoal_cells is None else [(int(cell[0]), int(cell[1])) for cell in subgoal_cells]
        for cell in subgoals:
            _check_free_cell(maze_map, cell, "subgoal_cells entry")
            if cell in (tuple(start_cell), tuple(goal_cell)):
                raise ValueError(f"subgoal_cells entry {cell} is the start or the goal cell; pick another cell.")
        if not math.isfinite(subgoal_reward):
            raise ValueError(f"subgoal_reward must be finite, got {subgoal_reward}.")
        for name, value in (("start_noise", start_noise), ("goal_noise", goal_noise)):
            if not 0.0 <= value < 0.5:
                raise ValueError(f"{name} must lie in [0, 0.5) (half a cell), got {value}.")
        if distance_threshold <= 0:
            raise ValueError(f"distance_threshold must be positive, got {distance_threshold}.")
        self.start_cell = (int(start_cell[0]), int(start_cell[1]))
        self.goal_cell = (int(goal_cell[0]), int(goal_cell[1]))
        self.start_noise = float(start_noise)
        self.goal_noise = float(goal_noise)
        self.distance_threshold = float(distance_threshold)
        self.terminate_at_goal = terminate_at_goal
        self.render_mode = render_mode

        point_xml = path.join(path.dirname(point_module.__file__), "../assets/point/point.xml")
        self.maze, xml_file = Maze.make_maze(point_xml, maze_map, 1, _MAZE_HEIGHT)
        try:
            self.point_env = PointEnv(
                xml_file=xml_file,
                render_mode=render_mode,
                default_camera_config={"distance": 12.5 if len(maze_map) > 8 else 8.8},
                **kwargs,
            )
        finally:
            # The model is compiled; gymnasium-robotics leaves this temporary XML in /tmp forever.
            if os.path.exists(xml_file):
                os.remove(xml_file)
        self._target_site_id = MujocoModelNames(self.point_env.model).site_name2id["target"]
        self.action_space = self.point_env.action_space
        # The ball stays inside the outer wall ring: (x, y) lies within the map; velocities are unbounded.
        half_extent = np.array([len(maze_map[0]) / 2, len(maze_map) / 2])
        self.goal_space = spaces.Box(-half_extent, half_extent, dtype=np.float64)
        self.observation_space: spaces.Space = spaces.Box(
            np.concatenate([-half_extent, [-np.inf, -np.inf]]),
            np.concatenate([half_extent, [np.inf, np.inf]]),
            dtype=np.float64,
        )
        self._start_xy = self.maze.cell_rowcol_to_xy(np.array(self.start_cell))
        self._goal_xy = self.maze.cell_rowcol_to_xy(np.array(self.goal_cell))
        self.subgoal_cells: tuple[tuple[int, int], ...] | None = None if subgoal_cells is None else tuple(subgoals)
        self.subgoal_reward = float(subgoal_reward)
        self.subgoals = np.array([self.maze.cell_rowcol_to_xy(np.array(cell)) for cell in subgoals]).reshape(-1, 2)
        self.goal = self._goal_xy.copy()
        self.reset_pos = self._start_xy.copy()

    # Task-relevant goals (rho_0 and rho_g*) for the reset-free / goal-selection machinery.
    def sample_initial_goal(self, rng: np.random.Generator) -> np.ndarray:
        """An initial state in goal space (rho_0): start-cell centre + U(-start_noise, start_noise)^2."""
        return self._start_xy + rng.uniform(-self.start_noise, self.start_noise, size=2)

    def sample_evaluation_goal(self, rng: np.random.Generator) -> np.ndarray:
        """An evaluation goal (rho_g*): goal-cell centre + U(-goal_noise, goal_noise)^2."""
        return self._goal_xy + rng.uniform(-self.goal_noise, self.goal_noise, size=2)

    def path_distance(self, achieved: np.ndarray, goal: np.ndarray, resolution: float = 0.05) -> np.ndarray:
        """Length of the shortest path through the maze's free cells from each point of ``achieved`` to ``goal``.

        The ground truth of learned distances (the world-model agent's diagnostics): Dijkstra over a grid of
        ``resolution`` spacing laid over the free cells (8-neighbour moves), plus each point's straight offset to
        its nearest grid node. Walls are treated as thin (the ball's radius is ignored).

        :param achieved: points ``(N, 2)`` (or one ``(2,)``) in the maze.
        :param goal: one point ``(2,)``.
        :param resolution: grid spacing.
        :return: distances ``(N,)`` (``inf`` for points outside every free cell).
        """
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import dijkstra

        maze_map = np.asarray(self.maze.maze_map)
        rows, cols = maze_map.shape
        n_x, n_y = int(round(cols / resolution)), int(round(rows / resolution))
        xs = (np.arange(n_x) + 0.5) * resolution - cols / 2
        ys = rows / 2 - (np.arange(n_y) + 0.5) * resolution
        free = maze_map[(np.arange(n_y) * resolution).astype(int)][:, (np.arange(n_x) * resolution).astype(int)] == 0
        index = -np.ones((n_y, n_x), dtype=np.int64)
        index[free] = np.arange(int(free.sum()))
        edges, weights = [], []
        for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
            a = index[max(0, -dy) : n_y - max(0, dy), max(0, -dx) : n_x - max(0, dx)]
            b = index[max(0, dy) : max(0, dy) + a.shape[0], max(0, dx) : max(0, dx) + a.shape[1]]
            ok = (a >= 0) & (b >= 0)
            edges.append(np.stack([a[ok], b[ok]]))
            weights.append(np.full(int(ok.sum()), resolution * math.hypot(dx, dy)))
        pairs, w = np.concatenate(edges, 1), np.concatenate(weights)
        n = int(free.sum())
        graph = coo_matrix((w, (pairs[0], pairs[1])), shape=(n, n)).tocsr()
        node_xy = np.stack(np.meshgrid(xs, ys), -1)[free]

        def nearest(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            col = np.clip(((points[:, 0] + cols / 2) / resolution).astype(int), 0, n_x - 1)
            row = np.clip(((rows / 2 - points[:, 1]) / resolution).astype(int), 0, n_y - 1)
            node = index[row, col]
            offset = np.where(node >= 0, np.linalg.norm(points - node_xy[np.maximum(node, 0)], axis=-1), np.inf)
            return node, offset

        points = np.asarray(achieved, dtype=np.float64).reshape(-1, 2)
        goal_node, goal_offset = nearest(np.asarray(goal, dtype=np.float64).reshape(1, 2))
        if goal_node[0] < 0:
            return np.full(len(points), np.inf)
        from_goal = dijkstra(graph, directed=False, indices=int(goal_node[0]))
        node, offset = nearest(points)
        return np.where(node >= 0, from_goal[np.maximum(node, 0)] + offset + goal_offset[0], np.inf)

    def _cell_xy(self, cell: Any, name: str, noise: float) -> np.ndarray:
        cell = np.asarray(cell, dtype=np.int64).reshape(2)
        _check_free_cell(self.maze.maze_map, (int(cell[0]), int(cell[1])), name)
        return self.maze.cell_rowcol_to_xy(cell) + self.np_random.uniform(-noise, noise, size=2)

    def _xy_option(self, value: Any, name: str) -> np.ndarray:
        xy = np.asarray(value, dtype=np.float64).reshape(2).copy()
        if not self.goal_space.contains(xy):
            raise ValueError(f"{name} {xy} lies outside the maze {self.goal_space.low}..{self.goal_space.high}.")
        return xy

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        """Reset to the start region with the goal in the goal region (drawn from exactly rho_0 / rho_g*).

        :param options: optional overrides: ``reset_cell`` / ``goal_cell`` (``(row, col)``, noise added as
            configured) or ``reset_pos`` / ``goal`` (exact ``(x, y)``).
        """
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - set(_RESET_OPTIONS)
        if unknown:
            raise ValueError(f"Unknown reset options {sorted(unknown)}; PointMaze tasks accept {_RESET_OPTIONS}.")
        if options.get("goal") is not None:
            self.goal = self._xy_option(options["goal"], "goal")
        elif options.get("goal_cell") is not None:
            self.goal = self._cell_xy(options["goal_cell"], "goal_cell", self.goal_noise)
        else:
            self.goal = self.sample_evaluation_goal(self.np_random)
        if options.get("reset_pos") is not None:
            self.reset_pos = self._xy_option(options["reset_pos"], "reset_pos")
        elif options.get("reset_cell") is not None:
            self.reset_pos = self._cell_xy(options["reset_cell"], "reset_cell", self.start_noise)
        else:
            self.reset_pos = self.sample_initial_goal(self.np_random)
        self.point_env.model.site_pos[self._target_site_id] = np.append(self.goal, _MAZE_HEIGHT / 2)
        self.point_env.init_qpos[:2] = self.reset_pos
        point_obs, _ = self.point_env.reset(seed=seed)
        success = self._success(point_obs)
        info = {"is_success": success, "success": success}
        if self.subgoal_cells is not None:
            info["subgoal_reached"] = False
        return self._observation(point_obs), info

    def _success(self, point_obs: np.ndarray) -> bool:
        return bool(goal_distance(point_obs[:2], self.goal) <= self.distance_threshold)

    def _observation(self, point_obs: np.ndarray) -> Any:
        return point_obs.copy()

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict]:
        action = np.asarray(action, dtype=np.float64)
        if not np.all(np.isfinite(action)):
            raise ValueError(f"PointMaze got a non-finite action {action!r}.")
        point_obs, _, _, _, _ = self.point_env.step(action)  # clips the action to [-1, 1]
        success = self._success(point_obs)
        info = {"is_success": success, "success": success}
        reward, done = float(success), success
        if self.subgoal_cells is not None:
            xy = point_obs[:2]  # one 1-d distance per sub-goal: cheaper than the batched form for two points
            at_subgoal = not success and any(
                goal_distance(xy, subgoal) <= self.distance_threshold for subgoal in self.subgoals
            )
            info["subgoal_reached"] = at_subgoal
            if at_subgoal:
                reward, done = self.subgoal_reward, True
        return self._observation(point_obs), reward, done and self.terminate_at_goal, False, info

    def render(self) -> Any:
        return self.point_env.render()

    def close(self) -> None:
        self.point_env.close()


class PointMazeGoalTaskEnv(PointMazeTaskEnv):
    """Goal-env variant of :class:`PointMazeTaskEnv` (gymnasium-robotics ``Dict`` observation).

    ``observation`` = ``(x, y, vx, vy)``, ``achieved_goal`` = ``(x, y)``, ``desired_goal`` = the goal;
    vectorised :meth:`compute_reward`. Does not terminate at the goal unless ``terminate_at_goal=True``.

    :param args: positional parameters of :class:`PointMazeTaskEnv`.
    :param terminate_at_goal: end the episode on success (default False here, unlike :class:`PointMazeTaskEnv`).
    :param kwargs: other parameters of :class:`PointMazeTaskEnv`.
    """

    def __init__(self, *args: Any, terminate_at_goal: bool = False, **kwargs: Any) -> None:
        if kwargs.get("subgoal_cells") is not None:
            raise ValueError(
                "subgoal_cells is an option of the episodic PointMazeTaskEnv only: the goal env's compute_reward "
                "(HER relabelling) would not pay the sub-goal rewards. Use PointMazeTaskEnv."
            )
        super().__init__(*args, terminate_at_goal=terminate_at_goal, **kwargs)
        low, high = self.goal_space.low, self.goal_space.high
        self.observation_space = spaces.Dict(
            {
                "observation": self.observation_space,
                "achieved_goal": spaces.Box(low, high, dtype=np.float64),
                "desired_goal": spaces.Box(low, high, dtype=np.float64),
            }
        )

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """1.0 where ``||achieved - desired|| <= distance_threshold`` else 0.0, for batches ``(..., 2)``."""
        distance = goal_distance(achieved_goal, desired_goal)
        if distance.ndim == 0:  # one goal: called once per step by the goal-commanding wrappers
            return np.float64(distance <= self.distance_threshold)
        return (distance <= self.distance_threshold).astype(np.float64)

    def _observation(self, point_obs: np.ndarray) -> dict[str, np.ndarray]:
        return {
            "observation": point_obs.copy(),
            "achieved_goal": point_obs[:2].copy(),
            "desired_goal": self.goal.copy(),
        }


def goal_distance(achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
    """Euclidean distance over the last axis (one formula for ``step`` and ``compute_reward``)."""
    diff = np.subtract(achieved_goal, desired_goal, dtype=np.float64)
    if diff.ndim == 1:
        # one goal per env step: a dot product is ~3x cheaper than the reductions below
        return np.float64(math.sqrt(diff.dot(diff)))
    return np.sqrt(np.einsum("...i,...i->...", diff, diff))


def _check_free_cell(maze_map: list[list[int]], cell: tuple[int, int], name: str) -> None:
    row, col = int(cell[0]), int(cell[1])
    if not (0 <= row < len(maze_map) and 0 <= col < len(maze_map[0])):
        raise ValueError(f"{name} {tuple(cell)} is outside the {len(maze_map)}x{len(maze_map[0])} maze map.")
    if maze_map[row][col] == 1:
        raise ValueError(f"{name} {tuple(cell)} is a wall cell; pick a cell whose maze_map entry is 0.")
