"""When a result is too poor to use: the one rule every command applies before it says "done".

A result outside these bounds is still written (it may be what the user asked for), but the command warns once,
with the figure and the bound, and the edit's ``report.json`` lists the warnings. docs/reliability.md explains the
bounds.
"""

from __future__ import annotations

MAX_INVERTED_TETS = 0.01
"""Fraction of the proxy's tets a lifted frame may invert. Each inverted tet folds space (samples there map
backwards; where it overlaps its neighbours the renderer picks one): a few slivers do not show, a percent does."""

MAX_FOLDED_FACES = 0.01
"""Fraction of the surface faces a deformed frame may fold (normal turned by more than 90° from the rest face's):
a fold the surface edit itself makes is carried into space by any lift."""

MAX_CROSSING_FACES = 0
"""Surface faces a deformed frame may push through others (counted where the lift misses its residual target): no
injective map of space follows a surface through itself, so the lift misses it there; any count explains the miss."""

MIN_HELD_OUT_PSNR = 20.0
"""Held-out PSNR (dB) below which a trained field is not usable yet: its renders are mostly background and its
level set a fragment (the demo's fields reach 30+ dB; a field stopped after a few steps, 14 dB)."""


def edit_warnings(report: dict) -> list[str]:
    """report (``report.json`` of an edit: ``proxy.tets``, ``surface.faces``, ``per_frame[i].inverted_tets``,
    ``.flipped_surface_faces``, ``.crossing_surface_faces`` and ``.residual_max``) → one message per bound the worst
    frame exceeds."""
    frames = report["per_frame"]
    tets, faces = report["proxy"]["tets"], report["surface"]["faces"]
    found = []
    for key, total, bound, what in (
        (
            "inverted_tets",
            tets,
            MAX_INVERTED_TETS,
            "inverted tets: the lift folds space there (tears, doubled surface)",
        ),
        ("flipped_surface_faces", faces, MAX_FOLDED_FACES, "folded surface faces: the deformation itself folds"),
    ):
        worst = max(range(len(frames)), key=lambda f: frames[f][key])
        count = frames[worst][key]
        if count > bound * total:
            found.append(f"frame {worst}: {count} of {total} {what} (more than {bound:.0%}; see docs/reliability.md)")
    crossing = [frame.get("crossing_surface_faces") or 0 for frame in frames]
    worst = max(range(len(frames)), key=crossing.__getitem__)
    if crossing[worst] > MAX_CROSSING_FACES:
        found.append(
            f"frame {worst}: {crossing[worst]} of {faces} surface faces pass through others: no map of space follows "
            f"the surface there (lift residual {frames[worst]['residual_max']:.1e} × bbox; see docs/reliability.md)"
        )
    return found


def training_warnings(log: dict) -> list[str]:
    """log (a field's training log: ``eval`` = [(seconds, held-out PSNR), ...], ``steps``) → a message when the last
    held-out PSNR is below :data:`MIN_HELD_OUT_PSNR`."""
    evaluations = log.get("eval") or []
    if not evaluations or evaluations[-1][1] >= MIN_HELD_OUT_PSNR:
        return []
    psnr, steps = evaluations[-1][1], log.get("steps", "?")
    return [
        f"held-out PSNR {psnr:.1f} dB after {steps} steps is below {MIN_HELD_OUT_PSNR:.0f} dB: the field is not "
        "usable yet (train longer: --field-options.train.max-seconds / --field-options.train.max-steps)"
    ]
