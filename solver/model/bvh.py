"""Read a BVH (Biovision hierarchy) file: the skeleton and, when present, its clip.

Grammar read (line breaks LF, CRLF or CR, mixed; any whitespace between tokens)::

    HIERARCHY
    ROOT <name>            (one or more roots)
    {
      OFFSET x y z
      CHANNELS n <channel>...      X/Y/Z position, X/Y/Z rotation, any subset, any order
      JOINT <name> { ... }         (nested)
      End Site { OFFSET x y z }   ("End" and "Site" in any case; a name after them ignored)
    }
    MOTION                 (optional)
    Frames: N
    Frame Time: t
    N lines of values, one per channel in hierarchy order

Conventions. A joint's transform in its parent's frame is ``T(p) * R``: ``p`` is the
OFFSET, except on the axes the joint has position channels for, where the channel's
value replaces the offset (Blender's importer and exporter; the CMU/cgspeed files have
root OFFSET 0 so both readings agree). ``R`` applies the rotation channels as intrinsic
rotations in the order listed: channels "Zrotation Yrotation Xrotation" give
R = Rz(a) Ry(b) Rx(c), exactly the chain's ROTATIONAL joint with axes "zyx" (Blender
reads the same order as its reversed extrinsic Euler). Rotation values are degrees,
converted to radians; lengths are the file's unit times ``unit_m`` (BVH states no unit:
0.01 for centimetres).

``read_bvh`` reads both parts; ``read_bvh_skeleton`` the hierarchy alone (what a chain
needs: the MOTION block is not parsed, nor refused).

Bones: every ROOT and JOINT, named as in the file, with ``rotation_order`` its rotation
channels' axes (so by default it moves about exactly those); every End Site a fixed bone
named ``<parent>_end`` (a fingertip or toe tip to put an effector on).

Errors are ``InvalidModel`` with ``joint`` the joint's name (or ``bvh``, ``MOTION``)
and ``field`` ``line <n>`` (1-based; ``HIERARCHY`` when the hierarchy ends early, none
for the size cap and ``unit_m``): unknown keywords, a missing brace, OFFSET or
CHANNELS, a channel count that differs from the channels listed, a repeated or unknown
channel, a duplicate name, too many joints or too deep, a frame with too many or too
few values, fewer frame lines than ``Frames``, non-finite numbers.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from solver.errors import InvalidModel
from solver.model import Transform
from solver.model.bones import MAX_BONES, MAX_NAME_LENGTH, Bone, Channel, Motion, Skeleton

MAX_BYTES = 64_000_000  # ten minutes of 100 channels at 120 fps is about 60 MB
MAX_DEPTH = 256
MAX_FRAMES = 1_000_000
_CHANNELS = {c.value.lower(): c for c in Channel}
# A decimal number; float() alone would also take "nan", "inf" and "1_0".
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")


@dataclass(frozen=True, slots=True)
class BvhFile:
    """What a BVH file holds.

    Attributes:
        skeleton: The bones (see the module docstring).
        motion: The clip in radians and metres, or None without a MOTION block.
    """

    skeleton: Skeleton
    motion: Motion | None


@dataclass(slots=True)
class _Node:
    name: str
    parent: str | None
    line: int
    offset: tuple[float, float, float] | None = None
    channels: tuple[Channel, ...] = ()
    end_site: bool = False


def read_bvh(
    text: str,
    *,
    unit_m: float = 1.0,
    name: str = "bvh",
    max_bytes: int = MAX_BYTES,
    max_bones: int = MAX_BONES,
    max_depth: int = MAX_DEPTH,
    max_frames: int = MAX_FRAMES,
) -> BvhFile:
    """Parse a BVH document.

    Args:
        text: The file's text.
        unit_m: Metres per file length unit (1.0: the file is in metres).
        name: The skeleton's name.
        max_bytes: Cap on the text's UTF-8 size [bytes].
        max_bones: Cap on bones (joints and End Sites).
        max_depth: Cap on the hierarchy's depth.
        max_frames: Cap on MOTION frames.

    Raises:
        InvalidModel: see the module docstring.
    """
    lines = _lines(text, unit_m, max_bytes)
    nodes, motion_line = _hierarchy(lines, max_bones=max_bones, max_depth=max_depth)
    skeleton = Skeleton(name, tuple(_bone(node, unit_m) for node in nodes))
    motion = None
    if motion_line is not None:
        layout = tuple((n.name, c) for n in nodes for c in n.channels)
        motion = _motion(lines, motion_line, layout, unit_m, max_frames)
    return BvhFile(skeleton, motion)


def read_bvh_skeleton(
    text: str,
    *,
    unit_m: float = 1.0,
    name: str = "bvh",
    max_bytes: int = MAX_BYTES,
    max_bones: int = MAX_BONES,
    max_depth: int = MAX_DEPTH,
) -> Skeleton:
    """The skeleton of a BVH document, its MOTION block not read: for a caller that
    builds a chain and needs no clip (the service). A motion block that ``read_bvh``
    refuses (``Frames`` off by one, a comma decimal) does not stop the skeleton, and a
    long clip costs no parsing.

    Raises:
        InvalidModel: as ``read_bvh``, for the hierarchy and the arguments.
    """
    lines = _lines(text, unit_m, max_bytes)
    nodes, _ = _hierarchy(lines, max_bones=max_bones, max_depth=max_depth)
    return Skeleton(name, tuple(_bone(node, unit_m) for node in nodes))


def _lines(text: str, unit_m: float, max_bytes: int) -> list[str]:
    """The text's lines (any line breaks), after the checks on the arguments."""
    if not isinstance(text, str):
        raise InvalidModel(f"BVH must be text (str), got {type(text).__name__}", joint="bvh")
    if len(text) > max_bytes or len(text.encode("utf-8", "surrogatepass")) > max_bytes:
        raise InvalidModel(f"BVH is larger than {max_bytes} bytes", joint="bvh")
    if not (isinstance(unit_m, int | float) and math.isfinite(unit_m) and unit_m > 0.0):
        raise InvalidModel(f"unit_m must be finite and > 0, got {unit_m!r}", joint="bvh")
    return text.removeprefix("\ufeff").replace("\r\n", "\n").replace("\r", "\n").split("\n")


def _bone(node: _Node, unit_m: float) -> Bone:
    assert node.offset is not None
    return Bone(
        name=node.name,
        parent=node.parent,
        rest=Transform(np.array(node.offset) * unit_m),
        channels=node.channels,
        rotation_order="".join(c.axis for c in node.channels if c.is_rotation),
    )


class _Lines:
    """Non-empty lines as token lists, with their 1-based line numbers."""

    def __init__(self, lines: list[str], start: int, stop: int) -> None:
        self._items = [(k + 1, ln.split()) for k in range(start, stop) if (ln := lines[k]).strip()]
        self._pos = 0

    def next(self, where: str) -> tuple[int, list[str]]:
        if self._pos >= len(self._items):
            raise InvalidModel("unexpected end of the hierarchy", joint=where, field="HIERARCHY")
        item = self._items[self._pos]
        self._pos += 1
        return item

    def done(self) -> bool:
        return self._pos >= len(self._items)


def _hierarchy(
    lines: list[str], *, max_bones: int, max_depth: int
) -> tuple[list[_Node], int | None]:
    """Nodes in file order (parents first) and the index of the MOTION line, if any."""
    first = next((k for k, ln in enumerate(lines) if ln.strip()), None)
    if first is None or lines[first].split() != ["HIERARCHY"]:
        raise InvalidModel("the file must start with HIERARCHY", joint="bvh", field="line 1")
    motion = next((k for k, ln in enumerate(lines) if ln.split()[:1] == ["MOTION"]), None)
    stream = _Lines(lines, first + 1, len(lines) if motion is None else motion)
    nodes: list[_Node] = []
    names: set[str] = set()
    stack: list[_Node] = []  # open blocks
    while not stream.done():
        line, tokens = stream.next("bvh")
        where = f"line {line}"
        keyword = tokens[0]
        current = stack[-1] if stack else None
        end = _end_site(tokens)
        if keyword in ("ROOT", "JOINT") or end:
            if (keyword == "ROOT") != (current is None):
                raise InvalidModel(
                    "ROOT only at the top level, JOINT and End Site only inside a joint",
                    joint=current.name if current else "bvh",
                    field=where,
                )
            if current is not None and current.end_site:
                raise InvalidModel("an End Site has no children", joint=current.name, field=where)
            rest = tokens[2:] if end else tokens[1:]
            brace = bool(rest) and rest[-1] == "{"
            if brace:
                rest = rest[:-1]
            if end:
                assert current is not None
                # A name after "End Site" (some exporters write one) is ignored, as
                # Blender's importer does: the bone is always <parent>_end.
                name = f"{current.name}_end"
            else:
                name = " ".join(rest)
                if not name:
                    raise InvalidModel(f"{keyword} needs a name", joint="bvh", field=where)
            if len(name) > MAX_NAME_LENGTH:
                raise InvalidModel(
                    f"names have at most {MAX_NAME_LENGTH} characters",
                    joint=name[:MAX_NAME_LENGTH],
                    field=where,
                )
            if name in names:
                raise InvalidModel("duplicate joint name", joint=name, field=where)
            if len(nodes) >= max_bones:
                raise InvalidModel(f"more than {max_bones} joints", joint=name, field=where)
            if len(stack) >= max_depth:
                raise InvalidModel(f"deeper than {max_depth}", joint=name, field=where)
            if not brace:
                brace_line, brace_tokens = stream.next(name)
                if brace_tokens != ["{"]:
                    raise InvalidModel("expected '{'", joint=name, field=f"line {brace_line}")
            node = _Node(name, current.name if current else None, line, end_site=end)
            names.add(name)
            nodes.append(node)
            stack.append(node)
        elif keyword == "}" and len(tokens) == 1:
            if current is None:
                raise InvalidModel("unmatched '}'", joint="bvh", field=where)
            if current.offset is None:
                raise InvalidModel("missing OFFSET", joint=current.name, field=where)
            stack.pop()
        elif keyword == "OFFSET" and current is not None:
            if current.offset is not None:
                raise InvalidModel("a second OFFSET", joint=current.name, field=where)
            if len(tokens) != 4:
                raise InvalidModel("OFFSET needs 3 numbers", joint=current.name, field=where)
            x, y, z = (_number(t, current.name, where) for t in tokens[1:])
            current.offset = (x, y, z)
        elif keyword == "CHANNELS" and current is not None:
            current.channels = _channels(current, tokens, where)
        else:
            raise InvalidModel(
                f"unexpected {' '.join(tokens)[:40]!r}",
                joint=current.name if current else "bvh",
                field=where,
            )
    if stack:
        raise InvalidModel(
            "the hierarchy ends before this joint's '}'", joint=stack[-1].name, field="HIERARCHY"
        )
    if not nodes:
        raise InvalidModel("the hierarchy has no ROOT", joint="bvh", field="HIERARCHY")
    return nodes, motion


def _end_site(tokens: list[str]) -> bool:
    return tokens[0].lower() == "end" and len(tokens) > 1 and tokens[1].lower() == "site"


def _channels(node: _Node, tokens: list[str], where: str) -> tuple[Channel, ...]:
    if node.end_site:
        raise InvalidModel("an End Site has no channels", joint=node.name, field=where)
    if node.channels:
        raise InvalidModel("a second CHANNELS line", joint=node.name, field=where)
    if len(tokens) < 2 or not tokens[1].isdigit():
        raise InvalidModel("CHANNELS needs a count", joint=node.name, field=where)
    count, listed = int(tokens[1]), tokens[2:]
    if count != len(listed):
        raise InvalidModel(
            f"CHANNELS declares {count} channels but lists {len(listed)}",
            joint=node.name,
            field=where,
        )
    channels = []
    for token in listed:
        channel = _CHANNELS.get(token.lower())
        if channel is None:
            raise InvalidModel(f"unknown channel {token!r}", joint=node.name, field=where)
        if channel in channels:
            raise InvalidModel(f"channel {token!r} listed twice", joint=node.name, field=where)
        channels.append(channel)
    return tuple(channels)


def _number(token: str, joint: str, where: str) -> float:
    if not _NUMBER.fullmatch(token):
        raise InvalidModel(f"{token[:40]!r} is not a finite number", joint=joint, field=where)
    value = float(token)
    if not math.isfinite(value):  # 1e999
        raise InvalidModel(f"{token[:40]!r} is not a finite number", joint=joint, field=where)
    return value


def _header_value(lines: list[str], k: int, label: str) -> str:
    text = lines[k].strip() if k < len(lines) else ""
    if not text.startswith(label):
        raise InvalidModel(f"expected {label!r}", joint="MOTION", field=f"line {k + 1}")
    return text[len(label) :].strip()


def _motion(
    lines: list[str],
    motion_line: int,
    layout: tuple[tuple[str, Channel], ...],
    unit_m: float,
    max_frames: int,
) -> Motion:
    k = motion_line + 1
    while k < len(lines) and not lines[k].strip():
        k += 1
    frames_text = _header_value(lines, k, "Frames:")
    if not frames_text.isdigit():
        raise InvalidModel(
            f"Frames must be a count, got {frames_text[:40]!r}",
            joint="MOTION",
            field=f"line {k + 1}",
        )
    n_frames = int(frames_text)
    if n_frames > max_frames:
        raise InvalidModel(f"more than {max_frames} frames", joint="MOTION", field=f"line {k + 1}")
    k += 1
    time_text = _header_value(lines, k, "Frame Time:")
    frame_time = _number(time_text, "MOTION", f"line {k + 1}")
    if frame_time <= 0.0:
        raise InvalidModel("Frame Time must be > 0", joint="MOTION", field=f"line {k + 1}")
    n_channels = len(layout)
    # Every value takes a character and a separator: a declared block larger than the
    # text is truncated, and refusing it here bounds the array allocated below.
    remaining = sum(len(ln) + 1 for ln in lines[k + 1 :])
    if 2 * n_frames * n_channels > remaining + 1:
        raise InvalidModel(
            f"truncated: Frames declares {n_frames} frames of {n_channels} values, more "
            "than the rest of the file can hold",
            joint="MOTION",
            field=f"line {k}",
        )
    values = np.empty((n_frames, n_channels))
    row = 0
    for j in range(k + 1, len(lines)):
        tokens = lines[j].split()  # one line at a time: no list of all the tokens
        if not tokens:
            continue
        where = f"line {j + 1}"
        if row == n_frames:
            raise InvalidModel(
                f"more frame lines than Frames: {n_frames}", joint="MOTION", field=where
            )
        if len(tokens) != n_channels:
            raise InvalidModel(
                f"frame {row} has {len(tokens)} values, the hierarchy has {n_channels} channels",
                joint="MOTION",
                field=where,
            )
        try:
            values[row] = np.array(tokens, dtype=np.float64)
        except ValueError:
            bad = next((t for t in tokens if not _NUMBER.fullmatch(t)), tokens[0])
            _number(bad, "MOTION", where)
        if not np.isfinite(values[row]).all():
            bad = next(t for t, v in zip(tokens, values[row], strict=True) if not math.isfinite(v))
            raise InvalidModel(f"{bad[:40]!r} is not a finite number", joint="MOTION", field=where)
        row += 1
    if row < n_frames:
        raise InvalidModel(
            f"truncated: Frames declares {n_frames}, the file has {row} frame lines",
            joint="MOTION",
            field=f"line {len(lines)}",
        )
    rotation = np.array([c.is_rotation for _, c in layout], dtype=bool)
    values[:, rotation] = np.radians(values[:, rotation])
    values[:, ~rotation] *= unit_m
    return Motion(frame_time, values, layout)
