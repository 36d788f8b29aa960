"""Splat files: the INRIA ``point_cloud.ply`` layout (and nerfstudio's variant of it) and the ``.splat`` format.

**PLY** (read by parsing the header, the body as one numpy structured array; ``binary_little_endian`` or
``binary_big_endian``, each property ``float`` or ``double`` — any numeric type is read): one ``vertex`` element with
``x y z``, optionally ``nx ny nz`` (ignored), ``f_dc_0..2``, ``f_rest_0..(3(K−1)−1)`` channel-major (the ``K − 1``
coefficients of red, then green, then blue; ``K = (d + 1)²``, ``d`` the SH degree 0..3), ``opacity`` (logit),
``scale_0..2`` (log), ``rot_0..3`` (w x y z). nerfstudio's ``ns-export gaussian-splat`` of a degree-0 model writes
``colors`` instead of ``f_dc_*``: one ``uchar`` property declared, three bytes (RGB) written per vertex; its colour
``c / 255`` is read as the DC term ``(c / 255 − ½) / SH_C0``.

**.splat** (antimatter15's web viewer format): 32-byte records, no header, no SH beyond the DC term —
``x y z`` float32, linear scales float32 ×3, RGBA uint8 (``rgb = SH_C0 · f_dc + ½``, ``a = sigmoid(opacity)``, each
×255), the unit quaternion w x y z as uint8 ``round(128 q + 128)``.

Other splat formats (SuperSplat's compressed PLY, Niantic's ``.spz``) are recognised and refused by name; a PLY that
is a mesh or a plain point cloud is refused saying so. Every error is one :class:`NerfEditError` naming the file.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.splats.model import SH_C0, SplatModel, degree_of
from nerfedit_plugin.io.atomic import atomic_path

PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
"""PLY scalar type name → numpy type code (without byte order)."""

SPLAT_RECORD = np.dtype([("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rotation", "u1", 4)])
"""One ``.splat`` record (32 bytes)."""

MAX_HEADER = 1 << 20
"""A PLY header longer than this (bytes) is not read."""

OPACITY_BYTE_RANGE = (0.25, 254.75)
"""``.splat`` alpha bytes are read clamped to this range before the logit, so 0 and 255 give finite logits that
write back to the same bytes."""


def _error(path: Path, problem: str) -> NerfEditError:
    return NerfEditError(f"{path}: {problem}")


def _ply_header(path: Path, head: bytes) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]], int]:
    """``(format, [(element, count, [(property, type) …])], header length in bytes)``; list properties have the type
    ``"list"``."""
    end = head.find(b"end_header")
    if end < 0:
        raise _error(path, "PLY header without end_header (truncated or not a PLY file)")
    stop = head.index(b"\n", end) + 1 if b"\n" in head[end:] else None
    if stop is None:
        raise _error(path, "PLY header without a line end after end_header")
    try:
        lines = head[:stop].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise _error(path, "PLY header is not ASCII text") from None
    fmt, elements = None, []
    for number, line in enumerate(lines[1:-1], start=2):
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) == 3:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in PLY_TYPES:
            elements[-1][2].append((words[2], words[1]))
        elif words[0] == "property" and elements and len(words) == 5 and words[1] == "list":
            elements[-1][2].append((words[4], "list"))
        else:
            raise _error(path, f"PLY header line {number} not understood: {line!r}")
    if fmt is None:
        raise _error(path, "PLY header without a format line")
    return fmt, elements, stop


def _classify(path: Path, elements) -> list[tuple[str, str]]:
    """The vertex properties of a splat PLY; errors for what is not one (say what it is, and what takes it)."""
    names = {name for name, _, _ in elements}
    props = {p for _, _, plist in elements for p, _ in plist}
    if "chunk" in names or any(p.startswith("packed_") for p in props):
        raise _error(
            path,
            "a compressed splat PLY (SuperSplat / PlayCanvas: chunk and packed_* properties), which is not read; "
            "decompress it to the INRIA layout (e.g. SuperSplat's export as PLY)",
        )
    vertex = [e for e in elements if e[0] == "vertex"]
    if not vertex:
        raise _error(path, f"PLY without a vertex element (elements: {', '.join(sorted(names)) or 'none'})")
    _, count, plist = vertex[0]
    vprops = [p for p, _ in plist]
    splat_keys = {"opacity", "scale_0", "rot_0"}
    if not splat_keys & set(vprops):
        faces = [c for name, c, _ in elements if name == "face"]
        if faces and faces[0] > 0:
            raise _error(
                path,
                f"a triangle mesh ({count} vertices, {faces[0]} faces), not a Gaussian splat model: "
                f"`nerfedit train --field mesh --data {path}` takes it",
            )
        raise _error(
            path,
            f"a plain point cloud ({count} points with {', '.join(vprops)}), not a Gaussian splat model (no opacity, "
            "scale_*, rot_*): a capture's sparse points are read through a nerfstudio transforms.json "
            "(ply_file_path) by `nerfedit train --data TRANSFORMS.json`",
        )
    if any(t == "list" for _, t in plist):
        raise _error(path, "splat PLY with a list property in its vertex element")
    return plist


def _f_rest_count(path: Path, props: list[str]) -> int:
    rest = sorted(int(m.group(1)) for p in props if (m := re.fullmatch(r"f_rest_(\d+)", p)))
    if rest != list(range(len(rest))):
        raise _error(path, f"f_rest_* properties are not numbered 0..{len(rest) - 1} without gaps")
    if len(rest) % 3 or degree_of(len(rest) // 3 + 1) is None:
        raise _error(
            path,
            f"{len(rest)} f_rest_* properties, which is no SH degree (0, 9, 24 or 45 for degrees 0, 1, 2, 3)",
        )
    return len(rest)


def read_ply(path: str | os.PathLike) -> SplatModel:
    """A splat model from the PLY ``path`` (module docstring); float64 properties stay float64. Validated
    (:meth:`SplatModel.validate`)."""
    path = Path(path)
    with open(path, "rb") as handle:
        head = handle.read(MAX_HEADER)
    if not head.startswith(b"ply"):
        raise _error(path, "not a PLY file (it does not start with 'ply')")
    fmt, elements, offset = _ply_header(path, head)
    plist = _classify(path, elements)
    if fmt == "ascii":
        raise _error(path, "ASCII PLY splat files are not read (write binary_little_endian)")
    order = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(fmt)
    if order is None:
        raise _error(path, f"unknown PLY format {fmt!r}")
    count = next(c for name, c, _ in elements if name == "vertex")
    props = [p for p, _ in plist]
    types = dict(plist)
    nerfstudio_colors = "colors" in types and types["colors"] in ("uchar", "uint8") and "f_dc_0" not in types
    fields = [(p, "u1", (3,)) if (nerfstudio_colors and p == "colors") else (p, order + PLY_TYPES[t]) for p, t in plist]
    dtype = np.dtype(fields)
    required = ["x", "y", "z", "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    if not nerfstudio_colors:
        required[3:3] = ["f_dc_0", "f_dc_1", "f_dc_2"]
    missing = [p for p in required if p not in types]
    if missing:
        raise _error(path, f"splat PLY without the vertex properties {', '.join(missing)}")
    n_rest = _f_rest_count(path, props)
    if nerfstudio_colors and n_rest:
        raise _error(path, "splat PLY with both colors and f_rest_* (nerfstudio writes colors only at SH degree 0)")
    size = path.stat().st_size
    if size < offset + count * dtype.itemsize:
        raise _error(
            path,
            f"truncated: {count} Gaussians of {dtype.itemsize} bytes need {offset + count * dtype.itemsize} bytes, "
            f"the file has {size}",
        )
    body = np.fromfile(path, dtype=dtype, count=count, offset=offset)

    def stack(names: list[str]) -> np.ndarray:
        kinds = {body.dtype[n].kind for n in names}
        out = np.float64 if any(body.dtype[n].itemsize == 8 for n in names) else np.float32
        if not kinds <= {"f"}:
            out = np.float64
        return np.stack([body[n].astype(out, copy=False) for n in names], axis=-1)

    means = stack(["x", "y", "z"])
    dtype_out = means.dtype
    if nerfstudio_colors:
        dc = ((body["colors"].astype(np.float64) / 255.0 - 0.5) / SH_C0).astype(dtype_out)
    else:
        dc = stack(["f_dc_0", "f_dc_1", "f_dc_2"]).astype(dtype_out)
    k_rest = n_rest // 3
    sh = np.empty((count, k_rest + 1, 3), dtype=dtype_out)
    sh[:, 0] = dc
    if k_rest:
        rest = stack([f"f_rest_{i}" for i in range(n_rest)]).astype(dtype_out)  # (N, 3 (K-1)) channel-major
        sh[:, 1:] = rest.reshape(count, 3, k_rest).transpose(0, 2, 1)
    model = SplatModel(
        means,
        stack(["rot_0", "rot_1", "rot_2", "rot_3"]).astype(dtype_out),
        stack(["scale_0", "scale_1", "scale_2"]).astype(dtype_out),
        body["opacity"].astype(dtype_out),
        sh,
    )
    return model.validate(str(path))


def ply_bytes_header(model: SplatModel, dtype: str) -> bytes:
    """The INRIA header of ``model`` with every property of type ``dtype`` (``"float"`` or ``"double"``)."""
    k_rest = model.sh.shape[1] - 1
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * k_rest)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {len(model)}"]
    lines += [f"property {dtype} {name}" for name in names]
    return ("\n".join(lines + ["end_header"]) + "\n").encode("ascii")


def write_ply(model: SplatModel, path: str | os.PathLike, dtype: str = "float") -> None:
    """Write ``model`` in the INRIA layout (normals zero, ``f_rest`` channel-major), atomically; ``dtype`` =
    ``"float"`` (the layout every tool reads) or ``"double"``."""
    code = {"float": "<f4", "double": "<f8"}[dtype]
    n, k_rest = len(model), model.sh.shape[1] - 1
    columns = [
        model.means,
        np.zeros((n, 3)),
        model.sh[:, 0],
        model.sh[:, 1:].transpose(0, 2, 1).reshape(n, 3 * k_rest),
        model.opacities[:, None],
        model.log_scales,
        model.quats,
    ]
    body = np.concatenate([np.asarray(c, dtype=code) for c in columns], axis=1)
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        handle.write(ply_bytes_header(model, dtype))
        handle.write(np.ascontiguousarray(body).tobytes())


def read_splat(path: str | os.PathLike) -> SplatModel:
    """A degree-0 splat model from the ``.splat`` file ``path`` (module docstring). Validated."""
    path = Path(path)
    size = path.stat().st_size
    if size % SPLAT_RECORD.itemsize:
        raise _error(path, f"a .splat file is a list of 32-byte records; {size} bytes is not a multiple of 32")
    records = np.fromfile(path, dtype=SPLAT_RECORD)
    scale = records["scale"].astype(np.float64)
    if (scale <= 0).any():
        bad = ~(scale > 0).all(1)
        raise _error(path, f"{int(bad.sum())} Gaussian(s) with a scale <= 0 (first: Gaussian {int(bad.argmax())})")
    rgba = records["rgba"].astype(np.float64)
    alpha = np.clip(rgba[:, 3], *OPACITY_BYTE_RANGE) / 255.0
    model = SplatModel(
        records["position"].astype(np.float32),
        ((records["rotation"].astype(np.float32) - 128.0) / 128.0),
        np.log(scale).astype(np.float32),
        np.log(alpha / (1.0 - alpha)).astype(np.float32),
        ((rgba[:, None, :3] / 255.0 - 0.5) / SH_C0).astype(np.float32),
    )
    return model.validate(str(path))


def write_splat(model: SplatModel, path: str | os.PathLike) -> None:
    """Write ``model`` as a ``.splat`` file (DC colour only: higher SH bands are dropped), atomically, in the
    model's order."""
    records = np.zeros(len(model), dtype=SPLAT_RECORD)
    records["position"] = model.means
    records["scale"] = np.exp(model.log_scales.astype(np.float64))
    rgb = SH_C0 * model.sh[:, 0].astype(np.float64) + 0.5
    alpha = 1.0 / (1.0 + np.exp(-model.opacities.astype(np.float64)))
    records["rgba"][:, :3] = np.floor(np.clip(rgb, 0, 1) * 255 + 0.5)
    records["rgba"][:, 3] = np.floor(alpha * 255 + 0.5)
    quats = model.quats.astype(np.float64)
    quats = quats / np.linalg.norm(quats, axis=1, keepdims=True)
    records["rotation"] = np.clip(np.floor(quats * 128 + 128.5), 0, 255)
    with atomic_path(path) as tmp:
        records.tofile(tmp)


def read_splats(path: str | os.PathLike) -> SplatModel:
    """The splat model of the file ``path``: a PLY (by its first bytes) or a ``.splat`` file (by its suffix);
    ``.spz``, ``.ksplat`` and compressed PLYs are refused by name, anything else is an error saying what is read."""
    path = Path(path)
    if not path.is_file():
        raise _error(path, "splat file not found")
    with open(path, "rb") as handle:
        magic = handle.read(4)
    suffix = path.suffix.lower()
    if suffix == ".spz" or magic[:2] == b"\x1f\x8b":
        raise _error(
            path, "a .spz file (Niantic's compressed splat format, gzip), which is not read; convert it to PLY"
        )
    if suffix == ".ksplat":
        raise _error(path, "a .ksplat file (mkkellogg's compressed splat format), which is not read; convert it to PLY")
    if magic.startswith(b"ply"):
        return read_ply(path)
    if suffix == ".splat":
        return read_splat(path)
    raise _error(path, "not a splat file: expected a PLY (INRIA layout) or a .splat file")


def write_splats(model: SplatModel, path: str | os.PathLike) -> None:
    """Write ``model`` by the suffix of ``path``: ``.splat``, else the INRIA PLY (float)."""
    if Path(path).suffix.lower() == ".splat":
        write_splat(model, path)
    else:
        write_ply(model, path)
