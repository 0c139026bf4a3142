"""WindyGrid: the tabular task of the 2M chapter (thesis Ch. 5, Sec. 5.5.1, Fig. 5.4).

Registered as ``GCRL/WindyGrid-v0``.

Layout (rows top to bottom 0..6, columns left to right 0..9)::

    . . . . . . ^ . . .
    . . . . . . ^ . . .
    . . . . . . ^ X . .      X  trap (2, 7): reward -100, episode ends
    S . . . . . ^ G . .      S  start (3, 0); G goal (3, 7): episode ends
    . . . . . . ^ . . .      ^  wind column 6: after the move the agent is
    . . . . . . ^ . . .         pushed one row up with probability 0.2
    . . . . . . ^ . . .

- Observation: ``Discrete(70)``, index ``row * 10 + col`` (:func:`encode_cell` / :func:`decode_cell`).
- Actions: ``Discrete(4)``: 0 up, 1 right, 2 down, 3 left; moves into the border leave the agent in place.
- Wind: when the agent *starts* a step in column 6, the cell after the move is shifted one row up with
  probability ``wind_probability`` (clipped at the top border), so ``right`` from (3, 6) lands on the trap
  (2, 7) with probability 0.2.
- Reward: -1 per step; entering the trap gives ``trap_reward`` (-100) instead and terminates; entering the
  goal costs the usual -1 and terminates.
- Horizon: 100 steps (``TimeLimit`` truncation).

Why these numbers (the thesis's motivating example, written out in ``docs/envs.md``): the only 7-step
route is straight along row 3 and its *best-ever* return is -7, the highest any trajectory can get, so
episodic control (which keeps the maximum return seen per state-action) locks onto it. Its *expected*
return is ``0.8 * (-7) + 0.2 * (-106) = -26.8``, while the optimal policy (cross the wind in row 4, where a
gust pushes the agent onto the goal instead of the trap) earns ``0.2 * (-8) + 0.8 * (-9) = -8.8``
(undiscounted; :func:`windy_grid_optimal_value` computes it by value iteration for any discount).

Departures from the thesis: the thesis gives neither the trap position, the penalty nor the wind
probability; the values above are our choice, made so the claim above holds for every discount in (0, 1]
(the gap is ``gamma**6 * (99 p - gamma - (1 - p) gamma**2) > 0`` for p = 0.2). The authors' public
windy grid (Sutton & Barto's wind ``[0,0,0,1,1,1,2,2,1,0]``, no trap) is a different task.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_gcrl.common.validation import check_choice

N_ROWS = 7
N_COLS = 10
START_CELL = (3, 0)
GOAL_CELL = (3, 7)
TRAP_CELL = (2, 7)
WIND_COLUMN = 6
# (d_row, d_col) for actions 0 up, 1 right, 2 down, 3 left
ACTION_MOVES = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]], dtype=np.int64)
ACTION_NAMES = ("up", "right", "down", "left")


def encode_cell(row: int, col: int) -> int:
    """Observation index of grid cell ``(row, col)``: ``row * 10 + col``."""
    if not (0 <= row < N_ROWS and 0 <= col < N_COLS):
        raise ValueError(f"Cell ({row}, {col}) is outside the {N_ROWS}x{N_COLS} grid.")
    return row * N_COLS + col


def decode_cell(index: int) -> tuple[int, int]:
    """Grid cell ``(row, col)`` of observation ``index`` (inverse of :func:`encode_cell`)."""
    if not 0 <= index < N_ROWS * N_COLS:
        raise ValueError(f"Observation index {index} is outside [0, {N_ROWS * N_COLS}).")
    return divmod(int(index), N_COLS)


class WindyGridEnv(gym.Env[np.int64, np.int64]):
    """7x10 windy gridworld with a trap (thesis Ch. 5, Fig. 5.4); see the module docstring for the layout.

    :param wind_probability: probability that the wind in column 6 pushes the agent one row up.
    :param trap_reward: reward for entering the trap (replaces the -1 step reward; the episode ends).
    :param step_reward: reward of every other step, including the one that enters the goal.
    :param render_mode: ``None``, ``"ansi"`` (a text picture of the grid) or ``"rgb_array"`` (20 px cells:
        wind column blue, trap red, goal gold, agent black; SB3 asks for it when given an env id).
    """

    metadata = {"render_modes": ["ansi", "rgb_array"], "render_fps": 4}

    def __init__(
        self,
        wind_probability: float = 0.2,
        trap_reward: float = -100.0,
        step_reward: float = -1.0,
        render_mode: str | None = None,
    ) -> None:
        if not 0.0 <= wind_probability <= 1.0:
            raise ValueError(f"wind_probability must lie in [0, 1], got {wind_probability}.")
        check_choice("render_mode", render_mode, (None, *self.metadata["render_modes"]))
        self.wind_probability = float(wind_probability)
        self.trap_reward = float(trap_reward)
        self.step_reward = float(step_reward)
        self.render_mode = render_mode
        self.observation_space = spaces.Discrete(N_ROWS * N_COLS)
        self.action_space = spaces.Discrete(len(ACTION_MOVES))
        self.start_state = encode_cell(*START_CELL)
        self.goal_state = encode_cell(*GOAL_CELL)
        self.trap_state = encode_cell(*TRAP_CELL)
        self._cell = np.array(START_CELL, dtype=np.int64)

    def _move(self, cell: tuple[int, int] | np.ndarray, action: int, gust: bool) -> tuple[int, int]:
        """Deterministic part of the dynamics: the cell reached from ``cell`` with or without a gust."""
        row = min(max(int(cell[0]) + int(ACTION_MOVES[action, 0]), 0), N_ROWS - 1)
        col = min(max(int(cell[1]) + int(ACTION_MOVES[action, 1]), 0), N_COLS - 1)
        if gust and int(cell[1]) == WIND_COLUMN:
            row = max(row - 1, 0)
        return row, col

    def _outcome(self, state: int) -> tuple[float, bool]:
        """Reward for entering ``state`` and whether the episode ends there."""
        if state == self.trap_state:
            return self.trap_reward, True
        return self.step_reward, state == self.goal_state

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.int64, dict]:
        super().reset(seed=seed)
        if options:
            raise ValueError(f"WindyGrid takes no reset options, got {sorted(options)}.")
        self._cell[:] = START_CELL
        return np.int64(self.start_state), {}

    def step(self, action: int) -> tuple[np.int64, float, bool, bool, dict]:
        if not self.action_space.contains(action):
            raise ValueError(f"Invalid action {action!r}: expected an integer in [0, 4) (0 up 1 right 2 down 3 left).")
        gust = int(self._cell[1]) == WIND_COLUMN and self.np_random.random() < self.wind_probability
        self._cell[:] = self._move(self._cell, int(action), gust)
        state = encode_cell(int(self._cell[0]), int(self._cell[1]))
        reward, terminated = self._outcome(state)
        return np.int64(state), reward, terminated, False, {"gust": gust, "is_success": state == self.goal_state}

    def render(self) -> str | np.ndarray | None:
        if self.render_mode == "rgb_array":
            cell = 20
            image = np.full((N_ROWS * cell, N_COLS * cell, 3), 255, dtype=np.uint8)
            image[:, WIND_COLUMN * cell : (WIND_COLUMN + 1) * cell] = (173, 216, 230)
            for (row, col), colour in ((TRAP_CELL, (220, 20, 60)), (GOAL_CELL, (255, 215, 0))):
                image[row * cell : (row + 1) * cell, col * cell : (col + 1) * cell] = colour
            row, col = int(self._cell[0]), int(self._cell[1])
            image[row * cell + 5 : (row + 1) * cell - 5, col * cell + 5 : (col + 1) * cell - 5] = 0
            image[::cell, :] = image[:, ::cell] = 128  # grid lines
            return image
        if self.render_mode != "ansi":
            return None
        rows = []
        for r in range(N_ROWS):
            line = []
            for c in range(N_COLS):
                if (r, c) == tuple(self._cell):
                    line.append("A")
                elif (r, c) == GOAL_CELL:
                    line.append("G")
                elif (r, c) == TRAP_CELL:
                    line.append("X")
                elif c == WIND_COLUMN:
                    line.append("^")
                else:
                    line.append(".")
            rows.append(" ".join(line))
        return "\n".join(rows) + "\n"

    def transition_model(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The exact MDP as arrays, for dynamic programming.

        :return: ``(P, R, terminal)``: ``P[s, a, s']`` transition probabilities, ``R[s, a]`` expected
            immediate reward, ``terminal[s]`` True for the goal and the trap. Terminal states are absorbing
            with zero reward, so ``P`` rows always sum to one.
        """
        n_states, n_actions = self.observation_space.n, self.action_space.n
        P = np.zeros((n_states, n_actions, n_states))
        R = np.zeros((n_states, n_actions))
        terminal = np.zeros(n_states, dtype=bool)
        terminal[[self.goal_state, self.trap_state]] = True
        for s in range(n_states):
            if terminal[s]:
                P[s, :, s] = 1.0
                continue
            cell = decode_cell(s)
            gusts = [(False, 1.0)]
            if cell[1] == WIND_COLUMN:
                gusts = [(False, 1.0 - self.wind_probability), (True, self.wind_probability)]
            for a in range(n_actions):
                for gust, prob in gusts:
                    s_next = encode_cell(*self._move(cell, a, gust))
                    P[s, a, s_next] += prob
                    R[s, a] += prob * self._outcome(s_next)[0]
        return P, R, terminal


def windy_grid_value_iteration(
    gamma: float = 1.0, tol: float = 1e-10, max_iterations: int = 100_000, **env_kwargs: Any
) -> tuple[np.ndarray, np.ndarray]:
    """Optimal state values and a greedy optimal policy of WindyGrid by value iteration.

    :param gamma: discount factor in (0, 1]; gamma = 1 converges because every policy that avoids
        termination keeps paying -1 per step.
    :param tol: stop when the largest value change is below this.
    :param max_iterations: safety bound on sweeps.
    :param env_kwargs: forwarded to :class:`WindyGridEnv` (e.g. ``wind_probability``).
    :return: ``(V, policy)`` arrays of shape ``(70,)``.
    """
    if not 0.0 < gamma <= 1.0:
        raise ValueError(f"gamma must lie in (0, 1], got {gamma}.")
    P, R, terminal = WindyGridEnv(**env_kwargs).transition_model()
    V = np.zeros(P.shape[0])
    for _ in range(max_iterations):
        Q = R + gamma * P @ V
        Q[terminal] = 0.0
        V_new = Q.max(axis=1)
        if np.max(np.abs(V_new - V)) < tol:
            V = V_new
            break
        V = V_new
    else:
        raise RuntimeError(f"Value iteration did not converge in {max_iterations} sweeps; raise max_iterations.")
    Q = R + gamma * P @ V
    return V, Q.argmax(axis=1)


def windy_grid_policy_value(policy: np.ndarray, gamma: float = 1.0, **env_kwargs: Any) -> np.ndarray:
    """Exact state values of a deterministic policy (linear solve of the Bellman equation).

    :param policy: action per state, shape ``(70,)``.
    :param gamma: discount factor in (0, 1]; with gamma = 1 the policy must reach a terminal state.
    :param env_kwargs: forwarded to :class:`WindyGridEnv`.
    :return: ``V`` of shape ``(70,)``.
    """
    P, R, terminal = WindyGridEnv(**env_kwargs).transition_model()
    policy = np.asarray(policy, dtype=np.int64)
    if policy.shape != (P.shape[0],):
        raise ValueError(f"policy must have shape ({P.shape[0]},), got {policy.shape}.")
    idx = np.arange(P.shape[0])
    P_pi, R_pi = P[idx, policy], R[idx, policy]
    P_pi[terminal] = 0.0
    R_pi[terminal] = 0.0
    try:
        return np.linalg.solve(np.eye(P.shape[0]) - gamma * P_pi, R_pi)
    except np.linalg.LinAlgError as err:
        raise ValueError("The policy never terminates from some state; use gamma < 1 to evaluate it.") from err


def windy_grid_optimal_value(gamma: float = 1.0, **env_kwargs: Any) -> float:
    """Optimal expected return from the start state (3, 0): the line the tabular 2M plots draw as optimum.

    Undiscounted with the default parameters: ``-8.8``.
    """
    V, _ = windy_grid_value_iteration(gamma=gamma, **env_kwargs)
    return float(V[encode_cell(*START_CELL)])
