"""Methods of a comparison: a name that resolves to exactly what ``rl_zoo3 train`` would run.

A *method* is an algorithm plus an RL-Zoo hyperparameter file (``policy``, ``env_wrapper``,
``callback``, ``normalize``, ``policy_kwargs``... per environment id). Three spellings are accepted:

``ALGO``
    an algorithm name, ours (:data:`sb3_gcrl.algorithms.ALGORITHMS`) or RL-Zoo's (``rl_zoo3.utils.ALGOS``).
    Its hyperparameters for an env are looked up, in order, in ``zoo_configs/ALGO.yml``, in the
    ``zoo_configs/ALGO_*.yml`` files (e.g. ``sac_ch4.yml``), then in RL-Zoo's own ``hyperparams/ALGO.yml``;
    the first file with a section for the env id (or a ``default`` section) wins.
``ALGO:CONFIG``
    an explicit config: a path to a ``.yml``/``.py`` file or the stem of a file in ``zoo_configs/``
    (``sac:reset_free_morefree``). The method is labelled with the config's file stem.
``LABEL=ALGO[:CONFIG]``
    the same with a chosen label for tables and plots (``morefree=sac:reset_free_morefree``).
"""

from __future__ import annotations

import difflib
import hashlib
import re
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym

from sb3_gcrl.cli import ZOO_CONFIGS_DIR
from sb3_gcrl.zoo_config import read_zoo_config

_LABEL_RE = re.compile(r"^[A-Za-z0-9_.\-+]+$")


def available_algorithms() -> list[str]:
    """Algorithm names a method may use: this package's and RL-Zoo's (sorted)."""
    from rl_zoo3.utils import ALGOS

    from sb3_gcrl.algorithms import ALGORITHMS

    return sorted(set(ALGORITHMS) | set(ALGOS))


def _zoo_default_config(algo: str) -> Path:
    import rl_zoo3

    return Path(rl_zoo3.__file__).resolve().parent / "hyperparams" / f"{algo}.yml"


def config_env_ids(config: Path) -> list[str]:
    """Environment ids (sections) of an RL-Zoo hyperparameter file; ``.py`` files expose ``hyperparams``.

    :param config: path of the file.
    :return: its top-level keys (``default``/``atari`` included when present).
    """
    return list(read_zoo_config(config))


def _covers(config: Path, env_id: str) -> bool:
    sections = config_env_ids(config)
    return env_id in sections or "default" in sections


@dataclass(frozen=True)
class Method:
    """A method as the user named it, before it meets an environment.

    :param label: name used in tables, plots and run folders.
    :param algo: key of ``rl_zoo3.utils.ALGOS`` once :func:`sb3_gcrl.cli.register_zoo_algorithms` ran.
    :param config: explicit hyperparameter file, or None to search for one per environment.
    """

    label: str
    algo: str
    config: Path | None = None

    def candidate_configs(self, config_dir: Path) -> list[Path]:
        """Files searched for this method's hyperparameters, in priority order."""
        if self.config is not None:
            return [self.config]
        own = [config_dir / f"{self.algo}.yml", *sorted(config_dir.glob(f"{self.algo}_*.yml"))]
        return [path for path in [*own, _zoo_default_config(self.algo)] if path.is_file()]

    def config_for(self, env_id: str, config_dir: Path = ZOO_CONFIGS_DIR) -> Path:
        """The hyperparameter file used on ``env_id``.

        :param env_id: gymnasium id.
        :param config_dir: folder of the package's zoo configs.
        :return: path of the first candidate file with a section for ``env_id`` (or ``default``).
        :raises ValueError: when no file covers the env; the message lists the envs that are covered.
        """
        candidates = self.candidate_configs(config_dir)
        for config in candidates:
            if _covers(config, env_id):
                return config
        covered = sorted({env for config in candidates for env in config_env_ids(config)})
        searched = ", ".join(str(path) for path in candidates) or f"no {self.algo}*.yml file in {config_dir}"
        raise ValueError(
            f"Method {self.label!r} has no hyperparameters for env {env_id!r} (searched: {searched}). "
            f"Envs it covers: {covered}. Add a section {env_id!r} to one of these files, or name a config "
            f"explicitly with '{self.algo}:path/to/config.yml'."
        )


def method_label(spec: str) -> str:
    """The label a method spec gets in tables, plots and run folders: ``LABEL``, else the config's stem, else ``ALGO``.

    :param spec: ``ALGO``, ``ALGO:CONFIG`` or ``LABEL=ALGO[:CONFIG]``.
    :return: the label (not validated; :func:`parse_method` checks it).
    """
    label, _, body = spec.rpartition("=")
    algo, _, config_name = body.partition(":")
    return label or (Path(config_name).stem if config_name else algo)


def parse_method(spec: str, config_dir: Path = ZOO_CONFIGS_DIR) -> Method:
    """Parse ``ALGO``, ``ALGO:CONFIG`` or ``LABEL=ALGO[:CONFIG]`` (see the module docstring).

    :param spec: the method as written on the command line.
    :param config_dir: folder where a bare config stem is looked up.
    :return: the method.
    :raises ValueError: unknown algorithm or missing config file; the message lists the valid choices.
    """
    label, _, body = spec.rpartition("=")
    algo, _, config_name = body.partition(":")
    algos = available_algorithms()
    if algo not in algos:
        close = difflib.get_close_matches(algo, algos, n=3)
        hint = f" Did you mean {close}?" if close else ""
        raise ValueError(
            f"Unknown method {spec!r}: {algo!r} is not an algorithm.{hint} Valid algorithms: {algos}. "
            "A method is ALGO, ALGO:CONFIG (a .yml path or a stem in zoo_configs/) or LABEL=ALGO[:CONFIG]."
        )
    config: Path | None = None
    if config_name:
        config = Path(config_name)
        if not config.suffix:
            config = config_dir / f"{config_name}.yml"
        if not config.is_file():
            stems = sorted(path.stem for path in config_dir.glob("*.yml"))
            raise ValueError(
                f"Config {config_name!r} of method {spec!r} not found at {config}. Files in {config_dir}: {stems}"
            )
        config = config.resolve()
    label = method_label(spec)
    if not _LABEL_RE.match(label):
        raise ValueError(f"Method label {label!r} may only use letters, digits and _ . - + (it names folders)")
    return Method(label=label, algo=algo, config=config)


def check_env_id(env_id: str) -> None:
    """Raise a clear error when ``env_id`` is not registered with gymnasium.

    :param env_id: gymnasium id, e.g. ``GCRL/GrowingTree-v0``.
    :raises ValueError: listing close matches and this package's ``GCRL/`` ids.
    """
    if env_id in gym.registry:
        return
    close = difflib.get_close_matches(env_id, list(gym.registry), n=5)
    ours = sorted(key for key in gym.registry if key.startswith("GCRL/"))
    raise ValueError(
        f"Unknown env {env_id!r}. Close matches: {close}. This package's envs: {ours}. "
        "Envs of another package need `--gym-packages <module>` (the module must register them on import)."
    )


def file_digest(path: Path) -> str:
    """Short SHA-256 of a file, stored with each run so that a changed config is never silently reused."""
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]
