"""Tabletop: EARL's kinematic mug-moving task (thesis Section 3.7.1 "Tabletop"; Sharma et al. 2021, EARL),
re-implemented in numpy as a goal environment.

A gripper ("fist") and a mug move on a 5.6 x 5.6 table (positions clipped to [-2.8, 2.8]). The dynamics are
EARL's, which are kinematic (EARL writes MuJoCo positions directly and never integrates physics), so no
simulator is needed:

- action Box(-1, 1, (3,)), scaled to +-0.2: ``(dx, dy, grip)``;
- ``grip > 0``: if nothing is held and the mug is within 0.4 of the fist (before it moves), grasp it; a held
  mug stays held. ``grip <= 0``: release;
- the fist moves by ``(dx, dy)`` (then clipped); a held mug moves by the fist's actual displacement (then
  clipped).

Spaces: ``observation`` (6,) = fist xy, mug xy, EARL's attached flags ((-1, -1) free, (0, 0) held);
``achieved_goal`` / ``desired_goal`` (4,) = fist xy, mug xy. EARL's flat 12-dim observation is
``observation`` + its 6-dim goal whose last two entries (attached flags) are constant and never used; our goal
space drops them. Success (EARL): ``||achieved - desired|| <= 0.2``, i.e. the mug at its target *and* the fist
back at the table centre. Reward: 1 on success, else 0 (EARL's sparse reward). Never terminates.

rho_0: the fixed start, fist (0, 0), mug (2.5, 0). rho_g*: one of EARL's four goals, fist (0, 0) and the mug
at (-2.5, -1), (-2.5, 1), (0, 2) or (0, -2), drawn uniformly ("four goal locations sampled in turn").
Evaluation horizon 200; hard reset every 2e5 steps (EARL ``train_horizon``).

Departure from EARL: none in the dynamics. No MuJoCo scene: ``render_mode="rgb_array"`` draws a top view in
numpy (fist blue, filled while holding; mug red; the mug's goal a green ring; the fist's goal a grey ring).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from gymnasium_robotics.core import GoalEnv

from sb3_gcrl.envs.reset_free.reset_options import commanded_goal

#: Success radius on (fist xy, mug xy).
SUCCESS_THRESHOLD = 0.2

TABLE_HALF_SIZE = 2.8
MAX_STEP = 0.2
GRASP_RADIUS = 0.4
#: Goal-space box (fist xy, mug xy), for binning visited goals and heatmaps.
GOAL_LOW, GOAL_HIGH = (-TABLE_HALF_SIZE,) * 4, (TABLE_HALF_SIZE,) * 4
#: rho_0 in goal space: fist xy, mug xy.
INITIAL_GOAL = np.array([0.0, 0.0, 2.5, 0.0])
#: rho_g*: EARL's four evaluation goals (fist back at the centre, mug at one of four targets).
EVALUATION_GOALS = np.array(
    [
        [0.0, 0.0, -2.5, -1.0],
        [0.0, 0.0, -2.5, 1.0],
        [0.0, 0.0, 0.0, 2.0],
        [0.0, 0.0, 0.0, -2.0],
    ]
)
_FREE, _HELD = -1.0, 0.0


class TabletopEnv(GoalEnv):
    """``GCRL/Tabletop-v0``: EARL's Tabletop (kinematic gripper moving a mug to one of four goals).

    :param render_mode: ``None`` or ``"rgb_array"`` (a top view drawn in numpy).
    :param render_size: side of the rendered square image in pixels.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 20}
    #: success radius in goal space (the name gymnasium-robotics' goal envs use)
    distance_threshold: ClassVar[float] = SUCCESS_THRESHOLD

    def __init__(self, render_mode: str | None = None, render_size: int = 200) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"Tabletop renders only 'rgb_array' (or render_mode=None), got {render_mode!r}")
        self.render_mode = render_mode
        self.render_size = int(render_size)
        bound = np.float32(TABLE_HALF_SIZE)
        goal_box = spaces.Box(-bound, bound, shape=(4,), dtype=np.float32)
        obs_low = np.array([-bound] * 4 + [_FREE] * 2, dtype=np.float32)
        obs_high = np.array([bound] * 4 + [_HELD] * 2, dtype=np.float32)
        self.observation_space = spaces.Dict(
            {
                "observation": spaces.Box(obs_low, obs_high, dtype=np.float32),
                "achieved_goal": goal_box,
                "desired_goal": goal_box,
            }
        )
        self.action_space = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        # State: fist xy, mug xy (float64 internally, as EARL's MuJoCo qpos).
        self._positions = INITIAL_GOAL.copy()
        self._held = False
        self.goal = EVALUATION_GOALS[0].copy()

    # --- task-relevant goals ------------------------------------------------------------------------------------
    def sample_initial_goal(self, rng: np.random.Generator) -> np.ndarray:
        """rho_0: the fixed start (fist at the centre, mug at (2.5, 0))."""
        return INITIAL_GOAL.astype(np.float32)

    def sample_evaluation_goal(self, rng: np.random.Generator) -> np.ndarray:
        """rho_g*: one of EARL's four goals, uniformly."""
        return EVALUATION_GOALS[rng.integers(len(EVALUATION_GOALS))].astype(np.float32)

    # --- goal-env API -------------------------------------------------------------------------------------------
    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """EARL's sparse reward, vectorised over leading dims: 1.0 within 0.2 of the goal, else 0.0."""
        distance = np.linalg.norm(np.asarray(achieved_goal) - np.asarray(desired_goal), axis=-1)
        return (distance <= SUCCESS_THRESHOLD).astype(np.float32)

    def compute_terminated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> bool:
        return False

    def compute_truncated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> bool:
        return False

    def _get_obs(self) -> dict[str, np.ndarray]:
        flag = _HELD if self._held else _FREE
        achieved = self._positions.astype(np.float32)
        return {
            "observation": np.concatenate([achieved, np.array([flag, flag], dtype=np.float32)]),
            "achieved_goal": achieved,
            "desired_goal": self.goal.copy(),
        }

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        self._positions = self.sample_initial_goal(self.np_random).astype(np.float64)
        self._held = False
        goal = commanded_goal(options, self.observation_space["desired_goal"], "Tabletop")
        self.goal = self.sample_evaluation_goal(self.np_random) if goal is None else goal
        obs = self._get_obs()
        return obs, {"is_success": bool(self.compute_reward(obs["achieved_goal"], self.goal, None) > 0)}

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (3,):
            raise ValueError(f"Tabletop actions have shape (3,), got {action.shape}")
        if not np.all(np.isfinite(action)):
            raise ValueError(f"Tabletop got a non-finite action {action}")
        move = np.clip(action, -1.0, 1.0) * MAX_STEP
        fist, mug = self._positions[:2], self._positions[2:]
        if move[2] > 0:
            if not self._held and np.linalg.norm(fist - mug) < GRASP_RADIUS:
                self._held = True
        else:
            self._held = False
        new_fist = np.clip(fist + move[:2], -TABLE_HALF_SIZE, TABLE_HALF_SIZE)
        if self._held:
            self._positions[2:] = np.clip(mug + (new_fist - fist), -TABLE_HALF_SIZE, TABLE_HALF_SIZE)
        self._positions[:2] = new_fist
        obs = self._get_obs()
        reward = float(self.compute_reward(obs["achieved_goal"], self.goal, None))
        return obs, reward, False, False, {"is_success": reward > 0}

    def render(self) -> np.ndarray | None:
        """Top view of the table as an (H, W, 3) uint8 image (``render_mode="rgb_array"``), else None."""
        if self.render_mode != "rgb_array":
            return None
        size = self.render_size
        image = np.full((size, size, 3), 235, dtype=np.uint8)
        # Pixel grid in table coordinates (x right, y up).
        coords = (np.arange(size) + 0.5) / size * 2 * TABLE_HALF_SIZE - TABLE_HALF_SIZE
        x, y = np.meshgrid(coords, coords[::-1])

        def distance(point: np.ndarray) -> np.ndarray:
            return np.hypot(x - point[0], y - point[1])

        ring = 2.5 * TABLE_HALF_SIZE / size  # ~2.5 px
        image[np.abs(distance(self.goal[:2]) - SUCCESS_THRESHOLD) < ring] = (150, 150, 150)
        image[np.abs(distance(self.goal[2:]) - SUCCESS_THRESHOLD) < ring] = (40, 170, 60)
        mug = self._positions[2:]
        image[(np.abs(x - mug[0]) < 0.15) & (np.abs(y - mug[1]) < 0.15)] = (200, 40, 40)
        fist = distance(self._positions[:2])
        image[(fist < 0.12) if self._held else (np.abs(fist - 0.1) < ring)] = (40, 70, 200)
        return image
