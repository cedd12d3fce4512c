"""The scene: loading meshes and scene files, camera-driven subdivision, the split trees, the
hierarchy over original elements, and the decisions taken from geometry (effects, closure)."""
