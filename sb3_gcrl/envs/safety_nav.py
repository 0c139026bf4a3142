"""PointGoal and CarGoal: Safety-Gym's Goal0 navigation tasks rebuilt on plain MuJoCo (thesis Ch. 4).

Thesis source: Sec. 4.5.2, Fig. 4.3 ("Safexp-PointGoal", "Safexp-CarGoal"), Table 4.2 (state dims 24 and
36, action dim 2), Table 4.4 (CEC hyperparameters): sparse reward, "locations of both goals and agents are
initialized with small randomness every episode". Safety-Gym (mujoco-py, MuJoCo 2.0) does not run on our stack and
safety-gymnasium, its maintained port, only with repairs (:mod:`sb3_gcrl.envs.safety_gymnasium_compat`), so the robots
and the Goal task are rebuilt here from their robot models and task settings. With safety-gymnasium installed, the
tests run its robots beside ours from the same pose with the same actions: positions, velocities and sensors agree
to rounding for hundreds of steps (``tests/test_safety_gymnasium.py``).

Registered ids:

==========================  =====================  =========  ==========================================
id                          observation            horizon    episode end
==========================  =====================  =========  ==========================================
``GCRL/PointGoal-v0``       ``Box (24,) float32``  1000       terminates in the goal zone, reward 1
``GCRL/CarGoal-v0``         ``Box (36,) float32``  1000       terminates in the goal zone, reward 1
==========================  =====================  =========  ==========================================

Robots (Safety-Gym's ``point.xml`` / ``car.xml``):

- Point: a sphere (radius 0.1) with a small box "nose" on slide x / slide y / hinge z joints; actuator 0 is a motor
  pushing along the heading (gear 0.3), actuator 1 a velocity servo on the hinge (gear 0.3, gain 1: torque
  ``0.3 * clip(u - 0.3 * omega, -0.05, 0.05)``, so full turning torque until ``omega`` nears ``u / 0.3``);
  timestep 0.002 s. At this gain MuJoCo's Euler step integrates the servo's velocity feedback unstably and the force
  limit bounds the result: below saturation the turn rate chatters between two values on alternate physics steps
  (about +-0.48 rad/s around 0 at ``u = 0``). The real robot does the same, and its gyro reads that chatter too.
- Car: a box chassis on a free joint with two wheels on hinge joints (left / right motors, torque-limited to
  0.02) and a passive rear ball; timestep 0.004 s. Driving straight needs both wheels turning the same
  way, turning needs them to differ: both actions must be coordinated (thesis Sec. 4.5).

Observation (Safety-Gym's flattened layout, keys in alphabetical order): ``accelerometer`` (3),
[Car: ``ballangvel_rear`` (3), ``ballquat_rear`` as a 3x3 rotation matrix (9)], ``goal_lidar`` (12),
``gyro`` (3), ``magnetometer`` (3), ``velocimeter`` (3); all but the lidar are MuJoCo sensors read from
``data.sensordata``. The goal lidar is Safety-Gym's "pseudo" lidar: ``n`` bins around the robot in its own
frame, the bin containing the goal reads the closeness ``max(0, 3 - d) / 3`` (``d`` the planar distance,
``lidar_max_dist = 3`` as Safety-Gym's benchmark suite), and its two neighbours read that closeness times the
goal's angular offset within the bin (``alias``) and times ``1 - alias`` (Safety-Gym's aliasing). Safety-Gym
uses 16 bins (28 / 40 dims); Table 4.2's 24 / 36 dims fit 12 bins exactly, so we use 12 (inferred, the thesis
does not name the bin count).

Task: goal zone of radius ``goal_size = 0.3`` (Safety-Gym Goal); reaching it (planar distance from the
robot body to the goal centre ``<= 0.3``) pays 1, sets ``info["is_success"]`` and terminates. Start: robot
at (-0.5, 0), goal at (0.5, 0), each position + U(-0.1, 0.1) per coordinate (the thesis's "small randomness" of
the locations), heading uniform in [-pi, pi) as in Safety-Gym. Both points lie inside Safety-Gym's Goal0
placement extents [-1, 1]^2 and respect its 0.4 / 0.305 keep-outs; their distance, 1.0, is about the mean
robot-goal distance of Goal0's random layouts (0.97). Actions ``Box(-1, 1, (2,))`` are the controls, clipped to their
range [-1, 1] as Safety-Gym does; each env step runs 10 physics steps (Safety-Gym's frame skip, fixed).

Departures from Safety-Gym (docs/envs.md): sparse reward only (Safety-Gym adds a dense distance-progress
reward) and termination at the goal (Safety-Gym draws a new goal and continues); fixed nominal start and
goal with small noise (Safety-Gym draws both anywhere in [-1, 1]^2); 12 lidar bins; float32 observations
(safety-gymnasium's are float64, and it flattens its keys in insertion order, not Safety-Gym's sorted order).
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from sb3_gcrl.common.validation import check_choice

_RESET_OPTIONS = ("reset_pos", "goal", "heading")
#: radius of the goal zone (Safety-Gym's Goal task)
GOAL_SIZE = 0.3
#: height of the robot body's frame above the floor at the start (both robots' XML)
_BODY_HEIGHT = 0.1

# Shared scene: an (infinite) floor plane, a visual goal zone (no collisions), an overhead camera.
_SCENE = """
<mujoco model="{name}">
  <compiler angle="radian"/>
  <option timestep="{timestep}"/>
  <visual><global offwidth="{width}" offheight="{height}"/></visual>
  <default>
    <geom condim="6" density="{density}" rgba="0.74 0.04 0.18 1"{geom_size}/>
    <joint damping="0.001"/>
    <motor ctrlrange="-1 1" ctrllimited="true" forcerange="-{force} {force}" forcelimited="true"/>
    <velocity ctrlrange="-1 1" ctrllimited="true" forcerange="-{force} {force}" forcelimited="true"/>
    <site size="0.032" type="sphere"/>
  </default>
  <worldbody>
    <light pos="0 0 4" dir="0 0 -1" directional="true"/>
    <camera name="overview" pos="0 0 4.5" xyaxes="1 0 0 0 1 0"/>
    <geom name="floor" type="plane" size="3.5 3.5 0.1" rgba="0.85 0.85 0.85 1"/>
    <body name="goal" mocap="true" pos="0 0 0">
      <geom name="goal" type="cylinder" size="{goal_size} 0.01" contype="0" conaffinity="0"
            rgba="0 1 0 0.35"/>
    </body>
    {robot}
  </worldbody>
  <sensor>
    {extra_sensors}
    <accelerometer site="robot" name="accelerometer"/>
    <velocimeter site="robot" name="velocimeter"/>
    <gyro site="robot" name="gyro"/>
    <magnetometer site="robot" name="magnetometer"/>
  </sensor>
  <actuator>
    {actuators}
  </actuator>
</mujoco>
"""

# Safety-Gym's point robot: slide x/y + hinge z, forward force along the heading and a turning torque.
_POINT = {
    "timestep": 0.002,
    "density": 1,
    "geom_size": "",
    "force": 0.05,
    "robot": """
    <body name="robot" pos="0 0 0.1">
      <joint name="x" type="slide" axis="1 0 0" damping="0.01"/>
      <joint name="y" type="slide" axis="0 1 0" damping="0.01"/>
      <joint name="z" type="hinge" axis="0 0 1" damping="0.005"/>
      <geom name="robot" type="sphere" size="0.1" friction="1 0.01 0.01"/>
      <geom name="pointarrow" type="box" pos="0.1 0 0" size="0.05 0.05 0.05" rgba="0 0.15 0.4 1"/>
      <site name="robot" rgba="1 0 0 0.1"/>
    </body>""",
    "extra_sensors": "",
    "actuators": """<motor name="x" site="robot" gear="0.3 0 0 0 0 0"/>
    <velocity name="z" joint="z" gear="0.3"/>""",
}

# Safety-Gym's car: box chassis on a free joint, two driven wheels (hinges about the body x axis, so the car
# rolls along its y axis), a passive rear ball; the ball joint's quaternion and angular velocity are observed.
_CAR = {
    "timestep": 0.004,
    "density": 5,
    "geom_size": ' size="0.05" type="sphere"',
    "force": 0.02,
    "robot": """
    <body name="robot" pos="0 0 0.1">
      <site name="robot"/>
      <joint name="robot" type="free" damping="0"/>
      <geom name="robot" type="box" size="0.1 0.1 0.05"/>
      <geom name="back_bumper" type="box" pos="0 0.15 0" size="0.1 0.01 0.05" rgba="0 0.15 0.4 1"/>
      <geom name="back_connector" type="box" pos="0 0.125 0" size="0.01 0.025 0.03" rgba="0 0.15 0.4 1"/>
      <geom name="front_bumper" type="box" pos="0 -0.165 0" size="0.05 0.01 0.05" rgba="0 0.15 0.4 1"/>
      <geom name="front_connector" type="box" pos="0 -0.13 0.04" size="0.05 0.03 0.01" rgba="0 0.15 0.4 1"/>
      <body name="left" pos="-0.1 0.1 -0.05">
        <joint name="left" type="hinge" axis="1 0 0"/>
        <geom name="left" type="cylinder" fromto="-0.055 0 0 -0.005 0 0"/>
      </body>
      <body name="right" pos="0.1 0.1 -0.05">
        <joint name="right" type="hinge" axis="1 0 0"/>
        <geom name="right" type="cylinder" fromto="0.005 0 0 0.055 0 0"/>
      </body>
      <body name="rear" pos="0 -0.1 -0.05">
        <joint name="rear" type="ball"/>
        <geom name="rear"/>
      </body>
    </body>""",
    "extra_sensors": """<ballquat joint="rear" name="ballquat_rear"/>
    <ballangvel joint="rear" name="ballangvel_rear"/>""",
    "actuators": """<motor name="left" joint="left" gear="1"/>
    <motor name="right" joint="right" gear="1"/>""",
}

_ROBOTS = {"point": _POINT, "car": _CAR}


def robot_xml(robot: str, goal_size: float = GOAL_SIZE, width: int = 480, height: int = 480) -> str:
    """The MJCF model of the scene with Safety-Gym's ``"point"`` or ``"car"`` robot.

    :param robot: ``"point"`` or ``"car"``.
    :param goal_size: radius of the (visual) goal zone.
    :param width: offscreen framebuffer width (rendering).
    :param height: offscreen framebuffer height (rendering).
    """
    if robot not in _ROBOTS:
        raise ValueError(f"robot must be one of {sorted(_ROBOTS)}, got {robot!r}.")
    return _SCENE.format(name=robot, goal_size=goal_size, width=width, height=height, **_ROBOTS[robot])


def pseudo_lidar(ego_xy: np.ndarray, num_bins: int, max_dist: float) -> np.ndarray:
    """Safety-Gym's pseudo lidar of one object at ``ego_xy`` (robot frame) with aliasing into both neighbours.

    Bin ``i`` covers angles ``[2 pi i / n, 2 pi (i + 1) / n)`` counter-clockwise from the robot's x axis. The
    object's bin reads ``c = max(0, max_dist - d) / max_dist``; the next bin ``alias * c`` and the previous bin
    ``(1 - alias) * c``, ``alias`` being the object's angular offset within its bin (fraction of a bin).

    :param ego_xy: the object's planar position in the robot's frame.
    :param num_bins: number of bins around the full circle.
    :param max_dist: distance at which the reading falls to 0.
    """
    obs = np.zeros(num_bins)
    dist = math.hypot(ego_xy[0], ego_xy[1])
    angle = math.atan2(ego_xy[1], ego_xy[0]) % (2 * math.pi)
    bin_size = 2 * math.pi / num_bins
    index = min(int(angle / bin_size), num_bins - 1)
    closeness = max(0.0, max_dist - dist) / max_dist
    alias = angle / bin_size - index
    obs[(index + 1) % num_bins] = alias * closeness
    obs[(index - 1) % num_bins] = max(obs[(index - 1) % num_bins], (1 - alias) * closeness)
    obs[index] = closeness
    return obs


def _xy(value: Any, name: str) -> np.ndarray:
    xy = np.asarray(value, dtype=np.float64)
    if xy.shape != (2,) or not np.all(np.isfinite(xy)):
        raise ValueError(f"{name} must be a finite (x, y) pair, got {value!r}.")
    return xy.copy()


class SafetyGoalEnv(gym.Env):
    """Safety-Gym's Goal0 task (open plane, one goal zone, no hazards) with a sparse, terminating reward.

    :param robot: ``"point"`` (24-dim observation) or ``"car"`` (36-dim).
    :param start_xy: nominal robot start position.
    :param goal_xy: nominal goal position.
    :param start_noise: half-width of the uniform noise added to each start coordinate.
    :param goal_noise: half-width of the uniform noise added to each goal coordinate.
    :param heading: nominal robot heading (rad, yaw of the robot's frame).
    :param heading_noise: half-width of the uniform noise added to the heading (default pi: uniform, as
        Safety-Gym; with a nearly fixed heading the Point faces the goal and a constant full push solves the task).
    :param goal_size: radius of the goal zone (Safety-Gym: 0.3).
    :param lidar_num_bins: goal-lidar bins (12 fits the thesis's Table 4.2; Safety-Gym: 16).
    :param lidar_max_dist: distance at which the lidar reads 0 (Safety-Gym's suite: 3).
    :param frame_skip: physics steps per env step (Safety-Gym: 10).
    :param terminate_at_goal: end the episode on reaching the goal zone.
    :param render_mode: ``None`` or ``"rgb_array"`` (overhead camera; ``MUJOCO_GL=egl`` on a headless machine).
    :param width: rendered frame width.
    :param height: rendered frame height.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(
        self,
        robot: str = "point",
        start_xy: tuple[float, float] = (-0.5, 0.0),
        goal_xy: tuple[float, float] = (0.5, 0.0),
        start_noise: float = 0.1,
        goal_noise: float = 0.1,
        heading: float = 0.0,
        heading_noise: float = math.pi,
        goal_size: float = GOAL_SIZE,
        lidar_num_bins: int = 12,
        lidar_max_dist: float = 3.0,
        frame_skip: int = 10,
        terminate_at_goal: bool = True,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
    ) -> None:
        if robot not in _ROBOTS:
            raise ValueError(f"robot must be one of {sorted(_ROBOTS)}, got {robot!r}.")
        for name, value in (("start_noise", start_noise), ("goal_noise", goal_noise), ("heading_noise", heading_noise)):
            if not value >= 0:
                raise ValueError(f"{name} must be non-negative, got {value}.")
        for name, value in (("goal_size", goal_size), ("lidar_max_dist", lidar_max_dist)):
            if not value > 0:
                raise ValueError(f"{name} must be positive, got {value}.")
        for name, value in (("lidar_num_bins", lidar_num_bins), ("frame_skip", frame_skip)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}.")
        check_choice("render_mode", render_mode, (None, *self.metadata["render_modes"]))
        self.robot = robot
        self.start_xy = _xy(start_xy, "start_xy")
        self.goal_xy = _xy(goal_xy, "goal_xy")
        self.start_noise = float(start_noise)
        self.goal_noise = float(goal_noise)
        self.heading = float(heading)
        self.heading_noise = float(heading_noise)
        self.goal_size = float(goal_size)
        self.lidar_num_bins = int(lidar_num_bins)
        self.lidar_max_dist = float(lidar_max_dist)
        self.frame_skip = int(frame_skip)
        self.terminate_at_goal = terminate_at_goal
        self.render_mode = render_mode
        self.width, self.height = int(width), int(height)

        self.model = mujoco.MjModel.from_xml_string(robot_xml(robot, self.goal_size, self.width, self.height))
        self.data = mujoco.MjData(self.model)
        self._robot_body = self.model.body("robot").id
        self._goal_mocap = self.model.body("goal").mocapid[0]
        # the controls' ranges (both robots: [-1, 1], the action space); an action is clipped to them, as Safety-Gym
        self._ctrl_ranges = [(float(low), float(high)) for low, high in self.model.actuator_ctrlrange]
        # Sensor slices in Safety-Gym's (alphabetical) observation order; the lidar goes in between.
        names = ["accelerometer"] + (["ballangvel_rear", "ballquat_rear"] if robot == "car" else [])
        self._sensors_before = [self._sensor_slice(name) for name in names]
        self._sensors_after = [self._sensor_slice(name) for name in ("gyro", "magnetometer", "velocimeter")]
        sizes_before = [3, 3, 9] if robot == "car" else [3]
        n_before, n_after = sum(sizes_before), 9
        obs_dim = n_before + self.lidar_num_bins + n_after
        low = np.full(obs_dim, -np.inf, dtype=np.float32)
        high = np.full(obs_dim, np.inf, dtype=np.float32)
        low[n_before : n_before + self.lidar_num_bins] = 0.0
        high[n_before : n_before + self.lidar_num_bins] = 1.0
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.model.nu,), dtype=np.float32)
        self._lidar_slice = slice(n_before, n_before + self.lidar_num_bins)
        self.goal = self.goal_xy.copy()
        self._renderer: mujoco.Renderer | None = None

    def _sensor_slice(self, name: str) -> slice:
        sensor = self.model.sensor(name)
        return slice(int(sensor.adr[0]), int(sensor.adr[0] + sensor.dim[0]))

    # Task-relevant goals (rho_0 and rho_g*), as the PointMaze tasks declare them.
    def sample_initial_goal(self, rng: np.random.Generator) -> np.ndarray:
        """A start position (rho_0): ``start_xy`` + U(-start_noise, start_noise)^2."""
        return self.start_xy + rng.uniform(-self.start_noise, self.start_noise, size=2)

    def sample_evaluation_goal(self, rng: np.random.Generator) -> np.ndarray:
        """A goal position (rho_g*): ``goal_xy`` + U(-goal_noise, goal_noise)^2."""
        return self.goal_xy + rng.uniform(-self.goal_noise, self.goal_noise, size=2)

    @property
    def robot_xy(self) -> np.ndarray:
        """The robot body's planar position."""
        return self.data.xpos[self._robot_body, :2].copy()

    @property
    def robot_yaw(self) -> float:
        """The robot frame's yaw (rad): the angle of its x axis in the plane."""
        xmat = self.data.xmat[self._robot_body]
        return math.atan2(xmat[3], xmat[0])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        """Reset the robot near ``start_xy`` and the goal near ``goal_xy``.

        :param options: optional overrides ``reset_pos`` / ``goal`` (exact ``(x, y)``) and ``heading`` (rad).
        """
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - set(_RESET_OPTIONS)
        if unknown:
            raise ValueError(f"Unknown reset options {sorted(unknown)}; Safety goal tasks accept {_RESET_OPTIONS}.")
        # Fixed draw order (goal, start, heading) so that a seed gives one layout whatever the overrides.
        goal = self.sample_evaluation_goal(self.np_random)
        start = self.sample_initial_goal(self.np_random)
        heading = self.heading + self.np_random.uniform(-self.heading_noise, self.heading_noise)
        if options.get("goal") is not None:
            goal = _xy(options["goal"], "goal")
        if options.get("reset_pos") is not None:
            start = _xy(options["reset_pos"], "reset_pos")
        if options.get("heading") is not None:
            heading = float(options["heading"])
        self.goal = goal.copy()
        mujoco.mj_resetData(self.model, self.data)
        self.data.mocap_pos[self._goal_mocap] = [goal[0], goal[1], 0.0]
        quat = [math.cos(heading / 2), 0.0, 0.0, math.sin(heading / 2)]  # yaw only
        if self.robot == "point":
            # As Safety-Gym builds its scene: the body frame at the start pose, the slide and hinge joints at zero
            # (the slides then move along the start heading's axes). Joints at the pose from a world-aligned frame
            # are the same mechanism, but their rounding differs, and the turning actuator's chatter (module doc)
            # grows such differences into a different trajectory within a few env steps.
            self.model.body_pos[self._robot_body] = [start[0], start[1], _BODY_HEIGHT]
            self.model.body_quat[self._robot_body] = quat
        else:  # free joint: the pose is its position and quaternion
            self.data.qpos[:7] = [start[0], start[1], _BODY_HEIGHT, *quat]
        mujoco.mj_forward(self.model, self.data)
        success = self._success()
        return self._observation(), {"is_success": success}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        values = [float(value) for value in np.ravel(action)]  # two floats: cheaper than array arithmetic
        if len(values) != self.model.nu or not all(math.isfinite(value) for value in values):
            raise ValueError(f"{type(self).__name__} needs {self.model.nu} finite action values, got {action!r}.")
        ctrl = self.data.ctrl
        for i, (value, (low, high)) in enumerate(zip(values, self._ctrl_ranges)):
            ctrl[i] = min(max(value, low), high)
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        mujoco.mj_forward(self.model, self.data)  # sensors of the new state (as Safety-Gym)
        success = self._success()
        info = {"is_success": success}
        return self._observation(), float(success), success and self.terminate_at_goal, False, info

    def _success(self) -> bool:
        x, y = self.data.xpos[self._robot_body, :2]
        return math.hypot(x - self.goal[0], y - self.goal[1]) <= self.goal_size

    def _observation(self) -> np.ndarray:
        sensordata = self.data.sensordata
        parts = [sensordata[s] for s in self._sensors_before]
        if self.robot == "car":  # the ball joint's quaternion as a rotation matrix (Safety-Gym)
            matrix = np.empty(9)
            mujoco.mju_quat2Mat(matrix, parts[2])
            parts[2] = matrix
        # goal in the robot's frame: R^T (goal - robot)
        offset = np.array([self.goal[0], self.goal[1], 0.0]) - self.data.xpos[self._robot_body]
        ego = self.data.xmat[self._robot_body].reshape(3, 3).T @ offset
        parts.append(pseudo_lidar(ego[:2], self.lidar_num_bins, self.lidar_max_dist))
        parts.extend(sensordata[s] for s in self._sensors_after)
        return np.concatenate(parts).astype(np.float32)

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, self.height, self.width)
        self._renderer.update_scene(self.data, camera="overview")
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


class PointGoalEnv(SafetyGoalEnv):
    """Safety-Gym's Point robot on the Goal0 task (``GCRL/PointGoal-v0``, 24-dim observation).

    :param kwargs: parameters of :class:`SafetyGoalEnv` except ``robot``.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(robot="point", **kwargs)


class CarGoalEnv(SafetyGoalEnv):
    """Safety-Gym's Car robot on the Goal0 task (``GCRL/CarGoal-v0``, 36-dim observation).

    :param kwargs: parameters of :class:`SafetyGoalEnv` except ``robot``.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(robot="car", **kwargs)
