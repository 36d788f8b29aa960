"""The editor's "render" action: lift a surface edit into the run's tet proxy and render the field from the editor's
view, unedited and edited, at preview resolution.

The proxy comes from the proxy cache (built once per mesh, as ``nerfedit edit`` builds it) and the ``tet-arap`` lift
is bound to it once (its factorisation); each render lifts the current surface and renders through the bent rays.
The preview lift skips refinement (``refine_rounds=0``): what ``nerfedit edit`` writes may refine the proxy where the
lift misses the surface, so a final render can differ slightly where the proxy is coarse.
"""

from __future__ import annotations

import os

import numpy as np
import torch

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.data.cameras import Cameras
from nerfedit_plugin.edit.lift import Lift, LiftConfig
from nerfedit_plugin.edit.proxy import ProxyConfig, cached_proxy
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.pipeline.edit import default_cache_dir
from nerfedit_plugin.pipeline.run import Run
from nerfedit_plugin.render.renderer import render_image
from nerfedit_plugin.render.views import default_render_config
from nerfedit_plugin.viewer.picking import View


def view_cameras(view: View, width: int) -> Cameras:
    """The pinhole camera of ``view`` at ``width`` pixels (height by the view's aspect ratio), for the renderer."""
    height = max(1, round(width * view.height / view.width))
    projection = np.asarray(view.projection, dtype=np.float64)
    fx, fy = 0.5 * width * projection[0, 0], 0.5 * height * projection[1, 1]
    c2w = torch.as_tensor(view.camera_to_world[None], dtype=torch.float32)
    return Cameras(c2w, fx, fy, width / 2.0, height / 2.0, width, height)


class FieldPreview:
    """Renders ``run``'s field beside its edit through ``rest`` (the run's mesh); ``width`` pixels wide."""

    def __init__(self, run: Run, rest: SurfaceMesh, *, width: int = 128, cache_dir: str | os.PathLike | None = None):
        self.run, self.rest, self.width = run, rest, width
        self.cache_dir = cache_dir or default_cache_dir()
        self.field = run.field("cpu")
        self.config = default_render_config(self.field)
        self._lift: Lift | None = None
        self._unedited: tuple[bytes, np.ndarray] | None = None
        self.last: DeformationField | None = None
        """The deformation of the last edited render (its proxy layers)."""

    def deformation(self, deformed: np.ndarray) -> DeformationField:
        """The surface ``deformed (V,3)`` lifted into the proxy (built or read from the cache on first use)."""
        if self._lift is None:
            proxy, _ = cached_proxy(self.rest, ProxyConfig(), self.cache_dir, self.run.camera_distance())
            self._lift = Lift(proxy, self.rest, "tet-arap", LiftConfig(refine_rounds=0))
        lifted, _ = self._lift(np.asarray(deformed, dtype=np.float64)[None])
        return DeformationField(self._lift.proxy.vertices, self._lift.proxy.tets, lifted)

    def unedited(self, view: View) -> np.ndarray:
        """(H,W,3) float32 in [0,1]: the field from ``view`` (kept while the view stays)."""
        key = np.asarray(view.view, dtype=np.float64).tobytes() + np.asarray(view.projection).tobytes()
        if self._unedited is None or self._unedited[0] != key:
            self._unedited = (key, self._render(view, None))
        return self._unedited[1]

    def edited(self, view: View, deformed: np.ndarray) -> np.ndarray:
        """(H,W,3) float32 in [0,1]: the field bent by the surface edit ``deformed (V,3)``, from ``view``."""
        self.last = self.deformation(deformed)
        return self._render(view, self.last)

    def _render(self, view: View, deformation: DeformationField | None) -> np.ndarray:
        with torch.no_grad():
            image = render_image(self.field, view_cameras(view, self.width), 0, self.config, deformation=deformation)
        return image.float().cpu().numpy()
