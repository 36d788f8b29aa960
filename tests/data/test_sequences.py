"""Synthetic mesh sequences: shared connectivity, rest pose first, the motion each generator promises, and the
sequence folder writer (npz or PLY frames, atomic)."""

import numpy as np
import pytest

from nerfedit_plugin.data.sequences import bending_capsule, capsule, twisting_bar, write_sequence
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh


@pytest.mark.parametrize("make", [bending_capsule, twisting_bar])
def test_frames_start_at_rest_and_are_deterministic(make):
    rest, frames = make(n_frames=5)
    assert frames.shape == (5, rest.n_vertices, 3) and frames.dtype == np.float64
    np.testing.assert_array_equal(frames[0], rest.vertices)
    again_rest, again = make(n_frames=5)
    np.testing.assert_array_equal(again, frames)
    np.testing.assert_array_equal(again_rest.faces, rest.faces)
    assert rest.to_trimesh().is_watertight


def test_bending_capsule_turns_its_top_and_keeps_its_bottom():
    rest, frames = bending_capsule(n_frames=3, degrees=90.0)
    bottom, top = rest.vertices[:, 2] < -0.2, rest.vertices[:, 2] > 0.2
    np.testing.assert_array_equal(frames[-1][bottom], rest.vertices[bottom])
    turned = rest.vertices[top] @ np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]).T  # 90° about x
    np.testing.assert_allclose(frames[-1][top], turned, atol=1e-12)


def test_twisting_bar_preserves_height_and_distance_to_the_axis():
    rest, frames = twisting_bar(n_frames=2, degrees=180.0)
    np.testing.assert_array_equal(frames[-1][:, 2], rest.vertices[:, 2])
    radius = np.linalg.norm(rest.vertices[:, :2], axis=1)
    np.testing.assert_allclose(np.linalg.norm(frames[-1][:, :2], axis=1), radius, atol=1e-12)
    top = rest.vertices[:, 2] == rest.vertices[:, 2].max()
    np.testing.assert_allclose(frames[-1][top, :2], -rest.vertices[top, :2], atol=1e-12)  # half a turn at the top


@pytest.mark.parametrize("format", ["npz", "ply"])
def test_write_sequence_round_trips(tmp_path, format):
    rest, frames = bending_capsule(n_frames=3, count=(12, 6))
    written = write_sequence(tmp_path / "seq", rest, frames, format=format)
    assert [p.name for p in written][:2] == ["rest.ply", "frames.npz" if format == "npz" else "frame_0000.ply"]
    assert all(p.is_file() for p in written)
    loaded = SurfaceMesh.load(written[0])
    np.testing.assert_array_equal(loaded.faces, rest.faces)
    if format == "npz":
        back = np.load(written[1])["frames"]
    else:
        back = np.stack([SurfaceMesh.load(p).vertices for p in written[1:]])
    np.testing.assert_array_equal(back, frames)  # float64 on disk
    with pytest.raises(NerfEditError, match="output folder exists"):
        write_sequence(tmp_path / "seq", rest, frames, format=format)


def test_bad_arguments_are_errors(tmp_path):
    rest = capsule(count=(8, 4))
    with pytest.raises(NerfEditError, match=r"frames: expected shape \(F, \d+, 3\)"):
        write_sequence(tmp_path / "x", rest, np.zeros((2, 3, 3)))
    with pytest.raises(NerfEditError, match="n_frames"):
        bending_capsule(n_frames=0)
    assert not (tmp_path / "x").exists()
