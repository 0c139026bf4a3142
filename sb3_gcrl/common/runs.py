"""TensorBoard runs named after the algorithm's class, for SB3 algorithms that keep SB3's own ``learn``."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.type_aliases import MaybeCallback


class ClassNamedRunsMixin:
    """Mix in before an SB3 algorithm: ``learn`` names the TensorBoard run after the class (``TwoMemoryDQN_1``,
    ``TabularQLearning_1``) unless ``tb_log_name`` is given."""

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

        :param total_timesteps: env steps.
        :param callback: SB3 callback(s).
        :param log_interval: episodes between log dumps.
        :param tb_log_name: TensorBoard run name (``None``: the class name).
        :param reset_num_timesteps: start counting from 0.
        :param progress_bar: show a progress bar.
        """
        return super().learn(  # type: ignore[misc]
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=type(self).__name__ if tb_log_name is None else tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
