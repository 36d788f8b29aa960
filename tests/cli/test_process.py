"""``nerfedit process``: a video of a generated, textured scene → a COLMAP workspace with the true cameras."""

import sys
import warnings
from pathlib import Path

import imageio.v2 as imageio

from nerfedit_plugin.cli.app import main
from nerfedit_plugin.data.datasets import read_transforms


def test_a_video_becomes_a_capture_with_the_true_cameras(tmp_path, capsys):
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    import bench_capture

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        workspace, truth, size = bench_capture.make_capture(tmp_path, views=16, resolution=192)  # the tiny SfM's
    names = sorted(truth)
    with imageio.get_writer(tmp_path / "orbit.mp4", format="FFMPEG", fps=8, codec="libx264", quality=10) as writer:
        for name in names:
            writer.append_data(imageio.imread(workspace / "images" / name))
    capture = tmp_path / "capture"
    argv = ["process", "--video", str(tmp_path / "orbit.mp4"), "--out", str(capture), "--frames", "16"]
    assert main(argv) == 0
    assert "16 of 16 images registered" in " ".join(capsys.readouterr().out.split())
    assert sorted(p.name for p in (capture / "images").iterdir()) == [f"frame_{i:04d}.png" for i in range(16)]
    assert imageio.imread(capture / "images" / "frame_0000.png").shape == (192, 192, 3)
    assert len(read_transforms(capture).image_paths) == 16  # what `nerfedit train --data` reads
    truth = {f"frame_{i:04d}.png": truth[name] for i, name in enumerate(names)}
    errors = bench_capture.camera_errors(capture, truth, size)
    assert errors["rotation_deg_max"] < 1.0 and errors["centre_error_max"] < 0.01
    assert main(argv) == 2 and "exists" in capsys.readouterr().err  # never replaced without --overwrite
