"""Sawyer Door: EARL's door-closing task (thesis Section 3.7.1 "Sawyer Door"; Sharma et al. 2021, EARL) as a
goal environment on metaworld 3.0.0's ``door-close-v3`` scene.

Optional dependency: ``pip install metaworld==3.0.0``. Its requirements (gymnasium>=1.1, mujoco>=3.0, numpy,
scipy, imageio) are met by our stack, so nothing else changes; metaworld >= 3.1 pins mujoco 3.3 (not ours). Without
it, making the env raises an ImportError that names that command.

EARL's task, kept: a Sawyer arm (mocap xyz control, action Box(-1, 1, (4,)) = xyz displacement x 1 cm +
gripper) must close a door that starts open. Arm start (0, 0.4, 0.2); door start angle -pi/3 + U(0, pi/20)
(open 51-60 degrees); goal: the door closed (angle 0). State (``observation``, 7 dims, as EARL): hand xyz,
normalised finger opening, handle xyz. Goal space (``achieved_goal``/``desired_goal``, 3 dims): handle xyz.
Success (EARL): ``||handle - goal handle|| <= 0.02``; reward 1 on success, else 0 (EARL's sparse reward).
Never terminates. rho_0: the handle position of a freshly reset (open) door; rho_g*: the handle position of
the closed door (a single goal). Evaluation horizon 300 steps; hard reset every 2e5 steps.

Departures: EARL ships its own copy of metaworld v2's door XML (door body at z = 0.10); we use metaworld
3.0.0's asset (door body at z = 0.15, metaworld's own default), so handle coordinates are shifted by 5 cm in z
against EARL's hard-coded goal - we compute the closed-door handle position from the scene instead of copying
numbers. EARL's 7-dim goal also lists the hand; only its handle part enters EARL's success test, so our goal
space is that part. The thesis text quotes start-angle noise of (0, 18) degrees; we follow EARL's code
(U(0, pi/20) rad = 0-9 degrees). Thesis Section 3.10's simplified door (workspace box, door stop) is not this
task: the benchmark results (Figure 3.4) of the baselines use the original one implemented here.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from gymnasium_robotics.core import GoalEnv

from sb3_gcrl.envs.reset_free.reset_options import commanded_goal

#: EARL's success radius on the handle position (metres).
SUCCESS_THRESHOLD = 0.02
#: EARL's arm start and door placement (door base z from metaworld 3's asset, see the module docstring).
HAND_START = np.array([0.0, 0.4, 0.2])
DOOR_POSITION = np.array([0.1, 0.95, 0.15])
#: Door start angle: EARL's -pi/3 plus U(0, pi/20) (negative = open).
DOOR_START_ANGLE = -np.pi / 3
DOOR_START_NOISE = np.pi / 20
DOOR_CLOSED_ANGLE = 0.0
#: Goal-space box: the handle's path over the hinge range [-2, 0] rad (it moves in the plane z = 0.150).
GOAL_LOW, GOAL_HIGH = (-0.35, 0.45, 0.14), (0.30, 0.75, 0.16)

METAWORLD_INSTALL = "pip install metaworld==3.0.0"


class SawyerDoorEnv(GoalEnv):
    """``GCRL/SawyerDoor-v0``: close the door with a Sawyer arm (EARL's Sawyer Door on metaworld 3).

    :param render_mode: forwarded to metaworld (``"rgb_array"``, ``"human"``, ``"depth_array"`` or None).
    :param width: render width in pixels.
    :param height: render height in pixels.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array", "depth_array"], "render_fps": 80}
    #: success radius in goal space (the name gymnasium-robotics' goal envs use)
    distance_threshold: ClassVar[float] = SUCCESS_THRESHOLD

    def __init__(self, render_mode: str | None = None, width: int = 480, height: int = 480) -> None:
        try:
            from metaworld.envs.sawyer_door_close_v3 import SawyerDoorCloseEnvV3
        except ImportError as error:
            raise ImportError(
                f"GCRL/SawyerDoor-v0 needs metaworld 3.0.0, which is not installed. Install it with "
                f"`{METAWORLD_INSTALL}` (later metaworld releases pin an older mujoco than ours)."
            ) from error
        self.render_mode = render_mode
        sim = SawyerDoorCloseEnvV3(render_mode=render_mode, width=width, height=height)
        # Configure metaworld's env as EARL does: fixed door placement and arm start, no episode limit
        # (reset-free training runs for up to 2e5 steps between resets), task marked as set.
        sim.max_path_length = np.iinfo(np.int64).max
        sim._set_task_called = True
        sim._freeze_rand_vec = True
        sim._last_rand_vec = DOOR_POSITION.copy()
        sim.hand_init_pos = HAND_START.copy()
        self._sim = sim
        self._door_qpos_adr = sim.door_qpos_adr

        self.action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        goal_box = spaces.Box(-np.inf, np.inf, shape=(3,), dtype=np.float64)
        self.observation_space = spaces.Dict(
            {
                "observation": spaces.Box(-np.inf, np.inf, shape=(7,), dtype=np.float64),
                "achieved_goal": goal_box,
                "desired_goal": goal_box,
            }
        )
        # Handle positions of the closed door (the goal) and the fully reset open door, read from the scene.
        sim.reset()
        self._closed_handle = self._handle_at_angle(DOOR_CLOSED_ANGLE)
        self.goal = self._closed_handle.copy()

    # --- helpers ------------------------------------------------------------------------------------------------
    def _handle_at_angle(self, angle: float) -> np.ndarray:
        self._sim._set_obj_xyz(np.array(angle))
        return self._sim.data.geom("handle").xpos.copy()

    def _get_obs(self) -> dict[str, np.ndarray]:
        state = self._sim._get_curr_obs_combined_no_goal()[:7].astype(np.float64)
        return {"observation": state, "achieved_goal": state[4:7].copy(), "desired_goal": self.goal.copy()}

    @property
    def door_angle(self) -> float:
        """Current door hinge angle (radians, 0 = closed, negative = open)."""
        return float(self._sim.data.qpos[self._door_qpos_adr])

    # --- task-relevant goals ------------------------------------------------------------------------------------
    def sample_initial_goal(self, rng: np.random.Generator) -> np.ndarray:
        """rho_0: the handle position of the open door at a start angle -pi/3 + U(0, pi/20).

        Computed by forward kinematics on a copy of the simulator state, which is restored afterwards.
        """
        qpos, qvel = self._sim.data.qpos.copy(), self._sim.data.qvel.copy()
        handle = self._handle_at_angle(DOOR_START_ANGLE + rng.uniform(0.0, DOOR_START_NOISE))
        self._sim.set_state(qpos, qvel)
        return handle

    def sample_evaluation_goal(self, rng: np.random.Generator) -> np.ndarray:
        """rho_g*: the handle position of the closed door (EARL has one evaluation goal)."""
        return self._closed_handle.copy()

    # --- goal-env API -------------------------------------------------------------------------------------------
    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """EARL's sparse reward, vectorised: 1.0 when the handle is within 2 cm of the goal, else 0.0."""
        distance = np.linalg.norm(np.asarray(achieved_goal) - np.asarray(desired_goal), axis=-1)
        return (distance <= SUCCESS_THRESHOLD).astype(np.float64)

    def compute_terminated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> bool:
        return False

    def compute_truncated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> bool:
        return False

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        self._sim.reset()  # metaworld's reset: arm to HAND_START (50 sim steps), door placed, fully open
        self._sim._set_obj_xyz(np.array(DOOR_START_ANGLE + self.np_random.uniform(0.0, DOOR_START_NOISE)))
        goal = commanded_goal(options, self.observation_space["desired_goal"], "SawyerDoor")
        self.goal = self.sample_evaluation_goal(self.np_random) if goal is None else goal
        obs = self._get_obs()
        return obs, {"is_success": bool(self.compute_reward(obs["achieved_goal"], self.goal, None) > 0)}

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (4,):
            raise ValueError(f"SawyerDoor actions have shape (4,), got {action.shape}")
        if not np.all(np.isfinite(action)):
            raise ValueError(f"SawyerDoor got a non-finite action {action}")
        self._sim.step(np.clip(action, -1.0, 1.0))
        obs = self._get_obs()
        reward = float(self.compute_reward(obs["achieved_goal"], self.goal, None))
        return obs, reward, False, False, {"is_success": reward > 0, "door_angle": self.door_angle}

    def render(self) -> Any:
        return self._sim.render()

    def close(self) -> None:
        self._sim.close()
