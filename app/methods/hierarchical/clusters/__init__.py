"""The cluster layer (SPEC §9; Smits, Arvo & Greenberg 1994): links between clusters of original
elements above the split trees. `refine` decides which cluster links a scene needs (the tree
over the originals and the oracle's bound), `tasks` cuts that refinement into Dask tasks,
`weights` gives each link its form factors and visible fraction, and `transport` carries light
over the links in the solve's passes and the final gather."""
