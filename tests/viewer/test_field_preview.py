"""The editor's render panel (:class:`~nerfedit_plugin.viewer.field_preview.FieldPreview`) on a splat run made from a
file and given its mesh by ``nerfedit extract``: the unedited panel is the field's render from the view, the rest
surface lifts to the identity (the same image), and an edit renders as the field moved by the lifted proxy."""

import numpy as np
import torch
import trimesh

from nerfedit_plugin.cli import main
from nerfedit_plugin.data.cameras import look_at
from nerfedit_plugin.fields.splats.files import write_ply
from nerfedit_plugin.fields.splats.model import surface_model
from nerfedit_plugin.pipeline.run import open_run
from nerfedit_plugin.render.renderer import render_image
from nerfedit_plugin.viewer.field_preview import FieldPreview, view_cameras
from nerfedit_plugin.viewer.picking import View


def test_the_render_panel_renders_a_splat_run_and_its_edit(tmp_path):
    ellipsoid = trimesh.creation.icosphere(subdivisions=3)
    ellipsoid.vertices *= [1.0, 0.6, 0.5]
    write_ply(surface_model(ellipsoid, 4000, seed=2, radius=0.06), tmp_path / "model.ply")
    run_dir = tmp_path / "run"
    assert main(["train", "--field", "splats", "--data", str(tmp_path / "model.ply"), "--out", str(run_dir)]) == 0
    assert main(["extract", "--run", str(run_dir), "--resolution", "32"]) == 0
    run = open_run(run_dir)
    rest = run.mesh()
    preview = FieldPreview(run, rest, width=48, cache_dir=tmp_path / "cache")
    c2w = look_at(torch.tensor([2.4, 0.6, 0.9]), torch.zeros(3)).double().numpy()
    projection = np.array([[1.4, 0, 0, 0], [0, 1.4, 0, 0], [0, 0, -1.0, -0.2], [0, 0, -1.0, 0]])
    view = View(np.linalg.inv(c2w), projection, 300, 300)

    unedited = preview.unedited(view)
    field = run.field("cpu")
    expected = render_image(field, view_cameras(view, 48), 0, preview.config).numpy()
    assert np.array_equal(unedited, expected)
    assert np.abs(preview.edited(view, rest.vertices) - unedited).max() < 1e-4  # the rest surface: no motion

    moved = rest.vertices.copy()
    moved[rest.vertices[:, 0] > 0.3, 2] += 0.25
    edited = preview.edited(view, moved)
    again = render_image(field, view_cameras(view, 48), 0, preview.config, deformation=preview.last).numpy()
    assert np.array_equal(edited, again)
    assert np.abs(edited - unedited).mean() > 0.005
