"""Every import between the package's subpackages points down the layers of ``docs/architecture.md``.

The layers are written once, in :data:`LAYERS` (bottom first), and the doc's layer table must list the same ones in
the same order. A package may import packages of lower layers and, without a cycle, of its own layer; an import of a
higher layer is an upward arrow and fails, unless :data:`UPWARD_EXCEPTIONS` names it with its reason. Every import
statement counts, wherever it stands (module level, inside a function, under ``if TYPE_CHECKING``), read from the
source with ``ast``. ``import sb3_gcrl`` alone is no arrow: Python imports the package root before any module in it.
"""

from __future__ import annotations

import ast
import graphlib
import re
from pathlib import Path

import pytest

import sb3_gcrl

PACKAGE_ROOT = Path(sb3_gcrl.__file__).parent
ARCHITECTURE_DOC = PACKAGE_ROOT.parent / "docs" / "architecture.md"

#: the package root's ``__init__.py``: the lazy facade (``sb3_gcrl.CEC``), above everything it exports
ROOT = "sb3_gcrl"

#: the layers, bottom first: (name, its packages); a top-level module (``cli.py``) is named without ``.py``
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("shared", ("common", "version")),
    ("building blocks", ("analysis", "envs", "goals", "memory")),
    ("mechanisms", ("wrappers", "her", "callbacks", "post_exploration", "episodic_control")),
    ("algorithms", ("cec", "mfec", "emac", "two_memory", "tabular", "imgep", "morefree", "reset_free_baselines")),
    ("runs", ("hyperparams_opt", "algorithms", "zoo_config", "zoo_checks", "zoo_train", "morefree_sac")),
    ("comparisons", ("compare",)),
    ("entry points", ("cli", "__main__", ROOT)),
)

#: upward arrows that stay for now, (importer, imported) -> why; each must still exist (a fixed one is removed here)
UPWARD_EXCEPTIONS: dict[tuple[str, str], str] = {}

LAYER_OF: dict[str, int] = {package: index for index, (_, packages) in enumerate(LAYERS) for package in packages}


def package_of(module: str) -> str | None:
    """The layered package a module name belongs to (``sb3_gcrl.memory.knn`` -> ``memory``), ``None`` outside."""
    parts = module.split(".")
    if parts[0] != ROOT:
        return None
    return parts[1] if len(parts) > 1 else ROOT


def source_package(path: Path) -> str:
    parts = path.relative_to(PACKAGE_ROOT).with_suffix("").parts
    return ROOT if parts == ("__init__",) else parts[0]


def packages_in(source: str, package: str) -> set[str]:
    """The packages of ``sb3_gcrl`` that a source imports, wherever the import statement stands.

    :param source: the source text.
    :param package: the dotted package the source's module is in (for relative imports).
    """
    found: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names if alias.name != ROOT]  # the root is imported first anyway
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the module's package
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                origin = ".".join([*base, node.module] if node.module else base)
            else:
                origin = node.module or ""
            # ``from sb3_gcrl import memory`` imports a subpackage, ``from sb3_gcrl import CEC`` the lazy facade
            modules = [f"{origin}.{alias.name}" for alias in node.names if is_module(alias.name)]
            names = modules if origin == ROOT and modules else [origin]
        else:
            continue
        found.update(owner for name in names if (owner := package_of(name)) is not None)
    return found


def is_module(name: str) -> bool:
    return (PACKAGE_ROOT / name).is_dir() or (PACKAGE_ROOT / f"{name}.py").is_file()


def imported_packages(path: Path) -> set[str]:
    """The other packages of ``sb3_gcrl`` that a source file of the package imports."""
    parts = path.relative_to(PACKAGE_ROOT).parts
    package = ".".join((ROOT, *parts[:-1]))
    return packages_in(path.read_text(), package) - {source_package(path)}


def import_graph() -> dict[str, dict[str, list[str]]]:
    """importer -> imported -> the files of the importer that import it."""
    graph: dict[str, dict[str, list[str]]] = {}
    for path in sorted(PACKAGE_ROOT.rglob("*.py")):
        for imported in imported_packages(path):
            graph.setdefault(source_package(path), {}).setdefault(imported, []).append(
                str(path.relative_to(PACKAGE_ROOT))
            )
    return graph


def upward_arrows(graph: dict[str, dict[str, list[str]]]) -> dict[tuple[str, str], list[str]]:
    return {
        (importer, imported): files
        for importer, targets in graph.items()
        for imported, files in targets.items()
        if LAYER_OF[imported] > LAYER_OF[importer]
    }


def test_every_package_has_one_layer() -> None:
    packages = {source_package(path) for path in PACKAGE_ROOT.rglob("*.py")}
    listed = [package for _, layer in LAYERS for package in layer]
    assert len(listed) == len(set(listed)), "a package is listed in two layers"
    assert packages - set(listed) == set(), "place the new package in a layer of LAYERS and of docs/architecture.md"
    assert set(listed) - packages == set(), "LAYERS lists a package that no longer exists"


def test_no_import_points_up_the_layers() -> None:
    upward = upward_arrows(import_graph())
    unexpected = {
        f"{importer} ({LAYERS[LAYER_OF[importer]][0]}) imports {imported} ({LAYERS[LAYER_OF[imported]][0]}): {files}"
        for (importer, imported), files in upward.items()
        if (importer, imported) not in UPWARD_EXCEPTIONS
    }
    assert not unexpected, sorted(unexpected)


def test_every_named_exception_still_points_up() -> None:
    fixed = set(UPWARD_EXCEPTIONS) - set(upward_arrows(import_graph()))
    assert not fixed, f"no longer imported upward, remove from UPWARD_EXCEPTIONS: {sorted(fixed)}"


def test_the_imports_within_a_layer_have_a_direction() -> None:
    """Packages of one layer may import each other one way only: the package graph (the named exceptions left out) has
    no cycle."""
    graph = {
        importer: {imported for imported in targets if (importer, imported) not in UPWARD_EXCEPTIONS}
        for importer, targets in import_graph().items()
    }
    try:
        tuple(graphlib.TopologicalSorter(graph).static_order())
    except graphlib.CycleError as error:
        pytest.fail(f"package import cycle: {' -> '.join(error.args[1])}")


def test_the_check_sees_every_kind_of_import() -> None:
    """A guard that the parser reads every kind of import statement, and that an upward one is reported."""
    source = """
from __future__ import annotations
from typing import TYPE_CHECKING
import numpy
import sb3_gcrl
import sb3_gcrl.memory.knn
from sb3_gcrl.common import validation
from ..goals import schedulers
from . import mode
from sb3_gcrl import envs, version
if TYPE_CHECKING:
    from sb3_gcrl.her import ExecutedActionHerReplayBuffer
def plot():
    from sb3_gcrl.analysis.plots import plot_visitation_heatmap
"""
    found = packages_in(source, "sb3_gcrl.wrappers")
    assert found == {"memory", "common", "goals", "wrappers", "envs", "version", "her", "analysis"}
    assert packages_in("from sb3_gcrl import CEC", "sb3_gcrl.common") == {ROOT}  # the facade: from the top layer
    assert upward_arrows({"common": {"memory": ["common/x.py"]}}) == {("common", "memory"): ["common/x.py"]}
    assert upward_arrows({"memory": {"common": ["memory/x.py"]}}) == {}


def documented_layers() -> list[tuple[str, tuple[str, ...]]]:
    """The layer table of docs/architecture.md, rows ``| L<n> <layer> | `<package>` | <its job> |``, in its order."""
    layers: dict[str, list[str]] = {}
    row = re.compile(r"^\| (L\d+ [a-z ]+) \| `([\w.]+?)(?:/|\.py)?` \|")
    for line in ARCHITECTURE_DOC.read_text().splitlines():
        if match := row.match(line):
            package = match.group(2)
            layers.setdefault(match.group(1), []).append(ROOT if package == "__init__" else package)
    return [(name, tuple(packages)) for name, packages in layers.items()]


def test_the_doc_lists_the_same_layers_in_the_same_order() -> None:
    documented = documented_layers()
    assert [name for name, _ in documented] == [f"L{number} {name}" for number, (name, _) in enumerate(LAYERS, 1)]
    for (name, packages), (_, written) in zip(LAYERS, documented):
        assert sorted(written) == sorted(packages), name
