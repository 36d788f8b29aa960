"""Lifts: rigid edits give rigid proxies, A t' = v' holds for tet-arap, baselines and ablations behave as defined."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nerfedit_plugin.edit.lift import Lift
from nerfedit_plugin.edit.spec import parse_edit_spec
from nerfedit_plugin.geometry.tets import tet_signed_volumes

ROT = Rotation.from_rotvec([0.3, -0.5, 0.8]).as_matrix()
SHIFT = np.array([0.2, -0.1, 0.4])


def bend(points: np.ndarray, amount: float = 0.6) -> np.ndarray:
    """A smooth non-rigid map: rotate about x by an angle growing with z (a bend of the capsule)."""
    angle = amount * np.clip(points[:, 2], 0, None)
    out = points.copy()
    out[:, 1] = points[:, 1] * np.cos(angle) - points[:, 2] * np.sin(angle)
    out[:, 2] = points[:, 1] * np.sin(angle) + points[:, 2] * np.cos(angle)
    return out


@pytest.mark.parametrize("method", ["tet-arap", "knn3", "closest-point"])
def test_identity_edit_is_identity(capsule, capsule_proxy, method):
    lifted, reports = Lift(capsule_proxy, capsule, method)(capsule.vertices[None])
    assert np.allclose(lifted[0], capsule_proxy.vertices, atol=1e-9 * capsule.bbox_diagonal)
    assert reports[0].residual_max < 1e-9 and reports[0].inverted_tets == 0


def test_rigid_edit_gives_rigid_proxy(capsule, capsule_proxy):
    moved = capsule.vertices @ ROT.T + SHIFT
    lifted, reports = Lift(capsule_proxy, capsule, "tet-arap")(moved[None])
    expected = capsule_proxy.vertices @ ROT.T + SHIFT
    assert np.abs(lifted[0] - expected).max() < 1e-4 * capsule.bbox_diagonal
    assert reports[0].residual_max < 1e-5 and reports[0].inverted_tets == 0


@pytest.mark.parametrize("method", ["knn3", "closest-point"])
def test_baselines_reproduce_translations(capsule, capsule_proxy, method):
    lifted, _ = Lift(capsule_proxy, capsule, method)((capsule.vertices + SHIFT)[None])
    assert np.allclose(lifted[0], capsule_proxy.vertices + SHIFT)


def test_tet_arap_fits_constraints_better_than_baselines(capsule, capsule_proxy):
    frames = np.stack([bend(capsule.vertices, a) for a in (0.3, 0.6)])
    lifted, reports = Lift(capsule_proxy, capsule, "tet-arap")(frames)
    assert lifted.shape == (2, len(capsule_proxy.vertices), 3)
    for report in reports:
        assert report.residual_max < 2e-3 and report.inverted_tets == 0 and report.degenerate_tets == 0
    _, knn = Lift(capsule_proxy, capsule, "knn3")(frames)
    assert reports[1].residual_rms < 0.5 * knn[1].residual_rms
    # every deformed tet keeps its orientation
    assert (tet_signed_volumes(lifted[1], capsule_proxy.tets) > 0).all()


def test_tet_edit_applies_handles_to_the_proxy(capsule, capsule_proxy):
    spec = parse_edit_spec(
        {
            "handles": [
                {"select": {"box": {"min": [-1, -1, -2], "max": [1, 1, -0.5]}}, "fixed": True},
                {"select": {"box": {"min": [-1, -1, 0.5], "max": [1, 1, 2]}}, "transform": {"translate": [0, 0.3, 0]}},
            ]
        }
    )
    lifted, reports = Lift(capsule_proxy, capsule, "tet-edit", edit=spec)(capsule.vertices[None])
    idx, targets = spec.handle_targets(capsule_proxy.vertices)
    assert np.allclose(lifted[0, idx], targets[0])
    assert reports[0].inverted_tets == 0


def test_direct_lift_evaluates_the_space_map(capsule, capsule_proxy):
    from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig
    from nerfedit_plugin.errors import NerfEditError

    class Surface(Deformer):
        def bind(self, rest, edit):
            self.rest = rest

        def deform(self):
            return bend(self.rest.vertices)[None]

    class Bend(Surface):
        def deform_points(self, points, frame):
            return bend(points)

    lifted, _ = Lift(capsule_proxy, capsule, "direct", deformer=Bend(DeformerConfig()))(bend(capsule.vertices)[None])
    assert np.allclose(lifted[0], bend(capsule_proxy.vertices))
    with pytest.raises(NerfEditError, match="has no deform_points"):
        Lift(capsule_proxy, capsule, "direct", deformer=Surface(DeformerConfig()))
