"""The thesis's tasks as registered gymnasium environments (namespace ``GCRL/``).

:func:`register_envs` runs when ``sb3_gcrl`` is imported; it also registers the gymnasium-robotics
and MinAtar environments so that no extra user step is needed.
"""

from __future__ import annotations

import gymnasium as gym

NAMESPACE = "GCRL"


def _register_third_party() -> None:
    import gymnasium_robotics
    import minatar.gym

    gym.register_envs(gymnasium_robotics)
    if "MinAtar/Breakout-v1" not in gym.registry:
        minatar.gym.register_envs()


def register_envs() -> None:
    """Register every environment of the package (idempotent)."""
    _register_third_party()
