"""Methods of a comparison: a name that resolves to exactly what ``rl_zoo3 train`` would run.

A *method* is an algorithm plus a section of an RL-Zoo hyperparameter file (``policy``, ``env_wrapper``,
``callback``, ``normalize``, ``policy_kwargs``... per environment id). Its hyperparameters are found as ``sb3-gcrl
train`` finds them (:func:`sb3_gcrl.zoo_config.resolve_config`). The spellings:

``ALGO``
    an algorithm name, ours (:data:`sb3_gcrl.algorithms.ALGORITHMS`) or RL-Zoo's (``rl_zoo3.utils.ALGOS``).
    Its hyperparameters for an env are looked up, in order, in ``zoo_configs/ALGO.yml``,
    ``zoo_configs/ALGO_thesis.yml``, then RL-Zoo's own ``hyperparams/ALGO.yml``; the first file with a section for the
    env id (or a ``default`` section) wins. Labelled ``ALGO``.
``ALGO@VARIANT``
    the same, with the section ``<env id>@VARIANT`` (``morefree@peg``: reset-free PEG). Labelled ``ALGO_VARIANT``.
``ALGO[@VARIANT]:CONFIG``
    an explicit config: a path to a ``.yml``/``.py`` file or the name of a file in ``zoo_configs/``
    (``morefree@peg:morefree_thesis``). Labelled with the config's file stem (and ``_VARIANT``).
``LABEL=ALGO[@VARIANT][:CONFIG]``
    the same with a chosen label for tables and plots (``peg_world_model=morefree@peg``).

A run stores the digest of its section (:attr:`~sb3_gcrl.zoo_config.ResolvedConfig.digest`), so a changed setting
is never silently reused; a variant's section, which RL-Zoo does not read from its file, is written to the
comparison's ``configs/`` folder and the run reads it from there.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from sb3_gcrl.zoo_checks import available_algorithms, check_algorithm, check_env_id
from sb3_gcrl.zoo_config import (
    VARIANT_SEPARATOR,
    ZOO_CONFIGS_DIR,
    ResolvedConfig,
    config_sections,
    find_config,
    resolve_config,
)

__all__ = ["Method", "available_algorithms", "check_env_id", "config_env_ids", "method_label", "parse_method"]

_LABEL_RE = re.compile(r"^[A-Za-z0-9_.\-+]+$")
_VARIANT_RE = re.compile(r"^[A-Za-z0-9_.\-+]+$")


def config_env_ids(config: Path) -> list[str]:
    """Environment ids (sections) of an RL-Zoo hyperparameter file; ``.py`` files expose ``hyperparams``.

    :param config: path of the file.
    :return: the envs it has a section for (``default``/``atari`` included when present; variants not listed).
    """
    return list(config_sections(config))


@dataclass(frozen=True)
class Method:
    """A method as the user named it, before it meets an environment.

    :param label: name used in tables, plots and run folders.
    :param algo: key of ``rl_zoo3.utils.ALGOS`` once :func:`sb3_gcrl.algorithms.register_zoo_algorithms` ran.
    :param config: explicit hyperparameter file, or None to search for one per environment.
    :param variant: the variant (sections ``<env id>@<variant>``), or None for the env's default section.
    """

    label: str
    algo: str
    config: Path | None = None
    variant: str | None = None

    def resolve(self, env_id: str, config_dir: Path = ZOO_CONFIGS_DIR) -> ResolvedConfig:
        """The file and section this method uses on ``env_id`` (:func:`~sb3_gcrl.zoo_config.resolve_config`).

        :param env_id: gymnasium id.
        :param config_dir: folder of the package's zoo configs.
        :return: the resolved section.
        :raises ValueError: no section for the env (or variant); the message names the files searched, the envs they
            cover and the variants of the env.
        """
        try:
            return resolve_config(self.algo, env_id, self.variant, self.config, config_dir)
        except ValueError as error:
            raise ValueError(f"Method {self.label!r}: {error}") from None

    def config_for(self, env_id: str, config_dir: Path = ZOO_CONFIGS_DIR) -> Path:
        """The hyperparameter file used on ``env_id`` (:meth:`resolve`'s file).

        :param env_id: gymnasium id.
        :param config_dir: folder of the package's zoo configs.
        :return: the file.
        :raises ValueError: when no file covers the env; the message lists the envs that are covered.
        """
        return self.resolve(env_id, config_dir).path


def _split_spec(spec: str) -> tuple[str, str, str, str]:
    """``LABEL=ALGO@VARIANT:CONFIG`` -> ``(label, algo, variant, config)``, absent parts empty."""
    label, _, body = spec.rpartition("=")
    head, _, config_name = body.partition(":")
    algo, _, variant = head.partition(VARIANT_SEPARATOR)
    return label, algo, variant, config_name


def method_label(spec: str) -> str:
    """The label a method spec gets in tables, plots and run folders: ``LABEL``, else the config's stem or ``ALGO``,
    with ``_VARIANT`` for ``@VARIANT``.

    :param spec: ``ALGO``, ``ALGO@VARIANT``, ``ALGO[@VARIANT]:CONFIG`` or ``LABEL=ALGO[@VARIANT][:CONFIG]``.
    :return: the label (not validated; :func:`parse_method` checks it).
    """
    label, algo, variant, config_name = _split_spec(spec)
    base = Path(config_name).stem if config_name else algo
    return label or (f"{base}_{variant}" if variant else base)


def parse_method(spec: str, config_dir: Path = ZOO_CONFIGS_DIR) -> Method:
    """Parse ``ALGO[@VARIANT][:CONFIG]`` or ``LABEL=ALGO[@VARIANT][:CONFIG]`` (see the module docstring).

    :param spec: the method as written on the command line.
    :param config_dir: folder where a bare config name is looked up.
    :return: the method.
    :raises ValueError: unknown algorithm, missing config file or a bad label; the message lists the valid choices.
    """
    _, algo, variant, config_name = _split_spec(spec)
    try:
        check_algorithm(algo)
    except ValueError as error:
        raise ValueError(
            f"Unknown method {spec!r}: {error} A method is ALGO, ALGO@VARIANT, ALGO[@VARIANT]:CONFIG (a .yml path or "
            "a file name in zoo_configs/) or LABEL=ALGO[@VARIANT][:CONFIG]."
        ) from None
    if variant and not _VARIANT_RE.match(variant):
        raise ValueError(f"Variant {variant!r} of method {spec!r} may only use letters, digits and _ . - +")
    config: Path | None = None
    if config_name:
        try:
            config = find_config(config_name, config_dir).resolve()
        except ValueError as error:
            raise ValueError(f"Method {spec!r}: {error}") from None
    label = method_label(spec)
    if not _LABEL_RE.match(label):
        raise ValueError(f"Method label {label!r} may only use letters, digits and _ . - + (it names folders)")
    return Method(label=label, algo=algo, config=config, variant=variant or None)
