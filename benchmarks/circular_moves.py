"""Would circular moves (RAPID ``MoveC``, KRL ``CIRC``, URScript ``movec``) serve the CAD's arcs better?

For every arc of the bundled problems' DXF paths (``ARC`` entities and polyline bulges) and of the
DXF of ``benchmarks/cad_chord.py`` (sharp corners and 20 mm arcs) it prints the arc (radius,
sweep, length), the straight moves the CAD stage places on it now (``read_cad_tracks``: at most
``spacing_m`` apart and within ``[cad] chord_tolerance_m`` of the arc), how many of those the
chord tolerance alone would need (``sweep / (2 acos(1 - tol / r))``, rounded up) and how many the
spacing alone (``length / spacing_m``, rounded up), and the circular moves that would replace them
(one per 90 deg of sweep: a via and an end target each). With ``--runs DIR`` (finished runs of the
same problems, ``DIR/<problem>/trajectory.csv``) it adds what a circular move would have to
reproduce along the arc: the largest angle between the refined tool axis and the one a circular
move gives, the orientation in the arc's tangent frame turned at a constant rate from the start
target's to the end target's (ABB's ``CirPathMode \\PathFrame``, KUKA's ``$CIRC_TYPE = #PATH``
with ``#VAR``), and the planned speed's range.

    python3 benchmarks/circular_moves.py [--runs /tmp/out]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from cad_chord import test_dxf  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from refine.cad import read_cad_tracks  # noqa: E402
from refine.cad.csv_ import metres_per_unit  # noqa: E402
from refine.problem import load_problem  # noqa: E402

PROBLEMS = ("glass_adhesive", "gp12_arc_weld", "kr8_arc_weld", "m20ia_arc_weld", "tig_weld")
ON_ARC_M = 1e-5
"""A waypoint this close to the arc's circle, inside its sweep, is on the arc [m]."""


def dxf_arcs(file: Path, layer: str | None, scale: float) -> list[tuple[np.ndarray, float, float, float]]:
    """Arcs of a DXF (centre (2,) [m], radius [m], start angle, signed sweep [rad]): ARCs and bulges."""
    import ezdxf
    from ezdxf.math import bulge_to_arc

    arcs = []
    for e in ezdxf.readfile(file).modelspace():
        if layer is not None and e.dxf.layer != layer:
            continue
        if e.dxftype() == "ARC":
            a0, a1 = math.radians(e.dxf.start_angle), math.radians(e.dxf.end_angle)
            arcs.append((np.array([e.dxf.center.x, e.dxf.center.y]) * scale, e.dxf.radius * scale, a0, (a1 - a0) % (2 * math.pi)))
        elif e.dxftype() == "LWPOLYLINE":
            pts = e.get_points("xyb")
            for (x0, y0, b), (x1, y1, _) in zip(pts, pts[1:], strict=False):
                if b:
                    c, a0, a1, r = bulge_to_arc((x0, y0), (x1, y1), b)
                    sweep = (a1 - a0) % (2 * math.pi)
                    arcs.append((np.array([c.x, c.y]) * scale, r * scale, a0, sweep))
    return arcs


def on_arc(p: np.ndarray, centre: np.ndarray, r: float, a0: float, sweep: float) -> np.ndarray:
    """Mask of the points (K, 2) on the arc."""
    d = p - centre
    ang = (np.arctan2(d[:, 1], d[:, 0]) - a0) % (2 * math.pi)
    return (np.abs(np.linalg.norm(d, axis=1) - r) < ON_ARC_M) & (ang <= sweep + 1e-9)


def along_arc(run: Path, T_world_cad: np.ndarray, centre, r, a0, sweep) -> str:  # noqa: ANN001
    """The refined orientation's turn in the arc's tangent frame and the speed range on the arc."""
    rows = np.genfromtxt(run / "trajectory.csv", delimiter=",", names=True)
    p_world = np.column_stack([rows["x_ref"], rows["y_ref"], rows["z_ref"]])
    p_cad = (np.linalg.inv(T_world_cad) @ np.column_stack([p_world, np.ones(len(p_world))]).T).T[:, :3]
    mask = on_arc(p_cad[:, :2], centre, r, a0, sweep)
    if mask.sum() < 2:
        return "no waypoints of the run on it"
    q = np.column_stack([rows["qx"], rows["qy"], rows["qz"], rows["qw"]])[mask]
    d = p_cad[mask, :2] - centre
    tangent_turn = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    tangent_turn -= tangent_turn[0]
    # the tool in the arc's frame: undo the frame's turn about the CAD z axis (in the world)
    R_cad = Rotation.from_matrix(T_world_cad[:3, :3])
    frame = R_cad * Rotation.from_rotvec(np.outer(tangent_turn, [0.0, 0.0, 1.0])) * R_cad.inv()
    in_frame = frame.inv() * Rotation.from_quat(q)
    # what the circular move would hold: the tool in the arc's frame turning at a constant rate from
    # its start to its end orientation (the slerp in that frame, at the fraction of the sweep)
    frac = tangent_turn / tangent_turn[-1]
    step = (in_frame[0].inv() * in_frame[-1]).as_rotvec()
    held = in_frame[0] * Rotation.from_rotvec(np.outer(frac, step))
    axis = in_frame.apply([0.0, 0.0, 1.0])  # the tool axis (a torch or nozzle may spin freely about it)
    held_axis = held.apply([0.0, 0.0, 1.0])
    drift = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", axis, held_axis), -1.0, 1.0))).max()
    demo = Rotation.from_quat(
        np.column_stack([rows["qx_demo"], rows["qy_demo"], rows["qz_demo"], rows["qw_demo"]])[mask]
    ).apply([0.0, 0.0, 1.0])
    held_world = (frame * held).apply([0.0, 0.0, 1.0])
    off_demo = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", held_world, demo), -1.0, 1.0))).max()
    refined_off = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", Rotation.from_quat(q).apply([0.0, 0.0, 1.0]), demo), -1.0, 1.0))).max()
    v = rows["speed"][mask] * 1e3
    return (
        f"{mask.sum()} run waypoints: tool turns {math.degrees(abs(tangent_turn[-1])):.1f} deg with the tangent, "
        f"its axis up to {drift:.2f} deg off the circular move's, which is up to {off_demo:.2f} deg off "
        f"the demonstration's (the refined: {refined_off:.2f} deg); speed {v.min():.2f}-{v.max():.2f} mm/s"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, help="folder of finished runs, DIR/<problem>/trajectory.csv")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cases = [(n, load_problem(ROOT / "problems" / n)) for n in PROBLEMS]
        settings = [(n, p.cad, p.frames.cad_in_world) for n, p in cases]
        settings.append(("test DXF (corners, 20 mm arcs)", test_dxf(Path(tmp)), None))
        print(f"{'path':31s} {'r mm':>6s} {'sweep':>6s} {'L mm':>6s} {'MoveL now':>9s} {'chord only':>10s} "
              f"{'spacing only':>12s} {'circular':>8s}")
        for name, cad, T in settings:
            scale = metres_per_unit(cad.units, str(cad.file))
            arcs = dxf_arcs(cad.file, cad.layer, scale)
            tracks = read_cad_tracks(cad, np.eye(4))  # in the drawing's frame
            tol = cad.chord_tolerance_m
            if not arcs:
                print(f"{name:31s} no arcs ({sum(len(t.s) for t in tracks)} waypoints on polylines)")
            for centre, r, a0, sweep in arcs:
                placed = sum(int(on_arc(t.positions[:, :2], centre, r, a0, sweep).sum()) for t in tracks) - 1
                chord = math.ceil(sweep / (2.0 * math.acos(1.0 - tol / r)) - 1e-9)
                spacing = math.ceil(r * sweep / cad.spacing_m - 1e-9)
                circular = math.ceil(sweep / (math.pi / 2) - 1e-9)
                line = (f"{name:31s} {r * 1e3:6.1f} {math.degrees(sweep):6.1f} {r * sweep * 1e3:6.1f} {placed:9d} "
                        f"{chord:10d} {spacing:12d} {circular:5d} x2")
                if args.runs is not None and T is not None and (args.runs / name / "trajectory.csv").exists():
                    line += "   " + along_arc(args.runs / name, T, centre, r, a0, sweep)
                print(line)


if __name__ == "__main__":
    main()
