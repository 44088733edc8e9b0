"""How far the straight moves between waypoints leave the CAD geometry: even spacing against kept features.

For every bundled problem's CAD path (and the DXF of ``tests/cad/test_cad_geometry.py``: sharp corners
and 20 mm arcs) it prints the waypoint count and the largest distance of the CAD geometry (the
reader's polyline, arcs flattened within 1 µm) from the polyline through the waypoints, once for the
waypoints at equal arc-length steps (``resample_by_arc_length``) and once as the CAD stage places
them (``read_cad_path``: feature points and corners kept, ``[cad] chord_tolerance_m``).

The distance is measured by projection, independently of the arc-length bookkeeping of
:func:`refine.paths.chord_error`: each geometry point against the nearest segment of the waypoints'
polyline (the two segments at each of its 8 nearest waypoints). With ``--runs DIR`` it measures the
reached TCP positions of finished runs instead (``DIR/<problem>/trajectory*.csv``).

    python3 benchmarks/cad_chord.py [--runs out/before]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from refine.cad import read_cad_tracks  # noqa: E402
from refine.cad.resample import resample_by_arc_length  # noqa: E402
from refine.problem import load_problem  # noqa: E402
from refine.settings import CadSettings  # noqa: E402

PROBLEMS = ("glass_adhesive", "glass_calibrated", "kr8_arc_weld", "tig_weld", "ur10e_sealing")


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance of each point to the nearest segment of ``polyline`` (near its 8 nearest vertices)."""
    tree = cKDTree(polyline)
    _, near = tree.query(points, k=min(8, len(polyline)))
    best = np.full(len(points), np.inf)
    for col in near.T:
        for j in (col - 1, col):
            j = np.clip(j, 0, len(polyline) - 2)
            a, b = polyline[j], polyline[j + 1]
            ab = b - a
            t = np.clip(np.einsum("ij,ij->i", points - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
            best = np.minimum(best, np.linalg.norm(a + t[:, None] * ab - points, axis=1))
    return best


def test_dxf(folder: Path) -> CadSettings:
    """The DXF of the tests: corners at (100, 0) and (120, 100) mm, two 20 mm quarter arcs."""
    import ezdxf

    doc = ezdxf.new()
    msp = doc.modelspace()
    msp.add_line((-2.5, 0), (100, 0))
    msp.add_line((100, 0), (100, 40))
    msp.add_arc((100, 60), 20.0, -90.0, 0.0)
    msp.add_line((120, 60), (120, 100))
    msp.add_lwpolyline([(120, 100, 0.0), (62.5, 100, math.tan(math.pi / 8)), (42.5, 120, 0.0)], format="xyb")
    path = folder / "bead.dxf"
    doc.saveas(path)
    return CadSettings(file=path, format="dxf", units="mm", spacing_m=0.005, layer="0")


def reached(runs: Path, name: str) -> np.ndarray | None:
    files = sorted((runs / name).glob("trajectory*.csv"))
    if not files:
        return None
    rows = [np.genfromtxt(f, delimiter=",", names=True) for f in files]
    return [np.column_stack([r["x"], r["y"], r["z"]]) for r in rows]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, help="measure the reached TCP of the runs in this folder")
    args = parser.parse_args()
    cases = [(name, load_problem(ROOT / "problems" / name)) for name in PROBLEMS]
    with tempfile.TemporaryDirectory() as tmp:
        settings = [(name, p.cad, p.frames.cad_in_world) for name, p in cases]
        settings.append(("test DXF (corners, 20 mm arcs)", test_dxf(Path(tmp)), np.eye(4)))
        print(f"{'path':34s} {'even: waypoints':>16s} {'chord mm':>9s} {'kept: waypoints':>16s} {'chord mm':>9s}")
        for name, cad, T in settings:
            tracks = read_cad_tracks(cad, T)
            n_even = n_kept = 0
            e_even = e_kept = 0.0
            for track in tracks:
                geometry = track.exact
                _, even = resample_by_arc_length(geometry, cad.spacing_m)
                n_even += len(even)
                n_kept += len(track.s)
                e_even = max(e_even, float(distance_to_polyline(geometry, even).max()))
                e_kept = max(e_kept, float(distance_to_polyline(geometry, track.positions).max()))
            line = f"{name:34s} {n_even:16d} {e_even * 1e3:9.4f} {n_kept:16d} {e_kept * 1e3:9.4f}"
            if args.runs is not None and (got := reached(args.runs, name)) is not None:
                e_run = max(float(distance_to_polyline(t.exact, r).max()) for t, r in zip(tracks, got, strict=False))
                line += f"   reached in {args.runs.name}: {e_run * 1e3:.4f} mm"
            print(line)


if __name__ == "__main__":
    main()
