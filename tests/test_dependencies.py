"""Dependencies between subpackages point one way (read from the source with ``ast``).

- :mod:`sb3_gcrl.analysis` (the reports) imports neither post-exploration nor the IMGEP agent: the exploration metrics
  they share live in :mod:`sb3_gcrl.common.metrics`, below all three;
- :mod:`sb3_gcrl.imgep` (the IMGEP loop) depends on :mod:`sb3_gcrl.post_exploration` (one of the loop's steps), and
  never the reverse: the all-goals evaluation reaches an IMGEP agent through the public
  :class:`~sb3_gcrl.post_exploration.GoalExplorationAgent` interface.
"""

from __future__ import annotations

import ast
import graphlib
import importlib
import pkgutil
from pathlib import Path

import pytest

import sb3_gcrl

PACKAGE_ROOT = Path(sb3_gcrl.__file__).parent

#: subpackage -> subpackages it must not import (at module level, or inside a function)
FORBIDDEN: dict[str, tuple[str, ...]] = {
    "analysis": ("post_exploration", "imgep"),
    "post_exploration": ("imgep",),
    "common": ("post_exploration", "imgep", "analysis"),
}


def imported_modules(path: Path) -> set[str]:
    """Absolute names of every module a source file imports, wherever the import statement stands."""
    package = ".".join(path.relative_to(PACKAGE_ROOT.parent).with_suffix("").parts[:-1])
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative import: resolve against the file's package
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                module = ".".join([*base, node.module] if node.module else base)
            else:
                module = node.module or ""
            names.add(module)
            names.update(f"{module}.{alias.name}" for alias in node.names)
    return names


def sources(subpackage: str) -> list[Path]:
    return sorted((PACKAGE_ROOT / subpackage).rglob("*.py"))


@pytest.mark.parametrize("subpackage", sorted(FORBIDDEN))
def test_subpackage_imports_nothing_above_it(subpackage: str) -> None:
    forbidden = tuple(f"sb3_gcrl.{name}" for name in FORBIDDEN[subpackage])
    offending = {
        f"{path.relative_to(PACKAGE_ROOT)} imports {name}"
        for path in sources(subpackage)
        for name in imported_modules(path)
        if name in forbidden or name.startswith(tuple(f"{prefix}." for prefix in forbidden))
    }
    assert not offending, sorted(offending)


def test_imgep_uses_post_exploration_and_the_shared_metrics() -> None:
    """The one direction that is allowed is the one the IMGEP agent takes (a guard that the check sees imports)."""
    names = set().union(*(imported_modules(path) for path in sources("imgep")))
    assert "sb3_gcrl.post_exploration.interface.GoalExplorationAgent" in names
    assert "sb3_gcrl.common.metrics" in names


@pytest.mark.parametrize("subpackage", ["analysis", "common", "imgep", "post_exploration"])
def test_each_subpackage_imports_on_its_own(subpackage: str) -> None:
    package = importlib.import_module(f"sb3_gcrl.{subpackage}")
    for module in pkgutil.iter_modules(package.__path__, f"{package.__name__}."):
        importlib.import_module(module.name)


def test_the_interface_is_what_the_evaluation_sees_of_an_imgep_agent() -> None:
    from sb3_gcrl.imgep import TabularIMGEP
    from sb3_gcrl.post_exploration import GoalExplorationAgent

    assert issubclass(TabularIMGEP, GoalExplorationAgent)
    evaluation = (PACKAGE_ROOT / "post_exploration" / "evaluation.py").read_text()
    for probe in ("getattr(self.model", "hasattr(self.model", "getattr(model", "hasattr(model"):
        assert probe not in evaluation


def test_the_metrics_keep_their_post_exploration_and_analysis_paths() -> None:
    from sb3_gcrl.analysis import visitation_entropy as from_analysis
    from sb3_gcrl.common.metrics import coverage, visitation_entropy
    from sb3_gcrl.post_exploration import coverage as from_post_exploration
    from sb3_gcrl.post_exploration.metrics import visitation_entropy as from_metrics_module

    assert from_analysis is visitation_entropy is from_metrics_module and from_post_exploration is coverage


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE_ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def test_the_module_import_graph_has_no_cycle() -> None:
    """Every import arrow between the package's modules points down: the graph has a topological order (imports
    inside functions count too). A cycle is reported as the chain of modules that closes it."""
    paths = sorted(PACKAGE_ROOT.rglob("*.py"))
    modules = {module_name(path) for path in paths}

    def owner(name: str) -> str | None:  # `from a.b import c` names module a.b, or a.b.c when c is a module
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph = {
        module_name(path): {target for name in imported_modules(path) if (target := owner(name))} - {module_name(path)}
        for path in paths
    }
    try:
        tuple(graphlib.TopologicalSorter(graph).static_order())
    except graphlib.CycleError as error:
        pytest.fail(f"import cycle: {' -> '.join(error.args[1])}")


def test_the_cycle_check_sees_a_cycle() -> None:
    with pytest.raises(graphlib.CycleError):
        tuple(graphlib.TopologicalSorter({"a": {"b"}, "b": {"a"}}).static_order())
