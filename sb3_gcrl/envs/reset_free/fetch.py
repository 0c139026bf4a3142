"""Reset-free Fetch manipulation tasks (thesis Section 3.7.1, "Fetch Push and Pick&Place", "Push (hard)",
"Pick&Place (hard)"; Figure 3.3).

Four goal environments built on gymnasium-robotics' ``MujocoFetchEnv`` (the ``FetchPush-v4`` /
``FetchPickAndPlace-v4`` robot, table and block). All keep Fetch's spaces: ``observation`` (25,),
``achieved_goal``/``desired_goal`` (3,) block position, action Box(-1, 1, (4,)) (xyz gripper displacement
x 5 cm + finger command), sparse reward ``-(d > 0.05)`` with ``info["is_success"] = d < 0.05`` (Fetch's). They
never terminate: the block cannot leave the table, so every state can be left. Registered with
``max_episode_steps`` = the evaluation horizon of the task table (50 steps).

Keeping the block in: the walls' contacts are stiffer than MuJoCo's defaults (a gripper pressing the block into
a wall would otherwise squeeze it through the soft contact - with object-only walls, which the arm passes, in
a few dozen steps), and behind them a position clamp puts a block centre that is more than 5 mm into a wall
back on the boundary with its outward velocity removed (a hard limit, as IBC's joint limits; in 4000 steps of
a scripted arm shoving the block at the walls it fired 3 times in ``ErgodicFetchPush`` and never in the
hard tasks).

``GCRL/ErgodicFetchPush-v0``, ``GCRL/ErgodicFetchPickAndPlace-v0`` (IBC's "ergodic" Fetch, thesis: "taken
from the IBC paper"):
    Initial block and goal distributions identical to FetchPush/FetchPickAndPlace (block and goal within
    +-15 cm of the gripper's start; Pick&Place goals in the air w.p. 0.5, up to 45 cm). The block is kept on the
    table by four *object-only* walls bounding a 0.4 m x 0.4 m square centred at :data:`IBC_BOX_CENTER`: the
    walls collide with the block but not with the robot (MuJoCo contype/conaffinity bit 2), so - as in IBC -
    only the block is constrained and the arm moves anywhere. Departure: IBC bounds the block with joint
    limits, which jitter at the limit (thesis Section 3.7.1); contacts with a wall are the cleaner equivalent.
    Push keeps Fetch's blocked gripper, as IBC.

``GCRL/FetchPushHard-v0``, ``GCRL/FetchPickAndPlaceHard-v0`` (the thesis's own variants):
    Real 15 cm walls (colliding with robot and block) stand on the four table edges, enclosing the whole table
    top (0.5 m x 0.7 m, :data:`HARD_ARENA_LOW`/:data:`HARD_ARENA_HIGH`, about 2.2x IBC's area), and the
    gripper's mocap target is clipped to 3 cm inside that arena and 35 cm above the table (the robot's
    workspace is limited, so a block in a corner needs a precise approach). Taller walls would be hit by the
    upper arm when the gripper reaches the robot-side edge. The gripper is released in both (gymnasium-robotics'
    Push hard-codes ``block_gripper=True`` and its scene has no finger actuators, so Push (hard) uses the
    Pick&Place scene, which differs only by those actuators). The block always starts at
    :data:`HARD_OBJECT_START` (table centre). Push (hard) goals: U(-0.15, 0.15)^2 around that point, on the
    table. Pick&Place (hard) goals: only in the air, uniform in a 5 x 5 x 10 cm box above the start point,
    10-20 cm above the table.
    Our choices where the thesis gives no number: arena = table top, start = table centre, gripper start 20 cm
    above the table (Pick&Place's, also for Push (hard), since the thesis gives both the same initial state),
    height of the air box.

Task-relevant goals (rho_0 / rho_g*) are declared by :meth:`sample_initial_goal` (block start position) and
:meth:`sample_evaluation_goal`; the env's own resets draw from the same two samplers.
Evaluation horizon 50 steps; EARL/IBC-style hard reset every 1e5 steps (thesis: "Hard reset will happen
after every 1e5 steps").
"""

from __future__ import annotations

from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium.utils import EzPickle
from gymnasium_robotics.envs.fetch.fetch_env import MujocoFetchEnv
from gymnasium_robotics.envs.fetch.pick_and_place import MODEL_XML_PATH as PICK_AND_PLACE_XML
from gymnasium_robotics.envs.fetch.push import MODEL_XML_PATH as PUSH_XML

from sb3_gcrl.envs.reset_free.reset_options import commanded_goal

#: Goal-reaching threshold on the block position (metres), as Fetch.
DISTANCE_THRESHOLD = 0.05

#: Table top height (z) of the Fetch scene; the table spans x in [1.05, 1.55], y in [0.40, 1.10].
TABLE_TOP_Z = 0.4
#: Centre and half-size (xy, metres) of the object-only box of the IBC-style tasks (IBC: a 0.4 m box).
IBC_BOX_CENTER = (1.34, 0.75)
IBC_BOX_HALF_SIZE = 0.2
#: Inner faces of the real walls of the hard tasks: the four table edges.
HARD_ARENA_LOW = (1.05, 0.40)
HARD_ARENA_HIGH = (1.55, 1.10)
#: Height of the hard tasks' walls above the table (metres).
HARD_WALL_HEIGHT = 0.15
#: Block start (xy) of the hard tasks: table centre.
HARD_OBJECT_START = (1.30, 0.75)
#: Pick&Place (hard) goal box: half-size in xy and height range above the resting block (metres).
HARD_AIR_GOAL_HALF_XY = 0.025
HARD_AIR_GOAL_HEIGHT = (0.10, 0.20)

_WALL_HALF_THICKNESS = 0.02
_BLOCK_HALF_SIZE = 0.025
# How far (metres) the block centre may press into a wall before the position clamp takes over.
_CLAMP_TOLERANCE = 0.005
#: How far MuJoCo's soft contacts let the block centre into the table (29 mm seen under random actions, the gripper
#: pressing the block down); the goal boxes reach this far below the table top, and ``_CLAMP_TOLERANCE`` beyond
#: the block centres that the walls allow.
_TABLE_PENETRATION = 0.04


def _goal_box(low_xy: tuple[float, float], high_xy: tuple[float, float], top: float) -> tuple[tuple, tuple]:
    """Block-centre box (xyz) between walls whose inner faces are at ``low_xy``/``high_xy``, from the table up to
    ``top``, widened by the contact penetrations.

    :param low_xy: inner faces of the walls on the low side (x, y).
    :param high_xy: inner faces of the walls on the high side (x, y).
    :param top: highest block centre (z).
    :return: the box's low and high corners.
    """
    reach = _BLOCK_HALF_SIZE - _CLAMP_TOLERANCE
    low = (round(low_xy[0] + reach, 6), round(low_xy[1] + reach, 6), round(TABLE_TOP_Z - _TABLE_PENETRATION, 6))
    return low, (round(high_xy[0] - reach, 6), round(high_xy[1] - reach, 6), top)


_IBC_BOX_LOW = (IBC_BOX_CENTER[0] - IBC_BOX_HALF_SIZE, IBC_BOX_CENTER[1] - IBC_BOX_HALF_SIZE)
_IBC_BOX_HIGH = (IBC_BOX_CENTER[0] + IBC_BOX_HALF_SIZE, IBC_BOX_CENTER[1] + IBC_BOX_HALF_SIZE)
#: Goal-space boxes (block centre xyz reachable inside the walls), for binning visited goals and heatmaps.
IBC_PUSH_GOAL_LOW, IBC_PUSH_GOAL_HIGH = _goal_box(_IBC_BOX_LOW, _IBC_BOX_HIGH, 0.50)
IBC_PICK_AND_PLACE_GOAL_LOW, IBC_PICK_AND_PLACE_GOAL_HIGH = _goal_box(_IBC_BOX_LOW, _IBC_BOX_HIGH, 0.95)
HARD_GOAL_LOW, HARD_GOAL_HIGH = _goal_box(HARD_ARENA_LOW, HARD_ARENA_HIGH, 0.80)
# Collision bit shared only by the block and the object-only walls (bit 0 is MuJoCo's default).
_OBJECT_ONLY_BIT = 2


class WalledFetchEnv(MujocoFetchEnv):
    """Fetch block manipulation with walls added to the scene (base class of the four tasks).

    Subclasses set the wall geometry and gripper limits through class attributes and the task-relevant goal
    distributions through :meth:`sample_initial_goal` / :meth:`sample_evaluation_goal`.

    :param model_path: Fetch scene XML (push or pick-and-place).
    :param block_gripper: keep the fingers closed (IBC Push) or let the agent open/close them.
    :param gripper_extra_height: start height of the gripper above Fetch's default pose.
    :param target_in_the_air: Pick&Place-style goals (used by the IBC-style evaluation goal sampler).
    :param reward_type: ``"sparse"`` (-1/0, default) or ``"dense"`` (negative distance), as Fetch.
    :param kwargs: forwarded to ``MujocoFetchEnv`` (``render_mode``, ``width``, ``height``, ...).
    """

    #: Inner faces of the four walls (xy low corner, xy high corner) and their top height.
    wall_low: ClassVar[tuple[float, float]]
    wall_high: ClassVar[tuple[float, float]]
    wall_top_z: ClassVar[float] = TABLE_TOP_Z + 1.0
    #: True: walls collide with robot and block. False: only with the block (invisible to the robot).
    walls_stop_robot: ClassVar[bool]
    #: Bounds of the gripper's mocap target (xyz low, xyz high), or None for Fetch's unlimited workspace.
    gripper_low: ClassVar[tuple[float, float, float] | None] = None
    gripper_high: ClassVar[tuple[float, float, float] | None] = None

    def __init__(
        self,
        model_path: str,
        block_gripper: bool,
        gripper_extra_height: float,
        target_in_the_air: bool,
        reward_type: str = "sparse",
        **kwargs: Any,
    ) -> None:
        if reward_type not in ("sparse", "dense"):
            raise ValueError(f"reward_type must be 'sparse' or 'dense', got {reward_type!r}")
        initial_qpos = {
            "robot0:slide0": 0.405,
            "robot0:slide1": 0.48,
            "robot0:slide2": 0.0,
            # Fetch parks the block at (1.25, 0.53) during setup, which is inside the IBC box's wall; park it at
            # the table centre instead (setup measures the block's resting height there).
            "object0:joint": [HARD_OBJECT_START[0], HARD_OBJECT_START[1], 0.4, 1.0, 0.0, 0.0, 0.0],
        }
        super().__init__(
            model_path=model_path,
            has_object=True,
            block_gripper=block_gripper,
            n_substeps=20,
            gripper_extra_height=gripper_extra_height,
            target_in_the_air=target_in_the_air,
            target_offset=0.0,
            obj_range=0.15,
            target_range=0.15,
            distance_threshold=DISTANCE_THRESHOLD,
            initial_qpos=initial_qpos,
            reward_type=reward_type,
            **kwargs,
        )
        if not TABLE_TOP_Z < self.height_offset < TABLE_TOP_Z + 0.03:
            raise RuntimeError(f"block resting height {self.height_offset:.3f} is not on the table: setup failed")
        self._mocap_low = None if self.gripper_low is None else np.asarray(self.gripper_low, dtype=np.float64)
        self._mocap_high = None if self.gripper_high is None else np.asarray(self.gripper_high, dtype=np.float64)
        # Bounds of the block centre (xy) used by the clamp in _step_callback: the walls' inner faces minus the
        # block's half size, plus a tolerance so that ordinary wall contacts never trigger it.
        inset = _BLOCK_HALF_SIZE - _CLAMP_TOLERANCE
        self._block_low = np.asarray(self.wall_low, dtype=np.float64) + inset
        self._block_high = np.asarray(self.wall_high, dtype=np.float64) - inset
        #: How often the position clamp fired since construction (a diagnostic: walls alone should hold).
        self.n_block_clamps = 0
        joint = self.model.joint("object0:joint")
        self._block_qpos = slice(int(joint.qposadr[0]), int(joint.qposadr[0]) + 2)
        self._block_qvel = slice(int(joint.dofadr[0]), int(joint.dofadr[0]) + 2)

    # --- scene construction -------------------------------------------------------------------------------------
    def _initialize_simulation(self) -> None:
        # As MujocoRobotEnv._initialize_simulation, but the model is compiled from an MjSpec with the walls added
        # (no temporary XML file is written).
        spec = mujoco.MjSpec.from_file(self.fullpath)
        self._add_walls(spec)
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self._model_names = self._utils.MujocoModelNames(self.model)
        self.model.vis.global_.offwidth = self.width
        self.model.vis.global_.offheight = self.height
        self._env_setup(initial_qpos=self.initial_qpos)
        self.initial_time = self.data.time
        self.initial_qpos = np.copy(self.data.qpos)
        self.initial_qvel = np.copy(self.data.qvel)

    def _add_walls(self, spec: mujoco.MjSpec) -> None:
        (x_lo, y_lo), (x_hi, y_hi) = self.wall_low, self.wall_high
        half_height = (self.wall_top_z - TABLE_TOP_Z) / 2.0
        z = TABLE_TOP_Z + half_height
        t = _WALL_HALF_THICKNESS
        x_mid, y_mid = (x_lo + x_hi) / 2.0, (y_lo + y_hi) / 2.0
        x_half, y_half = (x_hi - x_lo) / 2.0 + 2 * t, (y_hi - y_lo) / 2.0 + 2 * t
        walls = {
            "x_low": ([x_lo - t, y_mid, z], [t, y_half, half_height]),
            "x_high": ([x_hi + t, y_mid, z], [t, y_half, half_height]),
            "y_low": ([x_mid, y_lo - t, z], [x_half, t, half_height]),
            "y_high": ([x_mid, y_hi + t, z], [x_half, t, half_height]),
        }
        if self.walls_stop_robot:
            bits, rgba = 1, [0.55, 0.45, 0.35, 1.0]
        else:
            bits, rgba = _OBJECT_ONLY_BIT, [0.3, 0.3, 0.9, 0.08]  # faint: a constraint, not an obstacle
            block = spec.geom("object0")
            block.contype = block.contype | _OBJECT_ONLY_BIT
            block.conaffinity = block.conaffinity | _OBJECT_ONLY_BIT
        for side, (pos, size) in walls.items():
            spec.worldbody.add_geom(
                name=f"arena_wall_{side}",
                type=mujoco.mjtGeom.mjGEOM_BOX,
                pos=pos,
                size=size,
                rgba=rgba,
                contype=bits,
                conaffinity=bits,
                condim=3,
                # Stiff contacts (MuJoCo's defaults are solref (0.02, 1), solimp (0.9, 0.95)), dominating the
                # block's parameters in the mix: a gripper pressing the block into a wall cannot squeeze it in.
                solref=[0.01, 1.0],
                solimp=[0.99, 0.999, 0.001, 0.5, 2.0],
                solmix=1000.0,
            )

    # --- dynamics -----------------------------------------------------------------------------------------------
    def _set_action(self, action: np.ndarray) -> None:
        super()._set_action(action)
        if self._mocap_low is not None:
            # Limited robot workspace: the gripper's target never leaves the walled arena.
            np.clip(self.data.mocap_pos, self._mocap_low, self._mocap_high, out=self.data.mocap_pos)

    def _step_callback(self) -> None:
        super()._step_callback()  # keeps a blocked gripper closed
        # Safety net behind the walls: a gripper pressing the block into a wall can squeeze it through the soft
        # contact (always possible with the object-only walls, which the arm passes). A block centre past the
        # walls is put back on the boundary with its outward velocity removed - a hard position limit, like the
        # joint limits of IBC's version.
        xy = self.data.qpos[self._block_qpos]
        below, above = xy < self._block_low, xy > self._block_high
        if below.any() or above.any():
            self.n_block_clamps += 1
            self.data.qvel[self._block_qvel][below | above] = 0.0
            self.data.qpos[self._block_qpos] = np.clip(xy, self._block_low, self._block_high)
            mujoco.mj_forward(self.model, self.data)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """gymnasium-robotics' reset; ``options={"goal": g}`` commands the goal (other options raise)."""
        goal = commanded_goal(options, self.observation_space["desired_goal"], type(self).__name__)
        obs, info = super().reset(seed=seed)
        if goal is None:
            return obs, info
        self.goal = goal
        return self._get_obs(), info

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = super().step(action)
        return obs, float(reward), terminated, truncated, info  # Fetch returns a numpy float32 reward

    def _reset_sim(self) -> bool:
        mujoco.mj_resetData(self.model, self.data)
        self.data.time = self.initial_time
        self.data.qpos[:] = self.initial_qpos
        self.data.qvel[:] = self.initial_qvel
        object_qpos = self._utils.get_joint_qpos(self.model, self.data, "object0:joint").copy()
        object_qpos[:2] = self.sample_initial_goal(self.np_random)[:2]
        self._utils.set_joint_qpos(self.model, self.data, "object0:joint", object_qpos)
        mujoco.mj_forward(self.model, self.data)
        return True

    def _sample_goal(self) -> np.ndarray:
        return self.sample_evaluation_goal(self.np_random)

    # --- task-relevant goals ------------------------------------------------------------------------------------
    def sample_initial_goal(self, rng: np.random.Generator) -> np.ndarray:
        """rho_0: a block start position (goal space = block xyz)."""
        raise NotImplementedError

    def sample_evaluation_goal(self, rng: np.random.Generator) -> np.ndarray:
        """rho_g*: an evaluation goal for the block."""
        raise NotImplementedError


class _IBCFetchEnv(WalledFetchEnv):
    """IBC's ergodic Fetch: Fetch's own start/goal distributions, block held in a 0.4 m object-only box."""

    wall_low = (IBC_BOX_CENTER[0] - IBC_BOX_HALF_SIZE, IBC_BOX_CENTER[1] - IBC_BOX_HALF_SIZE)
    wall_high = (IBC_BOX_CENTER[0] + IBC_BOX_HALF_SIZE, IBC_BOX_CENTER[1] + IBC_BOX_HALF_SIZE)
    walls_stop_robot = False

    def sample_initial_goal(self, rng: np.random.Generator) -> np.ndarray:
        """rho_0 as Fetch: gripper start xy + U(-0.15, 0.15)^2, at least 10 cm from the gripper, on the table."""
        center = self.initial_gripper_xpos[:2]
        xy = center
        while np.linalg.norm(xy - center) < 0.1:
            xy = center + rng.uniform(-self.obj_range, self.obj_range, size=2)
        return np.array([xy[0], xy[1], self.height_offset])

    def sample_evaluation_goal(self, rng: np.random.Generator) -> np.ndarray:
        """rho_g* as Fetch: gripper start + U(-0.15, 0.15)^3 on the table; Pick&Place: w.p. 0.5 up to 45 cm up."""
        goal = self.initial_gripper_xpos[:3] + rng.uniform(-self.target_range, self.target_range, size=3)
        goal[2] = self.height_offset
        if self.target_in_the_air and rng.uniform() < 0.5:
            goal[2] += rng.uniform(0, 0.45)
        return goal


class _HardFetchEnv(WalledFetchEnv):
    """The thesis's hard Fetch: real walls on the table edges, limited gripper workspace, released gripper."""

    wall_low = HARD_ARENA_LOW
    wall_high = HARD_ARENA_HIGH
    # 15 cm tall: taller walls on the robot side are hit by the upper arm when the gripper reaches the near edge.
    wall_top_z = TABLE_TOP_Z + HARD_WALL_HEIGHT
    walls_stop_robot = True
    # The mocap target (gripper link) stays 3 cm inside the walls (where the gripper link touches them) and
    # at most 35 cm above the table.
    gripper_low = (HARD_ARENA_LOW[0] + 0.03, HARD_ARENA_LOW[1] + 0.03, TABLE_TOP_Z)
    gripper_high = (HARD_ARENA_HIGH[0] - 0.03, HARD_ARENA_HIGH[1] - 0.03, TABLE_TOP_Z + 0.35)

    def sample_initial_goal(self, rng: np.random.Generator) -> np.ndarray:
        """rho_0: the fixed block start (table centre, resting on the table)."""
        return np.array([HARD_OBJECT_START[0], HARD_OBJECT_START[1], self.height_offset])


class ErgodicFetchPushEnv(_IBCFetchEnv, EzPickle):
    """``GCRL/ErgodicFetchPush-v0``: IBC's ergodic Fetch Push (blocked gripper, block kept in a 0.4 m box).

    :param reward_type: ``"sparse"`` (thesis) or ``"dense"``, as in gymnasium-robotics' Fetch tasks.
    :param kwargs: forwarded to gymnasium-robotics' ``MujocoFetchEnv`` (e.g. ``render_mode``).
    """

    def __init__(self, reward_type: str = "sparse", **kwargs: Any) -> None:
        super().__init__(PUSH_XML, True, 0.0, False, reward_type=reward_type, **kwargs)
        EzPickle.__init__(self, reward_type=reward_type, **kwargs)


class ErgodicFetchPickAndPlaceEnv(_IBCFetchEnv, EzPickle):
    """``GCRL/ErgodicFetchPickAndPlace-v0``: IBC's ergodic Fetch Pick&Place (block kept in a 0.4 m box).

    :param reward_type: ``"sparse"`` (thesis) or ``"dense"``, as in gymnasium-robotics' Fetch tasks.
    :param kwargs: forwarded to gymnasium-robotics' ``MujocoFetchEnv`` (e.g. ``render_mode``).
    """

    def __init__(self, reward_type: str = "sparse", **kwargs: Any) -> None:
        super().__init__(PICK_AND_PLACE_XML, False, 0.2, True, reward_type=reward_type, **kwargs)
        EzPickle.__init__(self, reward_type=reward_type, **kwargs)


class FetchPushHardEnv(_HardFetchEnv, EzPickle):
    """``GCRL/FetchPushHard-v0``: Push (hard), goals U(-0.15, 0.15)^2 around the block start.

    :param reward_type: ``"sparse"`` (thesis) or ``"dense"``, as in gymnasium-robotics' Fetch tasks.
    :param kwargs: forwarded to gymnasium-robotics' ``MujocoFetchEnv`` (e.g. ``render_mode``).
    """

    def __init__(self, reward_type: str = "sparse", **kwargs: Any) -> None:
        # The finger actuators live in the pick-and-place scene; push.xml has none, so a "released" gripper
        # needs that scene (the two XML files differ only in those actuators).
        super().__init__(PICK_AND_PLACE_XML, False, 0.2, False, reward_type=reward_type, **kwargs)
        EzPickle.__init__(self, reward_type=reward_type, **kwargs)

    def sample_evaluation_goal(self, rng: np.random.Generator) -> np.ndarray:
        """rho_g*: block start + U(-0.15, 0.15)^2, on the table."""
        xy = np.asarray(HARD_OBJECT_START) + rng.uniform(-self.target_range, self.target_range, size=2)
        return np.array([xy[0], xy[1], self.height_offset])


class FetchPickAndPlaceHardEnv(_HardFetchEnv, EzPickle):
    """``GCRL/FetchPickAndPlaceHard-v0``: Pick&Place (hard), goals only in the air above the start.

    :param reward_type: ``"sparse"`` (thesis) or ``"dense"``, as in gymnasium-robotics' Fetch tasks.
    :param kwargs: forwarded to gymnasium-robotics' ``MujocoFetchEnv`` (e.g. ``render_mode``).
    """

    def __init__(self, reward_type: str = "sparse", **kwargs: Any) -> None:
        super().__init__(PICK_AND_PLACE_XML, False, 0.2, True, reward_type=reward_type, **kwargs)
        EzPickle.__init__(self, reward_type=reward_type, **kwargs)

    def sample_evaluation_goal(self, rng: np.random.Generator) -> np.ndarray:
        """rho_g*: uniform in a 5 x 5 x 10 cm box, 10-20 cm above the resting block at the start point."""
        xy = np.asarray(HARD_OBJECT_START) + rng.uniform(-HARD_AIR_GOAL_HALF_XY, HARD_AIR_GOAL_HALF_XY, size=2)
        z = self.height_offset + rng.uniform(*HARD_AIR_GOAL_HEIGHT)
        return np.array([xy[0], xy[1], z])
