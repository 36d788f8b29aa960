"""Rendering: the shared volume renderer (with optional ray bending) and writing rendered views to files."""
