"""What this package adds to SB3's own ``learn`` for its off-policy algorithms: TensorBoard runs named after the
algorithm's class, and a warning when the budget ends within the random warm-up (``learning_starts``)."""

from __future__ import annotations

import warnings
from typing import Any

from stable_baselines3.common.type_aliases import MaybeCallback


def warn_if_learning_never_starts(model: Any, total_timesteps: int, reset_num_timesteps: bool = True) -> None:
    """Warn when ``model.learn(total_timesteps)`` will end before the first update.

    SB3's off-policy ``learn`` trains only once ``num_timesteps > learning_starts``, and it counts the budget as
    ``total_timesteps`` plus the steps already done when ``reset_num_timesteps=False``. A budget that does not
    exceed ``learning_starts`` therefore collects random warm-up steps only and returns an untrained model.

    :param model: the algorithm about to learn (anything with ``learning_starts`` and ``num_timesteps``).
    :param total_timesteps: the ``total_timesteps`` given to ``learn``.
    :param reset_num_timesteps: the ``reset_num_timesteps`` given to ``learn``.
    """
    learning_starts = getattr(model, "learning_starts", None)
    if learning_starts is None:
        return
    done = 0 if reset_num_timesteps else int(model.num_timesteps)
    budget = int(total_timesteps) + done
    if budget > learning_starts:
        return
    counted = f"{total_timesteps} + {done} already done = {budget}" if done else f"{budget}"
    warnings.warn(
        f"{type(model).__name__}.learn: the budget of {counted} timesteps is <= learning_starts={learning_starts} "
        "(random warm-up steps before the first update), so this call trains nothing; raise total_timesteps or "
        "lower learning_starts",
        UserWarning,
        stacklevel=3,
    )


class ClassNamedRunsMixin:
    """Mix in before an SB3 algorithm: ``learn`` names the TensorBoard run after the class (``TwoMemoryDQN_1``,
    ``TabularQLearning_1``) unless ``tb_log_name`` is given, and warns when the budget does not exceed
    ``learning_starts`` (:func:`warn_if_learning_never_starts`)."""

    def learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> Any:
        """SB3's ``learn``; the TensorBoard run is named after the class unless ``tb_log_name`` is given.

        :param total_timesteps: env steps; a warning says so when they do not exceed ``learning_starts``.
        :param callback: SB3 callback(s).
        :param log_interval: episodes between log dumps.
        :param tb_log_name: TensorBoard run name (``None``: the class name).
        :param reset_num_timesteps: start counting from 0.
        :param progress_bar: show a progress bar.
        """
        warn_if_learning_never_starts(self, total_timesteps, reset_num_timesteps)
        return super().learn(  # type: ignore[misc]
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=type(self).__name__ if tb_log_name is None else tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
