"""Simulated demonstrations with slow hand wander, for the tracker frame check's tests and benchmark.

Each scene is a closed bead in a horizontal plane, demonstrated with the simulator's tracker errors
(noise, distortion, tremor, outliers) plus hand wander (``TrackerModel.wander_position_m``,
``wander_time_s``) cycling through 0.5-2 mm RMS and 0.1-1 s correlation time with the seed:

* ``small``: a round profile 30, 42 or 60 mm across, 0.18 m from the receiver, at 10 mm/s;
* ``large``: a rounded rectangle 0.5-3 m long (0.6 times as wide), the receiver 0.3 m under its
  centre, at 0.1 m/s.

:func:`frame_estimate` cleans and fuses the log as a run does, with the problem's
``source_in_world`` turned by a known angle about a world axis (or shifted), and returns the
frame estimate the gate judges.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from refine.demo import clean_demonstration
from refine.demo.quality import FrameEstimate
from refine.demo.simulate import TrackerModel, simulate_demonstration
from refine.frames import transform_from_xyz_rpy
from refine.fuse.frame_check import estimate_frame_error
from refine.fuse.fusion import fuse
from refine.paths import CadPath, Demonstration
from refine.settings import DemoSettings
from refine.synthetic import rounded_rectangle, tool_rotations

T_TCP_E = transform_from_xyz_rpy([-0.035, 0.0, -0.095], [180.0, 20.0, 0.0])
WANDER_M = (0.0005, 0.001, 0.0015, 0.002)
WANDER_TIME_S = (0.1, 0.3, 1.0)
SMALL_DIAMETERS_M = (0.030, 0.042, 0.060)
LARGE_LENGTHS_M = (0.5, 1.0, 2.0, 3.0)


@dataclass(frozen=True)
class Scene:
    """A simulated demonstration of a closed bead and its truth."""

    name: str
    demo: Demonstration
    cad: CadPath
    source_in_world: np.ndarray
    wander_m: float
    wander_time_s: float


def _bead(centre, half_u: float, half_v: float, r: float, spacing_m: float):
    n = max(int(2.0 * (half_u + half_v) * 2.0 / spacing_m), 60)
    u, v, du, dv, _, perimeter = rounded_rectangle(half_u, half_v, r, n)
    s = np.arange(n) * perimeter / n
    pos = np.asarray(centre, float) + np.column_stack([u, v, np.zeros(n)])
    tangent = np.column_stack([du, dv, np.zeros(n)])
    rots = tool_rotations(tangent, np.tile([0.0, 0.0, 1.0], (n, 1)), np.full(n, np.radians(10.0)))
    return s, pos, rots


@lru_cache(maxsize=64)
def scene(
    kind: str,
    seed: int,
    wander_m: float | None = None,
    wander_time_s: float | None = None,
    size_m: float | None = None,
) -> Scene:
    """The ``kind`` (``"small"`` or ``"large"``) scene for ``seed`` (module docstring); ``wander_m``,
    ``wander_time_s`` and ``size_m`` (diameter or length) override the seed's choice."""
    wander_m = WANDER_M[seed % len(WANDER_M)] if wander_m is None else wander_m
    wander_time_s = WANDER_TIME_S[(seed // 2) % len(WANDER_TIME_S)] if wander_time_s is None else wander_time_s
    if kind == "small":
        diameter = SMALL_DIAMETERS_M[seed % len(SMALL_DIAMETERS_M)] if size_m is None else size_m
        r = diameter / 2.0
        s, pos, rots = _bead([0.55, -0.25, 0.80], r + 1e-6, r + 1e-6, r, 0.001)
        T_F_S = transform_from_xyz_rpy([0.60, -0.42, 0.78], [0.0, 0.0, 90.0])
        speed, name = 0.01, f"round {diameter * 1e3:.0f} mm"
    elif kind == "large":
        length = LARGE_LENGTHS_M[seed % len(LARGE_LENGTHS_M)] if size_m is None else size_m
        s, pos, rots = _bead([0.0, 0.0, 0.0], length / 2, 0.3 * length, 0.05, 0.01)
        T_F_S = transform_from_xyz_rpy([0.02, -0.03, -0.30], [0.0, 0.0, 30.0])
        speed, name = 0.1, f"rectangle {length:.1f} m"
    else:
        raise ValueError(kind)
    model = TrackerModel(seed=seed, pause_s=1.0, wander_position_m=wander_m, wander_time_s=wander_time_s)
    sim = simulate_demonstration(s, pos, rots, np.full(len(s), speed), T_F_S, T_TCP_E, model)
    demo = clean_demonstration(sim.log, DemoSettings(file=Path(f"{kind}-{seed}.liberty")))
    name += f", wander {wander_m * 1e3:.1f} mm / {wander_time_s:g} s, seed {seed}"
    return Scene(name, demo, CadPath(s=s, positions=pos), T_F_S, wander_m, wander_time_s)


def given_frame(sc: Scene, angle_deg: float = 0.0, world_axis=(0.0, 0.0, 1.0), shift_m=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The problem's ``source_in_world``: the true one turned by ``angle_deg`` about ``world_axis``
    through the receiver, then moved by ``shift_m`` in the world."""
    T = sc.source_in_world.copy()
    turn = Rotation.from_rotvec(np.radians(angle_deg) * np.asarray(world_axis, float)).as_matrix()
    T[:3, :3] = turn @ T[:3, :3]
    T[:3, 3] += np.asarray(shift_m, float)
    return T


def frame_estimate(sc: Scene, T_F_S: np.ndarray, estimator=estimate_frame_error) -> FrameEstimate:
    """Fuse the scene's demonstration with ``T_F_S`` and estimate the frame error."""
    fused = fuse(sc.cad, sc.demo, T_F_S, T_TCP_E)
    return estimator(sc.demo, fused, T_F_S, T_TCP_E)
