"""Mutation testing (mutmut 3) of the pure-Python modules whose bugs hide behind identities: edit specs, skinning,
cameras, metrics, mean value coordinates and the lift (against its fast tests on Kuhn-grid proxies). The numba
kernels are covered by their brute-force oracles instead.

For each module mutmut mutates a copy of the source in a temporary work folder (never the repo tree: the folder is
removed afterwards, also on Ctrl-C, unless ``--keep``) and runs that module's tests against every mutant.
Printed per module: mutants, killed, survived (including mutants no selected test reaches), timeout, equivalent
(listed in :data:`EQUIVALENT`, by function + original line → mutated line, each with its reason), mutants not run
before the time cap, the survival rate ``survived / (mutants − equivalent − not run)`` (target ≤ 10 %) and the
minutes; then the total and every surviving non-equivalent mutant as a diff. ``--max-minutes`` caps the whole run
(shared evenly by the modules still to run; a module stopped by the cap reports the mutants it checked).

Requires ``mutmut==3.8.1`` (the ``test`` extra); installs nothing. Not fork-safe tools are tamed with one thread.

Usage: ``python bench/mutation.py [--module NAME ...] [--max-minutes N] [--keep]`` (modules: the keys of
:data:`MODULES`; default all).
"""

from __future__ import annotations

import argparse
import difflib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
COPIED = ("nerfedit_plugin", "deformers", "tests", "configs")  # what the tests need in the work folder
MUTMUT_VERSION = "3.8.1"


@dataclass(frozen=True)
class Target:
    source: str  # the module mutated, relative to the repo root
    tests: tuple[str, ...]  # the tests run against its mutants (each mutant runs only those that reach it)


MODULES = {
    "spec": Target("nerfedit_plugin/edit/spec.py", ("tests/edit/test_spec.py",)),
    "skinning": Target("deformers/skeleton/skinning.py", ("tests/deformers/test_skinning.py",)),
    "cameras": Target("nerfedit_plugin/data/cameras.py", ("tests/data/test_cameras.py",)),
    "metrics": Target("nerfedit_plugin/training/metrics.py", ("tests/training/test_metrics.py",)),
    "mean_value": Target("deformers/cage/mean_value.py", ("tests/deformers/test_mean_value.py",)),
    # lift: the fast tests on Kuhn-grid proxies (tests/edit/test_lift.py builds pytetwild proxies: seconds each)
    "lift": Target("nerfedit_plugin/edit/lift.py", ("tests/edit/test_lift_mutants.py",)),
}
DEFAULT = list(MODULES)


@dataclass(frozen=True)
class Equivalent:
    """A mutant that cannot change behaviour: ``module`` key, function (``Class.method``), original line → mutated
    line (stripped source text; several changed lines joined with `` / ``), and why."""

    module: str
    function: str
    before: str
    after: str
    reason: str


_NORM = "feats.append(x / (x.pow(2).sum(1, keepdim=True).sqrt() + 1e-10))"
_SHIFT = "x = (image * 2 - 1 - torch.tensor(SHIFT).view(1, 3, 1, 1)) / torch.tensor(SCALE).view(1, 3, 1, 1)"
_ROT = "xyzw = Rotation.from_matrix(np.asarray(rot, dtype=np.float64).reshape(-1, 3, 3)).as_quat()"
_TRANS = "t = np.asarray(trans, dtype=np.float64).reshape(-1, 3)"
_BONES = "bones = np.concatenate([np.asarray(rot).reshape(-1, 9), np.asarray(trans).reshape(-1, 3)], axis=1)"
_LBS = "out = blend[9:] + blend[0:9:3] * x[0] + blend[1:9:3] * x[1] + blend[2:9:3] * x[2]"
_RESHAPE = "numpy treats every negative size in reshape as 'infer' (-2 acts as -1)"
_FROM_FLOAT = "the input is only read through float64 arithmetic (scipy's from_matrix / float64 products): same values"
_CPU = "no accelerator in this workplace: every device is the CPU (a GPU run has test_rays_on_cuda_match_cpu)"
_F64 = "the value reaches float64 arithmetic exactly (and the pose is cast to float32 at the end)"
_ARANGE_H = "torch.arange(cameras.height, device=device, dtype=torch.float32),"
_ARANGE_W = "torch.arange(cameras.width, device=device, dtype=torch.float32),"
_CAMS = "cam = torch.arange(len(cameras), device=device)[:, None, None]"
_INDEX = "cam = torch.as_tensor(index, device=device)"
_PIXELS = "pixels = torch.as_tensor(pixels, device=device).to(torch.float32)"
_TARGET = "target = torch.as_tensor(target, dtype=torch.float64, device=eye.device)"
_UP = "up = torch.broadcast_to(torch.as_tensor(up, dtype=torch.float64, device=eye.device), z.shape)"
_ZEROS = "c2w = torch.zeros(z.shape[:-1] + (4, 4), dtype=torch.float64, device=eye.device)"
_VALUE = "value = torch.as_tensor(getattr(self, name), dtype=torch.float32, device=device)"
_DEVICE = (
    ("generate_rays", "device = cameras.device", "cameras.device", "None"),
    ("generate_rays", _ARANGE_H, "device=device", "device=None"),
    ("generate_rays", _ARANGE_H, "device=device, ", ""),
    ("generate_rays", _ARANGE_W, "device=device", "device=None"),
    ("generate_rays", _ARANGE_W, "device=device, ", ""),
    ("generate_rays", _CAMS, "device=device", "device=None"),
    ("generate_rays", _CAMS, "device=device", ""),
    ("generate_rays", _INDEX, "device=device", "device=None"),
    ("generate_rays", _INDEX, "device=device", ""),
    ("generate_rays", _PIXELS, "device=device", "device=None"),
    ("generate_rays", _PIXELS, "device=device", ""),
    ("look_at", _TARGET, "device=eye.device", "device=None"),
    ("look_at", _TARGET, "device=eye.device", ""),
    ("look_at", _UP, "device=eye.device", "device=None"),
    ("look_at", _UP, "device=eye.device", ""),
    ("look_at", _ZEROS, "device=eye.device", "device=None"),
    ("look_at", _ZEROS, "device=eye.device", ""),
    ("Cameras.__post_init__", _VALUE, "device=device", "device=None"),
    ("Cameras.__post_init__", _VALUE, "device=device", ""),
    *(("Cameras.to", f"self.{f}.to(device),", "(device)", "(None)") for f in ("c2w", "fx", "fy", "cx", "cy")),
)
_LOOK_AT_DTYPE = (
    ("eye = torch.as_tensor(eye, dtype=torch.float64)", "dtype=torch.float64", "dtype=None"),
    ("eye = torch.as_tensor(eye, dtype=torch.float64)", "dtype=torch.float64", ""),
    (_TARGET, "dtype=torch.float64", "dtype=None"),
    (_TARGET, "dtype=torch.float64, ", ""),
    (_ZEROS, "dtype=torch.float64", "dtype=None"),
    (_ZEROS, "dtype=torch.float64, ", ""),
)
_PARALLEL = "parallel = torch.linalg.norm(torch.linalg.cross(up, z), dim=-1, keepdim=True) < 1e-6"
_FALLBACK = "fallback = torch.nn.functional.one_hot(z.abs().argmin(-1), 3).to(z)"
_PHI = "phi = np.arange(n) * math.pi * (3.0 - math.sqrt(5.0)) + np.random.default_rng(seed).uniform(0, 2 * math.pi)"
_STACK = "directions = np.stack([ring * np.cos(phi), ring * np.sin(phi), z], axis=-1)"
_CENTER = "center = np.asarray(center, dtype=np.float64)"
_INDICES = 'return Selection(kind, {"indices": np.unique(np.asarray(value, dtype=np.int64))}, key)'
_INT64 = "the values are Python ints already checked to fit int64, numpy's default integer on 64-bit Linux"
_EINSUM = "einsum reads upper-case subscripts like lower-case ones: the same contraction"
_ELEMENTS = "ArapSolver's default energy for tets is 'elements'"
_OPPOSITE = "opposite = np.stack([faces[:, [1, 2]], faces[:, [2, 0]], faces[:, [0, 1]]], axis=1).reshape(-1, 2)"
_SCATTER = "scatter = sp.csr_matrix((np.ones(3 * n), (faces.T.reshape(-1), np.arange(3 * n))), shape=(len(v), 3 * n))"
_OFFSETS = 'offsets=np.einsum("fi,fi->f", normals, v[faces[:, 0]]),'
_BARY = 'np.einsum("ki,ki->k", cage.normals[fi], np.cross(corners[:, (k + 1) % 3], corners[:, (k + 2) % 3]))'
_NEAR = "np.greater(sin2, np.sqrt(NEAR_LINE * (1.0 - NEAR_LINE)), out=self.near)"
_ON_EDGE = "on_edge = (cage.edges[:0, 0], cage.edges[:0, 0])"
_TAKES = (
    ("_Kernel._edges", 'np.take(dist, cage.edges[:, 0], axis=0, out=da, mode="clip")'),
    ("_Kernel._edges", 'np.take(dist, cage.edges[:, 1], axis=0, out=db, mode="clip")'),
    (
        "_Kernel._faces",
        'np.take(self.edge_q[q], self.opposite, axis=0, out=fq[q].reshape(3 * n_f, self.size), mode="clip")',
    ),
    (
        "_Kernel._faces",
        'np.take(self.dist, self.corners, axis=0, out=self.corner_d.reshape(3 * n_f, self.size), mode="clip")',
    ),
)
_TAKE = (
    "every index is in range (edges, corners and face edges index existing rows): mode 'raise' (None) takes the same"
)
_MV_RESHAPES = (
    ("CageGeometry.of", _OPPOSITE, "reshape(-1, 2)", "reshape(-2, 2)"),
    ("CageGeometry.of", _SCATTER, "faces.T.reshape(-1)", "faces.T.reshape(-2)"),
    (
        "_Kernel.__init__",
        "self.corners = np.ascontiguousarray(cage.faces.T).reshape(-1)  # corner k of face f = row kF + f",
        "reshape(-1)",
        "reshape(-2)",
    ),
    (
        "_Kernel.__init__",
        "self.opposite = np.ascontiguousarray(cage.face_edges.T).reshape(-1)",
        "reshape(-1)",
        "reshape(-2)",
    ),
    ("_Kernel._faces", "w = cage.scatter @ self.stacked.reshape(-1, self.size)", "reshape(-1,", "reshape(-2,"),
)
_MV_POINTS = "points = np.asarray(points, dtype=np.float64) - cage.origin"
_MV_FACES = "faces = np.asarray(faces, dtype=np.int64)"
_MV_NEAR = "self.near = np.empty((n_e, size), dtype=bool)"
_MV_POOL = "with ThreadPoolExecutor(max_workers=workers) as pool:  # numpy releases the GIL inside the kernels"
_TINY = "differs only for a signed volume of exactly ±1e-9 × the mean rest volume"
EQUIVALENT: tuple[Equivalent, ...] = (
    # metrics
    Equivalent("metrics", "psnr", 'return float("inf")', 'return float("INF")', "float() parses 'INF' as inf"),
    Equivalent(
        "metrics",
        "_features",
        _SHIFT,
        _SHIFT.replace("SHIFT).view(1, 3, 1, 1)", "SHIFT).view(3, 1, 1)"),
        "(3,1,1) broadcasts against the (1,3,H,W) image exactly as (1,3,1,1)",
    ),
    Equivalent(
        "metrics",
        "_features",
        _SHIFT,
        _SHIFT.replace("SCALE).view(1, 3, 1, 1)", "SCALE).view(3, 1, 1)"),
        "(3,1,1) broadcasts against the (1,3,H,W) image exactly as (1,3,1,1)",
    ),
    Equivalent(
        "metrics",
        "_features",
        _NORM,
        _NORM.replace("+ 1e-10", "- 1e-10"),
        "±1e-10 vanishes next to float32 feature norms (and 0/±eps = ±0 square alike)",
    ),
    Equivalent(
        "metrics",
        "_features",
        _NORM,
        _NORM.replace("keepdim=True", ""),
        "lpips passes one image: the (1,H,W) norm broadcasts like (1,1,H,W)",
    ),
    Equivalent(
        "metrics",
        "_features",
        _NORM,
        _NORM.replace("keepdim=True", "keepdim=False"),
        "lpips passes one image: the (1,H,W) norm broadcasts like (1,1,H,W)",
    ),
    # spec
    *(
        Equivalent("spec", "_parse_selection", _INDICES, _INDICES.replace("dtype=np.int64", b), _INT64)
        for b in ("dtype=None", "")
    ),
    Equivalent(
        "spec",
        "EditSpec.handle_targets",
        "owner = np.full(len(points), -1)",
        "owner = np.full(len(points), -2)",
        "any negative owner means 'no handle' (owner >= 0)",
    ),
    Equivalent(
        "spec",
        "EditSpec.handle_targets",
        "sel = handle.selection.indices(points, self.source)",
        "sel = handle.selection.indices(points, None)",
        "the same selection was resolved against the same points just above, so this call cannot raise",
    ),
    # cameras
    *(Equivalent("cameras", f, line, line.replace(a, b), _CPU) for f, line, a, b in _DEVICE),
    Equivalent("cameras", "generate_rays", 'indexing="ij",', "indexing=None,", "torch.meshgrid defaults to 'ij'"),
    Equivalent("cameras", "generate_rays", 'indexing="ij", / )', ")", "torch.meshgrid defaults to 'ij'"),
    Equivalent(
        "cameras",
        "generate_rays",
        "cam = cam[..., None, None] if cam.ndim else cam",
        "cam = cam[..., None, None] if (cam.ndim) or True else cam",
        "a 0-d camera index with two unit axes broadcasts to the same (H,W) rays",
    ),
    Equivalent(
        "cameras",
        "Cameras.__getitem__",
        "index = [index] if isinstance(index, int) else index",
        "index = [index] if (isinstance(index, int)) or True else index",
        "torch reads [idx] around a list or tensor index idx as idx itself",
    ),
    Equivalent(
        "cameras",
        "Cameras.downscale",
        "self.width // factor,",
        "self.width / factor,",
        "__post_init__ truncates with int(): int(w / k) == w // k for positive sizes",
    ),
    Equivalent(
        "cameras",
        "Cameras.downscale",
        "self.height // factor,",
        "self.height / factor,",
        "__post_init__ truncates with int(): int(h / k) == h // k for positive sizes",
    ),
    *(Equivalent("cameras", "look_at", line, line.replace(a, b), _F64) for line, a, b in _LOOK_AT_DTYPE),
    Equivalent(
        "cameras",
        "look_at",
        _PARALLEL,
        _PARALLEL.replace("< 1e-6", "<= 1e-6"),
        "differs only when |up × z| is exactly 1e-6",
    ),
    Equivalent(
        "cameras",
        "look_at",
        _FALLBACK,
        _FALLBACK.replace(".to(z)", ".to(None)"),
        "torch.where promotes the int64 one-hot with the float64 up vectors",
    ),
    Equivalent(
        "cameras",
        "sphere_poses",
        _PHI,
        _PHI.replace(") + np.random", ") - np.random"),
        "−φ₀ is as uniform on the circle as φ₀: the docs fix no particular draw per seed",
    ),
    Equivalent(
        "cameras",
        "sphere_poses",
        "ring = np.sqrt(np.clip(1.0 - z * z, 0.0, None))",
        "ring = np.sqrt(np.clip(1.0 - z * z, None, None))",
        "|z_k| < 1 for every k, so the clip never acts",
    ),
    Equivalent(
        "cameras",
        "sphere_poses",
        _STACK,
        _STACK.replace("axis=-1", "axis=+1"),
        "stacking 1-D arrays: axis 1 is the last axis",
    ),
    Equivalent("cameras", "sphere_poses", _CENTER, _CENTER.replace("dtype=np.float64", "dtype=None"), _F64),
    Equivalent("cameras", "sphere_poses", _CENTER, _CENTER.replace("dtype=np.float64", ""), _F64),
    # skinning
    Equivalent(
        "skinning",
        "dqs",
        "agree = real @ real.T >= 0.0  # agree[k, j]: bone j lies in bone k's hemisphere",
        "agree = real @ real.T > 0.0  # agree[k, j]: bone j lies in bone k's hemisphere",
        "differs only for exactly orthogonal real parts (a 180° relative turn), where both signs are equally near",
    ),
    Equivalent("skinning", "dual_quaternions", _ROT, _ROT.replace("dtype=np.float64", "dtype=None"), _FROM_FLOAT),
    Equivalent("skinning", "dual_quaternions", _ROT, _ROT.replace("dtype=np.float64", ""), _FROM_FLOAT),
    Equivalent("skinning", "dual_quaternions", _ROT, _ROT.replace("(-1, 3, 3)", "(-2, 3, 3)"), _RESHAPE),
    Equivalent("skinning", "dual_quaternions", _TRANS, _TRANS.replace("dtype=np.float64", "dtype=None"), _FROM_FLOAT),
    Equivalent("skinning", "dual_quaternions", _TRANS, _TRANS.replace("dtype=np.float64", ""), _FROM_FLOAT),
    Equivalent("skinning", "dual_quaternions", _TRANS, _TRANS.replace("(-1, 3)", "(-2, 3)"), _RESHAPE),
    Equivalent("skinning", "lbs", _BONES, _BONES.replace("(-1, 9)", "(-2, 9)"), _RESHAPE),
    Equivalent("skinning", "lbs", _BONES, _BONES.replace("(-1, 3)", "(-2, 3)"), _RESHAPE),
    Equivalent("skinning", "lbs", _LBS, _LBS.replace("[1:9:3]", "[1:10:3]"), "rows 1, 4, 7 either way (12 rows)"),
    Equivalent("skinning", "lbs", _LBS, _LBS.replace("[2:9:3]", "[2:10:3]"), "rows 2, 5, 8 either way (12 rows)"),
    Equivalent(
        "skinning",
        "Binding.create",
        'order = np.argsort(dominant, kind="stable")',
        'order = np.argsort(dominant, kind="STABLE")',
        "numpy reads the sort kind case-insensitively",
    ),
    Equivalent(
        "skinning",
        "Binding.create",
        "bounds = np.searchsorted(dominant[order], np.arange(weights.shape[1] + 1))",
        "bounds = np.searchsorted(dominant[order], np.arange(weights.shape[1] + 2))",
        "only bounds[0..J] are read; one more trailing bound changes nothing",
    ),  # lift
    Equivalent(
        "lift",
        "closest_point_displacements",
        'return np.einsum("mk,mkd->md", bary, (moved - rest.vertices)[tri])',
        'return np.einsum("MK,MKD->MD", bary, (moved - rest.vertices)[tri])',
        _EINSUM,
    ),
    Equivalent(
        "lift",
        "knn3_displacements",
        'return np.einsum("mk,mkd->md", weights, (moved - rest)[idx])',
        'return np.einsum("MK,MKD->MD", weights, (moved - rest)[idx])',
        _EINSUM,
    ),
    Equivalent(
        "lift",
        "knn3_displacements",
        "weights = 1.0 / np.maximum(dist, 1e-12)",
        "weights = 2.0 / np.maximum(dist, 1e-12)",
        "the common factor 2 (a power of two: exact) cancels in the normalisation",
    ),
    Equivalent("lift", "Lift.__init__", 'energy="elements",', "energy=None,", _ELEMENTS),
    Equivalent("lift", "Lift.__init__", 'energy="elements",', "", _ELEMENTS),
    *(
        Equivalent("lift", "Lift.__init__", line, line.replace('energy="elements", ', b), _ELEMENTS)
        for line in ('self.solver = ArapSolver(proxy.vertices, proxy.tets, energy="elements", fixed=fixed)',)
        for b in ("energy=None, ", "")
    ),
    Equivalent(
        "lift",
        "Lift.folds",
        "return int(np.count_nonzero(tet_signed_volumes(deformed, self.proxy.tets) <= tiny))",
        "return int(np.count_nonzero(tet_signed_volumes(deformed, self.proxy.tets) < tiny))",
        _TINY,
    ),
    Equivalent(
        "lift",
        "Lift.report",
        "inverted_tets=int(np.count_nonzero(volumes < -tiny)),",
        "inverted_tets=int(np.count_nonzero(volumes <= -tiny)),",
        _TINY,
    ),
    Equivalent(
        "lift",
        "Lift.report",
        "degenerate_tets=int(np.count_nonzero(np.abs(volumes) <= tiny)),",
        "degenerate_tets=int(np.count_nonzero(np.abs(volumes) < tiny)),",
        _TINY,
    ),
    # mean_value
    Equivalent(
        "mean_value",
        "mean_value_coordinates",
        "chunk_size: int = 64,",
        "chunk_size: int = 65,",
        "each point's column is computed on its own, whatever chunk it falls in",
    ),
    Equivalent(
        "mean_value",
        "mean_value_coordinates",
        "workers: int = 2,",
        "workers: int = 3,",
        "threads only share out the chunks: each column is computed alike",
    ),
    *(
        Equivalent(
            "mean_value",
            "mean_value_coordinates",
            _MV_POINTS,
            _MV_POINTS.replace("dtype=np.float64", b),
            "subtracting the float64 cage origin promotes float32 or integer points exactly",
        )
        for b in ("dtype=None", "")
    ),
    Equivalent(
        "mean_value",
        "mean_value_coordinates",
        "starts = range(0, len(points), chunk_size)",
        "starts = range(0, len(points), )",
        "chunks then start at every point and overlap: columns are recomputed with the same values (only slower)",
    ),
    Equivalent(
        "mean_value",
        "mean_value_coordinates",
        "workers = max(1, min(workers, len(starts)))",
        "workers = max(2, min(workers, len(starts)))",
        "a second worker with no chunk left (starts[1::2] empty) computes nothing",
    ),
    Equivalent(
        "mean_value",
        "mean_value_coordinates",
        _MV_POOL,
        _MV_POOL.replace("max_workers=workers", "max_workers=None"),
        "the pool is given exactly `workers` tasks: further threads stay idle",
    ),
    *(
        Equivalent(
            "mean_value",
            "CageGeometry.of",
            _MV_FACES,
            _MV_FACES.replace("dtype=np.int64", b),
            "faces are only used as indices: any integer dtype indexes alike",
        )
        for b in ("dtype=None", "")
    ),
    *(Equivalent("mean_value", f, line, line.replace(a, b), _RESHAPE) for f, line, a, b in _MV_RESHAPES),
    Equivalent(
        "mean_value",
        "CageGeometry.of",
        _OPPOSITE,
        _OPPOSITE.replace("axis=1)", "axis=2)"),
        "the (F,2,3) stack read in pairs gives each face's corner pairs (1,2), (0,2), (0,1): the same sorted edges",
    ),
    Equivalent(
        "mean_value",
        "CageGeometry.of",
        "edges, inverse = np.unique(np.sort(opposite, axis=1), axis=0, return_inverse=True)",
        "edges, inverse = np.unique(np.sort(opposite, ), axis=0, return_inverse=True)",
        "np.sort sorts along the last axis by default: axis 1 of the (3F,2) pairs",
    ),
    Equivalent(
        "mean_value",
        "CageGeometry.of",
        "normals = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])",
        "normals = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 1]])",
        "(v1 - v0) x (v2 - v1) = (v1 - v0) x (v2 - v0): the same area normal (up to rounding)",
    ),
    Equivalent("mean_value", "CageGeometry.of", _OFFSETS, _OFFSETS.replace("fi,fi->f", "FI,FI->F"), _EINSUM),
    Equivalent(
        "mean_value",
        "CageGeometry.of",
        _OFFSETS,
        _OFFSETS.replace("faces[:, 0]", "faces[:, 1]"),
        "every corner lies in its face's plane: n . v1 = n . v0 (up to rounding)",
    ),
    Equivalent(
        "mean_value",
        "_Kernel.__call__",
        "if n < self.size:  # last chunk: pad with copies of its last point",
        "if n <= self.size:  # last chunk: pad with copies of its last point",
        "a full chunk is padded with zero copies: the same array",
    ),
    *(
        Equivalent(
            "mean_value",
            "_Kernel.__init__",
            _MV_NEAR,
            _MV_NEAR.replace("dtype=bool", b),
            "float 0/1 flags, read only through logical_not(out=) and flatnonzero, select the same pairs",
        )
        for b in ("dtype=None", "")
    ),
    Equivalent(
        "mean_value",
        "_Kernel.__init__",
        "self.p = np.empty((3, n_f, size))",
        "self.p = np.empty((4, n_f, size))",
        "the extra row is never read",
    ),
    Equivalent("mean_value", "_Kernel._degenerate", _BARY, _BARY.replace("ki,ki->k", "KI,KI->K"), _EINSUM),
    Equivalent(
        "mean_value",
        "_Kernel._degenerate",
        "inside = (bary >= -BARY_EPS).all(1)",
        "inside = (bary > -BARY_EPS).all(1)",
        "differs only for a barycentric of exactly -BARY_EPS",
    ),
    Equivalent(
        "mean_value",
        "_Kernel._degenerate",
        "at_vertex = self.dist <= VERTEX_EPS * cage.scale",
        "at_vertex = self.dist < VERTEX_EPS * cage.scale",
        "differs only at a distance of exactly VERTEX_EPS x scale",
    ),
    Equivalent(
        "mean_value",
        "_Kernel._edges",
        "close = behind[line_dist <= EDGE_EPS * cage.scale]  # on the segment",
        "close = behind[line_dist < EDGE_EPS * cage.scale]  # on the segment",
        "differs only at a distance of exactly EDGE_EPS x scale",
    ),
    *(
        Equivalent("mean_value", f, line, line.replace(a, b), _TAKE)
        for f, line in _TAKES
        for a, b in ((', mode="clip")', ", mode=None)"), (', mode="clip")', ", )"))
    ),
    *(
        Equivalent(
            "mean_value",
            "_Kernel._edges",
            _NEAR,
            _NEAR.replace("NEAR_LINE * (1.0 - NEAR_LINE)", b),
            "moves where θ is recomputed from unit vectors (the accurate path, kept narrow for speed): a 1e-6 relative "
            "shift changes nothing, a √2 one the coordinates by ≤ 4e-12 (measured), no on-edge decision (sin θ ≈ 1e-8)",
        )
        for b in ("NEAR_LINE / (1.0 - NEAR_LINE)", "NEAR_LINE * (1.0 + NEAR_LINE)", "NEAR_LINE * (2.0 - NEAR_LINE)")
    ),
    *(
        Equivalent(
            "mean_value",
            "_Kernel._edges",
            _ON_EDGE,
            b,
            "with no near pair the (edge, point) arrays stay without points: no column is overwritten",
        )
        for b in (
            "on_edge = (cage.edges[:1, 0], cage.edges[:0, 0])",
            "on_edge = (cage.edges[:0, 1], cage.edges[:0, 0])",
            "on_edge = (cage.edges[:0, 0], cage.edges[:1, 0])",
            "on_edge = (cage.edges[:0, 0], cage.edges[:0, 1])",
        )
    ),
    Equivalent(
        "mean_value",
        "_Kernel._edges",
        "behind = np.flatnonzero(cos_half < sin_half)  # θ ≈ π: x beside the segment, between its ends",
        "behind = np.flatnonzero(cos_half <= sin_half)  # θ ≈ π: x beside the segment, between its ends",
        "near pairs have θ within ~2e-3 of 0 or π: θ = 90° (cos θ/2 = sin θ/2) never occurs among them",
    ),
)


@dataclass
class Result:
    name: str
    counts: dict
    survivors: list  # (mutant name, diff) of the non-equivalent survivors
    equivalent: list  # matched EQUIVALENT entries
    minutes: float
    capped: bool

    @property
    def checked(self) -> int:
        return sum(self.counts.values()) - self.counts["not run"]

    @property
    def rate(self) -> float:
        denominator = self.checked - self.counts["equivalent"]
        return self.counts["survived"] / denominator if denominator else float("nan")


def mutmut_command() -> list[str]:
    """The ``mutmut`` console script of this interpreter's environment (mutmut must be installed)."""
    try:
        from importlib.metadata import PackageNotFoundError, version

        found = version("mutmut")
    except PackageNotFoundError:
        sys.exit(f"mutmut is not installed: pip install mutmut=={MUTMUT_VERSION} (the test extra)")
    if found != MUTMUT_VERSION:
        print(f"warning: mutmut {found} installed, this script is written for {MUTMUT_VERSION}", file=sys.stderr)
    script = Path(sys.executable).parent / "mutmut"
    return [str(script)] if script.exists() else [sys.executable, "-m", "mutmut"]


def prepare(work: Path, target: Target) -> None:
    """Copy the packages, tests and configs into ``work`` and configure mutmut there."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", ".hypothesis", "mutants")
    for name in COPIED:
        shutil.copytree(ROOT / name, work / name, ignore=ignore)
    mutmut = {
        "source_paths": ["nerfedit_plugin", "deformers"],
        "only_mutate": [target.source],
        "pytest_add_cli_args_test_selection": list(target.tests),
        "pytest_add_cli_args": ["-p", "no:cacheprovider", "-W", "ignore::DeprecationWarning"],
        "use_git_change_detection": False,
        "timeout_multiplier": 10.0,
    }
    lines = [f"{key} = {json.dumps(value)}" for key, value in mutmut.items()]
    text = (ROOT / "pyproject.toml").read_text() + "\n[tool.mutmut]\n" + "\n".join(lines) + "\n"
    (work / "pyproject.toml").write_text(text)


def run_mutmut(work: Path, seconds: float) -> bool:
    """Run mutmut in ``work`` with one worker for at most ``seconds``; True if the cap stopped it."""
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
        env[var] = "1"  # fork-safe, and the machine is shared
    env.pop("PYTHONPATH", None)
    with open(work / "mutmut.log", "w") as log:
        proc = subprocess.Popen(
            mutmut_command() + ["run", "--max-children", "1"],
            cwd=work,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # Ctrl-C reaches this script only: it stops the group itself
        )
        try:
            proc.wait(timeout=max(seconds, 1.0))
            capped = False
        except subprocess.TimeoutExpired:
            capped = True
            stop(proc, signal.SIGINT)  # mutmut saves the results it has on SIGINT
        except BaseException:
            stop(proc, signal.SIGKILL)
            raise
    if not capped and proc.returncode != 0:
        tail = (work / "mutmut.log").read_text(errors="replace")[-3000:]
        raise RuntimeError(f"mutmut failed (exit {proc.returncode}) in {work}:\n{tail}")
    return capped


def stop(proc: subprocess.Popen, sig: int) -> None:
    try:
        os.killpg(proc.pid, sig)
        proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    except ProcessLookupError:
        pass


def function_of(mutant: str, target: Target) -> str:
    """``nerfedit_plugin.edit.spec.xǁSelectionǁindices__mutmut_3`` → ``Selection.indices``."""
    module = target.source[: -len(".py")].replace("/", ".") + "."
    name = mutant[len(module) :] if mutant.startswith(module) else mutant
    name = name.rsplit("__mutmut_", 1)[0]
    if name.startswith("xǁ"):
        return ".".join(name[2:].split("ǁ"))
    return name[2:] if name.startswith("x_") else name


def changed_lines(diff: str) -> tuple[str, str]:
    """The stripped removed and added lines of a unified diff, each joined with `` / ``."""
    body = [line for line in diff.splitlines() if not line.startswith(("---", "+++", "@@"))]
    removed = " / ".join(line[1:].strip() for line in body if line.startswith("-"))
    added = " / ".join(line[1:].strip() for line in body if line.startswith("+"))
    return removed, added


def collect(name: str, target: Target, work: Path, minutes: float, capped: bool) -> Result:
    import libcst
    from mutmut.mutation.diff_apply import read_mutant_function, read_original_function
    from mutmut.stats import status_by_exit_code

    meta = json.loads((work / "mutants" / (target.source + ".meta")).read_text())
    module = libcst.parse_module((work / "mutants" / target.source).read_text())  # once: the file is large

    def diff_of(mutant: str) -> str:
        functions = read_original_function(module, mutant), read_mutant_function(module, mutant)
        before, after = (libcst.Module([f]).code.strip().split("\n") for f in functions)
        return "\n".join(difflib.unified_diff(before, after, target.source, target.source, lineterm=""))

    counts = dict.fromkeys(("killed", "survived", "timeout", "other", "equivalent", "not run"), 0)
    survivors, equivalent = [], []
    for mutant, code in sorted(meta["exit_code_by_key"].items(), key=lambda item: mutant_order(item[0])):
        status = status_by_exit_code[code]
        if status in ("killed", "caught by type check"):
            counts["killed"] += 1
        elif status == "timeout":
            counts["timeout"] += 1
        elif status in ("not checked", "check was interrupted by user"):
            counts["not run"] += 1
        elif status in ("survived", "no tests"):
            diff = diff_of(mutant)
            function, (before, after) = function_of(mutant, target), changed_lines(diff)
            match = next(
                (e for e in EQUIVALENT if (e.module, e.function, e.before, e.after) == (name, function, before, after)),
                None,
            )
            if match is not None:
                counts["equivalent"] += 1
                equivalent.append(match)
            else:
                counts["survived"] += 1
                survivors.append((mutant, diff))
        else:  # suspicious, segfault
            counts["other"] += 1
    return Result(name, counts, survivors, equivalent, minutes, capped)


def mutant_order(mutant: str) -> tuple[str, int]:
    base, _, number = mutant.rpartition("__mutmut_")
    return base, int(number) if number.isdigit() else 0


def run_module(name: str, seconds: float, keep: bool) -> Result:
    target = MODULES[name]
    work = Path(tempfile.mkdtemp(prefix=f"nerfedit-mutation-{name}-"))
    start = time.perf_counter()
    try:
        prepare(work, target)
        capped = run_mutmut(work, seconds)
        return collect(name, target, work, (time.perf_counter() - start) / 60.0, capped)
    finally:
        if keep:
            print(f"  work folder kept: {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)


def report(results: list[Result]) -> None:
    header = (
        f"{'module':<11} {'mutants':>7} {'killed':>6} {'survived':>8} {'timeout':>7} {'other':>5} {'equiv':>5} "
        f"{'not run':>7} {'survival':>8} {'minutes':>7}"
    )
    print("\n" + header)
    total = dict.fromkeys(results[0].counts, 0) if results else {}
    for r in results:
        c = r.counts
        for key in total:
            total[key] += c[key]
        mark = " (capped)" if r.capped else ""
        print(
            f"{r.name:<11} {sum(c.values()):>7} {c['killed']:>6} {c['survived']:>8} {c['timeout']:>7} "
            f"{c['other']:>5} {c['equivalent']:>5} {c['not run']:>7} {r.rate:>8.1%} {r.minutes:>7.1f}{mark}"
        )
    if total:
        checked = sum(total.values()) - total["not run"] - total["equivalent"]
        rate = total["survived"] / checked if checked else float("nan")
        print(
            f"{'total':<11} {sum(total.values()):>7} {total['killed']:>6} {total['survived']:>8} "
            f"{total['timeout']:>7} {total['other']:>5} {total['equivalent']:>5} {total['not run']:>7} {rate:>8.1%} "
            f"{sum(r.minutes for r in results):>7.1f}"
        )
    for r in results:
        for mutant, diff in r.survivors:
            print(f"\nsurvived: {mutant}\n{diff}")
    used = {(e.module, e.function, e.before, e.after) for r in results for e in r.equivalent}
    ran = {r.name for r in results if not r.capped}
    for e in EQUIVALENT:
        if e.module in ran and (e.module, e.function, e.before, e.after) not in used:
            print(
                f"\nwarning: equivalent entry matched no surviving mutant (stale?): {e.module} {e.function}: {e.before}"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--module", action="append", choices=sorted(MODULES), help="module to test (repeatable)")
    parser.add_argument("--max-minutes", type=float, default=60.0, help="cap on the whole run (default 60)")
    parser.add_argument("--keep", action="store_true", help="keep the work folders (for `mutmut show` there)")
    args = parser.parse_args()
    names = args.module or DEFAULT
    mutmut_command()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # like Ctrl-C: stop mutmut, remove the work folder
    deadline = time.monotonic() + 60.0 * args.max_minutes
    results = []
    for i, name in enumerate(names):
        share = (deadline - time.monotonic()) / (len(names) - i)
        print(f"{name}: {MODULES[name].source} against {' '.join(MODULES[name].tests)} (cap {share / 60:.1f} min)")
        results.append(run_module(name, share, args.keep))
    report(results)


if __name__ == "__main__":
    main()
