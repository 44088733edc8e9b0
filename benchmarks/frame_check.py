"""The tracker frame check over a matrix of cells, planted frame rotations and tracker noise.

Every bundled problem with a tracker log (``problems/*`` and ``problems/unreachable/*``) and two
simulated straight TIG seams are read, cleaned and fused as ``refine run`` does, with the
problem's ``source_in_world`` turned by a known angle about a world axis through the receiver
(the truth). Right frames (angle 0) are also run on copies of the log perturbed by white noise of
the tracker's size (``perturb_log``, one seed per copy). Each row prints the frame estimate the
gate judges (the observable part of the rotation, ± its standard uncertainty) and the verdict:
``stop`` (the run would stop), ``warn`` (a frame warning in ``demo_quality``), ``weak`` (the
"cannot be checked well" warning), ``ok`` (no frame warning) or ``refused`` (the fusion itself
refuses the demonstration: it does not follow the path). A right frame must give ``ok``; a
rotation of 5 or 10 deg must give ``stop`` (or ``refused``) unless about an axis the path cannot
show.

    python benchmarks/frame_check.py                         # everything (about 1.5 min alone)
    python benchmarks/frame_check.py tig_weld glass_adhesive --angles 0 5 --seeds 2
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from refine.cad import read_cad_path
from refine.demo import clean_demonstration, read_tracker_log
from refine.demo.quality import FRAME_STOP_DEG, FRAME_WARN_DEG, gate_dropouts
from refine.demo.simulate import TrackerModel, perturb_log, simulate_demonstration
from refine.errors import InputError
from refine.frames import transform_from_xyz_rpy
from refine.fuse.frame_check import gate_frame
from refine.fuse.fusion import fuse
from refine.paths import CadPath
from refine.problem import load_problem
from refine.settings import DemoSettings

ROOT = Path(__file__).resolve().parents[1]
AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


@dataclasses.dataclass
class Case:
    """What the frame gate needs: the CAD path, the raw log, the cleaning settings and the frames."""

    name: str
    cad: CadPath
    log: object
    settings: DemoSettings
    source_in_world: np.ndarray
    sensor_in_tcp: np.ndarray


def bundled(names: list[str] | None) -> list[Case]:
    """Every bundled problem with a tracker log (or those named)."""
    folders = sorted(p.parent for p in (ROOT / "problems").glob("*/problem.toml"))
    folders += sorted(p.parent for p in (ROOT / "problems" / "unreachable").glob("*/problem.toml"))
    cases = []
    for folder in folders:
        label = folder.name if folder.parent.name == "problems" else f"unreachable/{folder.name}"
        if names and folder.name not in names and label not in names:
            continue
        problem = load_problem(folder)
        if problem.demonstration is None or problem.cad is None or problem.cad.format == "pathml":
            continue
        cad = read_cad_path(problem.cad, problem.frames.cad_in_world)
        cases.append(
            Case(
                label,
                cad,
                read_tracker_log(problem.demonstration),
                problem.demonstration,
                problem.frames.source_in_world,
                problem.tool.sensor_in_tcp,
            )
        )
    return cases


def straight_seams(names: list[str] | None) -> list[Case]:
    """A straight 0.15 m TIG seam 0.6 m from the receiver, simulated with two tracker seeds."""
    T_F_S = transform_from_xyz_rpy([0.60, -0.42, 0.78], [0.0, 0.0, 90.0])
    T_TCP_E = transform_from_xyz_rpy([-0.035, 0.0, -0.095], [180.0, 20.0, 0.0])
    s = np.linspace(0.0, 0.15, 151)
    pos = np.array([0.55, -0.25, 0.80]) + s[:, None] * np.array([0.0, 1.0, 0.0])
    rots = np.repeat(np.diag([1.0, -1.0, -1.0])[None], len(s), axis=0)
    cases = []
    for seed in (2, 3):
        label = f"straight_seam/{seed}"
        if names and label not in names and "straight_seam" not in names:
            continue
        sim = simulate_demonstration(
            s, pos, rots, np.full(len(s), 0.005), T_F_S, T_TCP_E, TrackerModel(seed=seed, pause_s=1.0)
        )
        settings = DemoSettings(file=Path("seam.liberty"))
        cases.append(Case(label, CadPath(s=s, positions=pos), sim.log, settings, T_F_S, T_TCP_E))
    return cases


def rotated(T: np.ndarray, axis: str, angle_deg: float) -> np.ndarray:
    """``T`` turned by ``angle_deg`` about the world axis ``axis`` through its origin."""
    out = T.copy()
    out[:3, :3] = Rotation.from_rotvec(np.radians(angle_deg) * np.asarray(AXES[axis])).as_matrix() @ T[:3, :3]
    return out


def verdict(case: Case, log, T_F_S: np.ndarray, planted_s_deg: np.ndarray) -> tuple[str, str, float]:
    """The frame gate for ``log`` with ``T_F_S`` as the frame.

    Args:
        case: the cell.
        log: the raw tracker log.
        T_F_S: the (possibly rotated) frame given to refine.
        planted_s_deg: the planted rotation as a rotation vector in the receiver frame [deg].

    Returns:
        The verdict, the estimate as text and the planted rotation's part about the axes the
        path shows [deg] (NaN when the fusion refused).
    """
    raw, quality = gate_dropouts(log)
    demo = clean_demonstration(raw, case.settings)
    try:
        fused = fuse(case.cad, demo, T_F_S, case.sensor_in_tcp)
    except InputError as e:
        return "refused", str(e).split(":")[-1].strip()[:40], float("nan")
    try:
        q = gate_frame(quality, demo, fused, T_F_S, case.sensor_in_tcp)
        kind = "ok"
    except InputError:
        q = gate_frame(quality, demo, fused, T_F_S, case.sensor_in_tcp, accept=True)
        kind = "stop"
    f = q.frame
    frame_warnings = [w for w in q.warnings if "frame" in w]  # a rotation or an offset
    if kind == "ok" and frame_warnings:
        kind = "weak" if any("cannot be checked well" in w for w in frame_warnings) else "warn"
    hidden = ",".join(
        h["about"].replace("the path direction", "path").replace("receiver axis ", "S")
        for h in f.not_observable
    )
    planted = np.asarray(planted_s_deg, float)
    for h in f.not_observable:
        a = np.asarray(h["axis_in_source"])
        planted = planted - (planted @ a) * a
    text = f"{f.observable_rotation_deg:5.1f} ± {f.observable_sigma_deg:4.1f}" + (
        f" (hidden {hidden})" if hidden else ""
    )
    return kind, text, float(np.linalg.norm(planted))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "cases", nargs="*", help="problem folder names, e.g. tig_weld joint_wrap straight_seam"
    )
    parser.add_argument("--angles", nargs="+", type=float, default=[0.0, 2.0, 5.0, 10.0], help="[deg]")
    parser.add_argument("--axes", nargs="+", default=["x", "y", "z"], choices=list(AXES))
    parser.add_argument("--seeds", type=int, default=3, help="perturbed copies of each right-frame log")
    parser.add_argument(
        "--rotated-seeds", type=int, default=1, help="perturbed copies of each rotated-frame log"
    )
    args = parser.parse_args(argv)
    logging.disable(logging.WARNING)
    cases = bundled(args.cases or None) + straight_seams(args.cases or None)
    print(f"frame gate: warn above {FRAME_WARN_DEG} deg, stop above {FRAME_STOP_DEG} deg")
    print(
        f"{'case':34s} {'axis':>4s} {'deg':>5s} {'noise':>6s} {'shown':>5s}  {'estimate [deg]':34s} verdict"
    )
    bad = weak = 0
    z_scores = []
    summary: dict[tuple[str, str, float], list[str]] = {}
    t0 = time.perf_counter()
    for case in cases:
        rows = []
        if 0.0 in args.angles:
            rows.append(("-", 0.0, None))
            rows += [("-", 0.0, seed) for seed in range(1, args.seeds + 1)]
        rows += [
            (a, ang, seed)
            for a in args.axes
            for ang in args.angles
            if ang != 0.0
            for seed in [None, *range(1, args.rotated_seeds + 1)]
        ]
        for axis, angle, seed in rows:
            log = case.log if seed is None else perturb_log(case.log, TrackerModel(), 7000 + seed)
            T = case.source_in_world if angle == 0.0 else rotated(case.source_in_world, axis, angle)
            planted = np.radians(angle) * np.asarray(AXES[axis]) if angle else np.zeros(3)
            planted_s = np.degrees(case.source_in_world[:3, :3].T @ planted)
            kind, text, shown = verdict(case, log, T, planted_s)
            # a right frame must pass without a frame warning ("weak" says the path cannot show
            # one well, counted apart); a rotation whose observable part is >= 5 deg must stop
            wrong = (angle == 0.0 and kind in ("stop", "warn")) or (shown >= 5.0 and kind in ("ok", "weak"))
            weak += angle == 0.0 and kind == "weak"
            if kind != "refused":
                est, sigma = (float(v) for v in text.split(" (")[0].split("±"))
                z_scores.append(abs(est - shown) / max(sigma, 1e-9))
            bad += wrong
            cell = summary.setdefault((case.name, axis, angle), [])
            if seed is None:
                cell.insert(0, text.split(" (")[0] if kind != "refused" else "refused by the fusion")
            cell.append(kind)
            noise = "-" if seed is None else f"s{seed}"
            print(
                f"{case.name:34s} {axis:>4s} {angle:5.1f} {noise:>6s} {shown:5.1f}  {text:34s} {kind}"
                + ("  <-" if wrong else ""),
                flush=True,
            )
    print(
        f"{bad} rows against the truth (a right frame stopped or warned about, or an observable part "
        f">= 5 deg not stopped); {weak} right frames the path cannot check well; {time.perf_counter() - t0:.0f} s"
    )
    z = np.asarray(z_scores)
    print(
        f"uncertainty: the estimated angle is more than 2 sigma from the planted one in {np.mean(z > 2):.1%} "
        f"of {len(z)} rows, more than 3 sigma in {np.mean(z > 3):.1%}"
    )
    print("\nsummary: estimate of the log as recorded [deg], then the verdict of it and of each noisy copy")
    print(f"| {'case':34s} | axis | deg | {'estimate':21s} | verdicts |")
    print(f"|{'-' * 36}|------|-----|{'-' * 23}|----------|")
    for (name, axis, angle), (est, *kinds) in summary.items():
        print(f"| {name:34s} | {axis:4s} | {angle:3.0f} | {est:21s} | {' '.join(kinds)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
