"""View factors between a mesh's own facets (no camera): a second product on the same runtime."""
