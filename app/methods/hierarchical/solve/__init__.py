"""Transport and solve on the links (SPEC §8): the push-pull operator K = Push Gather Pull on the
leaves of the union tree (`transport`: the operator run in the driver or as pinned Dask groups;
`passes`: its numba kernels and the final gather) and the per-leaf vectors the solve needs and
writes back (`leaves`)."""
