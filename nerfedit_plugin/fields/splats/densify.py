r"""Adaptive density control of 3D Gaussian Splatting (Kerbl et al. 2023, §5): clone, split, prune, opacity reset —
on the field's parameters together with their Adam state, so the optimiser's moments stay aligned row for row.

- **Clone** (under-reconstruction: large view-space positional gradient, small Gaussian): a copy of each marked
  Gaussian is appended; the copies start with zero moments.
- **Split** (over-reconstruction: large gradient, large Gaussian): each marked Gaussian is replaced by two at
  ``μ ± R (s ⊙ z)``, ``z ~ N(0, I)`` (an antithetic pair of samples of the Gaussian, so the pair's mean is ``μ``),
  scales ``s / 1.6``, the other parameters copied; the children start with zero moments.
- **Prune**: the marked Gaussians (transparent or huge) are removed with their moments.
- **Opacity reset**: opacities are clamped to at most ``value`` and their moments zeroed.
"""

from __future__ import annotations

import math

import torch

from nerfedit_plugin.fields.splats.projection import rotation_matrices

SPLIT_SHRINK = 1.6
"""Children of a split have their parent's scales divided by this (3DGS's 0.8 · 2)."""


def replace_rows(field: torch.nn.Module, optimizer: torch.optim.Optimizer | None, values: dict, rows: torch.Tensor):
    """Set each parameter ``name`` of ``field`` to ``values[name]`` (rows of Gaussians); in ``optimizer`` the new
    parameter takes the moments of old row ``rows[j]`` for its row ``j``, zeros where ``rows[j] < 0`` (Adam's step
    count is kept)."""
    keep, fresh = rows >= 0, rows < 0
    for name, value in values.items():
        old = getattr(field, name)
        new = torch.nn.Parameter(value.detach().contiguous())
        if optimizer is not None:
            for group in optimizer.param_groups:
                for i, p in enumerate(group["params"]):
                    if p is old:
                        group["params"][i] = new
            state = optimizer.state.pop(old, None)
            if state:
                for key in ("exp_avg", "exp_avg_sq"):
                    moment = state[key].new_zeros(new.shape)
                    moment[keep] = state[key][rows[keep]]
                    moment[fresh] = 0.0
                    state[key] = moment
                optimizer.state[new] = state
        setattr(field, name, new)


def prune(field, optimizer, names: tuple[str, ...], remove: torch.Tensor) -> None:
    """Remove the Gaussians where ``remove (N,)`` is True (parameters ``names`` and their moments)."""
    rows = torch.nonzero(~remove)[:, 0]
    replace_rows(field, optimizer, {name: getattr(field, name).detach()[rows] for name in names}, rows)


def clone(field, optimizer, names: tuple[str, ...], marked: torch.Tensor) -> None:
    """Append a copy of each Gaussian where ``marked (N,)`` is True (zero moments)."""
    n, extra = len(marked), int(marked.sum())
    rows = torch.cat([torch.arange(n), torch.full((extra,), -1)])
    values = {name: torch.cat([getattr(field, name).detach(), getattr(field, name).detach()[marked]]) for name in names}
    replace_rows(field, optimizer, values, rows)


def split(field, optimizer, names: tuple[str, ...], marked: torch.Tensor, generator: torch.Generator) -> None:
    """Replace each Gaussian where ``marked (N,)`` is True by the antithetic pair of the module docstring; the field
    has ``means``, ``quats`` and ``log_scales`` among ``names``."""
    keep = torch.nonzero(~marked)[:, 0]
    parents = torch.nonzero(marked)[:, 0]
    means, quats, log_scales = (getattr(field, name).detach() for name in ("means", "quats", "log_scales"))
    z = torch.randn(len(parents), 3, generator=generator, dtype=means.dtype).to(means.device)
    offset = (rotation_matrices(quats[parents]) @ (torch.exp(log_scales[parents]) * z)[..., None])[..., 0]
    values = {}
    for name in names:
        value = getattr(field, name).detach()
        child = value[parents]
        if name == "means":
            pair = [child + offset, child - offset]
        elif name == "log_scales":
            pair = [child - math.log(SPLIT_SHRINK)] * 2
        else:
            pair = [child, child]
        values[name] = torch.cat([value[keep], *pair])
    rows = torch.cat([keep, torch.full((2 * len(parents),), -1, device=keep.device)])
    replace_rows(field, optimizer, values, rows)


def reset_opacity(field, optimizer, value: float) -> None:
    """Clamp ``field.opacities`` (logits) to at most ``logit(value)`` and zero their moments."""
    logits = field.opacities.detach()
    limit = math.log(value / (1.0 - value))
    replace_rows(field, optimizer, {"opacities": torch.clamp(logits, max=limit)}, torch.full((len(logits),), -1))
