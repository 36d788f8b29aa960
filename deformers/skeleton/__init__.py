"""The ``skeleton`` deformer: joints posed by a JSON pose or a BVH clip, linear-blend or dual-quaternion skinning
with automatic bone-heat weights."""

from deformers.skeleton.deformer import Skeleton, SkeletonConfig, SkeletonDeformer, closest_point_barycentrics

__all__ = ["Skeleton", "SkeletonConfig", "SkeletonDeformer", "closest_point_barycentrics"]
