"""Bring your own capture (issue 16): real structure from motion on a generated scene, checked against the truth.

Scene: ``sample:bunny`` and ``sample:cow`` on the generated floor inside the far shell, both with the ``noise``
texture (:data:`nerfedit_plugin.data.scene.TEXTURES`: SIFT needs corners everywhere in a frame), rendered at
``--resolution`` px from ``--views`` hemisphere cameras. Only the images go to COLMAP
(:func:`nerfedit_plugin.data.sfm.reconstruct`: SIFT, exhaustive matching, incremental mapping through pycolmap);
the workspace is read back as ``nerfedit train --data`` reads it (:func:`nerfedit_plugin.data.datasets.read_transforms`:
OpenCV → OpenGL, normalised). The recovered cameras are aligned to the true ones by the least-squares similarity of
their centres (Umeyama 1991) and compared: rotation error (degrees, the angle of ``R_trueᵀ R_align R_sfm``) and
centre error as a fraction of the scene size (the diagonal of the scene's foreground box). Targets: ≤ 1° and ≤ 1 %.

With ``--seconds S`` the ``nerf`` field is then trained for S CPU seconds on the recovered poses (the workspace) and
on the true poses (a nerfstudio ``transforms.json`` of the same images, same held-out split: every 8th image), and
the held-out PSNRs are compared (target: recovered ≥ true − 1 dB).

Usage: ``python bench/bench_capture.py [--views 48] [--resolution 256] [--seconds 0] [--out DIR]``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import skimage.io

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nerfedit_plugin.data.datasets import nerfstudio_transforms, read_image, read_transforms, to_uint8  # noqa: E402
from nerfedit_plugin.data.scene import generate_scene  # noqa: E402
from nerfedit_plugin.data.sfm import reconstruct  # noqa: E402
from nerfedit_plugin.data.synthetic import GenerateConfig  # noqa: E402

OBJECTS = ["sample:bunny", "sample:cow"]


def make_capture(out: Path, views: int, resolution: int, seed: int = 0) -> tuple[Path, dict, float]:
    """Render the scene and lay its images out as a COLMAP workspace ``out/workspace/images`` (RGB PNGs, named
    ``view_NNN.png``). Returns the workspace, the true OpenGL camera-to-world of each image name with its
    intrinsics, and the scene size (the foreground box's diagonal)."""
    data = out / "scene"
    config = GenerateConfig(
        out=data, objects=OBJECTS, n_train=views, n_val=1, n_test=1, resolution=resolution, seed=seed, overwrite=True
    )
    generate_scene(config, texture="noise")
    transforms = read_transforms(data, "train")
    workspace = out / "workspace"
    shutil.rmtree(workspace, ignore_errors=True)
    (workspace / "images").mkdir(parents=True)
    truth = {}
    for i, path in enumerate(transforms.image_paths):
        name = f"view_{i:03d}.png"
        rgb, _ = read_image(path)
        skimage.io.imsave(workspace / "images" / name, to_uint8(rgb), check_contrast=False)
        truth[name] = transforms.cameras[i]
    box = np.asarray(transforms.meta["aabb"], dtype=np.float64)
    return workspace, truth, float(np.linalg.norm(box[1] - box[0]))


def umeyama(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """``(s, R, t)`` minimising ``Σ ‖target_i − (s R source_i + t)‖²`` (Umeyama 1991)."""
    mu_s, mu_t = source.mean(0), target.mean(0)
    a, b = source - mu_s, target - mu_t
    u, d, vt = np.linalg.svd(b.T @ a / len(source))
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ flip @ vt
    scale = float(np.trace(np.diag(d) @ flip) / (a**2).sum(1).mean())
    return scale, rotation, mu_t - scale * rotation @ mu_s


def camera_errors(workspace: Path, truth: dict, scene_size: float) -> dict:
    """Read the workspace's model as nerfedit does, align it to ``truth`` and measure (see the module docstring)."""
    recovered = read_transforms(workspace)
    names = [p.name for p in recovered.image_paths]
    c2w = recovered.cameras.c2w.double().numpy()
    true_c2w = np.stack([truth[n].c2w[0].double().numpy() for n in names])
    scale, rotation, shift = umeyama(c2w[:, :3, 3], true_c2w[:, :3, 3])
    centres = scale * c2w[:, :3, 3] @ rotation.T + shift
    relative = np.einsum("nji,jk,nkl->nil", true_c2w[:, :3, :3], rotation, c2w[:, :3, :3])
    angles = np.degrees(np.arccos(np.clip((np.trace(relative, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)))
    centre_errors = np.linalg.norm(centres - true_c2w[:, :3, 3], axis=1) / scene_size
    focal = recovered.cameras.fx.double().numpy() / np.array([float(truth[n].fx[0]) for n in names])
    return {
        "registered": len(names),
        "images": len(truth),
        "rotation_deg_max": float(angles.max()),
        "rotation_deg_mean": float(angles.mean()),
        "centre_error_max": float(centre_errors.max()),
        "centre_error_mean": float(centre_errors.mean()),
        "focal_ratio_error_max": float(np.abs(focal - 1.0).max()),
    }


def true_pose_dataset(out: Path, workspace: Path, truth: dict) -> Path:
    """A nerfstudio ``transforms.json`` of the workspace's images with their true cameras (sorted by name, so the
    held-out split is the workspace's)."""
    from nerfedit_plugin.data.cameras import Cameras

    names = sorted(truth)
    cams = [truth[n] for n in names]
    cameras = Cameras(
        np.concatenate([c.c2w.numpy() for c in cams]),
        np.concatenate([c.fx.numpy() for c in cams]),
        np.concatenate([c.fy.numpy() for c in cams]),
        np.concatenate([c.cx.numpy() for c in cams]),
        np.concatenate([c.cy.numpy() for c in cams]),
        cams[0].width,
        cams[0].height,
    )
    folder = out / "true-poses"
    folder.mkdir(exist_ok=True)
    relative = [str(Path("..") / workspace.name / "images" / n) for n in names]
    (folder / "transforms.json").write_text(json.dumps(nerfstudio_transforms(cameras, relative)))
    return folder


def train_psnr(data: Path, out: Path, seconds: float) -> float:
    """Held-out PSNR of the ``nerf`` field trained for ``seconds`` CPU seconds on ``data``."""
    from nerfedit_plugin.fields.nerf import NerfConfig
    from nerfedit_plugin.io.run import train_run

    config = NerfConfig()
    config.train.max_seconds, config.train.clock, config.train.progress = seconds, "cpu", False
    config.train.eval_every_seconds = 0
    _, log = train_run("nerf", config, data, out, overwrite=True, device="cpu")
    return float(log["eval"][-1][1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--views", type=int, default=48)
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--seconds", type=float, default=0.0)
    parser.add_argument("--out", type=Path, default=Path("/tmp/nerfedit-bench-capture"))
    parser.add_argument("--reuse", action="store_true", help="keep the workspace of an earlier run (no new SfM)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    workspace, truth, size = make_capture(args.out, args.views, args.resolution)
    cpu, wall = time.process_time(), time.perf_counter()
    if not (args.reuse and (args.out / "sfm" / "sparse").is_dir()):
        shutil.rmtree(args.out / "sfm", ignore_errors=True)
        shutil.copytree(workspace, args.out / "sfm")
        reconstruct(args.out / "sfm", overwrite=True)
    workspace = args.out / "sfm"
    timing = {"sfm_cpu_s": time.process_time() - cpu, "sfm_wall_s": time.perf_counter() - wall}
    result = {"views": args.views, "resolution": args.resolution, **timing, **camera_errors(workspace, truth, size)}
    if args.seconds > 0:
        result["psnr_recovered"] = train_psnr(workspace, args.out / "run-recovered", args.seconds)
        truth_data = true_pose_dataset(args.out, workspace, truth)
        result["psnr_true"] = train_psnr(truth_data, args.out / "run-true", args.seconds)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
