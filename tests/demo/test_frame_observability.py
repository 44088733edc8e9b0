"""The tracker frame check on a straight seam: the rotation about the seam cannot be seen, the rest can.

A straight 0.15 m TIG seam 0.6 m from the receiver is demonstrated (simulated, with the tracker's
noise, distortion and tremor); the problem's ``source_in_world`` is then turned by a known angle
about a world axis. Rotating a straight line about its own direction moves none of its points, so
that component is not observable: it must be stated once in ``demo_quality`` and never warned
about. Rotations about the two axes across the seam move it and must still stop the run.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.demo import clean_demonstration
from refine.demo.quality import FRAME_STOP_DEG, DemoQuality
from refine.demo.simulate import TrackerModel, simulate_demonstration
from refine.errors import InputError
from refine.frames import transform_from_xyz_rpy
from refine.fuse.frame_check import gate_frame
from refine.fuse.fusion import fuse
from refine.paths import CadPath
from refine.settings import DemoSettings

T_F_S = transform_from_xyz_rpy([0.60, -0.42, 0.78], [0.0, 0.0, 90.0])  # as in problems/tig_weld
T_TCP_E = transform_from_xyz_rpy([-0.035, 0.0, -0.095], [180.0, 20.0, 0.0])
SEAM_DIR_F = np.array([0.0, 1.0, 0.0])


@pytest.fixture(scope="module", params=[2, 3])
def seam(request):
    s = np.linspace(0.0, 0.15, 151)
    pos = np.array([0.55, -0.25, 0.80]) + s[:, None] * SEAM_DIR_F
    rots = np.repeat(np.diag([1.0, -1.0, -1.0])[None], len(s), axis=0)  # torch pointing down
    sim = simulate_demonstration(
        s, pos, rots, np.full(len(s), 0.005), T_F_S, T_TCP_E, TrackerModel(seed=request.param, pause_s=1.0)
    )
    demo = clean_demonstration(sim.log, DemoSettings(file=Path("seam.liberty")))
    return demo, CadPath(s=s, positions=pos)


def _check(seam, world_axis, angle_deg):
    """The frame gate with source_in_world turned by angle_deg about world_axis (through the receiver)."""
    demo, cad = seam
    T = T_F_S.copy()
    T[:3, :3] = (
        Rotation.from_rotvec(np.radians(angle_deg) * np.asarray(world_axis, float)).as_matrix() @ T[:3, :3]
    )
    fused = fuse(cad, demo, T, T_TCP_E)
    return gate_frame(DemoQuality(n_samples=len(demo.t), sample_step_s=1 / 240), demo, fused, T, T_TCP_E)


@pytest.mark.parametrize("angle_deg", [0.0, 5.0])
def test_the_rotation_about_a_straight_seam_is_stated_once_not_warned(seam, caplog, angle_deg):
    with caplog.at_level(logging.INFO, logger="refine.fuse.frame_check"):
        quality = _check(seam, SEAM_DIR_F, angle_deg)  # about the seam itself: invisible
    assert quality.warnings == ()
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    frame = quality.as_json()["frame"]
    (hidden,) = frame["not_observable"]
    assert hidden["about"] == "the path direction"
    # the seam's direction in the receiver frame {S}: R_S_F @ u
    seam_dir_s = T_F_S[:3, :3].T @ SEAM_DIR_F
    assert abs(np.dot(hidden["axis_in_source"], seam_dir_s)) > np.cos(np.radians(5.0))
    assert hidden["sigma_deg"] > 10 * frame["observable_sigma_deg"]
    assert frame["observable_rotation_deg"] < FRAME_STOP_DEG


@pytest.mark.parametrize("world_axis", [(0.0, 0.0, 1.0), (1.0, 0.0, 0.0)], ids=["about z", "about x"])
@pytest.mark.parametrize("angle_deg", [5.0, 10.0])
def test_a_rotation_across_a_straight_seam_still_stops_the_run(seam, world_axis, angle_deg):
    with pytest.raises(InputError) as e:
        _check(seam, world_axis, angle_deg)
    msg = str(e.value)
    assert "--accept-frame-error" in msg and "not observable about the path direction" in msg
    angle = float(msg.split("rotated by ")[1].split(" ")[0])
    assert abs(angle - angle_deg) < 2.5  # the truth is angle_deg, all of it across the seam
