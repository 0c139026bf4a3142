"""GrowingTree: the toy task of the CEC chapter (thesis Ch. 4, Sec. 4.5.1, Table 4.3).

Registered as ``GCRL/GrowingTree-v0`` (episodic) and ``GCRL/GrowingTreeGoal-v0`` (goal env).

The agent "grows" (action > 0) or "cuts" (action < 0) a tree whose height is the state:
``height <- clip(height + action, -2, 2)``, starting from 0.

- Observation: ``Box(-2, 2, (1,), float32)``, the height. Goal variant: ``Dict(observation, achieved_goal,
  desired_goal)``, each ``Box(-2, 2, (1,))``; achieved goal = height, desired goal = 1.0.
- Action: ``Box(-0.1, 0.1, (1,), float32)`` as in the thesis (not normalised to [-1, 1]; SB3 algorithms
  rescale it themselves).
- Reward: 1.0 on the step that brings the height within the tolerance 0.1 of the target 1.0, else 0; the
  episodic variant terminates there. ``info["is_success"]`` marks it.
- Horizon: 200 steps (``TimeLimit``).

The optimal policy always plays +0.1 and succeeds on step 10 (9 steps of 0.1 end exactly *on* the
tolerance boundary, which does not count). Because float32 actions of 0.1 are slightly larger than 0.1,
success is tested as ``|height - goal| < tolerance - 1e-6`` so that this boundary case is decided the
same way in exact and in floating-point arithmetic.

Departures from the thesis: the goal variant (for the reset-free/goal-conditioned machinery) does not
terminate at the goal by default (``terminate_at_goal=False``), like gymnasium-robotics' Fetch tasks, so
HER relabelling never meets a terminal flag that belongs to another goal. Task-relevant goals:
``sample_initial_goal`` returns the start height 0, ``sample_evaluation_goal`` the target 1.0.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_gcrl.common.validation import check_choice

HEIGHT_LIMIT = 2.0
MAX_ACTION = 0.1
# Exact-arithmetic boundary cases (e.g. nine actions of 0.1 from 0) count as "not reached".
_BOUNDARY_MARGIN = 1e-6


def _height_space() -> spaces.Box:
    return spaces.Box(-HEIGHT_LIMIT, HEIGHT_LIMIT, shape=(1,), dtype=np.float32)


class GrowingTreeEnv(gym.Env):
    """Grow a tree to a target height (thesis Table 4.3); :class:`GrowingTreeGoalEnv` is the goal-env variant.

    :param goal: target height.
    :param tolerance: success when ``|height - goal| < tolerance``.
    :param start_height: height at reset.
    :param final_reward: reward on success.
    :param terminate_at_goal: end the episode on success.
    :param render_mode: ``None``, ``"ansi"`` (text) or ``"rgb_array"`` (the tree as a green bar, the target
        as a red line; SB3 asks for it when given an env id).
    """

    metadata = {"render_modes": ["ansi", "rgb_array"], "render_fps": 10}

    def __init__(
        self,
        goal: float = 1.0,
        tolerance: float = 0.1,
        start_height: float = 0.0,
        final_reward: float = 1.0,
        terminate_at_goal: bool = True,
        render_mode: str | None = None,
    ) -> None:
        for name, value in (("goal", goal), ("start_height", start_height)):
            if not -HEIGHT_LIMIT <= value <= HEIGHT_LIMIT:
                raise ValueError(f"{name} must lie in [-2, 2], got {value}.")
        if tolerance <= _BOUNDARY_MARGIN:
            raise ValueError(f"tolerance must be positive (> {_BOUNDARY_MARGIN}), got {tolerance}.")
        check_choice("render_mode", render_mode, (None, *self.metadata["render_modes"]))
        self.goal = float(goal)
        self.tolerance = float(tolerance)
        self.start_height = float(start_height)
        self.final_reward = float(final_reward)
        self.terminate_at_goal = terminate_at_goal
        self.render_mode = render_mode
        self.observation_space: spaces.Space = _height_space()
        self.action_space = spaces.Box(-MAX_ACTION, MAX_ACTION, shape=(1,), dtype=np.float32)
        self.height = self.start_height
        self.target = self.goal  # the height this episode must reach (the goal variant may command another)

    def _reached(self, distance: np.ndarray | float) -> np.ndarray | bool:
        return distance < self.tolerance - _BOUNDARY_MARGIN

    def _observation(self) -> Any:
        return np.array([self.height], dtype=np.float32)

    def _apply_reset_options(self, options: dict[str, Any]) -> None:
        self.height = float(options.pop("height", self.start_height))
        if not -HEIGHT_LIMIT <= self.height <= HEIGHT_LIMIT:
            raise ValueError(f"Reset height must lie in [-2, 2], got {self.height}.")

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        """Reset to ``start_height`` (override with ``options={"height": h}``)."""
        super().reset(seed=seed)
        options = dict(options or {})
        self._apply_reset_options(options)
        if options:
            raise ValueError(f"Unknown reset options {sorted(options)} for {type(self).__name__}.")
        return self._observation(), {"is_success": bool(self._reached(abs(self.height - self.target)))}

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict]:
        delta = float(np.asarray(action, dtype=np.float64).reshape(-1)[0])
        if not np.isfinite(delta):
            raise ValueError(f"GrowingTree got a non-finite action {action!r}.")
        delta = min(max(delta, -MAX_ACTION), MAX_ACTION)
        self.height = min(max(self.height + delta, -HEIGHT_LIMIT), HEIGHT_LIMIT)
        success = bool(self._reached(abs(self.height - self.target)))
        reward = self.final_reward if success else 0.0
        return self._observation(), reward, success and self.terminate_at_goal, False, {"is_success": success}

    def render(self) -> str | np.ndarray | None:
        if self.render_mode == "ansi":
            return f"height={self.height:+.3f} target={self.target:+.3f}\n"
        if self.render_mode == "rgb_array":
            pixels_per_unit = 50  # 200 px for the height range [-2, 2]
            image = np.full((4 * pixels_per_unit, 60, 3), 255, dtype=np.uint8)

            def row_of(height: float) -> int:
                return int(round((HEIGHT_LIMIT - height) * pixels_per_unit))

            image[min(row_of(self.height), image.shape[0] - 1) :, 20:40] = (34, 139, 34)
            target_row = min(row_of(self.target), image.shape[0] - 1)
            image[max(target_row - 1, 0) : target_row + 1, :] = (220, 20, 60)
            return image
        return None


class GrowingTreeGoalEnv(GrowingTreeEnv):
    """Goal-env variant of :class:`GrowingTreeEnv`: goal space = height.

    ``Dict(observation, achieved_goal, desired_goal)``, each ``Box(-2, 2, (1,))``; vectorised
    :meth:`compute_reward`; ``reset(options={"goal": g})`` commands another target. Does not terminate at
    the goal unless ``terminate_at_goal=True``.

    :param args: positional parameters of :class:`GrowingTreeEnv`.
    :param terminate_at_goal: end the episode on success (default False here, unlike :class:`GrowingTreeEnv`).
    :param kwargs: other parameters of :class:`GrowingTreeEnv`.
    """

    def __init__(self, *args: Any, terminate_at_goal: bool = False, **kwargs: Any) -> None:
        super().__init__(*args, terminate_at_goal=terminate_at_goal, **kwargs)
        self.observation_space = spaces.Dict(
            {key: _height_space() for key in ("observation", "achieved_goal", "desired_goal")}
        )

    # Task-relevant goals (rho_0 and rho_g*) for the reset-free / goal-selection machinery.
    def sample_initial_goal(self, rng: np.random.Generator) -> np.ndarray:
        """An initial state in goal space (rho_0): the start height."""
        return np.array([self.start_height], dtype=np.float32)

    def sample_evaluation_goal(self, rng: np.random.Generator) -> np.ndarray:
        """An evaluation goal (rho_g*): the target height."""
        return np.array([self.goal], dtype=np.float32)

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """Sparse reward for (batches of) goals of shape ``(..., 1)``; returns shape ``(...)``."""
        distance = np.abs(np.asarray(achieved_goal, np.float64)[..., 0] - np.asarray(desired_goal, np.float64)[..., 0])
        return np.where(self._reached(distance), self.final_reward, 0.0)

    def _observation(self) -> dict[str, np.ndarray]:
        height = np.array([self.height], dtype=np.float32)
        return {
            "observation": height,
            "achieved_goal": height.copy(),
            "desired_goal": np.array([self.target], dtype=np.float32),
        }

    def _apply_reset_options(self, options: dict[str, Any]) -> None:
        super()._apply_reset_options(options)
        target = float(np.asarray(options.pop("goal", self.goal), dtype=np.float64).reshape(-1)[0])
        if not -HEIGHT_LIMIT <= target <= HEIGHT_LIMIT:
            raise ValueError(f"Reset goal must lie in [-2, 2], got {target}.")
        self.target = target
