"""The one rule for results too poor to use (``nerfedit_plugin.quality``): the bounds, and the warning an edit or a
training run gives when it crosses them."""

import json

import numpy as np

from nerfedit_plugin.cli.app import main
from nerfedit_plugin.quality import (
    MAX_CROSSING_FACES,
    MAX_FOLDED_FACES,
    MAX_INVERTED_TETS,
    MIN_HELD_OUT_PSNR,
    edit_warnings,
    training_warnings,
)


def report(inverted, folded, tets=1000, faces=2000, crossing=None):
    crossing = crossing or [None] * len(inverted)
    frames = [
        {"inverted_tets": i, "flipped_surface_faces": f, "crossing_surface_faces": c, "residual_max": 4e-3}
        for i, f, c in zip(inverted, folded, crossing)
    ]
    return {"proxy": {"tets": tets}, "surface": {"faces": faces}, "per_frame": frames}


def test_edit_bounds_are_fractions_of_the_proxy_and_the_surface():
    at_bound = report([int(MAX_INVERTED_TETS * 1000)], [int(MAX_FOLDED_FACES * 2000)])
    assert edit_warnings(at_bound) == []
    (tets,) = edit_warnings(report([0, 11, 3], [0, 0, 0]))
    assert tets.startswith("frame 1: 11 of 1000 inverted tets") and "more than 1%" in tets
    (faces,) = edit_warnings(report([0], [21]))
    assert faces.startswith("frame 0: 21 of 2000 folded surface faces") and "more than 1%" in faces
    assert len(edit_warnings(report([50], [50]))) == 2


def test_any_crossing_face_warns():
    """Crossing faces are counted only where the lift misses its target (None elsewhere): any count explains it."""
    assert edit_warnings(report([0, 0], [0, 0], crossing=[None, MAX_CROSSING_FACES])) == []
    (message,) = edit_warnings(report([0, 0, 0], [0, 0, 0], crossing=[None, 3, 1]))
    assert message.startswith("frame 1: 3 of 2000 surface faces pass through others") and "4.0e-03 × bbox" in message


def test_training_bound_is_the_last_held_out_psnr():
    assert training_warnings({}) == []  # nothing held out, nothing to judge
    assert training_warnings({"eval": [(1.0, 12.0), (9.0, MIN_HELD_OUT_PSNR)], "steps": 40}) == []
    (message,) = training_warnings({"eval": [(1.0, 25.0), (9.0, 14.04)], "steps": 6})
    assert message.startswith("held-out PSNR 14.0 dB after 6 steps is below 20 dB") and "max-steps" in message


def test_a_folding_edit_warns_once_and_records_it(capsule, tmp_path, monkeypatch, capsys):
    """The top half of the capsule mirrored through z = 0 (given as the deformed mesh): its faces fold, and they lie
    on the bottom half's (the surface passes through itself). The inversion-free lift on the proxy as built
    (``--lift-options.refine-rounds 0``) keeps every tet positive and so, on most proxies pytetwild builds, misses
    that surface: the warnings are the folded and the crossing faces. The soft-ARAP lift alone
    (``--lift-options.no-injective``) follows it by inverting tets: the warnings are the inverted tets, the folded
    faces and, where its refined lift still misses the target, the crossing faces. (A lift may fit it within the
    target by flattening tets to slivers: then the crossing faces are not looked for.) The edit is written either
    way, and report.json holds the same messages."""
    monkeypatch.setenv("NERFEDIT_CACHE", str(tmp_path / "cache"))
    capsule.save(tmp_path / "rest.ply")
    mirrored = capsule.vertices.copy()
    top = mirrored[:, 2] > 0
    mirrored[top, 2] *= -1
    capsule.with_vertices(mirrored).save(tmp_path / "folded.ply")
    (tmp_path / "edit.json").write_text(json.dumps({"deformed": "folded.ply"}))
    argv = ["edit", "--mesh", str(tmp_path / "rest.ply"), "--deformer", "mesh", "--edit", str(tmp_path / "edit.json")]
    for name, options in (
        ("inversion-free", ["--lift-options.refine-rounds", "0"]),
        ("arap", ["--lift-options.no-injective"]),
    ):
        assert main([*argv, "--out", str(tmp_path / name), *options]) == 0
        err = capsys.readouterr().err.splitlines()
        written = json.loads((tmp_path / name / "report.json").read_text())
        frame = written["per_frame"][0]
        missed = frame["residual_max"] > 2e-3  # usually, not always: the proxy's tets are built in parallel
        words = ["inverted"] * (name == "arap") + ["fold"] + ["pass through"] * missed
        assert written["warnings"] == edit_warnings(written) and len(written["warnings"]) == len(words)
        assert err == [f"warning: {message}" for message in written["warnings"]]
        assert all(word in message for word, message in zip(words, written["warnings"]))
        assert frame["flipped_surface_faces"] >= np.count_nonzero(top) // 2
        if missed:  # the crossing faces are counted
            assert frame["crossing_surface_faces"] > 0
        else:  # within the target: not looked for
            assert frame["crossing_surface_faces"] is None
        assert (frame["inverted_tets"] > 0) == (name == "arap")


def test_a_field_trained_for_a_few_steps_warns(tiny_scene, tmp_path, capsys):
    options = ["--field-options.train.max-steps", "2", "--field-options.train.no-progress"]
    assert main(["train", "--data", str(tiny_scene), "--out", str(tmp_path / "run"), *options]) == 0
    (line,) = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert "held-out PSNR" in line and "after 2 steps is below 20 dB" in line
