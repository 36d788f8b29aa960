"""The ``cage`` deformer: a closed cage around the mesh, moved by the user; mean value (default) or Green
coordinates carry the cage's motion to the mesh and to any point inside it."""

from deformers.cage.deformer import CageConfig, CageDeformer, auto_cage, enclosure, validate_cage

__all__ = ["CageConfig", "CageDeformer", "auto_cage", "enclosure", "validate_cage"]
