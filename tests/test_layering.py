"""The project's layering: imports run downward only.

Every module under ``hybrid_calib/``, ``factors/`` and ``learned/`` is parsed with ``ast`` (imports at module
level and inside functions alike) and mapped to its layer:

 1 hybrid_calib.{geometry, config, errors, metrics, perturbation, atomic, words, seeds}
 2 hybrid_calib.data, hybrid_calib.sensors (what real data needs: pinhole camera)
 3 hybrid_calib.sim (the synthetic world and its ray-cast radar / LiDAR)
 4 factors
 5 hybrid_calib.calib, learned (neither imports the other)
 6 hybrid_calib.hybrid (the closed loop; the one place that imports both calib and learned)
 7 hybrid_calib.plots (+ fleet, compare, report)
 8 hybrid_calib.commands (incl. the demo), hybrid_calib.cli

A module may import its own layer or a lower one; only ``hybrid_calib.sim`` itself and the commands
layer may import ``hybrid_calib.sim``; ``hybrid_calib.plots`` (drawn from result types, reused by the report and
the commands) imports nothing else of layer 7.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("hybrid_calib", "factors", "learned")

# longest prefix wins; every module of the packages must match one
LAYERS: dict[str, int] = {
    "hybrid_calib": 1,  # the package docstring and __version__
    "hybrid_calib.geometry": 1,
    "hybrid_calib.config": 1,
    "hybrid_calib.errors": 1,
    "hybrid_calib.metrics": 1,
    "hybrid_calib.perturbation": 1,
    "hybrid_calib.atomic": 1,
    "hybrid_calib.words": 1,
    "hybrid_calib.seeds": 1,
    "hybrid_calib.data": 2,
    "hybrid_calib.sensors": 2,
    "hybrid_calib.sim": 3,
    "factors": 4,
    "hybrid_calib.calib": 5,
    "learned": 5,
    "hybrid_calib.hybrid": 6,
    "hybrid_calib.plots": 7,
    "hybrid_calib.fleet": 7,
    "hybrid_calib.compare": 7,
    "hybrid_calib.report": 7,
    "hybrid_calib.commands": 8,
    "hybrid_calib.cli": 8,
}
# pairs of the same layer that must not import each other
SIBLINGS_APART = (("hybrid_calib.calib", "learned"), ("hybrid_calib.fleet", "hybrid_calib.report"),
                  ("hybrid_calib.fleet", "hybrid_calib.compare"), ("hybrid_calib.compare", "hybrid_calib.report"))
SIM = "hybrid_calib.sim"
PLOTS = "hybrid_calib.plots"


def _prefix(module: str) -> str | None:
    best = None
    for p in LAYERS:
        inside = module == p or (module.startswith(p + ".") and p != "hybrid_calib")  # the package itself only
        if inside and (best is None or len(p) > len(best)):
            best = p
    return best


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _walk(tree: ast.AST, typing_only: bool):
    """``ast.walk``, without the bodies of ``if TYPE_CHECKING:`` blocks unless ``typing_only``."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        if not typing_only and isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING":
            todo.extend(node.orelse)
            continue
        todo.extend(ast.iter_child_nodes(node))


def _imports(path: Path, module: str, typing_only: bool = True) -> list[tuple[int, str]]:
    """(line, imported module) for every import statement of the file, relative ones resolved (``typing_only``: the
    imports of ``if TYPE_CHECKING:`` blocks too). ``from a import b`` yields ``a.b`` (b may be a submodule), which
    lands in a's layer either way."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node in _walk(tree, typing_only):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            found += [(node.lineno, f"{base}.{a.name}" if base else a.name) for a in node.names]
    return found


def _modules(root: Path) -> list[Path]:
    return sorted({p for pkg in PACKAGES if (root / pkg).is_dir() for p in (root / pkg).rglob("*.py")})


def layering_violations(root: Path = ROOT) -> list[str]:
    """One line per import under ``root`` that runs against the layering:
    ``file:line: module imports target (why)``."""
    bad = []
    for path in _modules(root):
        module = _module_name(path, root)
        own = _prefix(module)
        if own is None:
            bad.append(f"{path.relative_to(root)}: module {module} has no layer in tests/test_layering.py")
            continue
        seen = set()
        for line, target in _imports(path, module):
            other = _prefix(target)
            if other is None or (line, other) in seen:  # numpy, torch, ...; one line per statement
                continue
            seen.add((line, other))
            where = f"{path.relative_to(root)}:{line}: {module} imports {target}"
            if LAYERS[other] > LAYERS[own]:
                bad.append(f"{where} (layer {LAYERS[other]} from layer {LAYERS[own]})")
            elif any({own, other} == {a, b} for a, b in SIBLINGS_APART):
                bad.append(f"{where} ({own} and {other} must not import each other)")
            elif (target == SIM or target.startswith(SIM + ".")) and own != SIM and LAYERS[own] < 8:
                bad.append(f"{where} (only hybrid_calib.sim and the commands import the simulator)")
            elif own == PLOTS and other != PLOTS and LAYERS[other] == LAYERS[PLOTS]:
                bad.append(f"{where} (the plots draw result types; they import nothing else of layer 7)")
    return bad


def test_every_module_has_a_layer_and_imports_only_downward():
    assert len(_modules(ROOT)) > 50
    bad = layering_violations()
    assert not bad, "imports against the layering (layers: tests/test_layering.py):\n" + "\n".join(bad)


@pytest.mark.parametrize("source, reason", [
    ("from hybrid_calib.calib.result import VehicleResult\n", "layer 5 from layer 4"),
    ("def f():\n    from hybrid_calib.sim import world\n", "only hybrid_calib.sim and the commands"),
])
def test_the_check_names_file_and_import(tmp_path, source, reason):
    (tmp_path / "factors").mkdir()
    (tmp_path / "factors" / "bad.py").write_text(source)
    (line,) = layering_violations(tmp_path)
    assert line.startswith("factors/bad.py:") and "factors.bad imports hybrid_calib." in line and reason in line


def test_the_check_catches_calib_learned_sim_and_unknown_modules(tmp_path):
    (tmp_path / "learned").mkdir()
    (tmp_path / "learned" / "a.py").write_text("from hybrid_calib.calib import report_std\n")
    (tmp_path / "hybrid_calib" / "data").mkdir(parents=True)
    (tmp_path / "hybrid_calib" / "data" / "b.py").write_text("from ..sim.world import World\n")
    (tmp_path / "hybrid_calib" / "commands").mkdir()
    (tmp_path / "hybrid_calib" / "commands" / "c.py").write_text("import hybrid_calib.sim.simulate\n")
    (tmp_path / "hybrid_calib" / "viz.py").write_text("import numpy\n")
    bad = layering_violations(tmp_path)
    assert len(bad) == 3, bad
    assert any("learned/a.py:1" in b and "must not import each other" in b for b in bad)
    assert any("hybrid_calib/data/b.py:1" in b and "hybrid_calib.sim.world" in b for b in bad)
    assert any("hybrid_calib/viz.py: module hybrid_calib.viz has no layer" in b for b in bad)


def test_the_plots_import_nothing_else_of_their_layer(tmp_path):
    """plots/fleet.py imported fleet.summary's camera_offset (a calib concept, now calib.covariance's)."""
    (tmp_path / "hybrid_calib" / "plots").mkdir(parents=True)
    bad = tmp_path / "hybrid_calib" / "plots" / "bad.py"
    bad.write_text("def f():\n    from hybrid_calib.fleet import summary\n")
    (line,) = layering_violations(tmp_path)
    assert line.startswith("hybrid_calib/plots/bad.py:2:") and "nothing else of layer 7" in line


def literal_homes(value: str, root: Path = ROOT) -> list[str]:
    """``file:line`` of every string constant equal to ``value`` in the packages (docstrings hold it inside longer
    text, and are not equal to it)."""
    found = []
    for path in _modules(root):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Constant) and node.value == value:
                found.append(f"{path.relative_to(root)}:{node.lineno}")
    return found


def test_the_simulators_version_folder_is_named_once():
    """Probe 141: "v1.0-sim" was written out in 16 places (the commands' defaults, the demo, the uncertainty fit's
    real-root test) beside the simulator's own constant; one home, ``data.tables.SIM_VERSION``."""
    from hybrid_calib.data.tables import SIM_VERSION

    (home,) = literal_homes(SIM_VERSION)
    assert home.startswith("hybrid_calib/data/tables.py:"), home


def mutual_imports(root: Path = ROOT) -> list[str]:
    """``a <-> b`` for every two modules of the packages that import each other at run time, at module level or
    inside a function (a function-local import hides the cycle from Python, not the two halves of one concept);
    annotations' ``if TYPE_CHECKING:`` imports aside."""
    names = {_module_name(p, root): p for p in _modules(root)}
    edges: dict[str, set[str]] = {}
    for module, path in names.items():
        for _, target in _imports(path, module, typing_only=False):
            while target and target not in names:  # ``from a import name``: module a
                target = target.rpartition(".")[0]
            if target and target != module:
                edges.setdefault(module, set()).add(target)
    return sorted(f"{a} <-> {b}" for a, outs in edges.items() for b in outs if a < b and a in edges.get(b, ()))


def test_no_two_modules_import_each_other(tmp_path):
    """Probe 141: four pairs did, one side inside a function (calib.drift <-> calib.mount_monitor, data.nuscenes <->
    data.reference, atomic <-> errors, factors.correspondences <-> factors.io): each a concept cut in two. Its home now:
    data.reference.reference_nouns, data.mounts, errors.LOCK_NAME / RUNS_NAME, factors.io's arrays."""
    assert mutual_imports() == []
    (tmp_path / "factors").mkdir()
    (tmp_path / "factors" / "a.py").write_text("from factors.b import g\n")
    (tmp_path / "factors" / "b.py").write_text("def g():\n    from factors import a\n")
    assert mutual_imports(tmp_path) == ["factors.a <-> factors.b"]
