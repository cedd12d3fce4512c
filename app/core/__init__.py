"""Pure numerics: geometry, the camera, form-factor kernels, exact form factors, solvers and the
array bundles passed between stages. No Dask, no I/O."""
