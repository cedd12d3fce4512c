"""The geometric tolerances, in one frozen object (`TOL`, as trimesh's `constants.tol`): each field
says what it guards. Most are relative to the scene's size (its bounding-box diagonal), so that a
scene in millimetres and the same one in metres decide alike. The modules that use one name it
`TOL.<field>` (or keep a module-level alias of it where a numba kernel reads it as a constant).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Tolerances:
    """The tolerances (values chosen as their docstrings say; changing one changes outputs)."""

    cos: float = 1e-9
    """|cos| (relative to the segment length) below this counts as coplanar: exactly zero, not
    noise. One value for every stage that asks "do these two elements face each other?"
    (visibility, shafts, near field), so that they all agree on which pairs exist
    (core.geometry.COS_TOL)."""

    tie: float = 1e-9
    """Edge lengths within this relative difference count as equal when the subdivision picks
    the longest: keeps splits scale-free (scene.subdivide.TIE, read by the split trees' numba
    walks)."""

    weld: float = 1e-9
    """Corners of sub-elements closer than this, relative to the scene's diagonal, are one vertex
    of the smooth exports: far above float64 rounding of the split midpoints, far below any
    element's size (core.smooth)."""

    facing: float = 1e-6
    """Facing and behind tests of the originals (the originals tree, plan.facing_blocks,
    effects): distances below this times the scene's diagonal count as 0. Meshes come in
    float32: the triangles of one flat face lie on one plane only to about 1e-7 of the
    diagonal, and at 1e-9 they faced each other (scene.originals.TOL)."""

    closure_step: float = 1e-5
    """The closure's rays start this far off the surface, relative to the scene's size (at the
    default ray offset, `ray_offset_unit`; it scales with a larger one): beyond float32
    rounding, below `contact_window` (scene.closure)."""

    solid_step: float = 1e-5
    """The inside-a-solid test's rays start this far off the surface, relative to the scene's
    size, as the closure's (scene.contact)."""

    ray_offset_unit: float = 1e-6
    """The ray offset (rays.epsilon's default) the steps off a surface above are set for: a
    larger offset scales them by offset / this (scene.closure, scene.contact)."""

    contact_window: float = 5e-5
    """The contact window w, relative to the scene's bounding-box diagonal: a surface nearer
    than this to a sample point covers it (scene.contact.WINDOW)."""

    box_pad: float = 1e-6
    """Occluder boxes of the shaft test grow by this fraction of the scene's size
    (conservative: an occluder that touches a shaft is never missed; tracing.shafts)."""

    occluder_area: float = 1e-9
    """A flat face's elements whose areas sum to more than their convex hull's by this share
    overlap: the face is kept as it is (tracing.occluders)."""

    occluder_normal: float = 1e-9
    """Neighbours whose unit normals' dot product is within this of 1 may be one flat face (a
    small triangle of a flat face stored in float32 turns its normal by about 1e-6;
    tracing.occluders)."""

    occluder_plane: float = 1e-6
    """A flat face is one occluder polygon only where all its vertices lie within this of the
    scene's size of one plane (tracing.occluders)."""

    facet_plane: float = 1e-9
    """View factors' facing and plane tests: lengths below this fraction of the scene's size are
    0 (viewfactors.master)."""

    flat_spread: float = 1e-6
    """A cluster node's normal cone at most this wide counts as one normal in the link
    estimate: the triangles of a flat face in float32 differ by about 1e-7
    (methods/hierarchical/clusters/refine, read by numba)."""

    tiny_length: float = 1e-150
    """The smallest length taken for a direction (camera vectors): below it squares underflow
    to 0 (scene.load)."""

    plane_digits: int = 6
    """The image's edge test tells planes apart by their normal and offset (relative to the
    scene's size) rounded to this many decimal digits: a surface cut into many elements is one
    plane (stages.pixels.plane_ids)."""


#: The tolerances every module reads.
TOL = Tolerances()
