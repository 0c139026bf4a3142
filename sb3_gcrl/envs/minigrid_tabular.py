"""Tabular MiniGrid tasks of the post-exploration chapter (thesis Ch. 6, Sec. 6.5, Fig. 6.2-6.4).

Registered ids (all built by :func:`make_tabular_minigrid`):

===============================  ===============================  ==============  =========
id                               MiniGrid task                    observation     horizon
===============================  ===============================  ==============  =========
``GCRL/FourRoomsTabular-v0``     ``MiniGrid-FourRooms-v0``        Discrete(1444)  100
``GCRL/LavaCrossingTabular-v0``  ``MiniGrid-LavaCrossingS9N1-v0``  Discrete(324)   324
``GCRL/LavaGapTabular-v0``       ``MiniGrid-LavaGapS7-v0``        Discrete(196)   196
===============================  ===============================  ==============  =========

- Observation: the agent's tabular state ``(x, y, direction)`` as one index,
  ``index = (y * width + x) * 4 + direction`` (:func:`encode_state` / :func:`decode_state`; the goal space
  of the post-exploration agents is ``(x, y)``, i.e. ``index // 4``). Wall cells have indices too; they are
  never visited.
- Action: ``Discrete(3)``: 0 turn left, 1 turn right, 2 forward (MiniGrid's first three actions; the other
  four do nothing in these tasks). ``navigation_actions=False`` keeps MiniGrid's ``Discrete(7)``.
- Reward: MiniGrid's sparse ``1 - 0.9 * step_count / max_steps`` on reaching the green goal (terminates);
  stepping into lava terminates with reward 0. MiniGrid truncates at ``max_steps``.
- Layout: fixed per ``layout_seed`` (``gym.make(id, layout_seed=k)``, default 0): every reset regenerates the
  grid from that seed, so the walls, lava, goal and start pose are the same in every episode. The seed
  passed to ``reset`` cannot change anything (MiniGrid's dynamics are deterministic); the thesis's "10
  environment seeds" of the lava tasks are ``layout_seed=0..9``. These tasks are static, so the grid is
  built once and later resets only restore the start pose (``cache_layout=True``).

Departures from the thesis: the thesis does not name the sizes of the lava tasks; we use MiniGrid's
``LavaCrossingS9N1`` and ``LavaGapS7``. The action set is restricted to the three navigation actions. The
wrapper skips MiniGrid's 7x7 egocentric image (it replaces the observation anyway), which makes a step
about 6x faster.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding

N_DIRECTIONS = 4


def encode_state(x: int, y: int, direction: int, width: int) -> int:
    """Tabular index of agent pose ``(x, y, direction)`` in a grid ``width`` cells wide."""
    return (int(y) * width + int(x)) * N_DIRECTIONS + int(direction)


def decode_state(index: int, width: int) -> tuple[int, int, int]:
    """Agent pose ``(x, y, direction)`` of tabular ``index`` (inverse of :func:`encode_state`)."""
    cell, direction = divmod(int(index), N_DIRECTIONS)
    y, x = divmod(cell, width)
    return x, y, direction


def _require_minigrid(env: gym.Env, wrapper: str) -> None:
    from minigrid.minigrid_env import MiniGridEnv

    if not isinstance(env.unwrapped, MiniGridEnv):
        raise TypeError(
            f"{wrapper} needs a MiniGrid environment (minigrid.minigrid_env.MiniGridEnv), got "
            f"{type(env.unwrapped).__name__}; create it with gym.make('MiniGrid-...')."
        )


class FixedLayout(gym.Wrapper):
    """Regenerate a MiniGrid task from the same seed at every reset (one fixed layout and start pose).

    Like ``minigrid.wrappers.ReseedWrapper(env, seeds=[layout_seed])``, but a seed given to ``reset`` is not
    dropped: after the layout is built from ``layout_seed``, the env's ``np_random`` is re-seeded with it
    (MiniGrid's navigation dynamics never draw from it, so episodes stay identical).

    :param env: a MiniGrid environment.
    :param layout_seed: seed that selects the layout.
    :param cache_layout: build the grid once and afterwards only put the agent back at its start pose
        (about 20x faster resets). Only valid for static tasks whose grid nothing can change, e.g. FourRooms
        and the lava tasks (no doors, objects or moving obstacles); the registered tasks use it.
    """

    def __init__(self, env: gym.Env, layout_seed: int = 0, cache_layout: bool = False) -> None:
        _require_minigrid(env, "FixedLayout")
        if int(layout_seed) < 0:
            raise ValueError(f"layout_seed must be a non-negative integer, got {layout_seed}.")
        super().__init__(env)
        self.layout_seed = int(layout_seed)
        self.cache_layout = cache_layout
        self._start_pose: tuple[tuple[int, int], int] | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        base = self.env.unwrapped
        if self._start_pose is None or options:
            obs, info = self.env.reset(seed=self.layout_seed, options=options)
            if self.cache_layout:
                x, y = base.agent_pos
                self._start_pose = ((int(x), int(y)), int(base.agent_dir))
        else:
            # What MiniGridEnv.reset does after _gen_grid, on the unchanged grid built from layout_seed.
            base.agent_pos, base.agent_dir = self._start_pose
            base.carrying = None
            base.step_count = 0
            obs, info = base.gen_obs(), {}
        if seed is not None:
            base.np_random, _ = seeding.np_random(seed)
        return obs, info


class TabularMiniGridObservation(gym.Wrapper):
    """Replace a MiniGrid observation by the ``Discrete`` index of the agent's ``(x, y, direction)``.

    :param env: a MiniGrid environment (possibly wrapped).
    :param navigation_actions: restrict the action space to ``Discrete(3)`` (left, right, forward).
    :param skip_image: stop MiniGrid from rendering its egocentric image, which this wrapper discards
        anyway (it replaces ``gen_obs`` on the wrapped instance). Set False if another wrapper between
        this one and the base env reads the image.
    """

    def __init__(self, env: gym.Env, navigation_actions: bool = True, skip_image: bool = True) -> None:
        _require_minigrid(env, "TabularMiniGridObservation")
        super().__init__(env)
        base = env.unwrapped
        self.width = int(base.width)
        self.height = int(base.height)
        self.observation_space = spaces.Discrete(self.width * self.height * N_DIRECTIONS)
        if navigation_actions:
            # MiniGrid's actions 0, 1, 2 are left, right, forward: a prefix of its Discrete(7).
            self.action_space = spaces.Discrete(3)
        if skip_image:
            base.gen_obs = _no_image

    def encode(self, x: int, y: int, direction: int) -> int:
        """Index of pose ``(x, y, direction)`` in this grid."""
        return encode_state(x, y, direction, self.width)

    def decode(self, index: int) -> tuple[int, int, int]:
        """Pose ``(x, y, direction)`` of ``index`` in this grid."""
        return decode_state(index, self.width)

    def _state(self) -> np.int64:
        base = self.env.unwrapped
        return np.int64(encode_state(base.agent_pos[0], base.agent_pos[1], base.agent_dir, self.width))

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.int64, dict]:
        _, info = self.env.reset(seed=seed, options=options)
        return self._state(), info

    def step(self, action: int) -> tuple[np.int64, float, bool, bool, dict]:
        if not self.action_space.contains(action):
            raise ValueError(f"Invalid action {action!r} for action space {self.action_space}.")
        _, reward, terminated, truncated, info = self.env.step(action)
        info["is_success"] = bool(terminated and reward > 0)
        return self._state(), float(reward), terminated, truncated, info


def _no_image() -> dict[str, Any]:
    """Stand-in for ``MiniGridEnv.gen_obs`` when only the agent pose is observed."""
    return {}


def make_tabular_minigrid(
    minigrid_id: str,
    layout_seed: int = 0,
    navigation_actions: bool = True,
    cache_layout: bool = False,
    render_mode: str | None = None,
    **kwargs: Any,
) -> gym.Env:
    """Build a tabular MiniGrid task: ``TabularMiniGridObservation(FixedLayout(gym.make(minigrid_id)))``.

    :param minigrid_id: a MiniGrid id, e.g. ``"MiniGrid-LavaGapS7-v0"``.
    :param layout_seed: seed of the fixed layout.
    :param navigation_actions: see :class:`TabularMiniGridObservation`.
    :param cache_layout: see :class:`FixedLayout` (only for static tasks).
    :param render_mode: forwarded to MiniGrid (``"rgb_array"`` draws the full grid).
    :param kwargs: forwarded to the MiniGrid constructor (e.g. ``max_steps``).
    """
    import minigrid  # noqa: F401  (registers the MiniGrid ids)

    env = gym.make(minigrid_id, render_mode=render_mode, disable_env_checker=True, **kwargs).unwrapped
    return TabularMiniGridObservation(
        FixedLayout(env, layout_seed, cache_layout=cache_layout), navigation_actions=navigation_actions
    )
