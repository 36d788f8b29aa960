"""Biovision hierarchy (BVH) motion files: joint tree, rest offsets, channels and per-frame joint transforms.

Conventions (those of the format and of Blender / CMU readers): the rest pose has every channel at zero, so joint
heads are the cumulative ``OFFSET`` s and joint frames are world-aligned. A joint's local transform at a frame is
``T(offset + position channels) · R``, with ``R`` the product of its rotation channels in the order listed
(``Zrotation Xrotation Yrotation`` → ``Rz·Rx·Ry``, degrees). ``End Site`` offsets give leaf joints their tails.
The motion section has one line per frame with one value per channel, in hierarchy order.
Every syntax error raises :class:`NerfEditError` as ``file:line: problem``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from nerfedit_plugin.errors import NerfEditError

CHANNELS = ("xposition", "yposition", "zposition", "xrotation", "yrotation", "zrotation")


@dataclass(frozen=True)
class BvhClip:
    """A parsed BVH file. ``end_sites[j]`` is NaN for joints without an ``End Site``; ``motion (F, channels)``."""

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    end_sites: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    frame_time: float
    motion: np.ndarray
    source: str

    @property
    def heads(self) -> np.ndarray:
        """Rest joint positions ``(J,3)``: cumulative offsets (parents precede children in the file)."""
        heads = np.array(self.offsets, dtype=np.float64)
        for j, parent in enumerate(self.parents):
            if parent >= 0:
                heads[j] += heads[parent]
        return heads

    @property
    def n_frames(self) -> int:
        return len(self.motion)

    def local_transforms(self, frames: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Per-frame local rotations ``(F,J,3,3)`` and translations ``(F,J,3)`` (position channels).

        ``frames`` resamples the clip to that many evenly spaced times (slerp/lerp between neighbouring frames).
        """
        n_joints = len(self.names)
        if self.n_frames == 0:
            raise NerfEditError(f"{self.source}: no motion frames")
        rot = np.tile(np.eye(3), (self.n_frames, n_joints, 1, 1))
        trans = np.zeros((self.n_frames, n_joints, 3))
        column = 0
        for j, names in enumerate(self.channels):
            for name in names:
                values = self.motion[:, column]
                column += 1
                axis = "xyz".index(name[0])
                if name.endswith("position"):
                    trans[:, j, axis] = values
                else:
                    rot[:, j] = rot[:, j] @ Rotation.from_euler("xyz"[axis], values[:, None], degrees=True).as_matrix()
        if frames is None or frames == self.n_frames:
            return rot, trans
        times = np.linspace(0.0, self.n_frames - 1, frames)
        if self.n_frames == 1:
            return np.repeat(rot, frames, axis=0), np.repeat(trans, frames, axis=0)
        lo = np.minimum(np.floor(times).astype(int), self.n_frames - 2)
        s = (times - lo)[:, None]
        sampled = np.empty((frames, n_joints, 3, 3))
        for j in range(n_joints):
            sampled[:, j] = Slerp(np.arange(self.n_frames), Rotation.from_matrix(rot[:, j]))(times).as_matrix()
        return sampled, (1 - s[..., None]) * trans[lo] + s[..., None] * trans[lo + 1]


class _Tokens:
    """Whitespace tokens of the hierarchy section with their line numbers."""

    def __init__(self, lines: list[str], source: str) -> None:
        self.items = [
            (tok, number) for number, line in enumerate(lines, 1) for tok in re.sub(r"([{}])", r" \1 ", line).split()
        ]
        self.pos, self.source, self.last_line = 0, source, len(lines)

    def error(self, problem: str, line: int | None = None) -> NerfEditError:
        if line is None:
            line = self.items[self.pos][1] if self.pos < len(self.items) else self.last_line
        return NerfEditError(f"{self.source}:{line}: {problem}")

    def peek(self) -> str | None:
        return self.items[self.pos][0] if self.pos < len(self.items) else None

    def next(self, what: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise self.error(f"unexpected end of file, expected {what}")
        self.pos += 1
        return self.items[self.pos - 1]

    def expect(self, word: str) -> int:
        tok, line = self.next(repr(word))
        if tok.lower() != word.lower():
            raise self.error(f"expected {word!r}, got {tok!r}", line)
        return line

    def number(self, what: str) -> float:
        tok, line = self.next(what)
        try:
            value = float(tok)
        except ValueError:
            raise self.error(f"expected {what}, got {tok!r}", line) from None
        if not math.isfinite(value):
            raise self.error(f"{what} is not finite", line)
        return value

    def rest_of_line(self, line: int, what: str) -> str:
        words = []
        while self.pos < len(self.items) and self.items[self.pos][1] == line and self.items[self.pos][0] != "{":
            words.append(self.items[self.pos][0])
            self.pos += 1
        if not words:
            raise self.error(f"missing {what}", line)
        return " ".join(words)


def parse_bvh(path: str | Path) -> BvhClip:
    """Read a BVH file; errors name the file and line."""
    path = Path(path)
    source = str(path)
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise NerfEditError(f"{source}: cannot read BVH file ({exc})") from exc
    motion_at = next((i for i, line in enumerate(lines) if line.strip().upper() == "MOTION"), None)
    if motion_at is None:
        raise NerfEditError(f"{source}: no MOTION section")
    tokens = _Tokens(lines[:motion_at], source)
    tokens.expect("HIERARCHY")
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    end_sites: list[list[float]] = []
    channels: list[tuple[str, ...]] = []

    def offset() -> list[float]:
        tokens.expect("OFFSET")
        return [tokens.number(f"OFFSET {axis}") for axis in "xyz"]

    def joint(parent: int, line: int) -> None:
        index = len(names)
        names.append(tokens.rest_of_line(line, "joint name"))
        parents.append(parent)
        end_sites.append([math.nan] * 3)
        tokens.expect("{")
        offsets.append(offset())
        listed: tuple[str, ...] = ()
        if (tokens.peek() or "").upper() == "CHANNELS":
            tokens.next("CHANNELS")
            count = tokens.number("channel count")
            if count != int(count) or not 0 <= count <= 6:
                raise tokens.error(f"channel count must be an integer 0..6, got {count:g}")
            found = []
            for _ in range(int(count)):
                tok, at = tokens.next("a channel name")
                if tok.lower() not in CHANNELS:
                    raise tokens.error(f"unknown channel {tok!r} (expected X/Y/Z position/rotation)", at)
                found.append(tok.lower())
            if len(set(found)) != len(found):
                raise tokens.error(f"repeated channel in {' '.join(found)}", at)
            listed = tuple(found)
        channels.append(listed)
        while True:
            tok, at = tokens.next("JOINT, End Site or '}'")
            upper = tok.upper()
            if upper == "JOINT":
                joint(index, at)
            elif upper == "END":
                tokens.expect("Site")
                tokens.expect("{")
                end_sites[index] = offset()
                tokens.expect("}")
            elif tok == "}":
                return
            else:
                raise tokens.error(f"expected JOINT, End Site or '}}', got {tok!r}", at)

    while tokens.peek() is not None:
        tok, at = tokens.next("ROOT")
        if tok.upper() != "ROOT":
            raise tokens.error(f"expected ROOT, got {tok!r}", at)
        joint(-1, at)
    if not names:
        raise tokens.error("no ROOT joint")

    n_channels = sum(len(c) for c in channels)
    frame_time, motion = _parse_motion(lines, motion_at, n_channels, source)
    return BvhClip(
        tuple(names),
        tuple(parents),
        np.asarray(offsets, dtype=np.float64),
        np.asarray(end_sites, dtype=np.float64),
        tuple(channels),
        frame_time,
        motion,
        source,
    )


def _parse_motion(lines: list[str], motion_at: int, n_channels: int, source: str) -> tuple[float, np.ndarray]:
    """The frame time and the ``(frames, channels)`` values after ``MOTION``."""
    body = [(i + 1, line.strip()) for i, line in enumerate(lines) if i > motion_at and line.strip()]

    def header(k: int, pattern: str, what: str) -> str:
        if k >= len(body):
            raise NerfEditError(f"{source}:{len(lines)}: missing '{what}'")
        number, text = body[k]
        match = re.fullmatch(pattern, text, flags=re.IGNORECASE)
        if not match:
            raise NerfEditError(f"{source}:{number}: expected '{what} <value>', got {text!r}")
        return match.group(1)

    n_frames = int(header(0, r"Frames:\s*(\d+)", "Frames:"))
    try:
        frame_time = float(header(1, r"Frame\s+Time:\s*(\S+)", "Frame Time:"))
    except ValueError:
        raise NerfEditError(f"{source}:{body[1][0]}: Frame Time is not a number") from None
    rows = body[2:]
    if len(rows) != n_frames:
        at = rows[n_frames][0] if len(rows) > n_frames else len(lines)
        raise NerfEditError(f"{source}:{at}: header says {n_frames} frames, the file has {len(rows)} frame lines")
    values = []
    for number, text in rows:
        parts = text.split()
        if len(parts) != n_channels:
            raise NerfEditError(f"{source}:{number}: expected {n_channels} channel values, got {len(parts)}")
        try:
            row = [float(v) for v in parts]
        except ValueError:
            raise NerfEditError(f"{source}:{number}: non-numeric channel value") from None
        if not all(math.isfinite(v) for v in row):
            raise NerfEditError(f"{source}:{number}: channel value is NaN or Inf")
        values.append(row)
    return frame_time, np.asarray(values, dtype=np.float64).reshape(n_frames, n_channels)


def placed_bvh(text: str, scale: float, offset: np.ndarray) -> str:
    """The BVH ``text`` of the same clip for a world moved by ``x ↦ scale·x + offset``: every ``OFFSET`` (and
    ``End Site``) and every position channel value scaled, the root's ``OFFSET`` moved too; rotations unchanged."""
    out, positions, root, motion = [], [], True, False
    for line in text.splitlines():
        words = line.split()
        if not motion and words[:1] == ["OFFSET"]:
            value = scale * np.asarray(words[1:4], dtype=np.float64) + (offset if root else 0.0)
            line, root = line[: line.index("OFFSET")] + "OFFSET " + " ".join(map(repr, value.tolist())), False
        elif not motion and words[:1] == ["CHANNELS"]:
            positions += [name.lower().endswith("position") for name in words[2:]]
        elif words[:1] == ["MOTION"]:
            motion = True
        elif motion and words and words[0] not in ("Frames:", "Frame"):
            values = np.asarray(words, dtype=np.float64)
            values[np.asarray(positions)] *= scale
            line = " ".join(map(repr, values.tolist()))
        out.append(line)
    return "\n".join(out) + "\n"
