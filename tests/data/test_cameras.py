"""Cameras and rays: OpenGL convention, pixel-centre projection oracle, exact downscaling, poses on a sphere."""

import math

import numpy as np
import pytest
import torch

from nerfedit_plugin.data.cameras import Cameras, generate_rays, look_at, orbit_poses, sphere_poses


def random_cameras(n=4, width=40, height=30, seed=0) -> Cameras:
    g = torch.Generator().manual_seed(seed)
    eyes = torch.randn(n, 3, generator=g) * 3
    targets = torch.randn(n, 3, generator=g) * 0.3
    fx = 30 + 10 * torch.rand(n, generator=g)
    fy = 30 + 10 * torch.rand(n, generator=g)
    cx = width / 2 + torch.randn(n, generator=g)
    cy = height / 2 + torch.randn(n, generator=g)
    return Cameras(look_at(eyes, targets), fx, fy, cx, cy, width, height)


def test_principal_point_ray_points_down_minus_z_and_image_axes_follow_opengl():
    cams = random_cameras()
    for i in range(len(cams)):
        c2w = cams.c2w[i]
        principal = torch.stack([cams.cx[i], cams.cy[i]]) - 0.5  # pixel whose centre is the principal point
        origin, direction = generate_rays(cams, i, principal[None])
        assert torch.allclose(origin[0], c2w[:3, 3])
        assert torch.allclose(direction[0], -c2w[:3, 2], atol=1e-6)
        _, right = generate_rays(cams, i, (principal + torch.tensor([5.0, 0.0]))[None])
        _, below = generate_rays(cams, i, (principal + torch.tensor([0.0, 5.0]))[None])
        assert float(right[0] @ c2w[:3, 0]) > 0.1  # image +x (column) = camera +x
        assert float(below[0] @ c2w[:3, 1]) < -0.1  # image +row = camera −y (OpenGL: +y up)


def test_rays_pass_through_projected_points():
    """Pinhole oracle: project world points with K [R|t], the ray through that pixel position hits the point."""
    cams = random_cameras(seed=1)
    g = torch.Generator().manual_seed(2)
    for i in range(len(cams)):
        c2w = cams.c2w[i].double()
        cam_points = torch.cat([torch.rand(50, 2, generator=g) - 0.5, -1 - torch.rand(50, 1, generator=g)], 1)
        world = (c2w[:3, :3] @ cam_points.double().T).T + c2w[:3, 3]
        x = cams.fx[i] * cam_points[:, 0] / -cam_points[:, 2] + cams.cx[i]
        y = -cams.fy[i] * cam_points[:, 1] / -cam_points[:, 2] + cams.cy[i]
        origins, directions = generate_rays(cams, i, torch.stack([x, y], 1) - 0.5)
        to_point = torch.nn.functional.normalize(world.float() - origins, dim=-1)
        assert torch.allclose(directions, to_point, atol=1e-5)


def test_ray_batch_modes_agree_and_directions_are_unit():
    cams = random_cameras(n=3, width=7, height=5)
    origins, directions = generate_rays(cams)
    assert origins.shape == directions.shape == (3, 5, 7, 3)
    assert torch.allclose(directions.norm(dim=-1), torch.ones(3, 5, 7))
    one = generate_rays(cams, 1)
    assert torch.equal(one[1], directions[1]) and torch.equal(one[0], origins[1])
    subset = generate_rays(cams, torch.tensor([2, 0]))
    assert torch.equal(subset[1], directions[[2, 0]])
    idx = torch.tensor([0, 2, 1, 2])
    pix = torch.tensor([[0, 0], [6, 4], [3, 2], [1, 3]])
    per_ray = generate_rays(cams, idx, pix)
    assert torch.allclose(per_ray[1], directions[idx, pix[:, 1], pix[:, 0]])
    assert torch.equal(per_ray[0], origins[idx, pix[:, 1], pix[:, 0]])


def test_downscale_halves_intrinsics_and_maps_pixel_centres_exactly():
    cams = random_cameras(width=41, height=30)
    half = cams.downscale(2)
    assert (half.width, half.height) == (20, 15)
    for name in ("fx", "fy", "cx", "cy"):
        assert torch.allclose(getattr(half, name), getattr(cams, name) / 2)
    # the centre of coarse pixel (i, j) is the centre of the 2x2 block (2i .. 2i+1): fine coordinate 2i + 0.5
    coarse = torch.tensor([[0, 0], [19, 14], [7, 3]])
    _, d_coarse = generate_rays(half, 2, coarse)
    _, d_fine = generate_rays(cams, 2, 2 * coarse.float() + 0.5)
    assert torch.allclose(d_coarse, d_fine, atol=1e-6)
    back = cams.upscale(3).downscale(3)
    assert (back.width, back.height) == (cams.width, cams.height)
    assert torch.allclose(back.fx, cams.fx) and torch.allclose(back.cx, cams.cx)
    with pytest.raises(ValueError):
        cams.downscale(1.5)


def test_look_at_is_a_proper_rotation_facing_the_target_even_at_the_pole():
    eyes = torch.tensor([[2.0, 1.0, 0.5], [0.0, 0.0, 3.0], [0.0, 0.0, -3.0]])  # the last two: view along ±up
    c2w = look_at(eyes, torch.zeros(3))
    rot = c2w[:, :3, :3]
    assert torch.isfinite(c2w).all()
    assert torch.allclose(rot.transpose(1, 2) @ rot, torch.eye(3).expand(3, 3, 3), atol=1e-6)
    assert torch.allclose(torch.linalg.det(rot), torch.ones(3))
    assert torch.allclose(-rot[:, :, 2], torch.nn.functional.normalize(-eyes, dim=-1), atol=1e-6)
    assert float(rot[0, 2, 1]) > 0  # camera +y has a positive world-z component (world up)


@pytest.mark.parametrize("hemisphere", [False, True])
def test_sphere_poses_spread_evenly_look_at_centre_and_follow_the_seed(hemisphere):
    n, radius, center = 64, 2.0, torch.tensor([0.3, -0.2, 0.1])
    poses = sphere_poses(n, radius, center.tolist(), hemisphere=hemisphere, seed=3)
    eyes = poses[:, :3, 3]
    assert torch.allclose((eyes - center).norm(dim=1), torch.full((n,), radius), atol=1e-5)
    forward = -poses[:, :3, 2]
    assert torch.allclose(forward, torch.nn.functional.normalize(center - eyes, dim=-1), atol=1e-5)
    if hemisphere:
        assert bool(((eyes - center)[:, 2] > 0).all())
    # even spread: nearest-neighbour distance of a Fibonacci lattice ≈ sqrt(area / n); a random set gets far closer
    area = (2 if hemisphere else 4) * math.pi * radius**2
    dist = torch.cdist(eyes, eyes) + torch.eye(n) * 1e9
    assert float(dist.min()) > 0.5 * math.sqrt(area / n)
    assert torch.equal(poses, sphere_poses(n, radius, center.tolist(), hemisphere=hemisphere, seed=3))
    assert not torch.allclose(poses, sphere_poses(n, radius, center.tolist(), hemisphere=hemisphere, seed=4))


def test_from_fov_matches_blender_focal_length():
    cams = Cameras.from_fov(sphere_poses(2, 3.0), 80, 60, 0.6911112070083618)
    assert np.isclose(float(cams.fx[0]), 0.5 * 80 / math.tan(0.5 * 0.6911112070083618))
    assert torch.equal(cams.fx, cams.fy) and float(cams.cx[0]) == 40 and float(cams.cy[0]) == 30
    assert torch.allclose(cams.camera_angle_x, torch.full((2,), 0.6911112))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_rays_on_cuda_match_cpu():
    cams = random_cameras()
    o_cpu, d_cpu = generate_rays(cams)
    o_gpu, d_gpu = generate_rays(cams.to("cuda"))
    assert o_gpu.is_cuda and torch.allclose(d_gpu.cpu(), d_cpu, atol=1e-6) and torch.allclose(o_gpu.cpu(), o_cpu)


def test_cameras_validate_and_convert_their_fields():
    c2w = torch.eye(4, dtype=torch.float64).expand(2, 4, 4)
    cams = Cameras(c2w, torch.tensor([30.0, 31.0], dtype=torch.float64), 30.0, 20.0, 15.0, 1, 1)  # 1×1 is valid
    assert cams.c2w.dtype == cams.fx.dtype == cams.fy.dtype == torch.float32 and cams.fy.shape == (2,)
    with pytest.raises(ValueError, match=r"Cameras\.c2w: expected shape \(C,4,4\), got \(2, 3, 4\)"):
        Cameras(torch.zeros(2, 3, 4), 30.0, 30.0, 20.0, 15.0, 40, 30)
    with pytest.raises(ValueError, match=r"Cameras\.fx: expected shape \(2,\), got \(3,\)"):
        Cameras(c2w, torch.ones(3), 30.0, 20.0, 15.0, 40, 30)
    for width, height in ((0, 5), (5, 0)):
        with pytest.raises(ValueError, match=f"image size must be positive, got {width}x{height}"):
            Cameras(c2w, 30.0, 30.0, 20.0, 15.0, width, height)


def assert_same_cameras(a: Cameras, b: Cameras) -> None:
    assert (a.width, a.height) == (b.width, b.height)
    for name in ("c2w", "fx", "fy", "cx", "cy"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name


def test_indexing_keeps_the_batch_dimension_and_to_copies_every_field():
    cams = random_cameras(n=4, width=40, height=30)
    one = cams[1]
    assert len(one) == 1 and float(one.fx[0]) == float(cams.fx[1]) and torch.equal(one.c2w[0], cams.c2w[1])
    assert_same_cameras(cams[[1]], one)
    picked = cams[[2, 0]]
    for name in ("c2w", "fx", "fy", "cx", "cy"):
        assert torch.equal(getattr(picked, name), getattr(cams, name)[torch.tensor([2, 0])])
    assert_same_cameras(cams[torch.tensor([2, 0])], picked)
    assert (picked.width, picked.height) == (40, 30)
    assert_same_cameras(cams.to("cpu"), cams)


def test_scaling_factors_by_hand():
    cams = random_cameras(n=2, width=40, height=30)
    assert_same_cameras(cams.downscale(1), cams)
    assert_same_cameras(cams.upscale(1), cams)
    up = cams.upscale(2)
    assert (up.width, up.height) == (80, 60)
    for name in ("fx", "fy", "cx", "cy"):
        assert torch.equal(getattr(up, name), 2 * getattr(cams, name)), name
    assert cams.downscale(30).height == 1  # a factor equal to a side is allowed
    assert random_cameras(n=1, width=30, height=40).downscale(30).width == 1
    with pytest.raises(ValueError, match="downscale factor 31 exceeds the image size 40x30"):
        cams.downscale(31)
    with pytest.raises(ValueError, match="downscale factor must be a positive integer, got 0"):
        cams.downscale(0)
    with pytest.raises(ValueError, match="upscale factor must be a positive integer, got 1.5"):
        cams.upscale(1.5)


def test_rays_of_a_single_camera_need_no_index_and_are_float32():
    cams = random_cameras(n=3)
    single = cams[2]
    pixels = torch.tensor([[0.0, 0.0], [12.5, 7.25], [39.0, 29.0]], dtype=torch.float64)
    origins, directions = generate_rays(single, pixels=pixels)
    expected = generate_rays(cams, 2, pixels.float())
    assert directions.dtype == torch.float32
    assert torch.equal(origins, expected[0]) and torch.equal(directions, expected[1])
    with pytest.raises(ValueError, match="^generate_rays: pixels given for several cameras; pass index$"):
        generate_rays(cams, pixels=pixels)


def test_look_at_by_hand_for_one_camera_also_at_the_pole():
    # from −y looking at the origin with +z up: x = (1,0,0), y = (0,0,1), z = (0,−1,0)
    expected = [[1.0, 0, 0, 0], [0, 0, -1, -5], [0, 1, 0, 0], [0, 0, 0, 1]]
    assert torch.equal(look_at([0.0, -5.0, 0.0], [0.0, 0.0, 0.0]), torch.tensor(expected))
    # straight above: up ∥ view, so the least aligned world axis (x) is up: x = (0,−1,0), y = (1,0,0), z = (0,0,1)
    expected = [[0.0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 1, 5], [0, 0, 0, 1]]
    assert torch.equal(look_at([0.0, 0.0, 5.0], [0.0, 0.0, 0.0]), torch.tensor(expected))


def test_sphere_poses_defaults_formula_and_seeded_offset():
    assert torch.equal(sphere_poses(6, 2.0), sphere_poses(6, 2.0, hemisphere=False, seed=0))
    assert float(sphere_poses(6, 2.0)[:, 2, 3].min()) < 0  # the default is the whole sphere
    one = sphere_poses(1, 2.0)  # n = 1: a single camera on the equator
    assert abs(float(one[0, 2, 3])) < 1e-6 and abs(float(one[0, :3, 3].norm()) - 2.0) < 1e-6
    with pytest.raises(ValueError, match="sphere_poses: n must be >= 1, got 0"):
        sphere_poses(0, 1.0)
    # consecutive azimuths advance by the golden angle π(3 − √5)
    eyes = sphere_poses(8, 1.0, seed=5)[:, :3, 3].double()
    step = torch.diff(torch.atan2(eyes[:, 1], eyes[:, 0])) % (2 * math.pi)
    assert torch.allclose(step, torch.full((7,), math.pi * (3 - math.sqrt(5)), dtype=torch.float64), atol=1e-5)
    # the offset φ₀ (the azimuth of a single camera) is uniform on [0, 2π) over seeds
    first = torch.stack([sphere_poses(1, 1.0, seed=s)[0, :3, 3] for s in range(400)]).double()
    phi0 = torch.atan2(first[:, 1], first[:, 0]) % (2 * math.pi)
    assert 0.4 < float((phi0 < math.pi).double().mean()) < 0.6
    assert 0.1 < float((phi0 < 1.0).double().mean()) < 0.22  # 1 / 2π ≈ 0.16


def test_orbit_poses_stay_in_their_band_look_at_the_centre_and_follow_the_seed():
    center = np.array([0.5, -0.2, 0.3])
    poses = orbit_poses(40, 3.0, center, elevation=(5.0, 20.0), azimuth=(-130.0, -50.0), seed=4)
    offsets = poses[:, :3, 3].double().numpy() - center
    assert np.allclose(np.linalg.norm(offsets, axis=1), 3.0, atol=1e-5)
    elevation = np.degrees(np.arcsin(offsets[:, 2] / 3.0))
    azimuth = np.degrees(np.arctan2(offsets[:, 1], offsets[:, 0]))
    assert (elevation > 5 - 1e-3).all() and (elevation < 20 + 1e-3).all()
    assert (azimuth > -130 - 1e-3).all() and (azimuth < -50 + 1e-3).all()
    assert np.ptp(azimuth) > 70 and np.ptp(elevation) > 12  # spread over the band
    axes = -poses[:, :3, 2].double().numpy()
    assert np.allclose(axes, -offsets / 3.0, atol=1e-5)  # looking at the centre
    assert (poses[:, 2, 1] > 0).all()  # image up points up
    other = orbit_poses(40, 3.0, center, elevation=(5.0, 20.0), azimuth=(-130.0, -50.0), seed=5)[:, :3, 3].numpy()
    assert np.linalg.norm(poses[:, None, :3, 3].numpy() - other[None], axis=-1).min() > 1e-3  # held-out views differ
    assert torch.equal(poses, orbit_poses(40, 3.0, center, elevation=(5.0, 20.0), azimuth=(-130.0, -50.0), seed=4))
    with pytest.raises(ValueError, match="n must be >= 1"):
        orbit_poses(0, 1.0)
