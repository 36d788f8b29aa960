"""The built-in deformers' progress reports (``Deformer.on_progress``): what a long bind or deform tells, counting
up to its total; a deformer nobody listens to works as before."""

import json

import numpy as np

from deformers.arap import ArapConfig
from deformers.cage import CageConfig
from deformers.skeleton import SkeletonConfig
from nerfedit_plugin.edit.spec import parse_edit_spec

CHAIN = {
    "joints": [
        {"name": "lower", "parent": None, "head": [0, 0, -0.8]},
        {"name": "upper", "parent": "lower", "head": [0, 0, 0], "tail": [0, 0, 0.8]},
    ]
}
TOP = {"box": {"min": [-2, -2, 0.5], "max": [2, 2, 2]}}
BOTTOM = {"box": {"min": [-2, -2, -2], "max": [2, 2, -0.5]}}


def bound(config, rest, edit: dict, base_dir="."):
    """``config``'s deformer with a recording ``on_progress``, bound to ``rest`` → (deformer, reports)."""
    deformer, heard = config.setup(), []
    deformer.on_progress = lambda done, total=None, detail="": heard.append((done, total, detail))
    deformer.bind(rest, parse_edit_spec(edit, deformer.spec_keys, "edit.json", base_dir))
    return deformer, heard


def test_cage_bind_counts_vertex_blocks(capsule):
    edit = {
        "cage": "auto",
        "handles": [{"select": BOTTOM, "fixed": True}, {"select": TOP, "transform": {"translate": [0.2, 0, 0]}}],
    }
    cage, heard = bound(CageConfig(bind_block=100), capsule, edit)
    assert heard[0] == (0, None, "automatic cage")
    blocks = [(done, total) for done, total, _ in heard if total is not None]
    assert blocks == [(0, 3), (1, 3), (2, 3), (3, 3)]  # 290 vertices in blocks of 100
    heard.clear()
    cage.deform()  # the poses of the bind: posed then, nothing to tell
    assert heard == []


def test_cage_deform_that_evaluates_again_counts_its_blocks(capsule):
    edit = {"cage": "auto", "handles": [{"select": TOP, "transform": {"translate": [0.2, 0, 0]}}]}
    cage, heard = bound(CageConfig(bind_block=200, weights_budget_mb=0.0), capsule, edit)
    heard.clear()
    cage.deformed_cages = cage.deformed_cages * 1.1  # coordinates not kept: evaluated again, block by block
    cage.deform()
    assert [(done, total) for done, total, _ in heard] == [(0, 2), (1, 2), (2, 2)]


def test_skeleton_tells_the_bone_heat_steps_and_counts_frames(capsule, tmp_path):
    (tmp_path / "chain.json").write_text(json.dumps(CHAIN))
    edit = {"skeleton": "chain.json", "pose": {"upper": {"rotate": {"axis": [1, 0, 0], "degrees": 30}}}, "frames": 3}
    skeleton, heard = bound(SkeletonConfig(), capsule, edit, tmp_path)
    assert [d for _, total, d in heard if total is None] == [
        "bone-heat weights: visibility",
        "bone-heat weights: factorising",
        "bone-heat weights: solving for 2 bones",
    ]
    heard.clear()
    skeleton.deform()
    assert heard == [(f, 3, "skinning (dqs)") for f in range(4)]


def test_arap_counts_iterations_and_deforms_as_without_a_listener(capsule):
    edit = {"handles": [{"select": BOTTOM, "fixed": True}, {"select": TOP, "transform": {"translate": [0.3, 0, 0]}}]}
    arap, heard = bound(ArapConfig(max_iterations=50), capsule, edit)
    told = arap.deform()
    assert heard[0] == (0, None, "factorising") and heard[-1][:2] == (50, 50)
    done = [d for d, total, _ in heard if total is not None]
    assert done == sorted(done) and len(done) == arap.results[0].iterations + 2  # iterations 0…k, then the end
    quiet = ArapConfig(max_iterations=50).setup()
    quiet.bind(capsule, parse_edit_spec(edit, quiet.spec_keys, "edit.json", "."))
    assert np.array_equal(quiet.deform(), told)
