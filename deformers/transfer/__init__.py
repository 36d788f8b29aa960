"""The ``transfer`` deformer: deformation transfer (Sumner & Popović 2004) of a source mesh's pose sequence onto the
rest mesh, through a triangle correspondence (identity for the same connectivity, else fitted from markers)."""

from deformers.transfer.correspondence import Correspondence, correspondence, fit_source, match_triangles
from deformers.transfer.deformer import TransferConfig, TransferDeformer
from deformers.transfer.gradients import TransferSystem, gradient_operator

__all__ = [
    "Correspondence",
    "TransferConfig",
    "TransferDeformer",
    "TransferSystem",
    "correspondence",
    "fit_source",
    "gradient_operator",
    "match_triangles",
]
