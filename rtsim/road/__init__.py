"""Roads: plane, constant grade, and triangle meshes built from survey points; tyre contact queries."""
