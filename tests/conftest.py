"""Shared pytest settings: single-threaded torch (stable timings on a shared 2-core machine)."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import torch  # noqa: E402

torch.set_num_threads(1)
