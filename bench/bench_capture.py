"""Bring your own capture: real structure from motion on a generated scene, checked against the truth.

Scene: ``sample:bunny`` and ``sample:cow`` on the generated floor inside the far shell, both with the ``noise``
texture (:data:`nerfedit_plugin.data.scene.TEXTURES`: SIFT needs corners everywhere in a frame), rendered at
``--resolution`` px from ``--views`` hemisphere cameras. Only the images go to COLMAP
(:func:`nerfedit_plugin.data.sfm.reconstruct`: SIFT, exhaustive matching, incremental mapping through pycolmap);
the workspace is read back as ``nerfedit train --data`` reads it (:func:`nerfedit_plugin.data.datasets.read_transforms`:
OpenCV → OpenGL, normalised). The recovered cameras are aligned to the true ones by the least-squares similarity of
their centres (Umeyama 1991) and compared: rotation error (degrees, the angle of ``R_trueᵀ R_align R_sfm``) and
centre error as a fraction of the scene size (the diagonal of the scene's foreground box). Targets: ≤ 1° and ≤ 1 %.

With ``--seconds S`` the ``nerf`` defaults are then trained for S CPU seconds, on the images downscaled by
``--downscale``, on the recovered poses (the workspace) and on the true poses (a nerfstudio ``transforms.json`` of
the same registered images with their true cameras mapped into the recovered model's normalised frame, with its
foreground box: same images, same held-out split — every 8th —, same frame and box), and the PSNRs over all held-out
views are compared (target: recovered ≥ true − 1 dB). With ``--edit-seconds S`` the workflow of docs/captures.md
then runs through the command line on the recovered poses (:func:`edit_capture_run`): ``nerfedit train --field
FIELD`` (``--edit-field``, default ``nerf``) for S CPU seconds, extract (at ``--edit-level``), the bunny
moved by an ``objects`` spec, the held-out views rendered unedited and edited, and an orbit video of the edit.

Usage: ``python bench/bench_capture.py [--views 48] [--resolution 256] [--seconds 0] [--edit-seconds 0]
[--edit-field nerf] [--edit-level L] [--downscale 2] [--out DIR]``.
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


def align(workspace: Path, truth: dict) -> tuple:
    """Read the workspace's model as nerfedit does (normalised) and align it to ``truth``: the recovered
    transforms, the true OpenGL camera-to-world of each registered image (in the model's order) and the similarity
    ``(s, R, t)`` taking the model's normalised frame to the true one."""
    recovered = read_transforms(workspace)
    names = [p.name for p in recovered.image_paths]
    c2w = recovered.cameras.c2w.double().numpy()
    true_c2w = np.stack([truth[n].c2w[0].double().numpy() for n in names])
    return recovered, true_c2w, umeyama(c2w[:, :3, 3], true_c2w[:, :3, 3])


def camera_errors(workspace: Path, truth: dict, scene_size: float) -> dict:
    """Align the workspace's model to ``truth`` and measure (see the module docstring)."""
    recovered, true_c2w, (scale, rotation, shift) = align(workspace, truth)
    names = [p.name for p in recovered.image_paths]
    c2w = recovered.cameras.c2w.double().numpy()
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
    """A nerfstudio ``transforms.json`` of the registered images with their true cameras and intrinsics, expressed in
    the recovered model's normalised frame (the inverse of the alignment) with its foreground box as ``aabb``: same
    images, same order (so the same held-out split: every 8th), same frame and box; only the poses differ."""
    from nerfedit_plugin.data.cameras import Cameras

    recovered, true_c2w, (scale, rotation, shift) = align(workspace, truth)
    names = [p.name for p in recovered.image_paths]
    c2w = true_c2w.copy()
    c2w[:, :3, :3] = rotation.T @ true_c2w[:, :3, :3]
    c2w[:, :3, 3] = (true_c2w[:, :3, 3] - shift) @ rotation / scale
    intrinsics = [np.array([float(getattr(truth[n], key)[0]) for n in names]) for key in ("fx", "fy", "cx", "cy")]
    cameras = Cameras(c2w, *intrinsics, truth[names[0]].width, truth[names[0]].height)
    folder = out / "true-poses"
    folder.mkdir(exist_ok=True)
    relative = [str(Path("..") / workspace.name / "images" / n) for n in names]
    transforms = nerfstudio_transforms(cameras, relative)
    transforms["aabb"] = np.asarray(recovered.meta["aabb"]).tolist()
    (folder / "transforms.json").write_text(json.dumps(transforms))
    return folder


def train_psnr(data: Path, out: Path, seconds: float, downscale: int) -> float:
    """Held-out PSNR (every held-out view) of the ``nerf`` defaults trained for ``seconds`` CPU seconds on ``data``,
    its images downscaled by ``downscale``."""
    from nerfedit_plugin.fields.nerf import NerfConfig
    from nerfedit_plugin.pipeline.train import train_run

    config = NerfConfig()
    config.train.max_seconds, config.train.clock, config.train.progress = seconds, "cpu", False
    config.train.eval_every_seconds, config.train.eval_views = 0, 1000
    _, log = train_run("nerf", config, data, out, overwrite=True, device="cpu", downscale=downscale)
    return float(log["eval"][-1][1])


def nerfedit(*argv) -> float:
    """Run ``nerfedit ARGV --overwrite`` in this process; its wall seconds (a failure ends the bench)."""
    from nerfedit_plugin.cli.app import main as cli

    start = time.perf_counter()
    if cli([str(a) for a in argv] + ["--overwrite"]) != 0:
        raise SystemExit(f"nerfedit {argv[0]} failed")
    return time.perf_counter() - start


def edit_capture_run(
    out: Path,
    workspace: Path,
    truth: dict,
    downscale: int,
    field: str,
    seconds: float,
    level: float | None = None,
    shift: float = 0.25,
) -> dict:
    """docs/captures.md steps 3–7 on the recovered poses, through the command line: train ``field`` for ``seconds``
    CPU seconds (images downscaled by ``downscale``), extract the scene's objects (``--drop-plane --drop-floaters
    0.05``, at ``level`` when given), move the bunny by ``shift`` × the foreground box's size away from the cow (an
    ``objects`` spec selecting the component of the mesh vertex nearest to the bunny's true centre, mapped into the
    run's frame by the alignment), render the held-out views unedited and edited, and an orbit of the edit (24 shots,
    128 px, mp4). Returns each step's wall seconds, the held-out PSNR, the mesh's and the selected bunny's vertex
    counts and the fraction of held-out pixels the edit changed (by more than 10/255)."""
    from nerfedit_plugin.data.datasets import read_image
    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    run = out / f"run-edit-{field}"
    result = {
        "train_s": nerfedit("train", "--data", workspace, "--out", run, "--field", field, "--downscale", downscale,
                            "--field-options.train.max-seconds", seconds, "--field-options.train.clock", "cpu"),
    }  # fmt: skip
    result["psnr"] = float(json.loads((run / "log.json").read_text())["eval"][-1][1])
    recovered, _, (scale, rotation, offset) = align(workspace, truth)
    scene = json.loads((out / "scene" / "scene.json").read_text())
    bunny, cow = (  # the objects' true centres in the run's (normalised) frame
        rotation.T @ (np.asarray(o["box"]).mean(0) - offset) / scale for o in scene["objects"]
    )
    box = np.asarray(recovered.meta["aabb"])
    away = (bunny - cow) / np.linalg.norm(bunny - cow) * shift * float(np.linalg.norm(box[1] - box[0]))
    extract = ["extract", "--run", run, "--resolution", 192, "--drop-plane", "--drop-floaters", 0.05]
    extract += [] if level is None else ["--level", level]
    result["extract_s"] = nerfedit(*extract)
    mesh = SurfaceMesh.load(run / "mesh.ply")
    near = mesh.vertices[np.argmin(np.linalg.norm(mesh.vertices - bunny, axis=1))]  # a point picked on the mesh
    spec = {
        "objects": [
            {
                "name": "bunny",
                "select": {"component": {"near": near.tolist(), "drop_plane": True}},
                "place": {"translate": away.tolist()},
            }
        ]
    }
    (out / "move_bunny.json").write_text(json.dumps(spec))
    render = ["render", "--run", run, "--cameras", workspace, "--downscale", downscale]
    result["edit_s"] = nerfedit("edit", "--run", run, "--edit", out / "move_bunny.json", "--out", out / "edit")
    result["render_unedited_s"] = nerfedit(*render, "--out", out / "views")
    edited = out / "edit" / "deformation.npz"
    result["render_edited_s"] = nerfedit(*render, "--deformation", edited, "--out", out / "views-edited")
    orbit = ["--trajectory", "orbit", "--shots", 24, "--size", 128, "--video", "mp4", "--out", out / "orbit"]
    result["render_orbit_s"] = nerfedit("render", "--run", run, "--deformation", edited, *orbit)
    changed = [
        np.abs(read_image(path)[0] - read_image(out / "views-edited" / path.name)[0]).max(-1) > 10 / 255
        for path in sorted((out / "views").glob("*.png"))
    ]
    report = json.loads((out / "edit" / "report.json").read_text())
    bunny_vertices = report["objects"][0]["surface"]["vertices"]
    return {**result, "mesh_vertices": mesh.n_vertices, "bunny_vertices": bunny_vertices,
            "edited_pixels": float(np.mean(changed))}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--views", type=int, default=48)
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--seconds", type=float, default=0.0)
    parser.add_argument("--edit-seconds", type=float, default=0.0, help="train, extract, edit and render (0: skip)")
    parser.add_argument("--edit-field", default="nerf", help="the field the edit workflow trains")
    parser.add_argument("--edit-level", type=float, default=None, help="the extraction level (default: the field's)")
    parser.add_argument("--downscale", type=int, default=2, help="train on the images downscaled by this factor")
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
        truth_data = true_pose_dataset(args.out, workspace, truth)
        result["psnr_recovered"] = train_psnr(workspace, args.out / "run-recovered", args.seconds, args.downscale)
        result["psnr_true"] = train_psnr(truth_data, args.out / "run-true", args.seconds, args.downscale)
    if args.edit_seconds > 0:
        field, seconds, level = args.edit_field, args.edit_seconds, args.edit_level
        edit = edit_capture_run(args.out, workspace, truth, args.downscale, field, seconds, level)
        result["edit"] = edit
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
