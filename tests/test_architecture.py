"""The package's layers: each module imports only from its own layer or below, there are no
import cycles, imports sit at module top (but for optional dependencies), and no private name
crosses a module boundary. Read from the source with ``ast``, so nothing needs importing.

    core -> scene -> physics -> transport -> drivers -> estimators -> analysis, api -> package
    -> experiment, cli

(``jgi._xla``, the CPU-backend devices, sits below everything.)"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "jgi"
LAYERS = ["jgi._xla", "jgi.core", "jgi.scene", "jgi.physics", "jgi.transport", "jgi.drivers",
          "jgi.estimators", "jgi.analysis", "jgi.api", "jgi", "jgi.experiment", "jgi.cli"]
# may be imported inside functions: not installed by default (mitsuba, drjit), or slow to import
# and needed by few runs, where every jgi start-up would pay for them (`jgi render` on a cached
# program starts in seconds): Dask's distributed (0.7 s, studies on a cluster), colour-science
# (0.5 s, imported spectra), trimesh (0.4 s, mesh files and the metal ring)
OPTIONAL = {"mitsuba", "drjit", "distributed", "colour", "trimesh"}


def _modules() -> dict[str, tuple[Path, ast.Module]]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = (path, ast.parse(path.read_text(), str(path)))
    return out


MODULES = _modules()


def _is_package(name: str) -> bool:
    return MODULES[name][0].name == "__init__.py"


def _resolve(module: str, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module.split(".") if _is_package(module) else module.split(".")[:-1]
    base = base[: len(base) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(module: str, tree: ast.Module):
    """(target module, imported name or None, node, at module top) for every import of a jgi
    module; ``from pkg import sub`` names the submodule as the target."""
    top = {id(n) for n in tree.body}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, None, node, id(node) in top
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(module, node)
            for a in node.names:
                sub = f"{base}.{a.name}"
                if sub in MODULES:
                    yield sub, None, node, id(node) in top
                else:
                    yield base, a.name, node, id(node) in top


def _layer(module: str) -> int:
    best = max((p for p in LAYERS if module == p or module.startswith(p + ".")), key=len)
    return LAYERS.index(best)


def test_every_module_has_a_layer():
    for m in MODULES:
        assert any(m == p or m.startswith(p + ".") for p in LAYERS), m


def test_imports_are_at_module_top():
    bad = []
    for m, (path, tree) in MODULES.items():
        for target, _, node, top in _imports(m, tree):
            if not top and target.split(".")[0] not in OPTIONAL and not (
                    m == "jgi.cli" and target.startswith("jgi.")):   # a subcommand's module,
                # imported when that subcommand runs (`jgi render` need not load the studies)
                bad.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: {target}")
    assert not bad, "function-local imports:\n" + "\n".join(bad)


def test_no_private_name_crosses_a_module():
    bad = []
    for m, (path, tree) in MODULES.items():
        aliases = {}
        for target, name, node, _ in _imports(m, tree):
            if target.startswith("jgi") and name and name.startswith("_") and name != "__version__":
                bad.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: {target}.{name}")
            if target in MODULES and isinstance(node, ast.ImportFrom):
                for a in node.names:
                    if f"{_resolve(m, node)}.{a.name}" == target:
                        aliases[a.asname or a.name] = target
        for node in ast.walk(tree):   # module._private through an imported module
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in aliases and node.attr.startswith("_")
                    and not node.attr.startswith("__")):
                bad.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: "
                           f"{aliases[node.value.id]}.{node.attr}")
    assert not bad, "private names used across modules:\n" + "\n".join(bad)


def _graph() -> dict[str, set[str]]:
    graph = {m: set() for m in MODULES}
    for m, (_, tree) in MODULES.items():
        for target, _, _, top in _imports(m, tree):
            if top and target in MODULES and target != m:
                graph[m].add(target)
            # importing a name from a package runs the package's __init__ first
    return graph


def test_no_import_cycles():
    graph = _graph()
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                raise AssertionError("import cycle: " + " -> ".join(stack[stack.index(t):] + [t]))
            if t not in state:
                visit(t)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_go_downward(module):
    mine = _layer(module)
    up = [t for t in _graph()[module] if _layer(t) > mine]
    assert not up, f"{module} ({LAYERS[mine]}) imports from above: {sorted(up)}"


def test_one_alias_per_module():
    """A jgi module imported under an alias has that alias everywhere in the package, and an
    alias names one module (``B`` was bsdf in some modules and bvh in another)."""
    by_module: dict[str, set[str]] = {}
    by_alias: dict[str, set[str]] = {}
    for m, (_, tree) in MODULES.items():
        for target, _, node, _ in _imports(m, tree):
            if target not in MODULES or not isinstance(node, ast.ImportFrom):
                continue
            for a in node.names:
                if a.asname and f"{_resolve(m, node)}.{a.name}" == target:
                    by_module.setdefault(target, set()).add(a.asname)
                    by_alias.setdefault(a.asname, set()).add(target)
    assert not {k: v for k, v in by_module.items() if len(v) > 1}, by_module
    assert not {k: v for k, v in by_alias.items() if len(v) > 1}, by_alias


README = PACKAGE.parent / "README.md"


def test_readme_layout_table_matches_the_tree():
    """Every module and package the README's layout table names exists, and every module of the
    package is named by it (itself, or its package)."""
    text = README.read_text()
    table = text[text.index("## Layout"):]
    table = table[: table.index("\n## ", 5)] if "\n## " in table[5:] else table

    named = set(re.findall(r"`(jgi/[\w/.]+)`", table))
    for path in named:
        assert (PACKAGE.parent / path).exists(), f"README names {path}, which does not exist"
    for m, (path, _) in MODULES.items():
        rel = str(path.relative_to(PACKAGE.parent))
        covered = rel in named or any(rel.startswith(n) for n in named if n.endswith("/"))
        covered = covered or (path.name == "__init__.py" and rel.rsplit("/", 1)[0] + "/" in named)
        if path.name == "__init__.py" and not covered:
            covered = rel == "jgi/__init__.py" or any(
                n.startswith(rel.rsplit("/", 1)[0] + "/") for n in named)
        assert covered, f"{rel} is not in the README's layout table"


ROOT = PACKAGE.parent
SCRIPT_TREES = ("jgi", "tests", "experiments", "paper")
# experiment modules that are libraries, not scripts: tests may import these
EXPERIMENT_LIBRARIES = {"experiments.mitsuba_scene", "experiments.bench.smallvcm"}


def _sources(*trees: str):
    for tree in trees:
        for path in sorted((ROOT / tree).rglob("*.py")):
            yield path, ast.parse(path.read_text(), str(path))


def _absolute_imports(tree: ast.Module):
    """(module, node) for every import anywhere in the file, ``from pkg import sub`` giving
    ``pkg.sub`` as well as ``pkg``."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, node
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            yield node.module, node
            for a in node.names:
                yield f"{node.module}.{a.name}", node


def test_no_sys_path_edits():
    """Scripts run as modules (``python -m experiments.bench.bench``, ``python -m
    paper.pipeline``) and tests import packages, so nothing edits ``sys.path``."""
    bad = []
    for path, tree in _sources(*SCRIPT_TREES):
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and node.attr == "path"
                    and isinstance(node.value, ast.Name) and node.value.id == "sys"):
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not bad, "sys.path used:\n" + "\n".join(bad)


def _is_test_module(module: str) -> bool:
    """``tests.test_*`` or ``tests.conftest`` (or a name inside one)."""
    parts = module.split(".")
    return (parts[0] == "tests" and len(parts) > 1
            and (parts[1].startswith("test_") or parts[1] == "conftest"))


def test_tests_import_no_test_module_nor_experiment_script():
    """A test reads shared helpers from ``tests.support`` (and experiments' library modules),
    never from another test module, ``conftest`` or an experiment script."""
    bad = []
    for path, tree in _sources("tests"):
        for module, node in _absolute_imports(tree):
            parts = module.split(".")
            to_script = (parts[0] == "experiments" and len(parts) > 1
                         and not any(module == lib or module.startswith(lib + ".")
                                     or lib.startswith(module + ".")
                                     for lib in EXPERIMENT_LIBRARIES))
            if _is_test_module(module) or to_script:
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}: {module}")
    assert not bad, "tests importing test modules or experiment scripts:\n" + "\n".join(bad)


def test_experiments_and_paper_import_no_test_module():
    """Experiments and the paper's scripts share the tests' samplers and references through
    ``tests.support``, never through a test module or ``conftest``."""
    bad = []
    for path, tree in _sources("experiments", "paper"):
        for module, node in _absolute_imports(tree):
            if _is_test_module(module):
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}: {module}")
    assert not bad, "experiments or paper importing test modules:\n" + "\n".join(bad)
