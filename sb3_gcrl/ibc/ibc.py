"""Deprecated alias of :mod:`sb3_gcrl.reset_free_baselines.ibc` (runs pickled before the move name it)."""

from sb3_gcrl.reset_free_baselines.ibc import IBC

__all__ = ["IBC"]
