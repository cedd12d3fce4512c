"""The house keeps its layers: no import cycles (function-level imports included), imports only
point down, low layers never touch a Dask client, and worker-side code never reads the
configuration (every tunable is resolved on the driver and passed in)."""

from __future__ import annotations

import ast
import os

import pytest

APP = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "app")

# top to bottom; a module may import its own layer or lower ones
LAYERS = [
    {"cli"},
    {"pipeline", "study"},
    {"preprocess", "visibility", "links", "solve", "linksolve", "render", "dashboard", "cluster",
     "reference", "compare", "viewfactor"},
    {"operator", "solvers", "runner", "monitor", "settings", "nearfield", "effects", "closure",
     "enclosure", "preflight", "runlock", "faults"},
    {"store", "plan", "kernels", "passes", "shafts", "exact", "subdivide", "scene", "camera", "rays",
     "bvh", "vfkernels", "originals", "hierarchy"},
    {"types", "geometry", "config", "errors"},
]
# modules whose code runs on workers (or is pure): no configuration, no Client
WORKER_SIDE = {"bvh", "vfkernels", "store", "plan", "kernels", "passes", "shafts", "exact", "subdivide", "camera",
               "rays", "types", "geometry", "errors", "originals", "hierarchy"}


def _modules() -> dict:
    return {f[:-3]: os.path.join(APP, f) for f in os.listdir(APP)
            if f.endswith(".py") and f != "__init__.py"}


def _imports(path: str) -> set:
    """Modules of the package that `path` imports, anywhere in the file."""
    out = set()
    for node in ast.walk(ast.parse(open(path).read())):
        if isinstance(node, ast.ImportFrom):
            mod = node.module or ""
            if node.level == 1:
                out.update([mod.split(".")[0]] if mod else [a.name for a in node.names])
            elif mod.split(".")[0] == "radiosity":
                parts = mod.split(".")
                out.update([parts[1]] if len(parts) > 1 else [a.name for a in node.names])
    return out


def _layer(mod: str) -> int:
    for i, layer in enumerate(LAYERS):
        if mod in layer:
            return i
    raise AssertionError(f"app/{mod}.py is in no layer: add it to LAYERS in tests/test_layers.py")


def test_every_module_has_a_layer_and_imports_point_down():
    mods = _modules()
    bad = []
    for m, path in mods.items():
        for d in _imports(path) & set(mods):
            if d != m and _layer(d) < _layer(m):
                bad.append(f"{m} (layer {_layer(m)}) imports {d} (layer {_layer(d)})")
    assert not bad, "\n".join(bad)


def test_no_import_cycles():
    mods = _modules()
    graph = {m: _imports(p) & set(mods) - {m} for m, p in mods.items()}
    state, stack, cycles = {}, [], []

    def visit(u):
        state[u] = 1
        stack.append(u)
        for v in sorted(graph[u]):
            if state.get(v) == 1:
                cycles.append(" -> ".join(stack[stack.index(v):] + [v]))
            elif v not in state:
                visit(v)
        stack.pop()
        state[u] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "\n".join(cycles)


def _names(node) -> set:
    return {n.id for n in ast.walk(node) if isinstance(n, ast.Name)} | \
        {n.attr for n in ast.walk(node) if isinstance(n, ast.Attribute)}


@pytest.mark.parametrize("mod", sorted(WORKER_SIDE))
def test_worker_side_modules_read_no_configuration_and_use_no_client(mod):
    path = os.path.join(APP, f"{mod}.py")
    tree = ast.parse(open(path).read())
    reads = [n for n in ast.walk(tree) if isinstance(n, ast.Attribute) and n.attr == "get"
             and isinstance(n.value, ast.Name) and n.value.id == "config"]
    reads += [a for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module == "config"
              for a in n.names if a.name == "get"]
    assert not reads, f"app/{mod}.py reads config.get: resolve the value on the driver"
    dask_dist = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module} | \
        {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert not any(d.startswith("distributed") or d == "dask.distributed" for d in dask_dist), mod


def test_task_functions_read_no_configuration():
    """Every function a stage submits (task_*) gets its values as arguments."""
    found = 0
    for m, path in _modules().items():
        for node in ast.walk(ast.parse(open(path).read())):
            if isinstance(node, ast.FunctionDef) and node.name.startswith("task_"):
                found += 1
                assert "config" not in _names(node), f"{m}.{node.name} reads the configuration"
                assert "get" not in {n.attr for n in ast.walk(node) if isinstance(n, ast.Attribute)
                                     and isinstance(n.value, ast.Name) and n.value.id == "config"}
    assert found >= 6  # raster, subdivide, seed subscene, visibility, apply, gs sweep


def test_readme_layout_names_every_module():
    """The README's layout table is the map a newcomer reads: every module is on it."""
    readme = open(os.path.join(os.path.dirname(APP), "README.md")).read()
    section = readme[readme.index("## Layout"):]
    section = section[:section.index("\n## ", 5)] if "\n## " in section[5:] else section
    missing = [m for m in _modules() if f"`{m}`" not in section]
    assert not missing, f"README's Layout misses {missing}"


def test_tests_and_benchmarks_import_radiosity_not_app():
    """`app` is only the folder: importing it from the source tree loads a second copy of every
    module, so a monkeypatch on `app.x` never reaches the `radiosity.x` the code runs."""
    import re

    root = os.path.dirname(APP)
    bad = []
    for d in ("tests", "benchmarks"):
        for f in sorted(os.listdir(os.path.join(root, d))):
            if f.endswith(".py"):
                src = open(os.path.join(root, d, f)).read()
                bad += [f"{d}/{f}" for _ in re.findall(r"^\s*(?:from app\b|import app\b)", src, re.M)][:1]
    assert not bad, f"import app in {bad}"
