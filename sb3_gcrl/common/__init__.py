"""Building blocks shared across the package: model files, argument checks, seeded generators, run helpers, metrics.

The lowest layer: nothing here imports another subpackage of ``sb3_gcrl`` (see ``docs/architecture.md``).

* :mod:`sb3_gcrl.common.saving` — :class:`ModelFileMixin` (every algorithm of the package: atomic ``save`` that
  records the class, ``load`` that checks the file first and raises :class:`ModelFileError` naming the fix) and
  the atomic writes (:func:`atomic_file`).
* :mod:`sb3_gcrl.common.validation` — the package's argument checks (``check_int``, ``check_float``, ...).
* :mod:`sb3_gcrl.common.seeding` — the package's own random draws: generators seeded from SB3's seed
  (:class:`~sb3_gcrl.common.seeding.SeededGeneratorMixin`), never numpy's global one.
* :mod:`sb3_gcrl.common.arguments` — settings an algorithm hands to its policy, their defaults stated once.
* :mod:`sb3_gcrl.common.metrics` — exploration metrics of Ch. 6 (:func:`visitation_entropy`, :func:`coverage`).

The episodic memories, their actors, episodes and saved states are in :mod:`sb3_gcrl.memory`; the SB3 base classes
of CEC and MFEC in :mod:`sb3_gcrl.episodic_control`. The names above are imported on first access, so that the
light modules import without torch.
"""

from __future__ import annotations

import importlib
from typing import Any

#: exported name -> the module that defines it, imported on first access: the light modules (validation,
#: metrics) are used by the envs, which ``import sb3_gcrl`` registers without importing torch
_EXPORTS: dict[str, str] = {
    "ModelFileError": "saving",
    "ModelFileMixin": "saving",
    "atomic_file": "saving",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    """An exported name, imported from its module on first access.

    :param name: the attribute.
    :return: its value.
    """
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
