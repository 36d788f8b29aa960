"""The ``splats`` field backend: 3D Gaussian splats (files, projection, the CPU rasteriser, the field)."""
