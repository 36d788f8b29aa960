"""The spec copy in an edit folder is a spec that runs: the files a deformer read (a file, a list, a glob) are named
by absolute paths in it, so ``nerfedit edit --edit EDIT/spec`` reproduces the edit from any folder."""

import glob
import json
import os

import numpy as np
import yaml

from deformers.mesh import MeshConfig
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.pipeline.edit import run_edit


def test_a_copied_spec_names_the_deformer_files_absolute_and_reruns(capsule, tmp_path, proxy_cache, monkeypatch):
    spec_dir = tmp_path / "spec"
    (spec_dir / "poses").mkdir(parents=True)
    for i in range(2):
        capsule.with_vertices(capsule.vertices + [0.0, 0.0, 0.01 * (i + 1)]).save(spec_dir / "poses" / f"p{i}.ply")
    monkeypatch.chdir(tmp_path)  # the spec named relative to the working folder, as on a command line
    listed = [str(spec_dir / "poses" / f"p{i}.ply") for i in range(2)]
    specs = {
        "glob.json": ({"deformed": "poses/*.ply"}, [os.path.join(tmp_path, "spec", "poses/*.ply")]),
        "list.yaml": ({"deformed": ["poses/p0.ply", "poses/p1.ply"]}, listed),
    }
    for name, (spec, absolute) in specs.items():
        path = spec_dir / name
        path.write_text(json.dumps(spec) if name.endswith(".json") else yaml.safe_dump(spec))
        first = run_edit(capsule, MeshConfig(), os.path.relpath(path), tmp_path / name, lift="knn3",
                         cache_dir=proxy_cache)  # fmt: skip
        written = yaml.safe_load((first.out / name).read_text())
        assert (written["deformed"] if isinstance(written["deformed"], list) else [written["deformed"]]) == absolute
        monkeypatch.chdir(first.out)  # elsewhere: the copy still finds its files
        again = run_edit(capsule, MeshConfig(), name, tmp_path / f"again-{name}", lift="knn3", cache_dir=proxy_cache)
        monkeypatch.chdir(tmp_path)
        for mesh in ("deformed_mesh_0000.ply", "deformed_mesh_0001.ply"):
            np.testing.assert_array_equal(
                SurfaceMesh.load(again.out / mesh).vertices, SurfaceMesh.load(first.out / mesh).vertices
            )


def test_a_scene_spec_copy_names_its_objects_edit_files_absolute(tmp_path):
    """In a scene spec, the deformer keys of every object's and copy's ``edit`` that name files are rewritten; a value
    naming no file (another object's ``"auto"``), absolute names and keys no deformer read are kept. A folder with
    glob characters is escaped where the name is globbed."""
    from nerfedit_plugin.edit.spec import copy_spec_file

    folder = tmp_path / "scan[1]"
    (folder / "poses").mkdir(parents=True)
    for name in ("a.ply", "poses/p0.ply"):
        (folder / name).write_bytes(b"")
    edits = [{"cage": "a.ply", "note": "a.ply"}, {"cage": "auto"}, {"deformed": "poses/*.ply"}]
    copies = [{"edit": {"cage": "/b.ply"}}]
    objects = [{"name": f"o{i}", "select": {"box": {}}, "edit": e} for i, e in enumerate(edits)]
    objects[0]["copies"] = copies
    (folder / "scene.json").write_text(json.dumps({"objects": objects}))
    (tmp_path / "out").mkdir()
    copy_spec_file(folder / "scene.json", tmp_path / "out", {"cage": "path", "deformed": "paths"})
    written = [o["edit"] for o in json.loads((tmp_path / "out" / "scene.json").read_text())["objects"]]
    assert written[0] == {"cage": str(folder / "a.ply"), "note": "a.ply"} and written[1] == {"cage": "auto"}
    assert written[2] == {"deformed": os.path.join(glob.escape(str(folder)), "poses/*.ply")}
    assert glob.glob(written[2]["deformed"]) == [str(folder / "poses" / "p0.ply")]
    copied = json.loads((tmp_path / "out" / "scene.json").read_text())["objects"][0]["copies"][0]["edit"]
    assert copied == {"cage": "/b.ply"}
    from nerfedit_plugin.edit.spec import load_edit_spec

    (folder / "glob.json").write_text(json.dumps({"deformed": "poses/*.ply"}))  # the folder's "[1]" is no pattern
    assert load_edit_spec(folder / "glob.json", ("deformed",)).paths("deformed") == [folder / "poses" / "p0.ply"]
