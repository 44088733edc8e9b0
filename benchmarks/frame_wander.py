"""The tracker frame check under slow hand wander: false stops on right frames, detections of wrong ones.

Scenes from ``tests/demo/wander_scenes.py`` (round profiles 30-60 mm across and rounded rectangles
0.5-3 m long, hand wander 0.5-2 mm RMS with correlation times 0.1-1 s) are fused with the right
``source_in_world``, with it turned by 5 deg about world x, y or z, and with it shifted by 50 mm.
Per case it prints, over the seeds, how often the gate would stop (rotation), warn that the path
cannot check the frame well (``weak``: the least rotation it tells from noise is above
``WEAK_CHECK_DEG``, and it does not stop), warn about the offset, or find a rotation axis not
observable, and how often the fusion itself refused the demonstration (it does not follow the
path: a wrong frame caught before the check). ``--compare FILE`` runs another copy of
``refine/demo/quality.py`` (e.g. an older one) on the same fused data as well.

    python benchmarks/frame_wander.py --seeds 20
    python benchmarks/frame_wander.py --seeds 20 --compare /tmp/old/refine/demo/quality.py
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "demo"))

from wander_scenes import given_frame, scene  # noqa: E402

from refine.demo import quality  # noqa: E402
from refine.errors import InputError  # noqa: E402
from refine.fuse.fusion import fuse

CASES = {
    "right frame": {},
    "5 deg about x": {"angle_deg": 5.0, "world_axis": (1.0, 0.0, 0.0)},
    "5 deg about y": {"angle_deg": 5.0, "world_axis": (0.0, 1.0, 0.0)},
    "5 deg about z": {"angle_deg": 5.0, "world_axis": (0.0, 0.0, 1.0)},
    "shift 50 mm": {"shift_m": (0.05, 0.0, 0.0)},
}


KEYS = ("stop", "weak", "offset warning", "an axis not observable", "refused")


def verdict(module, est) -> tuple[bool, ...]:
    """(stop, weak, offset warning, a rotation axis not observable, refused) as ``module``'s gate decides."""
    stop = est.observable_rotation_deg > module.FRAME_STOP_DEG and module.frame_error_significant(est)
    weak = not stop and est.detectable_deg > module.WEAK_CHECK_DEG
    offset = est.offset_m > module.OFFSET_WARN_M and est.offset_chi2 > module._chi2_threshold(3)
    return stop, weak, offset, bool(est.not_observable), False


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--kinds", nargs="*", default=["small", "large"])
    parser.add_argument("--compare", type=Path, help="another quality.py to run on the same data")
    parser.add_argument("-v", action="store_true", help="one line per seed")
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)
    modules = {"now": quality}
    if args.compare:
        spec = importlib.util.spec_from_file_location("quality_compare", args.compare)
        other = importlib.util.module_from_spec(spec)
        sys.modules["quality_compare"] = other
        spec.loader.exec_module(other)
        modules = {"compare": other, "now": quality}
    for kind in args.kinds:
        counts = {(c, m): [0] * len(KEYS) for c in CASES for m in modules}
        for seed in range(args.seeds):
            sc = scene(kind, seed)
            for case, change in CASES.items():
                T = given_frame(sc, **change)
                try:
                    fused = fuse(sc.cad, sc.demo, T, wander_T_TCP_E())
                except InputError as e:
                    for m in modules:
                        counts[(case, m)][-1] += 1
                    if args.v:
                        print(f"{kind} {case:14s} {sc.name}: refused by the fusion: {e}", flush=True)
                    continue
                for m, module in modules.items():
                    est = module.estimate_frame_error(sc.demo, fused, T, wander_T_TCP_E())
                    v = verdict(module, est)
                    for k, hit in enumerate(v):
                        counts[(case, m)][k] += hit
                    if args.v:
                        print(
                            f"{kind} {case:14s} {m:7s} {sc.name}: {est.observable_rotation_deg:5.1f} ± "
                            f"{est.observable_sigma_deg:4.1f} deg, offset {est.offset_m * 1e3:4.0f} mm "
                            f"(chi2 {est.offset_chi2:.0f}), hidden {len(est.not_observable)}, "
                            f"{'STOP' if v[0] else 'pass'}{' WEAK' if v[1] else ''}{' OFFSET' if v[2] else ''}",
                            flush=True,
                        )
        for (case, m), row in counts.items():
            text = ", ".join(f"{key} {n:2d}/{args.seeds}" for key, n in zip(KEYS, row, strict=True))
            print(f"{kind:5s} {case:14s} {m:7s}: {text}", flush=True)


def wander_T_TCP_E():
    from wander_scenes import T_TCP_E

    return T_TCP_E


if __name__ == "__main__":
    main()
