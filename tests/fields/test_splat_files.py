"""Splat files: the INRIA PLY (float and double, SH degrees 0-3) round trips and agrees with Open3D's reader and
writer on well-formed files; nerfstudio's degree-0 variant and .splat files are read; bad files are one NerfEditError
naming the file and the problem. Every file is generated here."""

import gzip

import numpy as np
import pytest

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.splats.files import read_ply, read_splats, write_ply, write_splat
from nerfedit_plugin.fields.splats.model import SH_C0, SplatModel, synthetic_model
from nerfedit_plugin.geometry.mesh import SurfaceMesh


def _same(a: SplatModel, b: SplatModel) -> None:
    for x, y in zip(a.arrays(), b.arrays()):
        assert x.shape == y.shape
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_ply_round_trip_every_degree(tmp_path, degree):
    model = synthetic_model(40, degree, seed=degree)
    write_ply(model, tmp_path / "m.ply")
    back = read_ply(tmp_path / "m.ply")
    assert back.degree == degree and back.means.dtype == np.float32
    _same(model, back)


def test_double_properties_are_read_as_float64(tmp_path):
    model = synthetic_model(30, 2, seed=3, dtype=np.float64)
    write_ply(model, tmp_path / "d.ply", dtype="double")
    back = read_splats(tmp_path / "d.ply")
    assert back.means.dtype == np.float64
    _same(model, back)


@pytest.mark.parametrize("degree", [0, 3])
def test_open3d_reads_what_we_write_and_we_read_what_it_writes(tmp_path, degree):
    o3d = pytest.importorskip("open3d")
    model = synthetic_model(60, degree, seed=7)
    write_ply(model, tmp_path / "ours.ply")
    cloud = o3d.t.io.read_point_cloud(str(tmp_path / "ours.ply"))
    point = cloud.point
    np.testing.assert_array_equal(point.positions.numpy(), model.means)
    np.testing.assert_array_equal(point.f_dc.numpy(), model.sh[:, 0])
    np.testing.assert_array_equal(point.opacity.numpy()[:, 0], model.opacities)
    np.testing.assert_allclose(point.scale.numpy(), np.exp(model.log_scales), rtol=1e-6)  # Open3D holds exp(scale_i)
    np.testing.assert_array_equal(point.rot.numpy(), model.quats)
    if degree:
        np.testing.assert_array_equal(point.f_rest.numpy(), model.sh[:, 1:])  # (N, K-1, 3): channel-major in the file
    o3d.t.io.write_point_cloud(str(tmp_path / "open3d.ply"), cloud)  # Open3D orders the properties differently
    _same(model, read_ply(tmp_path / "open3d.ply"))


def _write_raw(path, properties, rows: bytes, count: int, extra_header: str = "") -> None:
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {count}"]
    header += [f"property {t} {n}" for t, n in properties]
    path.write_bytes(("\n".join(header) + "\n" + extra_header + "end_header\n").encode() + rows)


def test_nerfstudio_colors_variant(tmp_path):
    """ns-export gaussian-splat at SH degree 0 declares one ``uchar colors`` and writes three bytes per vertex."""
    n = 5
    rng = np.random.default_rng(0)
    floats = ["x", "y", "z", "nx", "ny", "nz"]
    rest = ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    colors = rng.integers(0, 256, size=(n, 3), dtype=np.uint8)
    head = rng.normal(size=(n, 6)).astype("<f4")
    tail = rng.normal(size=(n, 8)).astype("<f4")
    rows = b"".join(head[i].tobytes() + colors[i].tobytes() + tail[i].tobytes() for i in range(n))
    props = [("float", f) for f in floats] + [("uchar", "colors")] + [("float", f) for f in rest]
    _write_raw(tmp_path / "splat.ply", props, rows, n, "comment Vertical Axis: z\n")
    model = read_splats(tmp_path / "splat.ply")
    assert model.degree == 0
    np.testing.assert_array_equal(model.means, head[:, :3])
    np.testing.assert_allclose(SH_C0 * model.sh[:, 0] + 0.5, colors / 255.0, atol=1e-6)
    np.testing.assert_array_equal(model.opacities, tail[:, 0])
    np.testing.assert_array_equal(model.quats, tail[:, 4:])


def test_splat_format_round_trip(tmp_path):
    model = synthetic_model(200, 0, seed=2)
    write_splat(model, tmp_path / "a.splat")
    assert (tmp_path / "a.splat").stat().st_size == 32 * len(model)
    back = read_splats(tmp_path / "a.splat")
    np.testing.assert_array_equal(back.means, model.means)
    np.testing.assert_allclose(back.log_scales, model.log_scales, atol=1e-6)
    rgb = lambda m: SH_C0 * m.sh[:, 0] + 0.5  # noqa: E731
    np.testing.assert_allclose(rgb(back), np.clip(rgb(model), 0, 1), atol=0.5 / 255 + 1e-6)
    alpha = lambda m: 1 / (1 + np.exp(-m.opacities))  # noqa: E731
    np.testing.assert_allclose(alpha(back), alpha(model), atol=0.5 / 255 + 1e-6)
    unit = model.quats / np.linalg.norm(model.quats, axis=1, keepdims=True)
    np.testing.assert_allclose(back.quats, unit, atol=0.5 / 128 + 1e-6)
    write_splat(back, tmp_path / "b.splat")  # a read file writes back to the same bytes but for the rotation
    a = np.fromfile(tmp_path / "a.splat", dtype=np.uint8).reshape(-1, 32)
    b = np.fromfile(tmp_path / "b.splat", dtype=np.uint8).reshape(-1, 32)
    np.testing.assert_array_equal(a[:, :28], b[:, :28])
    assert np.abs(a[:, 28:].astype(int) - b[:, 28:]).max() <= 1


# ---- bad files ----------------------------------------------------------------------------------------------------
def _valid(tmp_path, **change):
    model = synthetic_model(10, 1, seed=1)
    for key, value in change.items():
        getattr(model, key)[...] = value
    path = tmp_path / "bad.ply"
    write_ply(model, path)
    return path


def _without(tmp_path, drop: str, degree: int = 1):
    """An INRIA file of 4 Gaussians without the property ``drop``."""
    model = synthetic_model(4, degree, seed=0)
    path = tmp_path / "full.ply"
    write_ply(model, path)
    full = np.fromfile(path, dtype=np.uint8)
    text = path.read_bytes().split(b"end_header\n")[0].decode().splitlines()
    names = [line.split()[2] for line in text if line.startswith("property")]
    body = np.frombuffer(full[len("\n".join(text)) + len("\nend_header\n") :].tobytes(), dtype="<f4")
    body = body.reshape(4, len(names))
    keep = [i for i, name in enumerate(names) if name != drop]
    out = tmp_path / f"no_{drop}.ply"
    _write_raw(out, [("float", names[i]) for i in keep], np.ascontiguousarray(body[:, keep]).tobytes(), 4)
    return out


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda d: _without(d, "f_dc_1"), r"without the vertex properties f_dc_1"),
        (lambda d: _without(d, "rot_3"), r"without the vertex properties rot_3"),
        (lambda d: _without(d, "f_rest_8"), r"8 f_rest_\* properties, which is no SH degree"),
        (lambda d: _without(d, "f_rest_3"), r"not numbered 0\.\.7 without gaps"),
        (lambda d: _valid(d, means=np.nan), r"10 Gaussian\(s\) with NaN/Inf means \(first: Gaussian 0\)"),
        (lambda d: _valid(d, sh=np.inf), r"NaN/Inf sh"),
        (lambda d: _valid(d, quats=0.0), r"10 Gaussian\(s\) with a zero rotation quaternion"),
    ],
)
def test_bad_splat_ply_is_one_clear_error(tmp_path, make, match):
    path = make(tmp_path)
    with pytest.raises(NerfEditError, match=match) as info:
        read_splats(path)
    assert str(info.value).startswith(str(path))


def test_empty_model(tmp_path):
    write_ply(SplatModel(*(a[:0] for a in synthetic_model(1, 0).arrays())), tmp_path / "empty.ply")
    with pytest.raises(NerfEditError, match=r"empty.ply: empty splat model \(0 Gaussians\)"):
        read_splats(tmp_path / "empty.ply")


def test_a_mesh_is_named_with_the_command_that_takes_it(tmp_path):
    SurfaceMesh(np.eye(3), np.array([[0, 1, 2]])).save(tmp_path / "mesh.ply")
    with pytest.raises(NerfEditError, match=r"mesh.ply: a triangle mesh \(3 vertices, 1 faces\).*--field mesh"):
        read_splats(tmp_path / "mesh.ply")


def test_a_point_cloud_is_named(tmp_path):
    rows = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    props = [("float", "x"), ("float", "y"), ("float", "z"), ("uchar", "red"), ("uchar", "green"), ("uchar", "blue")]
    _write_raw(tmp_path / "points.ply", props, rows.tobytes(), 3)
    with pytest.raises(NerfEditError, match=r"points.ply: a plain point cloud \(3 points with x, y, z, red"):
        read_splats(tmp_path / "points.ply")


def test_compressed_formats_are_named(tmp_path):
    header = (
        "ply\nformat binary_little_endian 1.0\nelement chunk 1\nproperty float min_x\n"
        "element vertex 1\nproperty uint packed_position\nend_header\n"
    )
    (tmp_path / "scene.compressed.ply").write_bytes(header.encode() + bytes(8))
    with pytest.raises(NerfEditError, match=r"compressed splat PLY \(SuperSplat"):
        read_splats(tmp_path / "scene.compressed.ply")
    (tmp_path / "scene.spz").write_bytes(gzip.compress(b"NGSP" + bytes(12)))
    with pytest.raises(NerfEditError, match=r"scene.spz: a .spz file"):
        read_splats(tmp_path / "scene.spz")


def test_truncated_ascii_and_foreign_files(tmp_path):
    path = _valid(tmp_path)
    path.write_bytes(path.read_bytes()[:-5])
    with pytest.raises(NerfEditError, match=r"bad.ply: truncated: 10 Gaussians"):
        read_splats(path)
    text = path.read_bytes().split(b"end_header")[0].replace(b"binary_little_endian", b"ascii") + b"end_header\n1 2\n"
    path.write_bytes(text)
    with pytest.raises(NerfEditError, match=r"ASCII PLY"):
        read_splats(path)
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(NerfEditError, match=r"notes.txt: not a splat file"):
        read_splats(tmp_path / "notes.txt")
    (tmp_path / "odd.splat").write_bytes(bytes(33))
    with pytest.raises(NerfEditError, match=r"odd.splat: .*not a multiple of 32"):
        read_splats(tmp_path / "odd.splat")
    with pytest.raises(NerfEditError, match=r"missing.ply: splat file not found"):
        read_splats(tmp_path / "missing.ply")
