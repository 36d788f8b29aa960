"""Geometry: surface meshes, surface and volumetric ARAP, tet-mesh utilities, Open3D ray casting."""
