"""Open3D viewer: the geometry layers of an edit, in a window or as a headless screenshot."""
