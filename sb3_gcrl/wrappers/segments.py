"""Training curves of reset-free and goal-commanded training: segments reported as SB3's Monitor reports episodes.

In training mode the wrappers of this package cut the physical stream of steps into the pieces SB3 sees as
episodes: reset-free *segments* (:class:`~sb3_gcrl.wrappers.ResetFreeWrapper`; one Go phase plus its Explore phase
for :class:`~sb3_gcrl.wrappers.GoExploreWrapper`, thesis Algorithm 1) and IMGEP episodes that end at the goal or after
post-exploration (:class:`~sb3_gcrl.post_exploration.PostExplorationWrapper`, thesis Ch. 6). SB3's ``Monitor`` sits
*below* these wrappers (``make_vec_env`` and RL-Zoo put it inside ``env_wrapper``), so it sees only the physical
episodes: none for ``hard_reset_every`` steps in reset-free mode, only the unsuccessful ones in post-exploration. Left
to it, the CSV would stay empty and SB3 would log no ``rollout/*`` values.

:class:`SegmentRecorder` fixes this in the outermost mode-switched wrapper, in training mode only. At the last step of
every segment it

* puts ``info["episode"] = {"r": return, "l": length, "t": seconds}`` (plus the Monitor's ``info_keywords``), which
  SB3 turns into ``rollout/ep_rew_mean`` and ``rollout/ep_len_mean``;
* sets ``info["is_success"]`` to whether the goal was reached at *some* step of the segment (SB3's
  ``rollout/success_rate`` reads the last step only, where a Go-Explore agent is usually exploring elsewhere);
* sets ``info["goal_kind"]`` to the kind of the commanded goal (``"forward"``, ``"back"``, ``"explore"``, ...), which
  the callbacks log as ``rollout/goal_success_<evaluation|initial|exploratory>``;
* writes the row into the CSV of the ``Monitor`` below, in the Monitor's own format, so ``rl_zoo3 plot_train`` and
  :func:`stable_baselines3.common.monitor.load_results` read it. While training, the Monitor's own rows (one per
  physical episode) are not written: the file holds segments only.

The evaluation env (same wrappers, never switched) keeps its Monitor untouched.
"""

from __future__ import annotations

import time
from typing import Any

from stable_baselines3.common.monitor import Monitor, ResultsWriter

#: info key holding, at the last step of a training segment, the kind of goal commanded during it
GOAL_KIND_KEY = "goal_kind"
#: thesis names of the scheduler's goal kinds (Algorithm 3): rho_g* ("forward", or the env's own goal, which our goal
#: envs draw from rho_g*), rho_0 ("back") and rho_E ("explore") goals
GOAL_KIND_NAMES = {"forward": "evaluation", "env": "evaluation", "back": "initial", "explore": "exploratory"}


def missing_info_keyword(key: str) -> ValueError:
    """The error for a ``Monitor`` ``info_keywords`` entry that the env's info lacks, naming the fixes.

    :param key: the missing info key.
    :return: the error to raise.
    """
    return ValueError(
        f"SB3's Monitor logs info[{key!r}] at the end of every episode (its info_keywords: RL-Zoo's monitor_kwargs), "
        f"but the env's info has no {key!r}. For a goal env that reports success under another key (gymnasium-robotics "
        "mazes: 'success'), put sb3_gcrl.wrappers.IsSuccessWrapper first in env_wrapper (it adds 'is_success' below "
        f"the Monitor); otherwise remove {key!r} from monitor_kwargs' info_keywords."
    )


class SegmentRecorder:
    """Return, length and success of the segments a training-mode wrapper shows SB3, reported like ``Monitor``.

    :param monitor: the SB3 ``Monitor`` below the recording wrapper (it gets the segment rows), or None.
    """

    def __init__(self, monitor: Monitor | None) -> None:
        self.monitor = monitor
        self.t_start = time.time() if self.monitor is None else self.monitor.t_start
        self._writer: ResultsWriter | None = None
        #: the Monitor's info_keywords (copied into every segment row)
        self.info_keywords: tuple[str, ...] = () if self.monitor is None else tuple(self.monitor.info_keywords)
        self.begin()

    def begin(self) -> None:
        """Start a new segment (called at every ``reset()``)."""
        self._return = 0.0
        self._length = 0
        self._reached = False

    def take_over_monitor(self, training: bool) -> None:
        """In training mode, write the Monitor's CSV rows here (segments); in evaluation mode, give it back.

        :param training: the wrapper's mode.
        """
        if self.monitor is None:
            return
        if training and self.monitor.results_writer is not None:
            self._writer, self.monitor.results_writer = self.monitor.results_writer, None
        elif not training and self._writer is not None:
            self.monitor.results_writer, self._writer = self._writer, None

    def step(self, reward: float, done: bool, info: dict[str, Any], goal_kind: str | None) -> None:
        """Account one training step; at the segment's last step (``done``), report the segment in ``info``.

        :param reward: the reward SB3 gets.
        :param done: ``terminated or truncated`` as SB3 gets them.
        :param info: the step's info dict (updated in place at the last step).
        :param goal_kind: the commanded goal's kind, None without goal commanding.
        """
        # hot path (every training step): no numpy, no calls but info.get
        self._return += reward
        self._length += 1
        if not self._reached and info.get("is_success"):
            self._reached = True
        if done:
            self._finish(info, goal_kind)

    def _finish(self, info: dict[str, Any], goal_kind: str | None) -> None:
        if "is_success" in info:  # envs that report no success keep reporting none
            info["is_success"] = self._reached
        if goal_kind is not None:
            info[GOAL_KIND_KEY] = goal_kind
        episode: dict[str, Any] = {
            "r": round(float(self._return), 6),
            "l": self._length,
            "t": round(time.time() - self.t_start, 6),
        }
        for key in self.info_keywords:
            if key not in info:
                raise missing_info_keyword(key)
            episode[key] = info[key]
        if self.monitor is not None:
            episode.update(self.monitor.current_reset_info)
        if self._writer is not None:
            self._writer.write_row(episode)
        info["episode"] = episode  # replaces the Monitor's own (a physical episode ending with this segment)
        self.begin()

    def close(self) -> None:
        """Give the CSV back to the Monitor, which closes it."""
        self.take_over_monitor(False)
