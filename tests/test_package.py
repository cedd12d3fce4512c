"""The top-level package: `import radiosity` is cheap, and what it offers (`__all__`) is what
`dir(radiosity)` and tab completion show, each name resolving to the documented object."""

from __future__ import annotations

import os
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
