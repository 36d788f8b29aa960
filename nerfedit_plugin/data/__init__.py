"""Data: cameras (OpenGL convention), Blender/nerfstudio datasets, the synthetic scene generator."""
