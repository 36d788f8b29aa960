"""The package's import graph: layers imported only downwards, no cycles, and plugins depending on the core only.

Every import counts, module level or inside a function (a lazy import is still a dependency); only imports under
``if TYPE_CHECKING:`` are left out (annotations, never executed).
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "nerfedit_plugin"
PLUGINS = ("deformers",)
FIELD_BACKENDS = ("nerfedit_plugin.fields",)  # every module of fields/ but the contract (base, checkpoint)
FIELD_CONTRACT = ("nerfedit_plugin.fields", "nerfedit_plugin.fields.base", "nerfedit_plugin.fields.checkpoint")
MAY_USE_PLUGINS = ("nerfedit_plugin.cli", "nerfedit_plugin.testing", "nerfedit_plugin.fields")
"""The command line and the kits may name built-ins; backends may share components among themselves."""

LAYERS = (
    ("errors", "timing", "io"),
    ("config", "registry", "quality"),
    ("geometry",),
    ("data",),
    ("bending",),
    ("edit",),
    ("fields.base", "fields.checkpoint"),
    ("render",),
    ("training",),
    ("fields",),
    ("pipeline",),
    ("viewer",),
    ("testing",),
    ("cli",),
    ("",),
)
"""The core's layers, bottom first, as module prefixes below ``nerfedit_plugin`` (the longest prefix that matches
names a module's layer; ``""`` is the package itself, the public API): file plumbing; configs and the registry;
meshes and solvers; cameras and datasets; deformations and point location; editing (specs, the Deformer contract,
proxy, lift); the Field contract; the renderer; the training loop; the field backends (which train through it); the
stage drivers and their folders; the viewer; the conformance kits; the command line. A module imports its own
layer and the ones below it, never one above."""


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(tree: ast.AST, module: str, is_package: bool) -> set[str]:
    """Absolute names of every module imported in ``tree`` (relative imports resolved)."""
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = module.split(".")[: len(module.split(".")) - node.level + (1 if is_package else 0)]
                base = ".".join(anchor + ([base] if base else []))
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)  # `from pkg import module`
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return found


def import_graph() -> dict[str, set[str]]:
    """module -> the project modules it imports (nerfedit_plugin and deformers)."""
    files = [p for top in (PACKAGE, *PLUGINS) for p in (ROOT / top).rglob("*.py")]
    modules = {_module_name(p): p for p in files}
    graph = {}
    for name, path in modules.items():
        names = _imports(ast.parse(path.read_text()), name, path.name == "__init__.py")
        graph[name] = {n for n in names if n in modules and n != name}
    return graph


def _in(module: str, prefixes) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def layer(module: str) -> int:
    """The index in :data:`LAYERS` of a module of the core."""
    rest = module.removeprefix(PACKAGE).removeprefix(".")
    best, found = -1, None
    for index, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if (rest == prefix or rest.startswith(prefix + ".") or prefix == "") and len(prefix) > best:
                best, found = len(prefix), index
    assert found is not None, f"{module} is in no layer"
    return found


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """``"a imports b"`` for every import of the core that runs up a layer."""
    core = [m for m in graph if m == PACKAGE or m.startswith(PACKAGE + ".")]
    return sorted(f"{m} imports {d}" for m in core for d in graph[m] if _in(d, (PACKAGE,)) and layer(d) > layer(m))


def test_layers_are_imported_downwards_only():
    wrong = upward_imports(import_graph())
    assert not wrong, "imports that run up a layer (tests/test_architecture.py, LAYERS):\n" + "\n".join(wrong)


@pytest.mark.parametrize(
    "module, dependency",
    [  # what the check finds in the layout before the pipeline floor (the modules' names of then), and a driver
        ("nerfedit_plugin.cli.demo", "nerfedit_plugin.demo"),  # the demo was the package's top-level module
        ("nerfedit_plugin.io.checkpoint", "nerfedit_plugin.config"),  # the field contract's file, in the plumbing
        ("nerfedit_plugin.io.checkpoint", "nerfedit_plugin.registry"),
        ("nerfedit_plugin.io.run", "nerfedit_plugin.config"),  # the train and extract stages, in the plumbing
        ("nerfedit_plugin.io.run", "nerfedit_plugin.data.datasets"),
        ("nerfedit_plugin.io.run", "nerfedit_plugin.data.normalization"),
        ("nerfedit_plugin.io.run", "nerfedit_plugin.fields.base"),
        ("nerfedit_plugin.io.run", "nerfedit_plugin.geometry.mesh"),
        ("nerfedit_plugin.io.run", "nerfedit_plugin.quality"),
        ("nerfedit_plugin.io.run", "nerfedit_plugin.registry"),
        ("nerfedit_plugin.io.run", "nerfedit_plugin.training.trainer"),
        ("nerfedit_plugin.render.executors", "nerfedit_plugin.pipeline.run"),  # a renderer opening run folders
        ("nerfedit_plugin.fields.base", "nerfedit_plugin.render.renderer"),
        ("nerfedit_plugin.viewer.field_preview", "nerfedit_plugin.cli.render"),
    ],
)
def test_the_layer_check_sees_an_upward_import(module, dependency):
    assert upward_imports({module: {dependency}, dependency: set()}) == [f"{module} imports {dependency}"]


def test_no_import_cycles():
    graph = import_graph()
    state: dict[str, int] = {}
    stack: list[str] = []

    def walk(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycle = stack[stack.index(nxt) :] + [nxt]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if nxt not in state:
                walk(nxt)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            walk(node)


def test_core_never_imports_plugins():
    """The core finds deformers and field backends through the registry, never by import."""
    wrong = []
    for module, deps in import_graph().items():
        if not module.startswith(PACKAGE) or _in(module, MAY_USE_PLUGINS):
            continue
        for dep in deps:
            backend = _in(dep, FIELD_BACKENDS) and dep not in FIELD_CONTRACT
            if _in(dep, PLUGINS) or backend:
                wrong.append(f"{module} imports {dep}")
    assert not wrong, "wrong-way imports:\n" + "\n".join(sorted(wrong))


def test_plugins_use_only_the_core():
    """Built-in deformers import the core and their own modules, like a third party would (no private kernels)."""
    wrong = [
        f"{m} imports {d}"
        for m, deps in import_graph().items()
        if _in(m, PLUGINS)
        for d in deps
        if any(part.startswith("_") for part in d.split(".")[1:] if part != "__init__")
    ]
    assert not wrong, "\n".join(sorted(wrong))


def test_the_checker_sees_lazy_imports_and_cycles(tmp_path):
    """The walker is not blind: a function-level import counts, a TYPE_CHECKING one does not."""
    tree = ast.parse(
        "import os\ndef f():\n    from nerfedit_plugin.io import run\n"
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from nerfedit_plugin import cli\n"
    )
    names = _imports(tree, "nerfedit_plugin.x", False)
    assert "nerfedit_plugin.io.run" in names and "nerfedit_plugin.cli" not in names
