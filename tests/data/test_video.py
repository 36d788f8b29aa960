"""Frames from a video or photos (:mod:`nerfedit_plugin.data.video`): spacing, downsizing, bad input."""

import imageio.v2 as imageio
import numpy as np
import pytest
from PIL import Image

from nerfedit_plugin.data.video import downsize, photos, process_capture, video_frames
from nerfedit_plugin.errors import NerfEditError


def _video(path, count, size=(48, 64)):
    """An MP4 whose frame i is a flat grey of level 10 i (so a read frame tells its index)."""
    with imageio.get_writer(path, format="FFMPEG", fps=10, codec="libx264", quality=10, macro_block_size=16) as w:
        for i in range(count):
            w.append_data(np.full((*size, 3), 10 * i, dtype=np.uint8))
    return path


def test_video_frames_are_evenly_spaced_first_and_last_included(tmp_path):
    frames = list(video_frames(_video(tmp_path / "v.mp4", 21), 5))
    assert [f.shape for f in frames] == [(48, 64, 3)] * 5
    levels = [round(float(f.mean()) / 10) for f in frames]
    assert levels == [0, 5, 10, 15, 20]
    assert len(list(video_frames(tmp_path / "v.mp4", 100))) == 21  # all of them when it has fewer


def test_downsize_bounds_the_longest_side():
    image = Image.new("RGB", (1000, 500))
    assert downsize(image, 200).size == (200, 100)
    assert downsize(image, None) is image and downsize(image, 2000) is image


@pytest.mark.parametrize("content", [b"not a video", b""])
def test_an_unreadable_video_is_one_error_naming_it(tmp_path, content):
    (tmp_path / "bad.mp4").write_bytes(content)
    with pytest.raises(NerfEditError, match=r"bad\.mp4: not a video ffmpeg can read \(.+\)$"):
        process_capture(tmp_path / "out", video=tmp_path / "bad.mp4")
    assert not (tmp_path / "out").exists()


def test_a_folder_given_as_the_video_points_to_images(tmp_path):
    (tmp_path / "photos").mkdir()
    with pytest.raises(NerfEditError, match=r"photos: a folder, not a video file \(a folder of photos is --images\)"):
        process_capture(tmp_path / "out", video=tmp_path / "photos")
    with pytest.raises(NerfEditError, match=r"none\.mp4: no such video file"):
        process_capture(tmp_path / "out", video=tmp_path / "none.mp4")
    assert not (tmp_path / "out").exists()


def test_too_few_frames_or_registered_images_leave_nothing(tmp_path):
    with pytest.raises(NerfEditError, match="2 frame\\(s\\); structure from motion needs at least 3"):
        process_capture(tmp_path / "out", video=_video(tmp_path / "v.mp4", 2))
    rng = np.random.default_rng(0)
    (tmp_path / "photos").mkdir()
    for i in range(3):  # unrelated noise: nothing matches
        Image.fromarray(rng.integers(0, 255, (64, 64, 3), dtype=np.uint8)).save(tmp_path / "photos" / f"p{i}.jpg")
    (tmp_path / "photos" / "notes.txt").write_text("not a photo")
    assert [p.name for p in photos(tmp_path / "photos")] == ["p0.jpg", "p1.jpg", "p2.jpg"]
    with pytest.raises(NerfEditError, match="registered"):
        process_capture(tmp_path / "out", images=tmp_path / "photos")
    assert not (tmp_path / "out").exists()
    with pytest.raises(NerfEditError, match="exactly one"):
        process_capture(tmp_path / "out")


def test_photos_of_different_sizes_are_one_error(tmp_path):
    (tmp_path / "photos").mkdir()
    for name, size in (("a", (64, 48)), ("b", (64, 48)), ("c", (48, 64))):
        Image.new("RGB", size).save(tmp_path / "photos" / f"{name}.png")
    with pytest.raises(NerfEditError, match="c is 48x64, the first photo 64x48"):
        process_capture(tmp_path / "out", images=tmp_path / "photos")
    assert not (tmp_path / "out").exists()
