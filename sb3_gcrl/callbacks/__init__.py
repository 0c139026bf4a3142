"""Callbacks for reset-free training: mode switch, intervention/goal logging, replay-buffer visitation."""

from sb3_gcrl.callbacks.reset_free import ResetFreeCallback
from sb3_gcrl.callbacks.visitation import (
    VisitationCallback,
    nearest_distances,
    task_relevant_fraction,
    visitation_histogram,
)

__all__ = [
    "ResetFreeCallback",
    "VisitationCallback",
    "nearest_distances",
    "task_relevant_fraction",
    "visitation_histogram",
]
