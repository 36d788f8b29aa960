"""Ray bending: accuracy against the exact deformed mesh, and the cost of an edited render.

Scene: a capsule (subdivided so its surface can bend) with the generator's texture, bent by 115° about the y axis
(an isometric, smooth edit). Its tet proxy (cached) is lifted from the exact deformed surface by each lift method.

1. Accuracy (the paper's comparison, without training error): the ``mesh`` field rendered through the bent rays
   vs a direct render of the deformed mesh (``synthetic.render_mesh``, what ``render_ground_truth`` writes), same
   cameras and supersampling; PSNR / SSIM per lift (tet-arap; also refined to a residual of 5e-4 instead of the
   default 2e-3, and on the proxy as built; closest-point, knn3), with the lift's tets and max residual. The bench's
   ceiling: the same renders through a perfect deformation, i.e. the deformed mesh's own field rendered unbent.
   Eight views (the two of the first benches, then six around the bend); the score is the PSNR of the mean squared
   error over all of them, each view's beside it. Nearly all of the error of every row, the ceiling's included, is a
   few silhouette rays that hit in one render and miss in the other, so one view's PSNR moves by 1–2 dB with a few
   pixels; eight views make the comparison with the ceiling a measurement rather than a draw.
   Targets: tet-arap ≥ 35 dB, and ≥ 48 dB or within 1 dB of the ceiling.
2. Cost of ray bending (anchor: the unedited render of the same field, camera and samples per ray): edited time /
   unedited time, target ≤ 1.25×, for the mesh field, for the ``nerf`` backend's plain dense grid (density +
   RGB, 64³, occupancy grid 32³) filled from the mesh (a stand-in for a trained field: opaque inside, empty
   outside) and for the ``neus`` backend's SDF grid filled with the mesh's signed distance, all bent by the default
   tet-arap lift (its proxy refined where the fit needed it). The one-time point-locator builds of a frame are
   reported separately.

Usage: ``python bench/bench_render.py [--quick] [--threads N] [--repeats N]`` (quick: 64×64, no supersampling, one
camera). Times are wall clock and process CPU time of renders with unedited and edited interleaved; the ratio is the
median over the repeats of edited / unedited of the same round (a pair shares the machine's load of its moment, so
its ratio hardly drifts; a ratio of two minima is at the mercy of one lucky unedited render), with the ratio of the
best times beside it. The CPU ratio with ``--threads 1`` is the one that other load on the machine disturbs least.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch
import trimesh

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import timed  # noqa: E402

from nerfedit_plugin.bending.deformation_field import DeformationField  # noqa: E402
from nerfedit_plugin.data.cameras import Cameras, look_at  # noqa: E402
from nerfedit_plugin.data.synthetic import bend, colorize, render_mesh  # noqa: E402
from nerfedit_plugin.edit.lift import Lift, LiftConfig  # noqa: E402
from nerfedit_plugin.edit.proxy import ProxyConfig, cached_proxy  # noqa: E402
from nerfedit_plugin.fields.mesh_field import MeshField  # noqa: E402
from nerfedit_plugin.fields.nerf import NerfConfig, NerfField  # noqa: E402
from nerfedit_plugin.fields.neus import NeusConfig, NeusField  # noqa: E402
from nerfedit_plugin.geometry import raycast  # noqa: E402
from nerfedit_plugin.geometry.mesh import SurfaceMesh  # noqa: E402
from nerfedit_plugin.render.renderer import RenderConfig, render_image  # noqa: E402
from nerfedit_plugin.training.metrics import ssim  # noqa: E402

TARGET_PSNR = 35.0
VIEWS = 8
TARGET_RATIO = 1.25
METHODS = ("tet-arap", "closest-point", "knn3")


def scene() -> tuple[SurfaceMesh, object]:
    capsule = trimesh.creation.capsule(height=1.3, radius=0.35, count=[24, 12])
    vertices, faces = trimesh.remesh.subdivide_to_size(capsule.vertices, capsule.faces, max_edge=0.05)
    mesh = colorize(SurfaceMesh(vertices, faces), seed=4)
    proxy, _ = cached_proxy(mesh, ProxyConfig(), Path(tempfile.gettempdir()) / "nerfedit-bench-proxy")
    return mesh, proxy


def grid_field(mesh: SurfaceMesh, box: torch.Tensor) -> NerfField:
    """The nerf backend's dense density+RGB grid with σ ≈ 200 inside the mesh, ≈ 0 outside, surface colours."""
    config = NerfConfig(resolution=64, features=3, decoder="rgb", upsample_steps=(), occupancy_resolution=32)
    field = NerfField(config, box)
    n = config.resolution
    axes = [torch.linspace(float(box[0, d]), float(box[1, d]), n + 1) for d in range(3)]
    lattice = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
    oracle = MeshField.from_mesh(mesh)
    inside = oracle.occupied(lattice)
    colors = oracle.surface_colors(lattice).clamp(1e-3, 1 - 1e-3)
    with torch.no_grad():
        field.grid.table[:, 0] = torch.where(inside, 200.0, -30.0) - field.shift
        field.grid.table[:, 1:] = torch.logit(colors)
    field.update_occupancy()
    return field


def sdf_field(mesh: SurfaceMesh, box: torch.Tensor) -> NeusField:
    """The neus backend's dense SDF+RGB grid holding the mesh's signed distance (Open3D), sharpness s·h = 4,
    surface colours: a stand-in for a trained NeuS field (every sample also needs the SDF gradient)."""
    config = NeusConfig(resolution=64, features=3, decoder="rgb", upsample_steps=(), occupancy_resolution=32)
    field = NeusField(config, box)
    lattice = field.grid.vertex_points().reshape(-1, 3)
    scene = raycast.raycasting_scene(mesh.vertices, mesh.faces)
    distance = torch.from_numpy(raycast.signed_distance(scene, lattice.numpy()))
    colors = MeshField.from_mesh(mesh).surface_colors(lattice).clamp(1e-3, 1 - 1e-3)
    with torch.no_grad():
        field.grid.table[:, 0] = distance.to(field.grid.table) / field.cell
        field.grid.table[:, 1:] = torch.logit(colors)
        field.log_sharpness.fill_(math.log(4.0))
    field.update_occupancy()
    return field


def ring_eyes() -> torch.Tensor:
    """(6,3) float32 camera positions at 3.5 from the bend's middle, every 45° from 90° to 315° about z, their
    heights 0.3 + 0.7 cos 3θ."""
    angle = torch.arange(2, VIEWS) * (2 * math.pi / VIEWS)
    return torch.stack([3.5 * torch.sin(angle) + 0.3, -3.5 * torch.cos(angle), 0.3 + 0.7 * torch.cos(3 * angle)], 1)


def clocked(fn) -> tuple[float, float]:
    """``(wall, process CPU)`` seconds of ``fn()``; with one torch thread the CPU time hardly depends on what else
    runs on the machine."""
    wall, cpu = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="64×64, no supersampling, one camera")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    parser.add_argument("--repeats", type=int, default=11, help="timed rounds (after one warm-up round)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    size, supersample, n_cams = (64, 1, 1) if args.quick else (100, 2, VIEWS)
    torch.manual_seed(0)
    print(f"torch threads: {torch.get_num_threads()}, {size}×{size}, supersample {supersample}, {n_cams} camera(s)")

    seconds, (mesh, proxy) = timed(scene)
    print(
        f"mesh {len(mesh.vertices)} vertices, proxy {len(proxy.vertices)} vertices / {len(proxy.tets)} tets "
        f"({seconds:.1f} s incl. cache)"
    )
    bent = bend(mesh.vertices, radius=1.0)
    eyes = torch.cat([torch.tensor([[0.0, -3.5, 0.3], [2.5, -2.5, 1.0]]), ring_eyes()])[:n_cams]
    cams = Cameras.from_fov(look_at(eyes, torch.tensor([0.3, 0.0, 0.0]).expand(n_cams, 3)), size, size, 0.75)
    truth = render_mesh(mesh.with_vertices(bent), cams, supersample=supersample)[0]
    field, config = MeshField.from_mesh(mesh), RenderConfig()
    lifts = {method: Lift(proxy, mesh, method) for method in METHODS}
    lifts["tet-arap, residual_target 5e-4"] = Lift(proxy, mesh, config=LiftConfig(residual_target=5e-4))
    lifts["tet-arap, proxy as built"] = Lift(proxy, mesh, config=LiftConfig(refine_rounds=0))
    lifted = {name: lift(bent[None])[0] for name, lift in lifts.items()}
    deformations = {
        name: DeformationField(lift.proxy.vertices, lift.proxy.tets, lifted[name]) for name, lift in lifts.items()
    }
    residuals = {name: lift.report(lifted[name][0], bent, 0, 0.0).residual_max for name, lift in lifts.items()}

    print(f"\n1. mesh field through bent rays vs the deformed mesh ({n_cams} views: PSNR of the mean squared error")
    print("   / mean SSIM, then each view's PSNR)")
    bent_field = MeshField.from_mesh(mesh.with_vertices(bent))
    ceiling = None
    for name in ("ceiling: the deformed mesh's field, unbent", *deformations):
        errors, similarities = [], []
        for i in range(n_cams):
            if name in deformations:
                image = render_image(field, cams, i, config, deformation=deformations[name], supersample=supersample)
            else:
                image = render_image(bent_field, cams, i, config, supersample=supersample)
            image = image.numpy()
            errors.append(float(((image - truth[i]) ** 2).mean()))
            similarities.append(ssim(image, truth[i]))
        score = -10 * math.log10(statistics.mean(errors))
        ceiling = score if ceiling is None else ceiling
        views = " ".join(f"{-10 * math.log10(error):5.2f}" for error in errors)
        extra = (
            f"  ({score - ceiling:+.2f} dB; {len(lifts[name].proxy.tets)} tets, residual {residuals[name]:.2e} × bbox)"
            if name in lifts
            else ""
        )
        print(f"   {name:42s} {score:6.2f} / {statistics.mean(similarities):.4f}  [{views}]{extra}")

    print(f"\n2. edited vs unedited render time ({config.n_samples} samples per ray, camera 0)")
    box = torch.stack([torch.from_numpy(proxy.vertices).amin(0) - 0.1, torch.from_numpy(proxy.vertices).amax(0) + 0.1])
    refined = lifts["tet-arap"].proxy  # the default lift's proxy (refined where the fit needed it)
    deformation = DeformationField(refined.vertices, refined.tets, lifted["tet-arap"])
    seconds, _ = timed(lambda: deformation.to_canonical(torch.zeros(1, 3), 0))
    print(f"   one-time point-locator builds (rest proxy + frame 0): {seconds:.2f} s")
    subjects = (
        ("mesh", field),
        ("dense grid", grid_field(mesh, box.float())),
        ("sdf grid", sdf_field(mesh, box.float())),
    )
    for name, subject in subjects:
        times: dict[str, list[tuple[float, float]]] = {"unedited": [], "edited": []}
        for repeat in range(args.repeats + 1):  # interleaved rounds, the first is a warm-up
            for key, bending in (("unedited", None), ("edited", deformation)):
                seconds = clocked(
                    lambda subject=subject, bending=bending: render_image(
                        subject, cams, 0, config, deformation=bending, supersample=supersample
                    )
                )
                times[key] += [seconds] if repeat else []
        for clock, column in (("wall", 0), ("cpu", 1)):
            unedited, edited = (statistics.median(t[column] for t in times[key]) for key in ("unedited", "edited"))
            paired = statistics.median(e[column] / u[column] for u, e in zip(times["unedited"], times["edited"]))
            best = min(t[column] for t in times["edited"]) / min(t[column] for t in times["unedited"])
            print(
                f"   {name:10s} {clock:4s} unedited {unedited:6.3f} s  edited {edited:6.3f} s (medians)  "
                f"ratio {paired:4.2f}× (of bests {best:4.2f}×; target ≤ {TARGET_RATIO}×)"
            )


if __name__ == "__main__":
    main()
