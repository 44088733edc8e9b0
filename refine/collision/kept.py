"""What a collision model of the same robot and moving bodies takes from the one built before it.

A re-solve builds a new :class:`refine.collision.model.CollisionModel` for the same robot, base,
tool and cell names, often with only the part moved. The pairs to check (their indices and labels),
the pairs' motion bounds and the moving bodies' hulls read none of the cell objects' shapes or
places, so the new model takes them from the previous one (:class:`Kept`), found by a digest of
everything they depend on (:func:`structure_key`).
"""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from refine.collision.geometry import Body
from refine.robot.model import Robot
from refine.types import Array

KEPT_MODELS = 8
"""Models whose pairs, motion bounds and moving hulls :data:`KEPT` keeps for the next model like them."""


@dataclass(eq=False)
class Kept:
    """What a model of the same robot, base, moving bodies, self margin and cell names takes as it is.

    None of it reads the cell objects' shapes or places (the pair rules for a cell object read only its
    name and whether it is the workpiece; the motion bounds only the moving bodies), so a re-solve whose
    part moved, or whose cone or margin changed, takes it from the previous call's model.
    """

    robot: Robot
    pin_model: pin.Model
    kept: list[tuple[int, int]]
    excluded: tuple[tuple[str, str, str], ...]
    notes: list[tuple[int, str, tuple]]  # the log lines of the selection, said again on each reuse
    motion: Array | None = None  # pair_reach of the pairs, read-only
    reach: Array | None = None  # joint_reach of the moving bodies, read-only
    hulls: dict[str, tuple[int, Array]] = field(default_factory=dict)  # moving bodies' hull corners
    # the pairs as the models index and name them: body indices (P,) each (read-only), their labels and
    # whether the other body is not a cell object (read-only); the bodies' order, labels and kinds are
    # all in the key, so a model of the same key indexes and names them alike
    index: tuple[Array, Array] | None = None
    labels: tuple[tuple[str, str], ...] | None = None
    self_pairs: Array | None = None


KEPT: dict[bytes, Kept] = {}
"""What :class:`Kept` the models built so far left, by :func:`structure_key`, oldest first."""
_LOCK = threading.Lock()


def structure_key(robot: Robot, base: Array, self_margin_m: float, bodies: list[Body]) -> bytes:
    """A digest of everything :class:`Kept` depends on: the moving bodies' geometry as built, not as named."""
    h = hashlib.blake2b(digest_size=24)
    h.update(repr((id(robot), id(robot.model), float(self_margin_m))).encode())
    h.update(base.tobytes())
    for b in bodies:
        h.update(repr((b.label, b.kind, b.joint, b.frame_id, b.workpiece, b.kind_params[0])).encode())
        if b.kind == "cell":
            continue
        for a in (b.link_T_shape, b.centre, b.half_extent, b.vertices, *b.kind_params[1:]):
            if a is not None:
                a = np.ascontiguousarray(a, dtype=float)
                h.update(repr(a.shape).encode() + a.tobytes())
    return h.digest()


def indexed_pairs(known: Kept, bodies: list[Body]) -> tuple[Array, Array, Array, tuple[tuple[str, str], ...]]:
    """The kept pairs' body indices (P,) each, whether each is a self pair (P,) and their labels.

    Made once per :class:`Kept` (read-only arrays) and taken as they are by every later model of its
    key: the key holds every body's label and kind in the bodies' order, which are all these read.
    """
    if known.labels is None or known.index is None or known.self_pairs is None:
        pa = np.array([p[0] for p in known.kept], dtype=int)
        pb = np.array([p[1] for p in known.kept], dtype=int)
        self_pairs = np.array([bodies[b].kind != "cell" for b in pb], dtype=bool)
        for a in (pa, pb, self_pairs):
            a.flags.writeable = False
        known.index, known.self_pairs = (pa, pb), self_pairs
        known.labels = tuple((bodies[a].label, bodies[b].label) for a, b in known.kept)
    return known.index[0], known.index[1], known.self_pairs, known.labels


def recall(key: bytes) -> Kept | None:
    """What a model of structure ``key`` left, or None."""
    with _LOCK:
        return KEPT.get(key)


def remember(key: bytes, known: Kept) -> None:
    """Keep ``known`` for the next model of structure ``key``, the oldest dropped past :data:`KEPT_MODELS`."""
    with _LOCK:
        KEPT[key] = known
        while len(KEPT) > KEPT_MODELS:
            del KEPT[next(iter(KEPT))]
