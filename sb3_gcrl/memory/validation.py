"""Deprecated location of the package's argument checks: use :mod:`sb3_gcrl.common.validation`."""

from __future__ import annotations

import warnings
from typing import Any

from sb3_gcrl.common import validation as _validation


def __getattr__(name: str) -> Any:
    """The check ``name`` of :mod:`sb3_gcrl.common.validation`, with a ``DeprecationWarning``."""
    value = getattr(_validation, name)  # AttributeError for a name the module never had
    warnings.warn(
        f"sb3_gcrl.memory.validation is deprecated: import {name} from sb3_gcrl.common.validation",
        DeprecationWarning,
        stacklevel=2,
    )
    return value
