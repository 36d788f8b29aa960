"""BVH parsing: hierarchy, offsets, channels and frames of a handwritten file; forward kinematics positions worked
out by hand; Euler channel order; resampling; and a line-numbered error for each kind of syntax error."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deformers.skeleton import Skeleton
from deformers.skeleton.bvh import parse_bvh
from nerfedit_plugin.errors import NerfEditError

TINY = """HIERARCHY
ROOT hips
{
  OFFSET 1 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT knee
  {
    OFFSET 0 -2 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -1 0
    }
  }
  JOINT spine
  {
    OFFSET 0 1 0
    CHANNELS 3 Xrotation Yrotation Zrotation
  }
}
MOTION
Frames: 2
Frame Time: 0.04
0 0 0 0 0 0 0 0 0 0 0 0
1 2 3 90 0 0 0 90 0 0 0 0
"""


def write(tmp_path, text, name="clip.bvh"):
    path = tmp_path / name
    path.write_text(text)
    return path


def fk_points(clip, frames=None):
    """Posed heads and tails ``(F,J,3)`` through the skeleton's forward kinematics."""
    skeleton = Skeleton.from_bvh(clip)
    rot, trans = skeleton.forward_kinematics(*clip.local_transforms(frames))
    heads = np.einsum("fjik,jk->fji", rot, skeleton.heads) + trans
    tails = np.einsum("fjik,jk->fji", rot, skeleton.tails) + trans
    return heads, tails


def test_parse_hierarchy_channels_and_motion(tmp_path):
    clip = parse_bvh(write(tmp_path, TINY))
    assert clip.names == ("hips", "knee", "spine") and clip.parents == (-1, 0, 0)
    assert np.array_equal(clip.offsets, [[1, 0, 0], [0, -2, 0], [0, 1, 0]])
    assert np.array_equal(clip.heads, [[1, 0, 0], [1, -2, 0], [1, 1, 0]])
    assert clip.channels[0] == ("xposition", "yposition", "zposition", "zrotation", "xrotation", "yrotation")
    assert clip.n_frames == 2 and clip.motion.shape == (2, 12) and clip.frame_time == 0.04
    assert np.array_equal(clip.end_sites[1], [0, -1, 0]) and np.isnan(clip.end_sites[[0, 2]]).all()


def test_forward_kinematics_positions_by_hand(tmp_path):
    clip = parse_bvh(write(tmp_path, TINY))
    skeleton = Skeleton.from_bvh(clip)
    assert np.allclose(skeleton.tails, [[1, -0.5, 0], [1, -3, 0], [1, 1, 0]])  # children mean, end site, point bone
    heads, tails = fk_points(clip)
    assert np.allclose(heads[0], skeleton.heads) and np.allclose(tails[0], skeleton.tails)  # frame 0 is the rest pose
    # frame 1: root at offset + (1,2,3) = (2,2,3), turned 90° about z; the knee bends 90° about x.
    assert np.allclose(heads[1], [[2, 2, 3], [4, 2, 3], [1, 2, 3]])
    assert np.allclose(tails[1, 1], [4, 2, 2])


def test_rotation_channels_compose_in_listed_order(tmp_path):
    text = TINY.replace("1 2 3 90 0 0 0 90 0 0 0 0", "0 0 0 30 40 50 0 0 0 10 20 70")
    rot, _ = parse_bvh(write(tmp_path, text)).local_transforms()
    r = lambda axis, deg: Rotation.from_euler(axis, deg, degrees=True).as_matrix()  # noqa: E731
    assert np.allclose(rot[1, 0], r("z", 30) @ r("x", 40) @ r("y", 50))  # Zrotation Xrotation Yrotation
    assert np.allclose(rot[1, 2], r("x", 10) @ r("y", 20) @ r("z", 70))  # Xrotation Yrotation Zrotation


def test_resampling_slerps_between_frames(tmp_path):
    clip = parse_bvh(write(tmp_path, TINY))
    rot, trans = clip.local_transforms(3)
    assert rot.shape == (3, 3, 3, 3) and trans.shape == (3, 3, 3)
    assert np.allclose(trans[1, 0], [0.5, 1.0, 1.5])
    assert np.allclose(rot[1, 0], Rotation.from_euler("z", 45, degrees=True).as_matrix())
    assert np.allclose(rot[1, 1], Rotation.from_euler("x", 45, degrees=True).as_matrix())
    full_rot, _ = clip.local_transforms()
    assert np.allclose(rot[[0, 2]], full_rot)


@pytest.mark.parametrize(
    "old, new, line, message",
    [
        ("ROOT hips\n{", "ROOT hips\n(", 3, "expected '{'"),
        (
            "Zrotation Xrotation Yrotation\n    End",
            "Zrotation Wrotation Yrotation\n    End",
            9,
            "unknown channel 'Wrotation'",
        ),
        ("OFFSET 0 -2 0", "OFFSET 0 minus2 0", 8, "expected OFFSET y"),
        ("CHANNELS 3 Zrotation", "CHANNELS 2.5 Zrotation", 9, "channel count"),
        (
            "CHANNELS 3 Xrotation Yrotation Zrotation",
            "CHANNELS 3 Xrotation Xrotation Zrotation",
            18,
            "repeated channel",
        ),
        ("    End Site", "    Finish Site", 10, "expected JOINT, End Site or '}'"),
        ("1 2 3 90 0 0 0 90 0 0 0 0", "1 2 3 90 0 0 0 90 0 0 0", 25, "expected 12 channel values, got 11"),
        ("1 2 3 90 0 0 0 90 0 0 0 0", "1 2 3 90 0 0 0 90 0 0 0 zero", 25, "non-numeric"),
        ("Frames: 2", "Frames: 3", 25, "header says 3 frames, the file has 2"),
        ("Frame Time: 0.04", "Frame Rate: 25", 23, "expected 'Frame Time:"),
        ("HIERARCHY", "HIERARCHIES", 1, "expected 'HIERARCHY'"),
    ],
)
def test_syntax_errors_name_file_and_line(tmp_path, old, new, line, message):
    assert old in TINY
    path = write(tmp_path, TINY.replace(old, new, 1))
    with pytest.raises(NerfEditError) as err:
        parse_bvh(path)
    assert str(err.value).startswith(f"{path}:{line}: ") and message in str(err.value), str(err.value)


def test_truncated_and_sectionless_files(tmp_path):
    with pytest.raises(NerfEditError, match="no MOTION section"):
        parse_bvh(write(tmp_path, TINY.split("MOTION")[0]))
    cut = TINY.replace("  }\n}\nMOTION", "MOTION")
    with pytest.raises(NerfEditError, match=r"clip.bvh:\d+: unexpected end of file"):
        parse_bvh(write(tmp_path, cut))
    with pytest.raises(NerfEditError, match="no ROOT joint"):
        parse_bvh(write(tmp_path, "HIERARCHY\nMOTION\nFrames: 0\nFrame Time: 0.1\n"))


def test_duplicate_joint_names_are_rejected(tmp_path):
    clip = parse_bvh(write(tmp_path, TINY.replace("JOINT spine", "JOINT knee")))
    with pytest.raises(NerfEditError, match="duplicate joint name 'knee'"):
        Skeleton.from_bvh(clip)
