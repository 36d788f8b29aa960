"""Animations: frame selections, nerfstudio camera paths, trajectories through ``nerfedit render``, videos, resume
guards, and the Ray executor (bit-identical to the local one, and complete when a worker is killed)."""

import json
import math
import os
import signal
import sys

import imageio.v2 as imageio
import numpy as np
import pytest
import torch

from nerfedit_plugin.cli.app import main
from nerfedit_plugin.data.datasets import read_transforms
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.pipeline.executors import LocalExecutor, RayExecutor, RenderJob
from nerfedit_plugin.render.animation import parse_frames, read_camera_path, trajectory


def run(*argv):
    assert main([str(a) for a in argv]) == 0, argv


@pytest.mark.parametrize(
    "spec, frames",
    [(None, [0, 1, 2, 3, 4]), ("all", [0, 1, 2, 3, 4]), ("3", [3]), ("1:4", [1, 2, 3]), (":2", [0, 1]),
     ("2:", [2, 3, 4]), ("::2", [0, 2, 4]), ("1:5:3", [1, 4])],
)  # fmt: skip
def test_frame_selections_are_python_ranges(spec, frames):
    assert parse_frames(spec, 5) == frames


@pytest.mark.parametrize(
    "spec, message",
    [("x", "expected N, A:B"), ("1:2:3:4", "expected N, A:B"), ("-1", "must be >= 0"), ("0:4:0", "the step must be"),
     ("5", "frame 5 is out of range"), ("0:9", "frame 5 is out of range"), ("3:3", "selects no frame")],
)  # fmt: skip
def test_bad_frame_selections_name_the_option(spec, message):
    with pytest.raises(NerfEditError, match=rf"^--frame: {message}"):
        parse_frames(spec, 5)


def camera_path(transforms, fps=12):
    """The cameras of ``transforms`` as the nerfstudio viewer exports a camera path (vertical fov in degrees)."""
    cams = transforms.cameras
    fov = [math.degrees(2 * math.atan(cams.height / (2 * float(fy)))) for fy in cams.fy]
    path = [{"camera_to_world": c2w.flatten().tolist(), "fov": f, "aspect": 1.0} for c2w, f in zip(cams.c2w, fov)]
    size = {"render_width": cams.width, "render_height": cams.height}
    return {"camera_type": "perspective", **size, "camera_path": path, "fps": fps, "seconds": len(path) / fps}


def test_a_nerfstudio_camera_path_gives_the_same_cameras(capsule_flow, tmp_path):
    transforms = read_transforms(capsule_flow / "data", "test")
    (tmp_path / "camera_path.json").write_text(json.dumps(camera_path(transforms)))
    cameras, fps = read_camera_path(tmp_path / "camera_path.json")
    assert fps == 12 and (cameras.width, cameras.height) == (transforms.cameras.width, transforms.cameras.height)
    assert torch.allclose(cameras.c2w, transforms.cameras.c2w) and torch.allclose(cameras.fy, transforms.cameras.fy)
    bad = {**camera_path(transforms), "render_height": 0}
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(NerfEditError, match=r"bad.json: render_height: expected a positive integer"):
        read_camera_path(tmp_path / "bad.json")
    bad = camera_path(transforms)
    bad["camera_path"][1]["fov"] = 180
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(NerfEditError, match=r"camera_path\[1\]: .* fov in \(0, 180\)"):
        read_camera_path(tmp_path / "bad.json")


def pixels(path):
    return imageio.imread(path)[..., :3]


def test_trajectories_render_the_frames_the_views_render(capsule_flow, tmp_path):
    """``fixed`` (view 1) and ``path`` (a camera path of the test cameras, frame i ↔ camera i) give, frame by frame,
    the pixels of the ``views`` render of that camera; ``orbit`` moves the camera; the videos hold every frame."""
    flow, deformation = capsule_flow, capsule_flow / "edit" / "deformation.npz"
    common = ["render", "--run", flow / "run", "--deformation", deformation]
    run(*common, "--cameras", flow / "data", "--out", tmp_path / "views")
    run(*common, "--trajectory", "fixed", "--cameras", flow / "data", "--view", 1, "--out", tmp_path / "fixed",
        "--video", "mp4", "gif")  # fmt: skip
    transforms = read_transforms(flow / "data", "test")
    names = [p.with_suffix(".png").name for p in transforms.image_paths]
    for f in range(3):
        assert np.array_equal(
            pixels(tmp_path / "fixed" / f"frame_{f:04d}.png"), pixels(tmp_path / "views" / f"frame_{f:04d}" / names[1])
        )
    assert len(imageio.mimread(tmp_path / "fixed" / "animation.gif")) == 3
    with imageio.get_reader(tmp_path / "fixed" / "animation.mp4") as video:
        shot = video.get_data(2)
        assert video.count_frames() == 3 and shot.shape[:2] == (24, 24)
    assert np.abs(shot.astype(float) - pixels(tmp_path / "fixed" / "frame_0002.png")).mean() < 8  # lossy H.264
    (tmp_path / "path.json").write_text(json.dumps(camera_path(transforms)))
    run(
        *common,
        "--trajectory",
        "path",
        "--cameras",
        tmp_path / "path.json",
        "--frame",
        "0:2",
        "--out",
        tmp_path / "path",
    )
    for f in range(2):
        assert np.array_equal(
            pixels(tmp_path / "path" / f"frame_{f:04d}.png"), pixels(tmp_path / "views" / f"frame_{f:04d}" / names[f])
        )
    run(*common, "--trajectory", "orbit", "--size", 16, "--frame", "0", "--shots", 4, "--out", tmp_path / "orbit",
        "--video", "gif")  # fmt: skip
    shots = [pixels(tmp_path / "orbit" / f"frame_{i:04d}.png") for i in range(4)]  # a still edit: named by shot
    assert shots[0].shape == (16, 16, 3) and len(imageio.mimread(tmp_path / "orbit" / "animation.gif")) == 4
    assert all(not np.array_equal(a, b) for a, b in zip(shots, shots[1:]))  # the camera turns


def test_orbit_shots_spread_the_frames_and_a_still_turns_once():
    from nerfedit_plugin.render.animation import STILL_ORBIT_SHOTS, orbit_shots

    assert orbit_shots([0, 1, 2], None) == [0, 1, 2] and orbit_shots([4, 5, 6], 6) == [4, 4, 5, 5, 6, 6]
    assert orbit_shots([0, 1, 2, 3], 2) == [0, 2] and orbit_shots([7], None) == [7] * STILL_ORBIT_SHOTS


def test_the_orbit_flies_where_the_training_cameras_stood(capsule_flow):
    """``Run.filming``: the orbit's cameras stand at the training cameras' median distance from the box centre, at
    their median elevation about the up direction, with their field of view (a run built from a mesh has no cameras:
    the default ring); the ring is perpendicular to ``up`` (also for another up than z)."""
    from nerfedit_plugin.pipeline.run import Run, open_run
    from nerfedit_plugin.render.views import turntable_cameras

    images = Run(capsule_flow / "run", "nerf", capsule_flow / "data", {})  # as if trained on the images
    box = torch.tensor([[-0.6, -0.5, -1.1], [0.6, 0.5, 1.1]], dtype=torch.float64)
    ring = images.filming(box, (0.0, 0.0, 1.0))
    train = read_transforms(capsule_flow / "data", "train").cameras
    offsets = train.c2w[:, :3, 3].double() - box.mean(0)
    orbit = turntable_cameras(box, 8, 16, **ring)
    eyes = orbit.c2w[:, :3, 3].double() - box.mean(0)
    np.testing.assert_allclose(torch.linalg.norm(eyes, dim=1), torch.linalg.norm(offsets, dim=1).median(), rtol=1e-6)
    np.testing.assert_allclose(orbit.fy / 16, train.fy.double().median() / train.height, rtol=1e-6)  # same fov
    sines = offsets[:, 2] / torch.linalg.norm(offsets, dim=1)
    np.testing.assert_allclose(eyes[:, 2] / torch.linalg.norm(eyes, dim=1), sines.median(), rtol=1e-6)
    sideways = turntable_cameras(box, 8, 16, up=(0.0, 1.0, 0.0), elevation_degrees=30.0)
    heights = sideways.c2w[:, 1, 3].double() - box.mean(0)[1]
    np.testing.assert_allclose(
        heights / torch.linalg.norm(sideways.c2w[:, :3, 3].double() - box.mean(0), dim=1), 0.5, rtol=1e-6
    )
    assert open_run(capsule_flow / "run").filming(box, (0.0, 0.0, 1.0)) == {}  # built from a mesh: no cameras


def test_resume_refuses_other_settings_and_trajectories_check_their_cameras(capsule_flow, tmp_path, capsys):
    flow, deformation = capsule_flow, capsule_flow / "edit" / "deformation.npz"
    common = ["render", "--run", flow / "run", "--deformation", deformation, "--out", tmp_path / "out"]
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / ".nerfedit-partial").write_text(json.dumps({"key": "0123456789abcdef", "shots": 3}))
    assert main([str(a) for a in common + ["--trajectory", "orbit", "--resume"]]) == 2
    assert "made with other settings" in capsys.readouterr().err
    assert main([str(a) for a in common + ["--trajectory", "path", "--cameras", flow / "data"]]) == 2
    assert "has 2 cameras for 3 frames" in capsys.readouterr().err
    assert main([str(a) for a in common + ["--trajectory", "fixed", "--cameras", flow / "data", "--view", 5]]) == 2
    assert "--view: 5 is out of range" in capsys.readouterr().err
    assert main([str(a) for a in common + ["--trajectory", "fixed", "--cameras", flow / "data", "--shots", 4]]) == 2
    assert "--shots: only for --trajectory orbit, not fixed" in capsys.readouterr().err


def test_ray_frames_equal_the_local_ones_and_survive_a_killed_worker(capsule_flow):
    """A local Ray cluster (2 CPUs, 2 actors): the frames are bit-identical to the local executor's; SIGKILL of the
    actor that still holds frames after the first arrives restarts it and its frames are retried."""
    ray = pytest.importorskip("ray")
    job = RenderJob(capsule_flow / "run", capsule_flow / "edit" / "deformation.npz", 1, threads=1)
    cameras, _ = trajectory("fixed", range(6), cameras=capsule_flow / "data", view=0)
    shots = [(f % 3, cameras[f]) for f in range(6)]
    threads = torch.get_num_threads()
    try:
        local = dict(LocalExecutor(job).map(shots))  # with the job's one thread, like each actor
    finally:
        torch.set_num_threads(threads)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        with pytest.raises(
            NerfEditError, match=r"--workers: 3 actors × 1 torch threads need 3 CPUs, the cluster has 2"
        ):
            RayExecutor(job, workers=3)
        executor = RayExecutor(job, workers=2)
        pids = ray.get([actor.pid.remote() for actor in executor.actors])
        got = {}
        for index, image in executor.map(shots):
            if not got:  # shots go round-robin: the actor of shot index + 1 still has work
                os.kill(pids[(index + 1) % 2], signal.SIGKILL)
            got[index] = image
        executor.close()
    finally:
        ray.shutdown()
    assert sorted(got) == list(range(6))
    assert all(np.array_equal(got[i], local[i]) for i in range(6))


def test_ray_problems_are_one_line_errors(capsule_flow, tmp_path, capsys, monkeypatch):
    common = ["render", "--run", capsule_flow / "run", "--deformation", capsule_flow / "edit" / "deformation.npz",
              "--trajectory", "fixed", "--cameras", capsule_flow / "data", "--out", tmp_path / "out"]  # fmt: skip
    for extra, message in [
        (["--executor", "ray", "--ray-address", "127.0.0.1:1"], "--ray-address: cannot reach a Ray cluster"),
        (["--executor", "ray", "--ray-address", "nowhere"], "--ray-address: expected HOST:PORT"),
        (["--workers", "2"], "--ray-address / --workers: only with --executor ray"),
    ]:
        assert main([str(a) for a in common + extra]) == 2
        assert message in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "ray", None)  # as if Ray were not installed
    assert main([str(a) for a in common + ["--executor", "ray"]]) == 2
    assert 'Ray is not installed (pip install "nerfedit[ray]")' in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
