"""CAM paths from G-code (RS-274 / ISO 6983 subset): the tool path of linear and arc feed moves.

What is read, per line (block):

* ``N`` line numbers, ``F``/``S``/``T``/``M``/``P``/``H``/``D``/``O`` words and ``%`` lines are
  ignored (``P`` on an arc is its number of turns, as in LinuxCNC). Comments in parentheses
  (not nested) and everything after ``;`` are removed; a leading ``/`` (block delete) is dropped.
* Motion, modal: ``G0`` rapid, ``G1`` linear feed, ``G2`` clockwise arc, ``G3`` counter-clockwise
  arc. A line with coordinates but no motion code repeats the last one.
* Arcs lie in the active plane ``G17`` (XY, default), ``G18`` (ZX) or ``G19`` (YZ); clockwise is
  seen from the positive end of the plane's normal axis (Z, Y or X). The centre is given by the
  offsets ``I J K`` (from the start point with ``G91.1``, the default; absolute with ``G90.1``)
  or by the radius ``R`` (``R > 0``: the arc of at most 180 degrees, ``R < 0``: the longer one).
  A coordinate on the normal axis makes a helix: that axis moves linearly with the angle. An
  arc whose end point is its start point (``I J K`` form) is a full circle.
* Units ``G20`` (inch) / ``G21`` (mm) override the ``units`` argument from where they appear;
  distance mode ``G90`` (absolute, default) / ``G91`` (relative).
* Codes that do not change the path are accepted and ignored (dwell, cutter compensation and tool
  length *cancel*, work offsets ``G54``-``G59`` (assumed zero), path control, feed modes); any
  other ``G`` code, and rotary or extra axes (``A B C U V W``), are an :class:`InputError`.

The machine starts at the program origin. The path is the sequence of feed moves (``G1``, ``G2``,
``G3``), split into *feed sequences* (tracks: one bead, seam or cut each):

* a rapid ``G0`` that moves ends a track;
* a plunge or retract, a ``G1`` that moves along Z alone (within :data:`PLUNGE_XY_TOLERANCE_M`
  in X and Y), ends a track and belongs to none;
* a closed loop ends a track: a feed move that ends at a block end of its own track (within
  :data:`LOOP_TOLERANCE_M`) makes the loop from that block end a closed track, and what came
  before it, if anything, an open one.

Arcs are discretised so that no chord is farther than ``arc_tolerance_m`` from the arc; their
points lie on the exact circle (or helix).
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from refine.cad.csv_ import METRES_PER_UNIT, metres_per_unit
from refine.cad.resample import FEATURE, FLATTENING, VERTEX, CadTrack
from refine.errors import InputError
from refine.plausible import CAD_COORDINATE_LIMIT_M, check_coordinates, check_point

logger = logging.getLogger(__name__)

#: Most full turns of one helical arc (the P word of G2/G3) [-].
MAX_ARC_TURNS = 1000

#: Largest distance between an arc and its chords [m].
ARC_TOLERANCE_M = 1e-5
#: Codes accepted without effect on the path.
IGNORED_G = {4, 40, 49, 54, 55, 56, 57, 58, 59, 61, 61.1, 64, 80, 93, 94, 95}
_PLANES = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}  # (u, v, normal) axis indices
_WORD = re.compile(r"([A-Z])\s*([+-]?(?:\d+\.?\d*|\.\d+))")
_IGNORED_LETTERS = set("NFSTMPHDO")
_AXES = {"X": 0, "Y": 1, "Z": 2}
_OFFSETS = {"I": 0, "J": 1, "K": 2}


#: Largest distance between an arc and its chords in the tracks of :func:`tracks_from_gcode` [m].
FLATTEN_TOLERANCE_M = 1e-6
#: A feed move that ends this close to a block end of its track closes a loop [m].
LOOP_TOLERANCE_M = 1e-6
#: A linear feed move whose XY motion is at most this is a plunge or retract along Z [m].
PLUNGE_XY_TOLERANCE_M = 1e-9


@dataclass
class _Sequence:
    points: list[NDArray] = field(default_factory=list)
    first_line: int = 0
    last_line: int = 0
    kinds: list[int] = field(default_factory=list)
    block_ends: list[tuple[int, int]] = field(default_factory=list)  # (point index, line)
    closed: bool = False

    def length(self) -> float:
        return float(np.linalg.norm(np.diff(np.array(self.points), axis=0), axis=1).sum())

    def split_loop(self, where: int) -> list[_Sequence]:
        """At a block end that the path returns to: the part before it and the closed loop from it."""
        if where == 0:
            self.closed = True
            return [self]
        m, line = next((k, ln) for k, ln in self.block_ends if k == where)
        before = _Sequence(self.points[: m + 1], self.first_line, line, self.kinds[: m + 1])
        before.block_ends = [(k, ln) for k, ln in self.block_ends if k <= m]
        first = next(ln for k, ln in self.block_ends if k > m)
        loop = _Sequence(self.points[m:], first, self.last_line, self.kinds[m:], closed=True)
        loop.block_ends = [(k - m, ln) for k, ln in self.block_ends if k >= m]
        return [before, loop]


def _strip_comments(text: str, where: str) -> str:
    out, depth = [], 0
    for ch in text:
        if ch == ";" and not depth:
            break
        if ch == "(":
            if depth:
                raise InputError(f"{where}: nested comment parentheses are not supported: {text!r}")
            depth = 1
        elif ch == ")":
            if not depth:
                raise InputError(f"{where}: ')' without '(' in {text!r}")
            depth = 0
        elif not depth:
            out.append(ch)
    if depth:
        raise InputError(f"{where}: unclosed comment '(' in {text!r}")
    return "".join(out).strip().lstrip("/")


def _words(line: str, where: str) -> list[tuple[str, float]]:
    text = line.upper()
    words, pos = [], 0
    for m in _WORD.finditer(text):
        if text[pos : m.start()].strip():
            break
        words.append((m.group(1), float(m.group(2))))
        pos = m.end()
    rest = text[pos:].strip()
    if rest:
        raise InputError(f"{where}: cannot read {rest!r} in {line!r} (expected words like X12.5)")
    return words


def _arc_points(start, end, centre, plane, ccw: bool, turns: int, tol: float, where: str) -> NDArray:
    """Points (after ``start``) of an arc or helix from ``start`` to ``end`` [m], shape (n, 3)."""
    u, v, w = plane
    r0 = math.hypot(start[u] - centre[0], start[v] - centre[1])
    r1 = math.hypot(end[u] - centre[0], end[v] - centre[1])
    if r0 < 1e-12 or abs(r1 - r0) > max(2e-6, 1e-3 * r0):
        raise InputError(
            f"{where}: arc start and end are not on one circle about the centre "
            f"(radii {r0 * 1e3:.6g} mm and {r1 * 1e3:.6g} mm)"
        )
    a0 = math.atan2(start[v] - centre[1], start[u] - centre[0])
    a1 = math.atan2(end[v] - centre[1], end[u] - centre[0])
    sweep = (a1 - a0) % (2.0 * math.pi) if ccw else -((a0 - a1) % (2.0 * math.pi))
    if abs(sweep) < 1e-12 and math.hypot(end[u] - start[u], end[v] - start[v]) < 1e-12:
        sweep = 2.0 * math.pi if ccw else -2.0 * math.pi
    sweep += math.copysign(2.0 * math.pi * (turns - 1), sweep)
    step = 2.0 * math.acos(1.0 - tol / r0) if tol < r0 else math.pi / 2
    n = max(2, math.ceil(abs(sweep) / min(step, math.pi / 4)))
    f = np.linspace(0.0, 1.0, n + 1)[1:]
    ang, rad = a0 + sweep * f, r0 + (r1 - r0) * f
    pts = np.empty((n, 3))
    pts[:, u] = centre[0] + rad * np.cos(ang)
    pts[:, v] = centre[1] + rad * np.sin(ang)
    pts[:, w] = start[w] + (end[w] - start[w]) * f
    pts[-1] = end
    return pts


def _centre_from_radius(start, end, plane, radius: float, ccw: bool, where: str) -> tuple[float, float]:
    u, v, _ = plane
    du, dv = end[u] - start[u], end[v] - start[v]
    d = math.hypot(du, dv)
    if d < 1e-12:
        raise InputError(f"{where}: an R-form arc needs an end point different from its start")
    half = d / 2.0
    if abs(radius) < half - max(1e-9, 1e-6 * half):
        raise InputError(
            f"{where}: arc radius R = {abs(radius) * 1e3:.6g} mm is smaller than half the chord "
            f"({half * 1e3:.6g} mm)"
        )
    h = math.sqrt(max(radius * radius - half * half, 0.0))
    side = (1.0 if ccw else -1.0) * (1.0 if radius > 0 else -1.0)  # + : centre left of chord
    mu, mv = start[u] + du / 2.0, start[v] + dv / 2.0
    return mu - side * h * dv / d, mv + side * h * du / d


def _program_index(program: int | str | None, n: int, source: str) -> int | None:
    if program is None:
        return None
    try:
        k = int(str(program).strip())
    except ValueError as e:
        raise InputError(f"{source}: feed sequence {program!r} is not a number (1..{n})") from e
    if not 1 <= k <= n:
        raise InputError(f"{source}: feed sequence {program!r} does not exist; the file has {n} (1..{n})")
    return k - 1


def _parse(
    path: Path, units: str, arc_tolerance_m: float, circles: list | None = None
) -> tuple[list[_Sequence], str]:
    """The feed tracks of a G-code file (see the module docstring) and the file's name for messages."""
    path = Path(path)
    source = f"G-code file {str(path)!r}"
    scale = metres_per_unit(units, str(path))
    if not (math.isfinite(arc_tolerance_m) and arc_tolerance_m > 0.0):
        raise InputError(f"{source}: arc_tolerance_m must be a number > 0 m, got {arc_tolerance_m!r}")
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{source} cannot be read: {e}") from e
    pos = np.zeros(3)
    motion: int | None = None
    plane, absolute, arc_absolute = _PLANES[17], True, False
    sequences: list[_Sequence] = []
    current: _Sequence | None = None
    for lineno, raw in enumerate(lines, start=1):
        where = f"{path}:{lineno}"
        text = _strip_comments(raw, where)
        if not text or text == "%":
            continue
        words = _words(text, where)
        target: dict[int, float] = {}
        offsets: dict[int, float] = {}
        radius: float | None = None
        turns = 1
        for letter, value in words:
            if letter == "G":
                code = round(value, 1)
                if code in (0, 1, 2, 3):
                    motion = int(code)
                elif code in _PLANES:
                    plane = _PLANES[int(code)]
                elif code in (20, 21):
                    scale = METRES_PER_UNIT["in" if code == 20 else "mm"]
                elif code in (90, 91):
                    absolute = code == 90
                elif code in (90.1, 91.1):
                    arc_absolute = code == 90.1
                elif code not in IGNORED_G:
                    raise InputError(f"{where}: unsupported code G{value:g} in {text!r}")
            elif letter in _AXES:
                target[_AXES[letter]] = value
            elif letter in _OFFSETS:
                offsets[_OFFSETS[letter]] = value
            elif letter == "R":
                radius = value
            elif letter == "P" and motion in (2, 3):
                if not 1 <= value <= MAX_ARC_TURNS:
                    raise InputError(f"{where}: P{value:g}: an arc's turns must be 1..{MAX_ARC_TURNS}")
                turns = int(value)
            elif letter not in _IGNORED_LETTERS:
                why = (
                    " (numbers in exponent notation such as 1e3 are not G-code, and E, a 3D printer's "
                    "extruder axis, is not read)"
                    if letter == "E"
                    else ""
                )
                raise InputError(f"{where}: unsupported word {letter}{value:g} in {text!r}{why}")
        if not target:
            continue
        if motion is None:
            raise InputError(f"{where}: coordinates before any motion code (G0/G1/G2/G3): {text!r}")
        end = pos.copy()
        for axis, value in target.items():
            end[axis] = value * scale + (pos[axis] if not absolute else 0.0)
        check_point(end.tolist(), CAD_COORDINATE_LIMIT_M, where, "end point")
        if motion == 0:
            if np.linalg.norm(end - pos) > 1e-12:
                current = None
            pos = end
            continue
        if motion == 1:
            if np.linalg.norm((end - pos)[:2]) <= PLUNGE_XY_TOLERANCE_M:  # a plunge or retract ends a track
                current = None
                pos = end
                continue
            new = end[None]
            new_kinds = [VERTEX]
        else:
            ccw = motion == 3
            if radius is not None:
                if not abs(radius * scale) <= CAD_COORDINATE_LIMIT_M:
                    raise InputError(
                        f"{where}: arc radius R = {radius * scale:.6g} m is outside the plausible range "
                        f"{CAD_COORDINATE_LIMIT_M:g} m: {text!r}"
                    )
                centre = _centre_from_radius(pos, end, plane, radius * scale, ccw, where)
            elif offsets:
                c = np.array([offsets.get(i, 0.0) * scale for i in range(3)])
                c = c if arc_absolute else c + pos
                centre = (c[plane[0]], c[plane[1]])
            else:
                raise InputError(f"{where}: arc G{motion} needs I/J/K or R: {text!r}")
            check_point(centre, CAD_COORDINATE_LIMIT_M, where, "arc centre")
            new = _arc_points(pos, end, centre, plane, ccw, turns, arc_tolerance_m, where)
            if circles is not None and abs(end[plane[2]] - pos[plane[2]]) <= 1e-12:  # a planar arc, not a helix
                c3 = np.zeros(3)
                c3[plane[0]], c3[plane[1]], c3[plane[2]] = centre[0], centre[1], pos[plane[2]]
                axis = np.zeros(3)
                axis[plane[2]] = 1.0
                circles.append((c3, math.hypot(pos[plane[0]] - centre[0], pos[plane[1]] - centre[1]), axis))
            check_coordinates(new, CAD_COORDINATE_LIMIT_M, lambda _k, at=where: at, "arc point")
            new_kinds = [FLATTENING] * (len(new) - 1) + [FEATURE]
        if np.linalg.norm(new[-1] - pos) <= 1e-12 and len(new) == 1:
            continue
        if current is None:
            current = _Sequence([pos.copy()], first_line=lineno, kinds=[VERTEX], block_ends=[(0, lineno)])
            sequences.append(current)
        if motion != 1:
            current.kinds[-1] = FEATURE  # an arc's ends are feature points
        back = [k for k, _ in current.block_ends if np.linalg.norm(current.points[k] - end) <= LOOP_TOLERANCE_M]
        current.points.extend(new)
        current.kinds.extend(new_kinds)
        current.last_line = lineno
        current.block_ends.append((len(current.points) - 1, lineno))
        pos = end
        if back:  # the path returns to a block end of its track: a closed loop ends the track
            current.points[-1] = current.points[back[0]].copy()
            sequences[-1:] = current.split_loop(back[0])
            current = None
    if not sequences:
        raise InputError(f"{source}: no feed moves (G1/G2/G3) found")
    return sequences, source


def points_from_gcode(
    path: str | Path,
    units: str = "mm",
    program: int | str | None = None,
    arc_tolerance_m: float = ARC_TOLERANCE_M,
) -> NDArray:
    """Read the feed path of a G-code program (see the module docstring for the dialect).

    Args:
        path: the G-code file (``.nc``, ``.ngc``, ``.gcode``, ``.tap``).
        units: length unit until the file says ``G20``/``G21``: ``"m"``, ``"mm"`` or ``"in"``.
        program: which feed sequence (track, 1-based, an int or a numeric string such as ``"2"``)
            when the file has several; None when there is only one.
        arc_tolerance_m: largest chord error of the arc discretisation [m], > 0.

    Returns:
        The feed path in the program's frame [m], shape (K, 3), K >= 2, from the start of the
        sequence's first feed move to the end of its last.

    Raises:
        InputError: unreadable file; a malformed line, an unsupported code or axis, an arc that
            is not a circle (naming the file and line); no feed moves; several feed sequences
            and no ``program`` (listing each one's start, length and lines); a bad ``program``.
    """
    sequences, source = _parse(Path(path), units, arc_tolerance_m)
    k = _program_index(program, len(sequences), source)
    if k is None and len(sequences) > 1:
        listed = "; ".join(
            f"{i}: lines {s.first_line}-{s.last_line}, starts at "
            f"{np.round(s.points[0] * 1e3, 3).tolist()} mm, length {s.length() * 1e3:.3f} mm"
            for i, s in enumerate(sequences, start=1)
        )
        raise InputError(
            f"{source}: {len(sequences)} feed sequences (tracks, split at rapids G0, plunges and retracts "
            f'along Z and closed loops): {listed}; choose one with cad.track = "<number>"'
        )
    chosen = sequences[k or 0]
    logger.debug(
        "%s: feed sequence %d of %d, %d points", source, (k or 0) + 1, len(sequences), len(chosen.points)
    )
    return np.array(chosen.points, dtype=float)


def tracks_from_gcode(
    path: str | Path, units: str = "mm", arc_tolerance_m: float = FLATTEN_TOLERANCE_M
) -> list[CadTrack]:
    """Every track (feed sequence) of a G-code program, with its block ends and arc ends.

    Tracks split at rapids, at plunges and retracts along Z and at closed loops (see the module
    docstring). Kinds (:class:`~refine.cad.resample.CadTrack`): the ends of arcs are feature
    points, the ends of linear blocks vertices, the points between an arc's ends flatten it.

    Args:
        path: the G-code file.
        units: length unit until the file says ``G20``/``G21``: ``"m"``, ``"mm"`` or ``"in"``.
        arc_tolerance_m: largest chord error of the arc discretisation [m], > 0.

    Returns:
        The tracks in file order, in the program's frame [m]; a closed one ends with its first point.

    Raises:
        InputError: what :func:`points_from_gcode` rejects except several sequences.
    """
    sequences, _ = _parse(Path(path), units, arc_tolerance_m)
    return [
        CadTrack(
            np.array(s.points, dtype=float),
            np.array(s.kinds, dtype=np.int8),
            s.closed,
            f"lines {s.first_line}-{s.last_line}",
        )
        for s in sequences
    ]


def gcode_circles(path: str | Path, units: str = "mm", arc_tolerance_m: float = FLATTEN_TOLERANCE_M) -> list:
    """The circles of the program's planar arc moves (G2/G3 without a helix's travel).

    Returns:
        ``(centre [m] (3,), radius [m], unit normal (3,))`` per arc, in the program's frame.
    """
    circles: list = []
    _parse(Path(path), units, arc_tolerance_m, circles)
    return circles
