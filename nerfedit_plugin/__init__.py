"""nerfedit: edit the geometry of neural radiance fields with mesh deformers (NeRF-Editing, CVPR 2022).

The public API: what users and plugin authors import. Names load lazily (PEP 562), so ``import nerfedit_plugin``
stays cheap; docs/architecture.md maps each name to its stage.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

#: public name -> module that defines it
_API = {
    # contracts and configs
    "NerfEditError": "errors",
    "InstantiateConfig": "config",
    "Deformer": "edit.deformer",
    "DeformerConfig": "edit.deformer",
    "Overlay": "edit.deformer",
    "Field": "fields.base",
    "FieldConfig": "fields.base",
    "discover": "registry",
    # geometry and data
    "SurfaceMesh": "geometry.mesh",
    "Cameras": "data.cameras",
    "Dataset": "data.datasets",
    "load_dataset": "data.datasets",
    "read_transforms": "data.datasets",
    "GenerateConfig": "data.synthetic",
    "generate_dataset": "data.synthetic",
    "generate_scene": "data.scene",
    "read_scene": "data.scene",
    "scene_mesh": "data.scene",
    # editing
    "EditSpec": "edit.spec",
    "load_edit_spec": "edit.spec",
    "parse_edit_spec": "edit.spec",
    "TetProxy": "edit.proxy",
    "ProxyConfig": "edit.proxy",
    "cached_proxy": "edit.proxy",
    "Lift": "edit.lift",
    "LiftConfig": "edit.lift",
    "run_edit": "pipeline.edit",
    "EditFolder": "pipeline.edit",
    # bending and rendering
    "BackwardMap": "bending.maps",
    "ForwardMap": "bending.maps",
    "PlacementMap": "bending.maps",
    "DeformationField": "bending.deformation_field",
    "SceneDeformation": "bending.scene_deformation",
    "load_deformation": "bending.scene_deformation",
    "RenderConfig": "render.renderer",
    "render_image": "render.renderer",
    "render_views": "render.views",
    # runs and checkpoints
    "Run": "pipeline.run",
    "open_run": "pipeline.run",
    "train_run": "pipeline.train",
    "extract_mesh": "pipeline.extract",
    "export_run": "pipeline.export",
    "save_field": "fields.checkpoint",
    "load_field": "fields.checkpoint",
    # metrics
    "evaluate_folders": "training.metrics",
    # conformance kits
    "check_deformer": "testing",
    "check_field": "testing",
    "parametrize_with_checks": "testing",
}

__all__ = sorted(_API)


def __getattr__(name: str) -> Any:
    if name in _API:
        value = getattr(importlib.import_module(f"{__name__}.{_API[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))


if TYPE_CHECKING:  # static analysers and IDEs see the eager imports
    from nerfedit_plugin.bending.deformation_field import DeformationField
    from nerfedit_plugin.bending.maps import BackwardMap, ForwardMap, PlacementMap
    from nerfedit_plugin.bending.scene_deformation import SceneDeformation, load_deformation
    from nerfedit_plugin.config import InstantiateConfig
    from nerfedit_plugin.data.cameras import Cameras
    from nerfedit_plugin.data.datasets import Dataset, load_dataset, read_transforms
    from nerfedit_plugin.data.scene import generate_scene, read_scene, scene_mesh
    from nerfedit_plugin.data.synthetic import GenerateConfig, generate_dataset
    from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig, Overlay
    from nerfedit_plugin.edit.lift import Lift, LiftConfig
    from nerfedit_plugin.edit.proxy import ProxyConfig, TetProxy, cached_proxy
    from nerfedit_plugin.edit.spec import EditSpec, load_edit_spec, parse_edit_spec
    from nerfedit_plugin.errors import NerfEditError
    from nerfedit_plugin.fields.base import Field, FieldConfig
    from nerfedit_plugin.fields.checkpoint import load_field, save_field
    from nerfedit_plugin.geometry.mesh import SurfaceMesh
    from nerfedit_plugin.pipeline.edit import EditFolder, run_edit
    from nerfedit_plugin.pipeline.export import export_run
    from nerfedit_plugin.pipeline.extract import extract_mesh
    from nerfedit_plugin.pipeline.run import Run, open_run
    from nerfedit_plugin.pipeline.train import train_run
    from nerfedit_plugin.registry import discover
    from nerfedit_plugin.render.renderer import RenderConfig, render_image
    from nerfedit_plugin.render.views import render_views
    from nerfedit_plugin.training.metrics import evaluate_folders
