"""The house keeps its layers: the folders of `app/` are the layers, imports only point down
(function-level imports included), sibling methods never import each other, no import cycles,
low layers never touch a Dask client, and worker-side code never reads the configuration (every
tunable is resolved on the driver and passed in)."""

from __future__ import annotations

import ast
import os

import pytest

APP = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "app")

# top to bottom, by folder (or top-level module); a module may import its own layer or lower ones
LAYERS = [
    {"cli"},
    {"validation"},
    {"pipeline"},
    {"stages", "viewfactors"},
    {"methods"},
    {"runtime"},
    {"scene"},
    {"tracing"},
    {"settings"},
    {"formats"},
    {"core"},
    {"config", "errors"},
]
# folders whose code runs on workers (or is pure, or reads and writes files given their values):
# no configuration, no Client
WORKER_SIDE = ("core", "formats", "scene", "tracing")
TOP_LEVEL_MAX = 5  # app/*.py, __init__ included


def _modules() -> dict:
    """Dotted module name under `radiosity` -> path, for every module of the package."""
    out = {}
    for d, _, files in os.walk(APP):
        for f in files:
            if f.endswith(".py") and f not in ("__init__.py", "__main__.py"):
                rel = os.path.relpath(os.path.join(d, f[:-3]), APP)
                out[rel.replace(os.sep, ".")] = os.path.join(d, f)
    return out


def _imports(name: str, path: str, mods: dict) -> set:
    """Modules of the package that `path` (module `name`) imports, anywhere in the file."""
    out = set()
    pkg = name.split(".")[:-1]
    for node in ast.walk(ast.parse(open(path).read())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[:len(pkg) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            elif (node.module or "").split(".")[0] == "radiosity":
                mod = node.module[len("radiosity."):] if "." in node.module else ""
            else:
                continue
            for a in node.names:
                sub = f"{mod}.{a.name}" if mod else a.name
                out.add(sub if sub in mods else mod)
        elif isinstance(node, ast.Import):
            out.update(a.name[len("radiosity."):] for a in node.names
                       if a.name.startswith("radiosity."))
    return {m for m in out if m in mods}


def _room(mod: str) -> str:
    return mod.split(".")[0]


def _layer(mod: str) -> int:
    for i, layer in enumerate(LAYERS):
        if _room(mod) in layer:
            return i
    raise AssertionError(f"app/{_room(mod)} is in no layer: add it to LAYERS in tests/test_layers.py")


def test_top_level_holds_few_modules():
    top = sorted(f for f in os.listdir(APP) if f.endswith(".py"))
    assert len(top) <= TOP_LEVEL_MAX, top


def test_every_module_has_a_layer_and_imports_point_down():
    mods = _modules()
    bad = []
    for m, path in mods.items():
        for d in _imports(m, path, mods):
            if _layer(d) < _layer(m):
                bad.append(f"{m} (layer {_layer(m)}) imports {d} (layer {_layer(d)})")
    assert not bad, "\n".join(bad)


def test_methods_do_not_import_each_other():
    """Each method folder stands on methods/base and the layers below, never on a sibling."""
    mods = _modules()
    bad = []
    for m, path in mods.items():
        parts = m.split(".")
        if parts[0] == "methods" and len(parts) > 2:
            for d in _imports(m, path, mods):
                dp = d.split(".")
                if dp[0] == "methods" and len(dp) > 2 and dp[1] != parts[1]:
                    bad.append(f"{m} imports {d}")
    assert not bad, "\n".join(bad)


def test_no_import_cycles():
    mods = _modules()
    graph = {m: _imports(m, p, mods) - {m} for m, p in mods.items()}
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


@pytest.mark.parametrize("mod", sorted(m for m in _modules() if _room(m) in WORKER_SIDE))
def test_worker_side_modules_read_no_configuration_and_use_no_client(mod):
    tree = ast.parse(open(_modules()[mod]).read())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
    assert "config" not in imported, f"{mod} imports config: resolve the value on the driver"
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
    assert found >= 6  # raster, subdivide, seed subscene, visibility, apply, gs sweep


# where settings are resolved: the CLI, the Python API's entry points (radiosity.render,
# radiosity.view_factors) and the settings module itself; everything below takes frozen objects
SETTINGS_BOUNDARY = ("cli", "pipeline", "viewfactors.api", "settings")


def _at_boundary(mod: str) -> bool:
    return any(mod == b or mod.startswith(b + ".") for b in SETTINGS_BOUNDARY)


def test_no_function_below_the_boundary_takes_settings_none():
    """A `settings=None` parameter meant "read dask.config now": below the boundary every
    function takes the run's settings object."""
    bad = []
    for m, path in _modules().items():
        if _at_boundary(m):
            continue
        for node in ast.walk(ast.parse(open(path).read())):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            a = node.args
            pos = a.posonlyargs + a.args
            pairs = list(zip(pos[len(pos) - len(a.defaults):], a.defaults)) + \
                [(p, d) for p, d in zip(a.kwonlyargs, a.kw_defaults) if d is not None]
            bad += [f"{m}.{node.name}:{node.lineno}" for p, d in pairs
                    if p.arg == "settings" and isinstance(d, ast.Constant) and d.value is None]
    assert not bad, f"settings=None below the boundary: {bad}"


def test_settings_are_resolved_only_at_the_boundary():
    """settings.resolve (and settings.options, which calls it) only in the boundary modules."""
    bad = []
    for m, path in _modules().items():
        if _at_boundary(m):
            continue
        tree = ast.parse(open(path).read())
        names = {a.asname or a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)
                 and n.module == "radiosity.settings" for a in n.names
                 if a.name in ("resolve", "options")}
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                f = node.func
                if (isinstance(f, ast.Name) and f.id in names) or (
                        isinstance(f, ast.Attribute) and f.attr in ("resolve", "options")
                        and isinstance(f.value, ast.Name) and f.value.id == "settings"):
                    bad.append(f"{m}:{node.lineno}")
    assert not bad, f"settings resolved below the boundary: {bad}"


def test_only_config_settings_and_the_cli_read_dask_config():
    """dask.config is read by config.py (the YAML and its reader) and settings.py (resolve),
    and by nothing else: not even the cluster start, which takes a settings.ClusterSettings and
    reaches dask's own keys (jobqueue.*, distributed.*) through config.dask_get."""
    bad = []
    for m, path in _modules().items():
        if m in ("config", "settings") or _room(m) == "cli":
            continue
        tree = ast.parse(open(path).read())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import) and any(a.name == "dask.config" for a in node.names):
                bad.append(f"{m}:{node.lineno} import dask.config")
            elif isinstance(node, ast.ImportFrom) and node.module == "dask" and any(
                    a.name == "config" for a in node.names):
                bad.append(f"{m}:{node.lineno} from dask import config")
            elif isinstance(node, ast.Attribute) and node.attr == "config" and \
                    isinstance(node.value, ast.Name) and node.value.id == "dask":
                bad.append(f"{m}:{node.lineno} dask.config")
            elif isinstance(node, ast.Attribute) and node.attr == "section" and \
                    isinstance(node.value, ast.Name) and node.value.id == "config":
                bad.append(f"{m}:{node.lineno} config.section")
    assert not bad, f"dask.config read outside config.py, settings.py and cli/: {bad}"


def test_no_module_is_named_after_the_standard_library():
    import sys

    bad = [m for m in _modules() if m.split(".")[-1] in sys.stdlib_module_names]
    assert not bad, bad


def test_architecture_layout_names_every_folder():
    """The docs' layout (docs/src/design/architecture.md, "Layout") is the map a newcomer reads:
    every folder is on it."""
    page = open(os.path.join(os.path.dirname(APP), "docs", "src", "design", "architecture.md")).read()
    section = page[page.index("## Layout"):]
    section = section[:section.index("\n## ", 5)] if "\n## " in section[5:] else section
    rooms = {_room(m) for m in _modules() if "." in m}
    missing = sorted(r for r in rooms if f"{r}/" not in section)
    assert not missing, f"the Layout of docs/src/design/architecture.md misses {missing}"


def test_tests_and_benchmarks_import_radiosity_not_app():
    """`app` is only the folder: importing it from the source tree loads a second copy of every
    module, so a monkeypatch on `app.x` never reaches the `radiosity.x` the code runs."""
    import re

    root = os.path.dirname(APP)
    bad = []
    for d in ("tests", "benchmarks"):
        for dirpath, _, files in os.walk(os.path.join(root, d)):
            for f in sorted(files):
                if f.endswith(".py"):
                    src = open(os.path.join(dirpath, f)).read()
                    rel = os.path.relpath(os.path.join(dirpath, f), root)
                    bad += [rel for _ in re.findall(r"^\s*(?:from app\b|import app\b)", src, re.M)][:1]
    assert not bad, f"import app in {bad}"


def test_tests_mirror_the_folders():
    """A newcomer finds a folder's tests in the same folder under tests/."""
    root = os.path.join(os.path.dirname(APP), "tests")
    rooms = {_room(m) for m in _modules() if "." in m}
    missing = sorted(r for r in rooms if not os.path.isdir(os.path.join(root, r)))
    assert not missing, f"tests/ has no folder for {missing}"


def _method_names() -> set:
    """The METHODS registry's keys, read from methods/base.py's source."""
    tree = ast.parse(open(os.path.join(APP, "methods", "base.py")).read())
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else \
            [node.target] if isinstance(node, ast.AnnAssign) else []
        if any(isinstance(t, ast.Name) and t.id == "METHODS" for t in targets):
            return {k.value for k in node.value.keys}
    raise AssertionError("methods/base.py has no METHODS registry")


def _named_methods(node, names: set) -> list:
    """The method names (string constants, alone or in a tuple, list or set) that a comparison
    `node` compares with."""
    out = []
    for side in [node.left, *node.comparators]:
        items = side.elts if isinstance(side, (ast.Tuple, ast.List, ast.Set)) else [side]
        out += [i.value for i in items if isinstance(i, ast.Constant) and i.value in names]
    return out


def test_no_method_module_imported_outside_methods():
    """Outside methods/, a method is reached through methods/base.py (its registry and
    protocol), never by importing a method's own modules: a new method is one folder and one
    registry line."""
    mods = _modules()
    bad = [f"{m} imports {d}" for m, path in mods.items() if _room(m) != "methods"
           for d in _imports(m, path, mods) if d.startswith("methods.") and d != "methods.base"]
    assert not bad, "\n".join(bad)


def test_no_method_name_compared_outside_methods():
    """Outside methods/, no code compares a value with a method's name (a METHODS key, alone
    or in a tuple): it asks the method for a capability instead (methods/base.py)."""
    names = _method_names()
    assert names >= {"pairs", "hierarchical"}
    bad = []
    for m, path in _modules().items():
        if _room(m) == "methods":
            continue
        for node in ast.walk(ast.parse(open(path).read())):
            if isinstance(node, ast.Compare) and _named_methods(node, names):
                bad.append(f"app/{path[len(APP) + 1:]}:{node.lineno} compares with "
                           f"{_named_methods(node, names)}")
    assert not bad, "\n".join(bad)


def test_the_method_name_check_finds_a_comparison():
    """The check above can fail: it finds `x == "pairs"` and `m in ("a", "hierarchical")`."""
    names = _method_names()
    found = [_named_methods(n, names) for src in ('x == "pairs"', 'm not in (None, "hierarchical")',
                                                  'y == "other"')
             for n in ast.walk(ast.parse(src)) if isinstance(n, ast.Compare)]
    assert found == [["pairs"], ["hierarchical"], []]


MODULE_MAX_LINES = 600
FUNCTION_MAX_LINES = 120  # numba kernels excepted: a kernel is one loop nest, split it and it slows


def _is_numba(fn) -> bool:
    for d in fn.decorator_list:
        target = d.func if isinstance(d, ast.Call) else d
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name in ("njit", "jit", "vectorize", "guvectorize", "generated_jit"):
            return True
    return False


def test_modules_and_functions_stay_short():
    """No module over 600 lines and no Python (non-numba) function over 120: a newcomer reads
    one concern at a time (issue 49)."""
    long_modules, long_functions = [], []
    for name, path in _modules().items():
        text = open(path).read()
        if text.count("\n") > MODULE_MAX_LINES:
            long_modules.append(f"{name} ({text.count(chr(10))} lines)")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not _is_numba(node):
                n = node.end_lineno - node.lineno + 1
                if n > FUNCTION_MAX_LINES:
                    long_functions.append(f"{name}.{node.name} ({n} lines)")
    assert not long_modules, long_modules
    assert not long_functions, long_functions
