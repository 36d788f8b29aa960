"""Every command finds the folders the others write: generate → train (the exact mesh field) → extract → edit --run
→ view / render → eval, and ``--load-config`` of each recording command re-runs it from its output folder."""

import json

import numpy as np
import pytest
import skimage.io
import trimesh

from nerfedit_plugin.cli.app import main
from nerfedit_plugin.data.synthetic import colorize
from nerfedit_plugin.pipeline.edit import EditFolder
from nerfedit_plugin.pipeline.run import open_run

EDIT = {
    "handles": [
        {"select": {"box": {"min": [-1, -1, -1], "max": [1, 1, -0.25]}}, "fixed": True},
        {"select": {"box": {"min": [-1, -1, 0.25], "max": [1, 1, 1]}}, "transform": {"translate": [0.15, 0, 0]}},
    ]
}


def run(*argv):
    assert main([str(a) for a in argv]) == 0, argv


@pytest.fixture(scope="module")
def flow(capsule, proxy_cache, tmp_path_factory):
    """A small generated dataset of the vertex-coloured capsule (long along z, the up axis of the generator's world),
    its mesh-field run, an edit of the run and a render of the run."""
    root = tmp_path_factory.mktemp("flow")
    colorize(capsule).save(root / "capsule.ply")
    (root / "edit.json").write_text(json.dumps(EDIT))
    run("generate", "--mesh", root / "capsule.ply", "--resolution", 32, "--n-train", 6, "--n-val", 1, "--n-test", 2,
        "--supersample", 1, "--up-axis", "z", "--out", root / "data")  # fmt: skip
    run("train", "--field", "mesh", "--data", root / "data" / "mesh.ply", "--out", root / "run")
    run("edit", "--run", root / "run", "--edit", root / "edit.json", "--out", root / "edit", "--cache-dir", proxy_cache)
    run("render", "--run", root / "run", "--cameras", root / "data", "--out", root / "renders")
    return root


def test_edit_run_maps_a_source_frame_spec_by_the_generators_transform(flow, proxy_cache):
    """The capsule (z in [−1, 1]) was normalised by ½ into the run's world: the edit of the fixture given in the
    capsule's own coordinates (``frame: source``: boxes and translation doubled) is the same edit."""
    source = {
        "frame": "source",
        "handles": [
            {"select": {"box": {"min": [-2, -2, -2], "max": [2, 2, -0.5]}}, "fixed": True},
            {"select": {"box": {"min": [-2, -2, 0.5], "max": [2, 2, 2]}}, "transform": {"translate": [0.3, 0, 0]}},
        ],
    }
    (flow / "source.json").write_text(json.dumps(source))
    out = flow / "edit-source"
    run("edit", "--run", flow / "run", "--edit", flow / "source.json", "--out", out, "--cache-dir", proxy_cache)
    deformed = [trimesh.load(folder / "deformed_mesh.ply", process=False).vertices for folder in (out, flow / "edit")]
    np.testing.assert_allclose(deformed[0], deformed[1], atol=1e-9)


def pngs(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.glob("*.png"))}


def test_train_then_extract_finds_the_run_and_keeps_the_mesh_fields_own_mesh(flow, capsys):
    before = (flow / "run" / "mesh.ply").read_bytes()
    run("extract", "--run", flow / "run")
    assert "own mesh" in capsys.readouterr().out.replace("\n", " ")
    assert (flow / "run" / "mesh.ply").read_bytes() == before


def test_view_of_an_edit_made_with_run_takes_the_runs_mesh_and_up(flow, tmp_path):
    edit = EditFolder.open(flow / "edit")
    assert (edit.mesh, edit.run) == (None, flow / "run")
    assert open_run(flow / "run").up() == (0.0, 0.0, 1.0)  # generated data: z-up
    extents = {}
    for name, up in (("auto", []), ("y", ["--up", 0, 1, 0])):
        shot = tmp_path / f"{name}.png"
        run("view", "--edit", flow / "edit", "--screenshot", shot, "--width", 160, "--height", 100, *up)
        image = skimage.io.imread(shot)[..., :3].astype(float)
        drawn = np.argwhere(np.abs(image - image[0, 0]).sum(-1) > 30)
        assert len(drawn) > 50
        extents[name] = np.ptp(drawn, axis=0)  # rows, columns
    rows, cols = extents["auto"]
    assert rows > cols / 2 and rows > 1.5 * extents["y"][0]  # upright (z up), not seen end-on as with y up


def test_render_of_the_run_is_scored_by_eval_against_the_dataset(flow, capsys):
    assert (flow / "renders" / "config.yml").is_file()  # next to the PNGs, ignored by eval
    for gt in (flow / "data" / "test", flow / "data"):  # the test images, or the dataset (its test split)
        run("eval", "--pred", flow / "renders", "--gt", gt, "--json-out", flow / "scores.json")
        mean = json.loads((flow / "scores.json").read_text())["mean"]  # exact field, same cameras: PSNR > 25 or inf
        assert (mean["psnr"] is None or mean["psnr"] > 25) and mean["ssim"] > 0.99
    capsys.readouterr()
    run("eval", "--pred", flow / "renders", "--gt", flow / "renders", "--json-out", flow / "same.json")
    assert "inf" in capsys.readouterr().out  # identical images: an infinite PSNR in the table, null in strict JSON

    def strict(constant):
        raise ValueError(f"not JSON: {constant}")

    scores = json.loads((flow / "same.json").read_text(), parse_constant=strict)
    assert scores["mean"]["psnr"] is None and scores["mean"]["ssim"] == 1.0


def test_render_of_the_edit_and_eval_of_an_animated_render(flow, capsys):
    one = json.loads((flow / "data" / "transforms_test.json").read_text())
    one.update(w=16, h=16, frames=one["frames"][:1])  # bent rays are slow: one small view
    (flow / "one.json").write_text(json.dumps(one))
    run("render", "--run", flow / "run", "--cameras", flow / "one.json", "--out", flow / "edited",
        "--deformation", flow / "edit" / "deformation.npz")  # fmt: skip
    assert list(pngs(flow / "edited")) == ["r_0.png"]
    (flow / "animated" / "frame_0000").mkdir(parents=True)
    assert main(["eval", "--pred", str(flow / "animated"), "--gt", str(flow / "data")]) == 2
    assert "an animated render; compare one frame" in capsys.readouterr().err


def test_load_config_of_each_recording_command_reruns_it(flow, tmp_path, proxy_cache):
    run("generate", "--load-config", flow / "data", "--out", tmp_path / "data")
    files = sorted(p.relative_to(flow / "data") for p in (flow / "data").rglob("*") if p.name != "config.yml")
    assert all(
        (tmp_path / "data" / f).read_bytes() == (flow / "data" / f).read_bytes() for f in files if f.suffix == ".png"
    )
    run("train", "--load-config", flow / "run", "--out", tmp_path / "run")
    assert open_run(tmp_path / "run").mesh().n_vertices == open_run(flow / "run").mesh().n_vertices
    run("edit", "--load-config", flow / "edit", "--out", tmp_path / "edit")
    assert (EditFolder.open(tmp_path / "edit").mesh, EditFolder.open(tmp_path / "edit").run) == (None, flow / "run")
    run("render", "--load-config", flow / "renders" / "config.yml", "--out", tmp_path / "renders")
    assert pngs(tmp_path / "renders") == pngs(flow / "renders")


def test_files_with_bad_values_name_the_file_and_what_is_wrong(flow, tmp_path, capsys):
    mesh = open_run(flow / "run").mesh()
    vertices = mesh.vertices.copy()
    vertices[5] = np.nan
    trimesh.Trimesh(vertices, mesh.faces, process=False).export(tmp_path / "nan.ply")  # SurfaceMesh refuses NaN
    assert main(["view", "--mesh", str(tmp_path / "nan.ply"), "--screenshot", str(tmp_path / "v.png")]) == 2
    err = capsys.readouterr().err
    assert "nan.ply: mesh vertices: vertex 5 is [nan, nan, nan]" in err and err.count("\n") == 1
    (tmp_path / "pred").mkdir()
    (tmp_path / "pred" / "r_0.png").write_text("not an image")
    (tmp_path / "pred" / "r_1.png").write_text("not an image")
    assert main(["eval", "--pred", str(tmp_path / "pred"), "--gt", str(flow / "renders")]) == 2
    err = capsys.readouterr().err
    assert "r_0.png: not a readable image (unknown format or corrupt data)" in err
    assert "pip" not in err and "`" not in err and err.count("\n") == 1
