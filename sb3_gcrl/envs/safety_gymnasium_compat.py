"""Import safety-gymnasium 1.0.0 on our stack (Python 3.11, gymnasium 1.x, MuJoCo 3, NumPy 2).

safety-gymnasium 1.0.0 pins gymnasium 0.28.1 and MuJoCo 2.3.3; it installs beside our stack only without its
dependencies (``pip install --no-deps safety-gymnasium==1.0.0 xmltodict``), and then does not import as shipped.
This module applies the three repairs its navigation tasks need, without touching the installed files:

1. the package's ``__init__`` imports gymnasium 0.28 modules (``gymnasium.wrappers.compatibility``, ...) and its
   vector / multi-agent code: the package is registered in ``sys.modules`` as a bare namespace for its own files,
   so ``safety_gymnasium.builder`` and what it imports load without that ``__init__``;
2. dataclass fields default to the ``COLOR`` arrays (``color: np.array = COLOR["goal"]``), which Python 3.11's
   dataclasses refuse as mutable (unhashable) defaults: the arrays are given an identity hash first;
3. MuJoCo 3's ``MjModel.jnt`` refuses the int32 array a sensor's ``objid`` is (the Car's ball joint sensors): while
   an agent reads its own model, that model answers ``jnt`` with an int index.

:func:`make_builder` returns safety-gymnasium's own env (``safety_gymnasium.builder.Builder``), with its 6-tuple
``step`` (observation, reward, cost, terminated, truncated, info).
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import types
import warnings
from typing import Any

import numpy as np

#: the install command of the version these repairs are written for
INSTALL_COMMAND = "pip install --no-deps safety-gymnasium==1.0.0 xmltodict"

_PACKAGE = "safety_gymnasium"
#: what must be importable: the package and the XML library its scene builder uses
_REQUIRED = (_PACKAGE, "xmltodict")
_patched = False


def safety_gymnasium_available() -> bool:
    """Whether safety-gymnasium (and xmltodict, which it needs) is installed; imports neither."""
    return all(importlib.util.find_spec(name) is not None for name in _REQUIRED)


class _HashableArray(np.ndarray):
    """An ndarray with an identity hash, so that a dataclass accepts it as a field default."""

    __hash__ = object.__hash__  # type: ignore[assignment]


class _IntIndexModel:
    """A MuJoCo model whose ``jnt`` accepts a one-element index array; every other attribute is the model's.

    :param model: the ``mujoco.MjModel`` to forward to.
    """

    def __init__(self, model: Any) -> None:
        self._model = model

    def __getattr__(self, name: str) -> Any:
        return getattr(self._model, name)

    def jnt(self, key: Any) -> Any:
        """The joint view of ``key`` (a name, an int or a one-element integer array).

        :param key: joint name or index.
        """
        if isinstance(key, np.ndarray):
            key = int(key.item())
        return self._model.jnt(key)


def _register_bare_package() -> None:
    spec = importlib.util.find_spec(_PACKAGE)
    if spec is None or spec.submodule_search_locations is None:
        raise ModuleNotFoundError(f"safety-gymnasium is not installed: {INSTALL_COMMAND}")
    package = types.ModuleType(_PACKAGE)
    package.__file__ = spec.origin  # its modules locate their assets next to this file
    package.__path__ = list(spec.submodule_search_locations)
    package.__spec__ = spec
    package.__package__ = _PACKAGE
    sys.modules[_PACKAGE] = package


def _patch() -> None:
    global _patched
    if _patched:
        return
    missing = [name for name in _REQUIRED if importlib.util.find_spec(name) is None]
    if missing:
        raise ModuleNotFoundError(f"not installed: {', '.join(missing)} ({INSTALL_COMMAND})")
    if _PACKAGE not in sys.modules:
        _register_bare_package()
    colors = importlib.import_module(f"{_PACKAGE}.assets.color").COLOR
    for name, color in colors.items():
        colors[name] = np.asarray(color).view(_HashableArray)
    base_agent = importlib.import_module(f"{_PACKAGE}.bases.base_agent").BaseAgent
    load_model = base_agent._load_model

    def _load_model_with_int_joints(agent: Any) -> None:
        load_model(agent)
        agent.engine.model = _IntIndexModel(agent.engine.model)  # replaced by the world's model at build time

    base_agent._load_model = _load_model_with_int_joints
    _patched = True


def make_builder(agent: str, task_id: str, config: dict[str, Any] | None = None) -> Any:
    """safety-gymnasium's env for ``task_id`` with the robot ``agent``, as its registry would make it.

    :param agent: safety-gymnasium's robot name (``"Point"``, ``"Car"``, ...).
    :param task_id: a safety-gymnasium task id, e.g. ``"SafetyPointGoal0-v0"`` (its task class comes from the
        id's task name and level).
    :param config: further entries of the task's config (e.g. ``{"observation_flatten": False}``).
    :return: a ``safety_gymnasium.builder.Builder``.
    :raises ModuleNotFoundError: where safety-gymnasium is not installed (the message names the install command).
    """
    _patch()
    builder = importlib.import_module(f"{_PACKAGE}.builder").Builder
    with warnings.catch_warnings():
        # its action Box is built from float32 bounds with a float64 dtype; gymnasium 1.x warns about the cast
        warnings.simplefilter("ignore", RuntimeWarning)
        return builder(task_id=task_id, config={"agent_name": agent, **(config or {})})


__all__ = ["INSTALL_COMMAND", "make_builder", "safety_gymnasium_available"]
