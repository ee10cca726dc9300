"""Where a family's shapes come from: a built-in procedural model, a folder of samples, a user's
generator file (:mod:`.files`) or a Blender file's Geometry Nodes modifier (:mod:`.blender`)."""
