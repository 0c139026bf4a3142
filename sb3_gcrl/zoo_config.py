"""RL-Zoo hyperparameter files (``zoo_configs/*.yml``, or ``.py`` files with ``hyperparams``): which section a run
uses (the checks every run passes before it starts: :mod:`sb3_gcrl.zoo_checks`).

The package ships one file per algorithm, RL-Zoo's convention (``hyperparams/<algo>.yml``): ``zoo_configs/<algo>.yml``
holds a section per env id, and variants of a setting (an ablation, a baseline of the same algorithm) as sections
keyed ``<env id>@<variant>`` (``GCRL/PointUMazeGoal-v0@peg``) that state only what differs, with YAML anchors and
merge keys. RL-Zoo itself picks the exact env-id key, so ``rl_zoo3 train -conf zoo_configs/<algo>.yml`` reads the
default sections. Where the default is a CPU preset and the thesis's scale needs a GPU, ``<algo>_thesis.yml`` has
the same sections at that scale. :func:`resolve_config` is the one lookup of ``sb3-gcrl train`` and
``sb3-gcrl compare``.
"""

from __future__ import annotations

import ast
import copy
import difflib
import hashlib
import json
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

#: the zoo configs this package ships (package data; a clone also has them as ``zoo_configs/`` at its root)
ZOO_CONFIGS_DIR = Path(__file__).resolve().parent / "zoo_configs"
#: joins an env id and a variant in a section key: ``GCRL/PointUMazeGoal-v0@peg``
VARIANT_SEPARATOR = "@"
#: the file of an algorithm's settings at the thesis's scale (a GPU), searched after ``<algo>.yml``
THESIS_SUFFIX = "_thesis"

#: config keys RL-Zoo's ``ExperimentManager`` consumes itself instead of passing them to the algorithm
ZOO_KEYS = frozenset(
    {
        "n_timesteps",
        "n_envs",
        "normalize",
        "env_wrapper",
        "vec_env_wrapper",
        "frame_stack",
        "callback",
        "monitor_kwargs",
        "env_kwargs",
        "noise_type",
        "noise_std",
    }
)


class ConfigNotFoundError(ValueError):
    """No config file, or no section of one, for an algorithm, env and variant; the message names the files searched,
    the envs they cover and the variants of the env."""


def parse_override(text: str) -> tuple[str, Any]:
    """One ``key:value`` override of the command line (``--hyperparams``, ``--env-kwargs``).

    The value is read as a Python literal first, as RL-Zoo's ``-params`` reads it (``None``, ``1e5``, ``[64, 64]``,
    ``'auto'``), and as YAML otherwise (``null``, ``{net_arch: [64]}``, a bare word such as ``MlpPolicy``; an
    expression such as ``dict(net_arch=[64])`` stays a string, which RL-Zoo evaluates for ``policy_kwargs``).

    :param text: ``key:value``; the value may contain further colons.
    :return: the key and the parsed value.
    :raises ValueError: without a colon or without a key.
    """
    key, sep, value = text.partition(":")
    if not sep or not key:
        raise ValueError(f"expected key:value (e.g. learning_starts:100), got {text!r}")
    try:
        return key, ast.literal_eval(value)
    except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
        return key, yaml.safe_load(value)


def section_key(env_id: str, variant: str | None = None) -> str:
    """The key of an env's section: the env id, or ``<env id>@<variant>``.

    :param env_id: gymnasium id.
    :param variant: variant name, or None for the env's default section.
    :return: the key.
    """
    return env_id if variant is None else f"{env_id}{VARIANT_SEPARATOR}{variant}"


def split_section_key(key: str) -> tuple[str, str | None]:
    """Inverse of :func:`section_key`: ``(env id, variant or None)``.

    :param key: a section key.
    :return: the env id and the variant.
    """
    env_id, separator, variant = str(key).partition(VARIANT_SEPARATOR)
    return env_id, (variant if separator else None)


def read_zoo_config(config: Path) -> dict[str, Any]:
    """All sections of an RL-Zoo hyperparameter file, keyed as in the file (``default``/``atari`` and
    ``<env id>@<variant>`` keys included; YAML anchors and merge keys resolved).

    :param config: ``.yml`` file, or ``.py`` file defining a ``hyperparams`` dict (RL-Zoo accepts both).
    :return: the sections.
    """
    if config.suffix == ".py":
        namespace: dict[str, Any] = {}
        exec(config.read_text(), namespace)
        return dict(namespace["hyperparams"])
    with open(config) as file:
        return dict(yaml.safe_load(file) or {})


def config_sections(config: Path) -> dict[str, list[str]]:
    """The envs a config file covers, each with its variants, in file order.

    :param config: hyperparameter file.
    :return: env id (or ``default``/``atari``) -> variant names.
    """
    sections: dict[str, list[str]] = {}
    for key in read_zoo_config(config):
        env_id, variant = split_section_key(key)
        sections.setdefault(env_id, [])
        if variant is not None:
            sections[env_id].append(variant)
    return sections


def zoo_config_section(config: Path, env_id: str) -> dict[str, Any] | None:
    """The section RL-Zoo would use for ``env_id`` (its own, else ``default``), or None if there is none.

    :param config: hyperparameter file.
    :param env_id: environment id.
    :return: the section's hyperparameters.
    """
    sections = read_zoo_config(config)
    key = _section_key(sections, env_id, None)
    return None if key is None else copy.deepcopy(dict(sections[key]))


def rl_zoo_config(algo: str) -> Path:
    """RL-Zoo's own hyperparameter file of ``algo`` (``rl_zoo3/hyperparams/<algo>.yml``; it may not exist)."""
    import rl_zoo3

    return Path(rl_zoo3.__file__).resolve().parent / "hyperparams" / f"{algo}.yml"


def default_config_files(algo: str, config_dir: Path = ZOO_CONFIGS_DIR) -> list[Path]:
    """The files searched for ``algo``'s hyperparameters when none is named, in order: ``<algo>.yml`` and
    ``<algo>_thesis.yml`` of ``config_dir``, then RL-Zoo's own ``hyperparams/<algo>.yml`` (those that exist).

    :param algo: algorithm name.
    :param config_dir: folder of the package's zoo configs.
    :return: the existing files.
    """
    candidates = [config_dir / f"{algo}.yml", config_dir / f"{algo}{THESIS_SUFFIX}.yml", rl_zoo_config(algo)]
    return [path for path in candidates if path.is_file()]


def _is_atari(env_id: str) -> bool:
    """RL-Zoo's test for an Atari env (its files have an ``atari`` section for them)."""
    import gymnasium as gym

    spec = gym.registry.get(env_id)
    return spec is not None and "AtariEnv" in str(spec.entry_point)


def _section_key(sections: Mapping[str, Any], env_id: str, variant: str | None) -> str | None:
    """The key of the section RL-Zoo's lookup gives ``env_id`` (env id, else ``atari`` for Atari envs, else
    ``default``), or exactly ``<env id>@<variant>`` for a variant; None when the file has no such section."""
    if variant is not None:
        key = section_key(env_id, variant)
        return key if key in sections else None
    for key in (env_id, "atari" if _is_atari(env_id) else None, "default"):
        if key is not None and key in sections:
            return key
    return None


@dataclass(frozen=True)
class ResolvedConfig:
    """The hyperparameters of a run: the section of a config file chosen for an env (and variant).

    :param path: the config file.
    :param key: the section's key in it (the env id, ``default``, or ``<env id>@<variant>``).
    :param env_id: the run's env.
    :param variant: the variant, or None for the env's default section.
    :param hyperparams: the section (anchors and merge keys resolved).
    """

    path: Path
    key: str
    env_id: str
    variant: str | None
    hyperparams: dict[str, Any]

    @property
    def where(self) -> str:
        """The file and section, for messages: ``/.../sac.yml (section GCRL/PointUMazeGoal-v0@naive)``."""
        return f"{self.path} (section {self.key})"

    @property
    def digest(self) -> str:
        """Short SHA-256 of the section's settings (a run stores it, so that a changed setting is never silently
        reused, while an edit elsewhere in the file leaves the run alone)."""
        text = json.dumps(self.hyperparams, sort_keys=True, default=repr)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    @property
    def rl_zoo_reads_it(self) -> bool:
        """Whether RL-Zoo, given :attr:`path`, picks this section itself (not for a variant's ``env@variant`` key)."""
        return self.variant is None

    def to_yaml(self) -> str:
        """A config file with this section alone, keyed by the plain env id (what RL-Zoo reads)."""

        class NoAliases(yaml.SafeDumper):
            def ignore_aliases(self, data: Any) -> bool:
                return True

        text = yaml.dump({self.env_id: self.hyperparams}, Dumper=NoAliases, sort_keys=False, width=120)
        return f"# {self.where}, resolved for {self.env_id}\n{text}"

    def zoo_file(self, folder: Path) -> Path:
        """A file RL-Zoo can read this section from: :attr:`path` itself when it picks the section there, else this
        section written to ``folder`` (named by content: an existing file of that name holds the same settings).

        :param folder: where a variant's section is written (created).
        :return: the file.
        """
        if self.rl_zoo_reads_it:
            return self.path
        from sb3_gcrl.common.saving import atomic_write_text

        env_slug = self.env_id.replace("/", "-")
        path = folder / f"{self.path.stem}{VARIANT_SEPARATOR}{self.variant}_{env_slug}_{self.digest}.yml"
        if not path.is_file():
            folder.mkdir(parents=True, exist_ok=True)
            atomic_write_text(path, self.to_yaml())
        return path


def shipped_config(name: str, config_dir: Path = ZOO_CONFIGS_DIR) -> Path | None:
    """The config this package ships under ``name`` (``"cec"``, ``"cec.yml"``), or None.

    :param name: file name in ``config_dir``, with or without ``.yml`` (names only: no path leaves the folder).
    :param config_dir: folder of the shipped configs.
    :return: its path, if there is such a file.
    """
    for candidate in (name, f"{name}.yml"):
        path = config_dir / candidate
        if Path(candidate).name == candidate and path.is_file():
            return path
    return None


def find_config(name: str | Path, config_dir: Path = ZOO_CONFIGS_DIR) -> Path:
    """The config file a user named: a path or a shipped file's name (``sac``, ``morefree_thesis.yml``).

    :param name: what ``-conf`` or compare's ``ALGO:CONFIG`` got.
    :param config_dir: folder of the shipped configs.
    :return: the file.
    :raises ConfigNotFoundError: no such file; the message lists the shipped names.
    """
    path = Path(name)
    if path.is_file():
        return path
    shipped = shipped_config(str(name), config_dir)
    if shipped is not None:
        return shipped
    names = sorted(p.stem for p in config_dir.glob("*.yml"))
    raise ConfigNotFoundError(
        f"config {str(name)!r} not found at {path.resolve()}, nor shipped under that name. Files in {config_dir}: "
        f"{names} (`sb3-gcrl list-configs` prints their env sections and variants)"
    )


def resolve_config(
    algo: str,
    env_id: str,
    variant: str | None = None,
    config: str | Path | None = None,
    config_dir: Path = ZOO_CONFIGS_DIR,
) -> ResolvedConfig:
    """The section a run of ``algo`` on ``env_id`` uses: the one lookup of ``sb3-gcrl train`` and ``compare``.

    Files, in order: the ``config`` named (:func:`find_config`), else ``<algo>.yml``, then ``<algo>_thesis.yml`` of
    ``config_dir``, then RL-Zoo's own ``hyperparams/<algo>.yml`` (:func:`default_config_files`); the first with a
    section for the env wins: ``<env id>@<variant>`` for a variant, else the env id, ``atari`` (Atari envs) or
    ``default``, as RL-Zoo looks it up.

    :param algo: algorithm name.
    :param env_id: gymnasium id.
    :param variant: variant name, or None for the env's default section.
    :param config: a file or shipped config name, or None to search the defaults.
    :param config_dir: folder of the package's zoo configs.
    :return: the file and section.
    :raises ConfigNotFoundError: no section; the message names the files searched, the envs they cover and the
        variants of ``env_id``.
    """
    variant = variant or None
    candidates = default_config_files(algo, config_dir) if config is None else [find_config(config, config_dir)]
    for path in candidates:
        sections = read_zoo_config(path)
        key = _section_key(sections, env_id, variant)
        if key is not None:
            if config is None and path.stem.endswith(THESIS_SUFFIX):
                _warn_thesis_scale_without_gpu(algo, env_id, path)
            return ResolvedConfig(path, key, env_id, variant, copy.deepcopy(dict(sections[key])))
    raise ConfigNotFoundError(_missing_section_message(algo, env_id, variant, candidates, config_dir))


def _warn_thesis_scale_without_gpu(algo: str, env_id: str, path: Path) -> None:
    """Warn when the default search falls back to a GPU-scale file (``<algo>_thesis.yml``) on a machine without CUDA:
    ``<algo>.yml`` has no CPU preset for the env."""
    import torch

    if not torch.cuda.is_available():
        warnings.warn(
            f"{algo} on {env_id}: {algo}.yml has no CPU preset for this env, so the thesis's GPU-scale section of "
            f"{path.name} is used, and this machine has no CUDA device: expect a very slow run (docs/results.md, "
            f"'What each CPU preset reaches at its budget'). Shrink it with --hyperparams (e.g. to the network and "
            f"batch sizes of a section of {algo}.yml) or pass -conf <your file>",
            UserWarning,
            stacklevel=3,
        )


def _missing_section_message(
    algo: str, env_id: str, variant: str | None, candidates: Sequence[Path], config_dir: Path
) -> str:
    wanted = f"{algo} on {env_id}" + (f", variant {variant!r}" if variant else "")
    if not candidates:
        return (
            f"No hyperparameters for {wanted}: no {algo}.yml or {algo}{THESIS_SUFFIX}.yml in {config_dir}, and RL-Zoo "
            f"has no hyperparams/{algo}.yml: pass `-conf <file.yml>` (sb3-gcrl compare: {algo}:<file.yml>)"
        )
    covered = []
    variants: list[str] = []
    for path in candidates:
        sections = config_sections(path)
        covered.append(f"{path} covers {sorted(sections)}")
        variants += [v for v in sections.get(env_id, []) if v not in variants]
    has_env = any(env_id in config_sections(path) for path in candidates)
    if variant is not None and has_env:
        close = difflib.get_close_matches(variant, variants, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        fix = f"variants of {env_id}: {variants or 'none'}{hint}"
    else:
        fix = f"Add a section {section_key(env_id, variant)!r} to one of these files, or pass another config file"
    return f"No hyperparameters for {wanted}. Searched: {'; '.join(covered)}. {fix}."
