"""File formats: the mesh readers (a registry by extension, formats.load: OBJ + MTL, glTF/GLB,
PLY, STL) that scene/ builds scenes from, and the writers that stages/ hand their results to:
EXR and PNG images, CSV and Parquet tables, GLB and PLY meshes and the HTML viewer. Each takes
plain arrays and explicit values (no configuration) and writes whole files (formats.files)."""
