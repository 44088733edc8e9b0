"""Which files a run writes: ``trajectory.csv``, PathML and the programs asked for.

One pass gives one trajectory. The passes of a multi-pass weld are written as one PathML document
with a Layer per weld layer and a Track per pass, and as one program holding every pass (KRL,
URScript) or one RAPID module per pass.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from refine.errors import InputError
from refine.paths import Trajectory
from refine.settings import PROGRAM_FORMATS, ProcessParameter

if TYPE_CHECKING:
    from refine.run.result import PassResult, RunResult

log = logging.getLogger(__name__)


def concatenate(trajectories: list[Trajectory]) -> Trajectory:
    """The passes end to end in one Trajectory (times and arc lengths restart with each pass)."""
    return Trajectory(
        *(np.concatenate([getattr(t, f) for t in trajectories]) for f in Trajectory.__dataclass_fields__)
    )


def _pathml_layers(passes: list[PassResult], problem) -> list:  # noqa: ANN001 - Problem
    from refine.export.pathml import LayerLayout, TrackLayout

    layers: dict[int, list[TrackLayout]] = {}
    start = 0
    mp = problem.multipass
    for p in passes:
        n = len(p.fused)
        params = list(problem.process.parameters)
        if mp is not None and len(passes) > 1:
            params += [
                ProcessParameter("lateral_offset", mp.lateral_offsets_m[p.layer - 1][p.index - 1], "m"),
                ProcessParameter("layer_height", mp.layer_height_m * (p.layer - 1), "m"),
            ]
        layers.setdefault(p.layer, []).append(TrackLayout(f"Track{p.index}", start, start + n, tuple(params)))
        start += n
    return [
        LayerLayout(f"Layer{k}", tuple(tracks), problem.process.parameters)
        for k, tracks in sorted(layers.items())
    ]


def write_outputs(result: RunResult, out_dir: Path, programs: tuple[str, ...]) -> dict[str, Path]:
    """Write the trajectory CSV, the PathML document and ``programs`` for every executable pass.

    Returns:
        kind -> path of each file written (nothing when no pass is executable).
    """
    from refine.export import write_pathml, write_trajectory_csv

    for kind in programs:
        if kind not in PROGRAM_FORMATS:
            raise InputError(f"program format {kind!r} is not one of {', '.join(PROGRAM_FORMATS)}")
    done = [p for p in result.passes if p.trajectory is not None]
    if len(done) < len(result.passes):
        log.warning(
            "%d of %d passes are infeasible: no files but result.json",
            len(result.passes) - len(done),
            len(result.passes),
        )
        return {}
    problem, name = result.problem, result.problem.file_stem
    trajectories = [p.trajectory for p in done if p.trajectory is not None]
    outputs: dict[str, Path] = {}
    spec = result.robot.spec
    controller = [replace(t, q=spec.to_controller(t.q)) for t in trajectories]  # the joints the pendant shows
    if len(trajectories) == 1:
        outputs["trajectory"] = write_trajectory_csv(out_dir / "trajectory.csv", controller[0])
        outputs["pathml"] = write_pathml(out_dir / f"{name}.aml", trajectories[0], problem)
    else:
        for k, (p, t) in enumerate(zip(done, controller, strict=True), start=1):
            outputs[f"trajectory_{k}"] = write_trajectory_csv(
                out_dir / f"trajectory_L{p.layer}P{p.index}.csv", t
            )
        outputs["pathml"] = write_pathml(
            out_dir / f"{name}.aml", concatenate(trajectories), problem, layers=_pathml_layers(done, problem)
        )
    from refine.export.program import ProgramPass, with_motions

    if any(not m.ok for m in getattr(result, "motions", ())):
        log.warning("a motion of the program failed its checks: no files but result.json")
        return {}
    named = [
        ProgramPass(p.name, t, getattr(p.refinement, "repairs", ()))  # no refinement: written from a plan
        for p, t in zip(done, trajectories, strict=True)
    ]
    named = with_motions(named, getattr(result, "motions", ()))
    if getattr(result, "motions", ()):
        from refine.export.motions_csv import write_motions_csv

        outputs["motions"] = write_motions_csv(out_dir / "motions.csv", result.motions)
    air_percent = round(problem.output.air_speed_share * 100.0)  # the air moves' joint speed [%]
    for kind in programs:
        if kind == "rapid":
            from refine.export import write_rapid

            if len(named) == 1:
                outputs["rapid"] = write_rapid(
                    out_dir / f"{name}.mod",
                    trajectories[0],
                    problem,
                    result.robot,
                    repairs=named[0].repairs,
                    air_in=named[0].air_in,
                    air_out=named[0].air_out,
                    air_in_s=named[0].air_in_s,
                    air_out_s=named[0].air_out_s,
                )
            for k, (p, t) in enumerate(zip(done, trajectories, strict=True), start=1):
                if len(named) > 1:  # with planned motions, module k runs after module k - 1 (the link)
                    planned = named[k - 1].air_in is not None
                    outputs[f"rapid_{k}"] = write_rapid(
                        out_dir / f"{name}_L{p.layer}P{p.index}.mod",
                        t,
                        problem,
                        result.robot,
                        repairs=getattr(p.refinement, "repairs", ()),
                        pass_name=p.name,
                        air_in=named[k - 1].air_in,
                        air_out=named[k - 1].air_out,
                        air_in_s=named[k - 1].air_in_s,
                        air_out_s=named[k - 1].air_out_s,
                        start_home=k == 1 or not planned,
                        end_home=k == len(named) or not planned,
                    )
        elif kind == "krl":
            from refine.export.krl import write_krl

            src, dat = write_krl(
                out_dir / f"{name}.src",
                trajectories[0],
                problem,
                result.robot,
                passes=named,
                ptp_percent=air_percent,
            )
            outputs["krl_src"], outputs["krl_dat"] = src, dat
        elif kind == "urscript":
            from refine.export.urscript import write_urscript

            outputs["urscript"] = write_urscript(
                out_dir / f"{name}.script",
                trajectories[0],
                problem,
                result.robot,
                passes=named,
            )
        elif kind == "tp":
            from refine.export.tp import write_tp

            outputs["tp"] = write_tp(
                out_dir / f"{name}.ls", trajectories[0], problem, result.robot, passes=named, ptp_percent=air_percent
            )
        elif kind == "inform":
            from refine.export.inform import write_inform

            outputs["inform"] = write_inform(
                out_dir / f"{name}.JBI",
                trajectories[0],
                problem,
                result.robot,
                passes=named,
                joint_percent=float(air_percent),
            )
        elif kind == "sunrise":
            from refine.export.sunrise import write_sunrise

            outputs["sunrise"] = write_sunrise(
                out_dir / f"{name}.java",
                trajectories[0],
                problem,
                result.robot,
                passes=named,
                joint_velocity_rel=air_percent / 100.0,
            )
    return outputs
