"""Background layers: a ground plane and a far sphere, each one surface with a 2D texture, for what the background
grid cannot resolve — a floor that runs to the horizon, and surroundings far away.

The background grid (:mod:`nerfedit_plugin.fields.background`) is dense in contracted space, so its cells grow with
the square of the distance from the foreground box: a checker floor a few box sizes away, or a textured wall far
off, falls in cells wider than its pattern, and training fills the space in front of the cameras with haze to
explain what the cells cannot hold. A layer is a surface traced exactly instead: every ray gets one sample where it
crosses it — the plane ``u · x = h`` (``u`` the world's up direction) on the way down, outside the foreground box;
the sphere ``|x − c| = R`` (``c`` the box centre) from inside — with opacity ``α = 1 − exp(−softplus(g₀))`` and
colour ``sigmoid(g₁..₃)`` read from a :class:`Texture` at the crossing: on the plane, the in-plane offset from ``c``
in units of :data:`GROUND_EXTENT` box half sides, contracted (L∞, as the 3D contraction) into ``[-2,2]²``; on the
sphere, the octahedral map of the direction from ``c``.

Where the layers are is fitted before training (:func:`fit_ground`, :func:`fit_far_sphere`) by a sweep, as
plane-sweep stereo does: for each candidate height (radius), the training pixels are traced to the candidate surface
and binned on it, and the candidate whose bins agree best in colour wins. A sweep whose best candidate does not stand
out (no floor in the images, a world without an up direction) leaves its layer off.

Once placed, the layers also say where the foreground box is empty (:func:`free_depths`, a photometric visual hull):
a pixel whose colour the other views agree on at the point where its ray meets the plane or the sphere (inside the
box too) sees that point, so its ray is empty up to it.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from nerfedit_plugin.data.cameras import generate_rays

GROUND_EXTENT = 4.0
"""The ground texture's uncontracted square: this many foreground-box half sides around the box centre."""
COARSEST = 32
"""Cells per side of a texture's coarsest level; each further level doubles it."""
SWEEP_RAYS = 200_000
"""Training pixels traced per sweep candidate."""
SWEEP_CANDIDATES = 81
"""Candidates of a sweep's first pass (a second pass of 21 refines around the best)."""
DISTINCT = 0.5
"""A sweep's best colour variance must be below this share of the median over the candidates for its layer to be
used."""
AGREE = 0.05
""":func:`free_depths`: a pixel sees a layer when no colour channel differs by more than this from the median of the
other views at its crossing ..."""
AGREE_VIEWS = 3
"""... and at least this many other views see the crossing."""


class Texture(torch.nn.Module):
    """``channels`` values over ``[-2,2]²``: the sum of bilinear levels of ``COARSEST``, 2·``COARSEST``, … ``size``
    cells per side (coarse levels fill in what few rays see, fine ones add detail); starts at the constant ``init
    (channels,)``."""

    def __init__(self, size: int, channels: int, init: torch.Tensor) -> None:
        super().__init__()
        self.sizes = [COARSEST << k for k in range(max(1, int(math.log2(size / COARSEST)) + 1))]
        tables = (torch.nn.Parameter(torch.zeros((n + 1) ** 2, channels)) for n in self.sizes)
        self.levels = torch.nn.ParameterList(tables)
        with torch.no_grad():
            self.levels[0] += torch.as_tensor(init, dtype=torch.float32)

    def forward(self, uv: torch.Tensor) -> torch.Tensor:
        """``uv (M,2)`` in ``[-2,2]²`` (clamped) → ``(M, channels)``."""
        return sum(self._level(uv, n, table) for n, table in zip(self.sizes, self.levels))

    @staticmethod
    def _level(uv: torch.Tensor, n: int, table: torch.Tensor) -> torch.Tensor:
        x = ((uv + 2.0) * (n / 4.0)).clamp(0.0, float(n))
        cell = x.detach().floor().clamp_max(n - 1)
        f = x - cell
        row = cell[:, 0].long() * (n + 1) + cell[:, 1].long()
        rows = torch.stack([row, row + 1, row + n + 1, row + n + 2], 1)
        g, h = 1.0 - f, f
        weights = torch.stack([g[:, 0] * g[:, 1], g[:, 0] * h[:, 1], h[:, 0] * g[:, 1], h[:, 0] * h[:, 1]], 1)
        return torch.bmm(weights[:, None], F.embedding(rows, table))[:, 0]


def contract2(q: torch.Tensor) -> torch.Tensor:
    """``(M,2)`` → ``[-2,2]²``: identity in the unit square, ``(2 − 1/n) q/n`` outside (``n = ‖q‖∞``)."""
    n = q.abs().amax(-1, keepdim=True).clamp_min(1.0)
    return (2.0 - 1.0 / n) * q / n


def octahedral(directions: torch.Tensor) -> torch.Tensor:
    """Unit ``directions (M,3)`` → ``[-1,1]²``, the octahedral map (upper hemisphere inside the diamond, the lower one
    folded into the corners): one to one, equal-area within a factor of two, continuous except across the square's
    edges (where the fold meets itself mirrored, below the horizon)."""
    a = directions / directions.abs().sum(-1, keepdim=True)
    folded = (1.0 - a[:, [1, 0]].abs()) * torch.where(a[:, :2] >= 0, 1.0, -1.0)
    return torch.where(a[:, 2:3] >= 0, a[:, :2], folded)


def plane_axes(up: torch.Tensor) -> torch.Tensor:
    """Unit ``up (3,)`` → ``(2,3)``: two orthonormal directions spanning the plane normal to it."""
    first = F.normalize(torch.linalg.cross(up, torch.eye(3, device=up.device)[int(up.abs().argmin())]), dim=0)
    return torch.stack([first, torch.linalg.cross(up, first)])


class GroundLayer(torch.nn.Module):
    """The plane ``up · x = height`` outside ``box (2,3)`` (module docstring); off until :func:`fit_ground` finds
    it (``active``)."""

    def __init__(self, box: torch.Tensor, size: int) -> None:
        super().__init__()
        self.register_buffer("box", box.clone())
        self.register_buffer("up", torch.tensor([0.0, 0.0, 1.0]))
        self.register_buffer("height", torch.tensor(0.0))
        self.register_buffer("active", torch.tensor(False))
        self.texture = Texture(size, 4, torch.tensor([4.0, 0.0, 0.0, 0.0]))

    def plane_distance(self, origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        """Rays ``(R,3)`` → distance along each to the plane ``(R,)``, ``inf`` unless it meets it ahead going down
        (the whole plane, the box's part too; whether or not the layer is active)."""
        down = directions @ self.up
        t = (self.height - origins @ self.up) / torch.where(down < -1e-6, down, torch.full_like(down, -1e-6))
        return torch.where((down < -1e-6) & (t > 0), t, torch.inf)

    def crossing(self, origins: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Rays ``(R,3)`` → distance to the plane ``(R,)`` and whether it counts ``(R,)`` bool (ahead, downwards,
        outside the box, the layer active)."""
        t = self.plane_distance(origins, directions)
        point = origins + t.nan_to_num(posinf=0.0)[:, None] * directions
        inside = ((point >= self.box[0]) & (point <= self.box[1])).all(-1)
        return t, t.isfinite() & ~inside & self.active

    def query(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Points on the plane ``(M,3)`` → ``(optical thickness (M,), rgb (M,3))``."""
        centre = (self.box[0] + self.box[1]) / 2
        half = float((self.box[1] - self.box[0]).mean()) / 2
        values = self.texture(contract2((points - centre) @ plane_axes(self.up).T / (GROUND_EXTENT * half)))
        return F.softplus(values[:, 0]), torch.sigmoid(values[:, 1:])


class FarSphereLayer(torch.nn.Module):
    """The sphere of ``radius`` about the centre of ``box (2,3)`` (module docstring), opaque; off until
    :func:`fit_far_sphere` finds it (``active``)."""

    def __init__(self, box: torch.Tensor, size: int) -> None:
        super().__init__()
        self.register_buffer("centre", (box[0] + box[1]) / 2)
        self.register_buffer("radius", torch.tensor(1.0))
        self.register_buffer("active", torch.tensor(False))
        self.texture = Texture(size, 3, torch.zeros(3))

    def crossing(self, origins: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Rays ``(R,3)`` from inside → distance to the sphere ``(R,)`` and whether it counts ``(R,)`` bool."""
        offset = origins - self.centre
        b = (offset * directions).sum(-1)
        c = (offset * offset).sum(-1) - self.radius**2
        return -b + torch.sqrt((b * b - c).clamp_min(0.0)), (c < 0) & self.active

    def query(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Points on the sphere ``(M,3)`` → ``(optical thickness (M,): opaque, rgb (M,3))``."""
        direction = F.normalize(points - self.centre, dim=-1)
        rgb = torch.sigmoid(self.texture(2.0 * octahedral(direction)))
        return torch.full_like(rgb[:, 0], 30.0), rgb


def _on_layer_device(distance, buffer: torch.Tensor, origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
    """``distance(origins, directions)`` of a layer evaluated on the device of its ``buffer``, back on the CPU."""
    return distance(origins.to(buffer.device), directions.to(buffer.device)).cpu()


def _pixels(dataset, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """:data:`SWEEP_RAYS` random covered training pixels (alpha ≥ 0.5: a transparent pixel sees no layer): origins,
    directions, colours ``(P,3)`` and views ``(P,)``."""
    origins, directions = (r.reshape(-1, 3).cpu() for r in generate_rays(dataset.cameras.to("cpu")))
    pixels = torch.arange(len(origins))
    if dataset.alpha is not None:
        pixels = torch.nonzero(dataset.alpha.reshape(-1).cpu() >= 0.5).squeeze(1)
    generator = torch.Generator().manual_seed(seed)
    pick = pixels[torch.randint(0, len(pixels), (SWEEP_RAYS,), generator=generator)] if len(pixels) else pixels
    views = pick // (len(origins) // len(dataset.cameras))
    return origins[pick], directions[pick], dataset.images.reshape(-1, 3).cpu()[pick], views


def _spread(keys: torch.Tensor, views: torch.Tensor, colours: torch.Tensor) -> float:
    """How much the views disagree on the colour of the bins ``keys (P,)`` int64: per bin, the spread of its views'
    mean colours about the bin's mean, weighted by pixels and pooled over the bins two views or more see (inf if
    none). Pixels of one view are not compared with each other: neighbours in an image agree on a smooth texture
    whatever the candidate."""
    pairs, pair_of, pair_size = torch.unique(keys * 4096 + views, return_inverse=True, return_counts=True)
    means = torch.zeros(len(pairs), 3).index_add_(0, pair_of, colours) / pair_size[:, None]
    bins, bin_of, bin_views = torch.unique(pairs // 4096, return_inverse=True, return_counts=True)
    weight = pair_size.to(colours.dtype)
    total = torch.zeros(len(bins)).index_add_(0, bin_of, weight)
    centre = torch.zeros(len(bins), 3).index_add_(0, bin_of, means * weight[:, None]) / total[:, None]
    shared = bin_views[bin_of] >= 2
    spread = ((means - centre[bin_of]) ** 2).sum(-1) * weight
    count = float(weight[shared].sum())
    return float(spread[shared].sum()) / count if count else math.inf


def _sweep(candidates: torch.Tensor, score) -> tuple[float, float, float]:
    """Best candidate of two passes (all ``candidates``, then 21 around the best): ``(value, its score, the median
    score of the first pass)``."""
    scores = [score(float(v)) for v in candidates]
    best = int(torch.tensor(scores).argmin())
    step = float(candidates[1] - candidates[0]) if len(candidates) > 1 else 0.0
    finer = torch.linspace(float(candidates[best]) - step, float(candidates[best]) + step, 21)
    fine = [score(float(v)) for v in finer]
    k = int(torch.tensor(fine).argmin())
    median = float(torch.tensor(scores).median())
    if fine[k] < scores[best]:
        return float(finer[k]), fine[k], median
    return float(candidates[best]), scores[best], median


def fit_ground(layer: GroundLayer, dataset, up: tuple[float, float, float] | None, seed: int = 0) -> dict:
    """Set ``layer``'s plane from the training images (module docstring): heights from 3 box half sides below the
    box centre to one above; bins of 1/24 half side on the plane, within 6 half sides of the centre. Returns what the
    sweep found (``height``, ``variance``, ``median``, ``active``)."""
    if up is None:
        layer.active.fill_(False)
        return {"active": False, "reason": "no up direction"}
    box = layer.box.cpu()
    centre, half = box.mean(0), float((box[1] - box[0]).mean()) / 2
    axis = torch.tensor(up, dtype=torch.float32)
    origins, directions, colours, views = _pixels(dataset, seed)
    down = directions @ axis < -1e-3
    origins, directions, colours, views = origins[down], directions[down], colours[down], views[down]

    def score(height: float) -> float:
        t = (height - origins @ axis) / (directions @ axis)
        point = origins + t[:, None] * directions
        keep = (t > 0) & ~((point >= box[0]) & (point <= box[1])).all(-1) & ((point - centre).abs().amax(-1) < 6 * half)
        cells = torch.floor((point[keep] - centre) @ axes.T * (24.0 / half)).long() + 200  # within 6 · 24 of 0
        return _spread(cells[:, 0] * 400 + cells[:, 1], views[keep], colours[keep])

    axes = plane_axes(axis)
    level = float(centre @ axis)
    height, variance, median = _sweep(torch.linspace(level - 3 * half, level + half, SWEEP_CANDIDATES), score)
    active = variance < DISTINCT * median
    layer.up.copy_(axis)
    layer.height.fill_(height)
    layer.active.fill_(active)
    return {"active": active, "height": height, "variance": variance, "median": median}


def fit_far_sphere(layer: FarSphereLayer, dataset, ground: GroundLayer | None = None, seed: int = 0) -> dict:
    """Set ``layer``'s radius from the training images (module docstring): radii from 1.5 to 40 times the farthest
    camera's distance from the centre (log-spaced), pixels binned by the octahedral map of their crossing's direction
    (bins two pixels wide), leaving out the pixels whose rays meet the active ``ground`` plane first. Returns what the
    sweep found."""
    origins, directions, colours, views = _pixels(dataset, seed + 1)
    centre = layer.centre.cpu()
    ground_at = torch.full((len(origins),), math.inf)  # where a ray meets the active ground plane, going down
    if ground is not None and bool(ground.active):
        ground_at = _on_layer_device(ground.plane_distance, ground.up, origins, directions)
    offset = origins - centre
    reach = float(offset.norm(dim=-1).max())
    b = (offset * directions).sum(-1)
    bins = max(16, round(1.1 * float(dataset.cameras.fx.median())))  # bins two pixels wide (1 uv unit ≈ 1.1 rad)

    def score(radius: float) -> float:
        t = -b + torch.sqrt((b * b - (offset * offset).sum(-1) + radius**2).clamp_min(0.0))
        sky = t < ground_at  # the ray meets the sphere before the ground
        point = offset[sky] + t[sky, None] * directions[sky]
        cells = torch.floor((octahedral(F.normalize(point, dim=-1)) + 1.0) * bins / 2).long()
        return _spread(cells[:, 0] * (bins + 1) + cells[:, 1], views[sky], colours[sky])

    candidates = torch.exp(torch.linspace(math.log(1.5 * reach), math.log(40 * reach), 60))
    radius, variance, median = _sweep(candidates, score)
    active = variance < DISTINCT * median
    layer.radius.fill_(radius)
    layer.active.fill_(active)
    return {"active": active, "radius": radius, "variance": variance, "median": median}


@torch.no_grad()
def free_depths(ground: GroundLayer | None, far: FarSphereLayer | None, dataset) -> torch.Tensor | None:
    """How far each training pixel's ray is empty ``(C,H,W)`` (camera-space depth; module docstring): up to where it
    first meets the active ``ground`` plane (going down, inside the foreground box too) or the active ``far`` sphere,
    when the pixel's colour is within :data:`AGREE` of the median colour of the other views there (bilinear, at least
    :data:`AGREE_VIEWS` views whose frame holds the point, occlusion not tested), else 0. None when no layer is
    active. A pixel that sees an object in front of the layer disagrees with the views that see the layer there;
    where most views see something else, the median is not the pixel's layer colour either, so the test errs towards
    0 (not known empty). One view at a time, in chunks of ~2²² colour lookups."""
    if not any(layer is not None and bool(layer.active) for layer in (ground, far)):
        return None
    cameras, images = dataset.cameras.to("cpu"), dataset.images.cpu()
    count, height, width = len(cameras), cameras.height, cameras.width
    world_to_camera = torch.linalg.inv(cameras.c2w)
    planes = images.permute(0, 3, 1, 2)
    chunk = max(1024, (1 << 22) // count)
    free = torch.zeros(count, height * width)
    for view in range(count):
        origins, directions = (r.reshape(-1, 3) for r in generate_rays(cameras, view))
        t = torch.full((len(origins),), math.inf)
        if ground is not None and bool(ground.active):
            t = _on_layer_device(ground.plane_distance, ground.up, origins, directions)
        if far is not None and bool(far.active):
            t = torch.minimum(t, _on_layer_device(lambda o, d: far.crossing(o, d)[0], far.centre, origins, directions))
        for start in range(0, len(origins), chunk):
            rows = slice(start, start + chunk)
            points = origins[rows] + t[rows, None] * directions[rows]
            colours = torch.full((len(points), count, 3), math.nan)
            for i in range(count):
                local = points @ world_to_camera[i, :3, :3].T + world_to_camera[i, :3, 3]  # OpenGL: looking down −z
                x = cameras.fx[i] * local[:, 0] / -local[:, 2] + cameras.cx[i]
                y = -cameras.fy[i] * local[:, 1] / -local[:, 2] + cameras.cy[i]
                inside = (local[:, 2] < 0) & (x >= 0) & (x < width) & (y >= 0) & (y < height) & (i != view)
                uv = torch.stack([x * (2 / width) - 1, y * (2 / height) - 1], -1).nan_to_num(0.0)
                sampled = F.grid_sample(planes[i : i + 1], uv[None, None], align_corners=False)[0, :, 0].T
                colours[:, i] = torch.where(inside[:, None], sampled, math.nan)
            enough = (~colours[..., 0].isnan()).sum(1) >= AGREE_VIEWS
            agree = (images[view].reshape(-1, 3)[rows] - colours.nanmedian(dim=1).values).abs().amax(-1) <= AGREE
            depth = t[rows] * (directions[rows] @ -cameras.c2w[view, :3, 2])
            free[view, rows] = torch.where(agree & enough & t[rows].isfinite(), depth, 0.0)
    return free.reshape(count, height, width)
