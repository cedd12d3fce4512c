"""Transport methods behind one seam: `base` holds the protocol and the registry; each method
lives in its own folder (pairs: the seed's all-pairs bits; hierarchical: links on split trees).
Importing the package registers the methods' store groups with the run store (base)."""

from radiosity.methods import base  # noqa: F401
