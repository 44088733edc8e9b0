"""The tracks of a CAD/CAM file fused with one demonstration that runs them all.

A G-code program or a DXF drawing can hold several tracks (:func:`refine.cad.read_cad_tracks`);
the worker demonstrates them one after the other, in the program's order, moving the tool in the
air between them. The tracks are joined into one open path (:func:`join_tracks`): each track's
waypoints, and between the end of one and the start of the next a straight connector with
waypoints at most the spacing apart. That path is fused as one (its direction and start are the
program's, not searched), and the fused path is cut back into the tracks (:func:`split_tracks`);
the connectors' waypoints are dropped. Each track then becomes a pass of the run.

The connectors stand for the worker's moves between tracks, which a hand does not make straight:
the alignment follows the demonstration along them as along a track.
"""

from __future__ import annotations

import math

import numpy as np

from refine.errors import InputError
from refine.paths import CadPath, FusedPath

#: Track ends closer than this are joined without a connector [m].
JOIN_TOLERANCE_M = 1e-9


def join_tracks(tracks: list[CadPath], spacing_m: float) -> tuple[CadPath, list[tuple[int, int]]]:
    """The tracks joined in order into one open path, with straight connectors between them.

    Args:
        tracks: the tracks in {F}, in the order they are run, at least two.
        spacing_m: largest step between the connectors' waypoints [m], > 0.

    Returns:
        The joined path (direction and start fixed) and, per track, the index of its first and
        last waypoint in it.

    Raises:
        InputError: fewer than two tracks or a non-positive spacing.
    """
    if len(tracks) < 2:
        raise InputError(f"join_tracks: needs at least 2 tracks, got {len(tracks)}")
    if not (math.isfinite(spacing_m) and spacing_m > 0.0):
        raise InputError(f"join_tracks: spacing_m must be a finite number > 0 m, got {spacing_m!r}")
    positions = [tracks[0].positions]
    steps = [np.diff(tracks[0].s)]
    ranges = [(0, len(tracks[0].s) - 1)]
    count = len(tracks[0].s)
    for track in tracks[1:]:
        a, b = positions[-1][-1], track.positions[0]
        gap = float(np.linalg.norm(b - a))
        if gap > JOIN_TOLERANCE_M:
            n = max(1, math.ceil(gap / spacing_m))
            f = np.linspace(0.0, 1.0, n + 1)[1:-1, None]
            connector = a + f * (b - a)
            positions += [connector, track.positions]
            steps += [np.full(n, gap / n), np.diff(track.s)]
            first = count + len(connector)
            count += len(connector) + len(track.s)
        else:
            positions.append(track.positions[1:])
            steps.append(np.diff(track.s))
            first = count - 1
            count += len(track.s) - 1
        ranges.append((first, count - 1))
    joined = CadPath(
        s=np.r_[0.0, np.cumsum(np.concatenate(steps))],
        positions=np.vstack(positions),
        closed=False,
        source=", ".join(t.source for t in tracks),
        direction_given=True,
        start_given=True,
    )
    return joined, ranges


def split_tracks(fused: FusedPath, tracks: list[CadPath], ranges: list[tuple[int, int]]) -> list[FusedPath]:
    """The fused joined path cut back into its tracks, each with its own arc length and CAD geometry.

    Args:
        fused: the fused joined path (:func:`join_tracks`).
        tracks: the tracks it was joined from.
        ranges: per track, the index of its first and last waypoint in ``fused``.

    Returns:
        One fused path per track; ``s`` is the track's own (from 0), ``t_demo`` the joined path's.
    """
    out = []
    for track, (i0, i1) in zip(tracks, ranges, strict=True):
        k = slice(i0, i1 + 1)
        out.append(
            FusedPath(
                s=track.s.copy(),
                positions=fused.positions[k].copy(),
                rotations=fused.rotations[k].copy(),
                speed=fused.speed[k].copy(),
                t_demo=fused.t_demo[k].copy(),
                residual=fused.residual[k].copy(),
                order=fused.order,
                exact_s=track.exact_s,
                exact=track.exact,
                demo_positions=None if fused.demo_positions is None else fused.demo_positions[k].copy(),
            )
        )
    return out
