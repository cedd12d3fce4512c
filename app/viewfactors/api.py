"""View factors between the user's own facets, for thermal-radiation engineers (issue 16):
`radiosity viewfactors MESH --out DIR` and `radiosity.view_factors(mesh) -> scipy.sparse.csr_matrix`.

F_ij is the fraction of the power leaving facet i (front side) that reaches facet j, so
A_i F_ij = A_j F_ji and row sums are <= 1 (= 1 in an enclosure). This module is the Python
API and the names the CLI uses; the stage is master.py (driver), task.py (workers), facets.py
(loading), outputs.py (checks and files). The method: docs/src/design/viewfactors-method.md.
"""

from __future__ import annotations

from radiosity.settings import Settings, options
from radiosity.viewfactors.facets import Facets, load_facets
from radiosity.viewfactors.master import ViewFactors, compute_viewfactors, resolve_params

__all__ = ["Facets", "ViewFactors", "compute_viewfactors", "in_process_mode", "load_facets",
           "resolve_params", "viewfactors"]

#: With radiosity.cluster.processes auto, meshes of at most this many facets run on threads in
#: the caller's process (as radiosity.render runs small scenes): no worker processes to start,
#: so a plain script needs no `if __name__ == "__main__"` guard. Chosen, not measured: half a
#: million pairs, where starting workers stops being the larger cost.
IN_PROCESS_FACETS = 1000


def in_process_mode(settings: Settings, facets: int) -> tuple[bool, str]:
    """(in_process, why) for a local cluster of the view factors of `facets` facets, as
    runtime/cluster.local_mode decides it for a render (its size there is camera samples,
    here facets): threads in this process up to IN_PROCESS_FACETS with processes auto."""
    from radiosity.runtime.cluster import local_mode

    in_process, why = local_mode(settings.cluster.processes, facets, IN_PROCESS_FACETS)
    return in_process, why.replace("camera samples", "facets")


def viewfactors(mesh, *, accuracy: float | None = None, enclosure: str | None = None,
                out: str | None = None, client=None, workers: int | None = None,
                resume: bool = False, progress: bool = False, settings: Settings | None = None):
    """The view-factor matrix of the facets of `mesh` (a mesh or scene path, a
    trimesh.Trimesh, a (vertices, faces) pair): scipy.sparse.csr_matrix (n, n), F[i, j] the
    fraction of the power leaving facet i (front side) that reaches facet j, rows in the
    order the facets were loaded (facets.csv in `out` names them).

    accuracy: target absolute error per factor (default radiosity.viewfactors.accuracy);
    enclosure: auto | on | off; out: run directory (default: a temporary one, removed after);
    client: a distributed.Client (default: a LocalCluster of `workers` for this call, on
    threads in this process for meshes of at most IN_PROCESS_FACETS facets);
    settings: a base settings.Settings (default: dask.config's), the options checked over it."""
    import tempfile

    from radiosity.runtime.cluster import open_client

    settings = options(settings, accuracy=accuracy, enclosure=enclosure)
    with tempfile.TemporaryDirectory(prefix="radiosity-vf-") as tmp:
        run = out or tmp
        if client is not None:
            return compute_viewfactors(mesh, run, client, settings, resume=resume,
                                       progress=progress).matrix
        mesh = load_facets(mesh, settings=settings)
        in_process, _ = in_process_mode(settings, len(mesh))
        with open_client(workers, quiet=True, in_process=in_process,
                         settings=settings.cluster) as c:
            return compute_viewfactors(mesh, run, c, settings, resume=resume,
                                       progress=progress).matrix


def heat(scene, *, emissivity: float | None = None, temperature_K: float | None = None,
         heat_flux_W_m2: float | None = None, environment_K: float | None = None,
         conductances: str | None = None, conductance_cutoff: float | None = None,
         accuracy: float | None = None, enclosure: str | None = None, out: str | None = None,
         client=None, workers: int | None = None, progress: bool = False,
         settings: Settings | None = None):
    """Radiative heat exchange between the facets of `scene`: a scene TOML whose materials
    carry `emissivity` and `temperature_K` or `heat_flux_W_m2` (docs: how-to/heat.md), or a
    mesh (path, trimesh.Trimesh, (vertices, faces)) whose every facet takes the keywords'
    values. The keywords are defaults for what the file leaves out; environment_K: what the
    facets see through openings (default the file's [environment], else 0 K).

    Returns a viewfactors.heat.HeatResult: `.table()` the facets.csv columns as arrays, `.solution` (radiosity,
    net flux, temperatures), `.conductances.GR` (scipy.sparse, (n+1) x (n+1), the environment
    last; None when not computed: conductances = auto | on | off), `.figures` the report.
    out: run directory (default: a temporary one, removed after); client: a
    distributed.Client (default: a local cluster of `workers`, on threads in this process for
    small meshes); settings: a base settings.Settings, the options checked over it."""
    import tempfile

    from radiosity.runtime.cluster import local_mode, open_client
    from radiosity.viewfactors.heat import compute_heat
    from radiosity.viewfactors.thermal import ThermalDefaults, heat_inputs

    settings = options(settings, accuracy=accuracy, enclosure=enclosure,
                       conductances=conductances, conductance_cutoff=conductance_cutoff)
    defaults = ThermalDefaults(emissivity, temperature_K, heat_flux_W_m2, environment_K)
    with tempfile.TemporaryDirectory(prefix="radiosity-heat-") as tmp:
        run = out or tmp
        if client is not None:
            return compute_heat(scene, run, client, settings, defaults, progress=progress)
        fac = load_facets(scene, settings=settings)
        heat_inputs(scene, fac, defaults)   # bad values fail before a cluster starts
        in_process, _ = local_mode(settings.cluster.processes, len(fac), IN_PROCESS_FACETS)
        with open_client(workers, quiet=True, in_process=in_process,
                         settings=settings.cluster) as c:
            return compute_heat(scene, run, c, settings, defaults, progress=progress)
