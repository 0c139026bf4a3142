"""Make MEDAL's demonstration sets with scripted controllers (thesis Ch. 3, Section 3.7.2: 30 episodes per task).

Each episode starts from a seeded physical reset (rho_0) and is driven to the env's own goal (rho_g*) by a scripted
controller; only successful episodes are kept, each cut a few steps after its first success. The files go to
``sb3_gcrl/reset_free_baselines/demos/<task>.npz`` (package data; format in ``sb3_gcrl.reset_free_baselines.demos``),
with the reset seeds and the controller's name recorded in the file.

Usage: ``python scripts/make_demos.py`` (every task below), or ``--tasks GCRL/Tabletop-v0 --episodes 30``.
The thesis used trained MoReFree agents (outside EARL) or EARL's demonstrations; scripted controllers reach the goal
by a direct route, so these demonstrations are narrower than a learned agent's.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import sb3_gcrl  # noqa: F401  (registers the GCRL/ tasks)
from sb3_gcrl.reset_free_baselines.demos import Demonstrations, demo_path

Controller = Callable[[gym.Env, dict[str, np.ndarray]], np.ndarray]


def growing_tree(env: gym.Env, obs: dict[str, np.ndarray]) -> np.ndarray:
    """Move the height toward the goal at full speed."""
    high = env.action_space.high
    return np.clip(obs["desired_goal"] - obs["achieved_goal"], -high, high).astype(np.float32)


def _maze_controller(waypoints: list[tuple[int, int]]) -> Controller:
    """P-controller through cell centres, then to the goal (PointMaze; about 160 steps across the U)."""
    state: dict[str, int] = {"k": 0}

    def control(env: gym.Env, obs: dict[str, np.ndarray]) -> np.ndarray:
        base = env.unwrapped
        targets = [base.maze.cell_rowcol_to_xy(np.array(cell)) for cell in waypoints] + [obs["desired_goal"]]
        xy, velocity = obs["observation"][:2], obs["observation"][2:]
        if state["k"] < len(targets) - 1 and np.linalg.norm(targets[state["k"]] - xy) < 0.3:
            state["k"] += 1
        return np.clip(4 * (targets[state["k"]] - xy) - velocity, -1, 1).astype(np.float32)

    control.reset = lambda: state.update(k=0)  # type: ignore[attr-defined]
    return control


def tabletop(env: gym.Env, obs: dict[str, np.ndarray]) -> np.ndarray:
    """Reach the mug, grasp it, carry it to its goal, release it, bring the fist back to the centre."""
    fist, mug, held = obs["observation"][:2], obs["observation"][2:4], obs["observation"][4] == 0.0
    fist_goal, mug_goal = obs["desired_goal"][:2], obs["desired_goal"][2:]

    def toward(target: np.ndarray) -> np.ndarray:
        return np.clip((target - fist) / 0.2, -1, 1)

    if np.linalg.norm(mug - mug_goal) > 0.05:
        if held:
            return np.append(toward(fist + mug_goal - mug), 1.0).astype(np.float32)  # the mug keeps its offset
        if np.linalg.norm(mug - fist) < 0.3:
            return np.array([0.0, 0.0, 1.0], dtype=np.float32)  # grasp
        return np.append(toward(mug), -1.0).astype(np.float32)
    return np.append(toward(fist_goal), -1.0).astype(np.float32)  # release, go back


#: task id -> (controller factory, extra steps kept after the first success)
TASKS: dict[str, Callable[[], Controller]] = {
    "GCRL/GrowingTreeGoal-v0": lambda: growing_tree,
    "GCRL/PointUMazeGoal-v0": lambda: _maze_controller([(3, 3), (1, 3), (1, 1)]),
    "GCRL/Tabletop-v0": lambda: tabletop,
}
CONTROLLER_NAMES = {
    "GCRL/GrowingTreeGoal-v0": "move toward the goal height at full speed",
    "GCRL/PointUMazeGoal-v0": "waypoint P-controller through cells (3,3), (1,3), (1,1)",
    "GCRL/Tabletop-v0": "reach, grasp, carry, release, return",
}


def make_demos(task: str, episodes: int = 30, first_seed: int = 0, extra_steps: int = 5) -> Demonstrations:
    """Drive ``episodes`` successful episodes of ``task`` with its scripted controller.

    :param task: a key of :data:`TASKS`.
    :param episodes: successful episodes to keep.
    :param first_seed: reset seed of the first episode (the next ones count up; failures are skipped).
    :param extra_steps: steps kept after the first success (the agent settles at the goal).
    :return: the demonstrations.
    """
    env = gym.make(task)
    controller = TASKS[task]()
    columns: dict[str, list[Any]] = {"obs": [], "next": [], "actions": [], "rewards": [], "starts": []}
    seeds: list[int] = []
    seed = first_seed
    while len(seeds) < episodes:
        if seed > first_seed + 10 * episodes:
            raise RuntimeError(f"the {task} controller fails too often ({len(seeds)} successes)")
        obs, _ = env.reset(seed=seed)
        if hasattr(controller, "reset"):
            controller.reset()
        episode: dict[str, list[Any]] = {key: [] for key in columns}
        after = None
        for _ in range(env.spec.max_episode_steps):
            action = controller(env, obs)
            next_obs, reward, terminated, truncated, info = env.step(action)
            episode["obs"].append(obs)
            episode["next"].append(next_obs)
            episode["actions"].append(action)
            episode["rewards"].append(float(reward))
            episode["starts"].append(not episode["starts"])
            obs = next_obs
            if info.get("is_success") and after is None:
                after = 0
            if after is not None:
                after += 1
                if after > extra_steps:
                    break
            if terminated or truncated:
                break
        if after is not None:
            seeds.append(seed)
            for key in columns:
                columns[key].extend(episode[key])
        seed += 1
    env.close()
    keys = list(columns["obs"][0])
    return Demonstrations(
        observations={k: np.stack([o[k] for o in columns["obs"]]) for k in keys},
        next_observations={k: np.stack([o[k] for o in columns["next"]]) for k in keys},
        actions=np.stack(columns["actions"]).astype(np.float32),
        rewards=np.array(columns["rewards"], dtype=np.float32),
        episode_starts=np.array(columns["starts"], dtype=bool),
        metadata={"env_id": task, "seeds": np.array(seeds, dtype=np.int64), "controller": CONTROLLER_NAMES[task]},
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", default=sorted(TASKS), choices=sorted(TASKS))
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--output-dir", type=Path, default=None, help="default: the package's demos folder")
    args = parser.parse_args(argv)
    for task in args.tasks:
        demos = make_demos(task, args.episodes, args.first_seed)
        path = demo_path(task) if args.output_dir is None else args.output_dir / demo_path(task).name
        path.parent.mkdir(parents=True, exist_ok=True)
        demos.save(path)
        print(f"{task}: {demos.n_episodes} episodes, {len(demos)} transitions -> {path}")


if __name__ == "__main__":
    main()
