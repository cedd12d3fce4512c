"""The top-level package: `import radiosity` is cheap, and what it offers (`__all__`) is what
`dir(radiosity)` and tab completion show, each name resolving to the documented object; and
what the package imports is installed with it (pandas, for one, is not needed)."""

from __future__ import annotations

import ast
import importlib.metadata
import os
import re
import subprocess
import sys
import tomllib

from helpers import ROOT


def test_dir_lists_the_api_and_every_name_resolves():
    import radiosity
    from radiosity.errors import RadiosityError
    from radiosity.pipeline import render
    from radiosity.viewfactors.api import viewfactors

    assert {"render", "view_factors", "RadiosityError", "__version__"} <= set(dir(radiosity))
    assert set(radiosity.__all__) <= set(dir(radiosity))
    assert radiosity.render is render and radiosity.view_factors is viewfactors
    assert radiosity.RadiosityError is RadiosityError
    for name in radiosity.__all__:
        getattr(radiosity, name)
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        assert radiosity.__version__ == tomllib.load(f)["project"]["version"]
    try:
        radiosity.rendr
    except AttributeError as e:
        assert "has no attribute 'rendr'" in str(e)
    else:
        raise AssertionError("radiosity.rendr resolved")


def test_import_and_dir_stay_cheap():
    """Neither `import radiosity` nor `dir(radiosity)` imports the pipeline, Dask or numba."""
    code = ("import sys, radiosity; names = dir(radiosity); "
            "print(sorted(m for m in ('radiosity.pipeline', 'dask', 'distributed', 'numba') "
            "if m in sys.modules)); print('render' in names)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       check=True)
    assert r.stdout.split("\n")[:2] == ["[]", "True"], r.stdout + r.stderr


# imported by app/ without being declared in pyproject.toml, each guarded where it is used
UNDECLARED = {"pyarrow": "Parquet copies of the light tables, written only when it is installed",
              "tornado": "the web server of distributed's dashboard (stated by distributed)",
              "drjit": "Mitsuba 3's array library (stated by mitsuba, the extra `reference`)"}


def test_every_imported_package_is_declared():
    """Every third-party module imported anywhere in app/ belongs to a distribution that
    pyproject.toml declares (a dependency or an extra), or is one of UNDECLARED."""
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        project = tomllib.load(f)["project"]
    declared = project["dependencies"] + sum(project["optional-dependencies"].values(), [])
    declared = {re.split(r"[ <>=!\[;]", d, 1)[0].lower().replace("_", "-") for d in declared}
    dists = importlib.metadata.packages_distributions()
    imported: dict[str, str] = {}
    for folder, _, files in os.walk(os.path.join(ROOT, "app")):
        for f in files:
            if not f.endswith(".py"):
                continue
            path = os.path.join(folder, f)
            for node in ast.walk(ast.parse(open(path, encoding="utf-8").read())):
                if isinstance(node, ast.Import):
                    tops = [a.name.split(".")[0] for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    tops = [node.module.split(".")[0]]
                else:
                    continue
                for top in tops:
                    imported.setdefault(top, os.path.relpath(path, ROOT))
    wrong = [f"{top} ({where})" for top, where in sorted(imported.items())
             if top not in sys.stdlib_module_names and top != "radiosity" and top not in UNDECLARED
             and not {d.lower().replace("_", "-") for d in dists.get(top, [top])} & declared]
    assert "numpy" in imported and not wrong, f"imported but not declared: {wrong}"
