"""A close pair found by the collision model, and the gradient of its signed distance."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from refine.types import Array


@dataclass(frozen=True, eq=False)
class Contact:
    """One close pair: a robot or tool body and a cell object or another robot body.

    Attributes:
        body: robot link name or ``"tool:<shape name>"``.
        other: cell object name, or the other link (or tool shape) for a self pair.
        distance_m: signed distance [m]; negative = penetration depth.
        point_body: witness point on the body, world frame [m], (3,).
        point_other: witness point on the other, world frame [m], (3,).
        normal: unit vector (3,) along which moving the body increases the distance (from the
            other towards the body when apart).
        link: the robot link the body point moves with (the flange link for tool shapes).
        self_pair: the other is part of the robot or tool too.
        other_link: the link the other's point moves with (self pairs), else None.
        margin_m: the clearance this pair must keep [m] (``margin_m`` or ``self_margin_m``).
        body_shape: the body's shape name (a link may carry several).
        other_shape: the other's shape name.
    """

    body: str
    other: str
    distance_m: float
    point_body: Array
    point_other: Array
    normal: Array
    link: str
    self_pair: bool
    other_link: str | None = None
    margin_m: float = 0.0
    body_shape: str = ""
    other_shape: str = ""

    @property
    def clearance_m(self) -> float:
        """Distance left above the pair's margin [m]; negative when the margin is broken."""
        return self.distance_m - self.margin_m


def linearised_distance(contact: Contact, J_body: Array, J_other: Array | None = None) -> Array:
    """Gradient of a contact's signed distance with respect to the joints, shape (n,).

    Args:
        contact: the contact.
        J_body: Jacobian (3, n) of ``contact.point_body`` as a point fixed to ``contact.link``.
        J_other: Jacobian (3, n) of ``contact.point_other`` (self pairs), None for a static object.
    """
    J = np.asarray(J_body, dtype=float)
    if J_other is not None:
        J = J - np.asarray(J_other, dtype=float)
    return contact.normal @ J
