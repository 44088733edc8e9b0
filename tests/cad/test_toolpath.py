"""A CAM toolpath with tool axes (CSV) as the path and its orientations, without a demonstration."""

from __future__ import annotations

import numpy as np
import pytest

from refine.cad.toolpath import fused_from_toolpath, read_toolpath
from refine.errors import InputError
from refine.frames import make_transform

R_Z90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def _quarter_circle(path, header: str | None = None, numbered: bool = True):
    """A quarter circle of radius 100 mm about the CAD z axis, counter-clockwise, the tool pointing down."""
    lines = [" Line 1,,,,,,", " Line 2,,,,,,"] if numbered else []
    if header:
        lines.append(header)
    for k, phi in enumerate(np.linspace(0.0, np.pi / 2, 31)):
        x, y = 100.0 * np.cos(phi), 100.0 * np.sin(phi)
        if header:
            lines.append(f"0,0,-1,{x:.9f},{y:.9f},0")  # i, j, k, x, y, z
        else:
            lines.append(f"{k + 1},{x:.9f},{y:.9f},0,0,0,-1" if numbered else f"{x:.9f},{y:.9f},0,0,0,-1")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_positions_and_axes_in_metres_in_file_order(tmp_path):
    points, axes = read_toolpath(_quarter_circle(tmp_path / "p.csv"), "mm")
    assert points.shape == (31, 3) and points[0] == pytest.approx([0.1, 0.0, 0.0])
    assert points[-1] == pytest.approx([0.0, 0.1, 0.0], abs=1e-12)
    assert axes == pytest.approx(np.tile([0.0, 0.0, -1.0], (31, 1)))
    headed, _ = read_toolpath(_quarter_circle(tmp_path / "h.csv", header="i,j,k,x,y,z", numbered=False), "mm")
    assert headed == pytest.approx(points)


def test_the_tcp_frame_points_the_tool_along_its_axis_and_x_along_the_travel(tmp_path):
    path = _quarter_circle(tmp_path / "p.csv")
    cad_in_world = make_transform(R_Z90, [1.0, 2.0, 0.5])
    fused = fused_from_toolpath(path, "mm", 0.005, 0.02, cad_in_world)
    # by hand: the arc is a quarter of a 0.1 m circle; turned 90 deg about z and moved
    assert fused.s[-1] == pytest.approx(np.pi / 2 * 0.1, rel=2e-3)
    assert np.max(np.diff(fused.s)) <= 0.005 + 1e-12
    assert fused.positions[0] == pytest.approx([1.0, 2.1, 0.5])
    radius = np.linalg.norm(fused.positions[:, :2] - [1.0, 2.0], axis=1)
    assert radius == pytest.approx(0.1, abs=2e-4)  # chords of the file's 3 deg steps
    assert fused.rotations[:, :, 2] == pytest.approx(np.tile([0.0, 0.0, -1.0], (len(fused), 1)), abs=1e-9)
    # the travel at the start is +y in the CAD frame, -x in the world; at the end -x in CAD, -y in the world
    assert fused.rotations[0][:, 0] == pytest.approx([-1.0, 0.0, 0.0], abs=3e-2)
    assert fused.rotations[-1][:, 0] == pytest.approx([0.0, -1.0, 0.0], abs=3e-2)
    assert np.allclose(np.linalg.det(fused.rotations), 1.0)
    assert fused.speed == pytest.approx(0.02) and fused.t_demo[-1] == pytest.approx(fused.s[-1] / 0.02)
    back = fused_from_toolpath(path, "mm", 0.005, 0.02, cad_in_world, reverse=True)
    assert back.positions[0] == pytest.approx(fused.positions[-1], abs=1e-9)
    assert back.rotations[0][:, 0] == pytest.approx([0.0, 1.0, 0.0], abs=3e-2)


def test_bad_toolpaths_name_the_line_and_the_problem(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("1,0,0,0,0,0,1\n2,10,0,0,0,0,0\n")
    with pytest.raises(InputError, match=r"p.csv line 2: tool axis .* is not a direction"):
        read_toolpath(path)
    path.write_text("0,0,0,0,0,1\n10,0,0\n")
    with pytest.raises(InputError, match=r"line 2: 3 numbers; expected x, y, z, i, j, k"):
        read_toolpath(path)
    path.write_text("x,y,z,i,j\n0,0,0,0,0\n")
    with pytest.raises(InputError, match=r"line 1: header x, y, z, i, j lacks column\(s\) k"):
        read_toolpath(path)
    path.write_text("0,0,0,0,0,1\n")
    with pytest.raises(InputError, match="needs at least 2 points, found 1"):
        read_toolpath(path)
    _quarter_circle(path)
    with pytest.raises(InputError, match=r"speed_m_s = 0.0 m/s: a toolpath needs a speed in \(0, 10\] m/s"):
        fused_from_toolpath(path, "mm", 0.005, 0.0, np.eye(4))


def test_a_problem_takes_its_orientations_from_the_toolpath(tmp_path):
    from refine.problem import load_problem
    from refine.run.stages import fused_path

    _quarter_circle(tmp_path / "path.csv")
    (tmp_path / "problem.toml").write_text(
        'name = "cam"\n[robot]\nmodel = "abb_irb4600_60_205"\n'
        '[tool]\nname = "t"\ntcp_in_flange = { xyz = [0, 0, 0.2] }\naxisymmetric = true\n'
        "[frames]\ncad_in_world = { xyz = [1.2, 0.0, 0.6] }\n"
        '[cad]\nfile = "path.csv"\nformat = "toolpath"\nunits = "mm"\nspeed_m_s = 0.05\n'
    )
    problem = load_problem(tmp_path)
    fused = fused_path(problem)
    assert fused.positions[0] == pytest.approx([1.3, 0.0, 0.6])
    assert fused.rotations[5][:, 2] == pytest.approx([0.0, 0.0, -1.0])
    text = (tmp_path / "problem.toml").read_text()
    (tmp_path / "problem.toml").write_text(text.replace('format = "toolpath"\n', 'format = "csv"\n'))
    with pytest.raises(InputError, match="speed_m_s .m/s. goes with format = 'toolpath'"):
        load_problem(tmp_path)


def test_a_tool_leaning_along_the_travel_keeps_x_square_to_its_axis(tmp_path):
    path = tmp_path / "line.csv"
    s30, c30 = 0.5, np.sqrt(3.0) / 2.0
    path.write_text("".join(f"{x},0,0,{s30},0,{-c30}\n" for x in range(0, 60, 10)))  # along x, leaning 30 deg
    fused = fused_from_toolpath(path, "mm", 0.005, 0.02, np.eye(4))
    # by hand: x = the travel (1, 0, 0) less its part along z, normalised: (cos 30, 0, sin 30)
    for R in fused.rotations:
        assert R[:, 2] == pytest.approx([s30, 0.0, -c30])
        assert R[:, 0] == pytest.approx([c30, 0.0, s30])
        assert R[:, 1] == pytest.approx([0.0, -1.0, 0.0])
