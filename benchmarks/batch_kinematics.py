"""The flange's placements and Jacobians of N joint rows: the batched chains against Pinocchio's row loop.

For each robot and batch size, the median CPU time (``time.process_time``, 7 medians of repeated
calls) of

* Pinocchio: ``computeFrameJacobian(..., LOCAL_WORLD_ALIGNED)`` and ``data.oMf`` row by row (what
  ``TcpKinematics.batch`` does under ``MIN_ROWS`` rows), and ``forwardKinematics`` with
  ``updateFramePlacement`` (``Robot.fk_many``'s loop);
* the NumPy chain: ``BatchChain.frame`` with and without the Jacobian (:mod:`refine.robot.chain`);
* the compiled chain: ``CompiledChain.frame`` with and without the Jacobian
  (:mod:`refine.robot.compiled_chain`; compiled, or found in the cache folder, before the timings);

and the largest difference of either chain from Pinocchio; then ``TcpKinematics.poses_jacobians`` and
``poses`` (a base placement and a TCP: the compiled chain composes them in C, the NumPy chain's
flange is composed in NumPy). Run with one BLAS thread:

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python3 benchmarks/batch_kinematics.py [--robots abb_irb4600_60_205,kuka_iiwa14_r820]
"""

from __future__ import annotations

import argparse
import copy
import os
import statistics
import time

import numpy as np
import pinocchio as pin

from refine.robot.chain import MIN_ROWS, BatchChain
from refine.robot.compiled_chain import COMPILED_MIN_ROWS, CompiledChain
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot

SIZES = (1, 2, 4, 8, 16, 32, 64, 128, 618, 4319)


def _loop_jacobian(
    model: pin.Model, data: pin.Data, fid: int, qs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Pinocchio row by row: the flange's placements (N, 4, 4) and Jacobians (N, 6, nv)."""
    J, T = np.empty((len(qs), 6, model.nv)), np.empty((len(qs), 4, 4))
    for k, q in enumerate(qs):
        J[k] = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL_WORLD_ALIGNED)
        T[k] = data.oMf[fid].homogeneous
    return T, J


def _loop_fk(model: pin.Model, data: pin.Data, fid: int, qs: np.ndarray) -> np.ndarray:
    """Pinocchio row by row: the flange's placements (N, 4, 4)."""
    T = np.empty((len(qs), 4, 4))
    for k, q in enumerate(qs):
        pin.forwardKinematics(model, data, q)
        T[k] = pin.updateFramePlacement(model, data, fid).homogeneous
    return T


def _cpu_ms(rows: int, fn, *args) -> float:  # noqa: ANN001, ANN002 - any callable and its arguments
    calls = max(1, 4000 // rows)
    times = []
    for _ in range(7):
        c0 = time.process_time()
        for _ in range(calls):
            fn(*args)
        times.append((time.process_time() - c0) / calls)
    return statistics.median(times) * 1e3


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", default="abb_irb4600_60_205,kuka_iiwa14_r820")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    print(f"MIN_ROWS = {MIN_ROWS}, COMPILED_MIN_ROWS = {COMPILED_MIN_ROWS}; load {os.getloadavg()[0]:.1f}")
    for name in args.robots.split(","):
        robot = load_robot(name)
        model, data, fid = robot.model, robot.model.createData(), robot.flange_id
        chain = BatchChain.from_model(model)
        fast = CompiledChain.from_model(model, fid)
        print(
            f"{name} ({robot.nq} joints, compiled: {fast.compiled}): rows, CPU [ms] of J by pinocchio / numpy chain /"
            " compiled chain, fk by pinocchio / numpy chain / compiled chain, largest difference"
        )
        for rows in SIZES:
            qs = rng.uniform(robot.spec.lower, robot.spec.upper, (rows, robot.nq))

            T0, J0 = _loop_jacobian(model, data, fid, qs)
            diff = 0.0
            for each in (chain, fast):
                T1, J1 = each.frame(qs, fid)
                diff = max(diff, np.abs(T0 - T1).max(), np.abs(J0 - J1).max())
            figures = [
                _cpu_ms(rows, _loop_jacobian, model, data, fid, qs),
                _cpu_ms(rows, chain.frame, qs, fid, True),
                _cpu_ms(rows, fast.frame, qs, fid, True),
                _cpu_ms(rows, _loop_fk, model, data, fid, qs),
                _cpu_ms(rows, chain.frame, qs, fid, False),
                _cpu_ms(rows, fast.frame, qs, fid, False),
            ]
            print(f"  {rows:5d}  " + " / ".join(f"{x:7.3f}" for x in figures) + f"  {diff:.1e}")
        slow = copy.copy(robot)
        slow.chain = CompiledChain.from_model(model, fid, compile=False)
        base = np.eye(4)
        base[:3, 3] = [0.1, -0.2, 0.3]
        tcp = np.eye(4)
        tcp[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
        tcp[:3, 3] = [0.01, 0.02, 0.25]
        kins = [TcpKinematics(r, base, tcp) for r in (slow, robot)]
        print("  TcpKinematics: rows, CPU [ms] of poses_jacobians numpy / compiled, poses numpy / compiled")
        for rows in (16, 128, 618, 4319):
            qs = rng.uniform(robot.spec.lower, robot.spec.upper, (rows, robot.nq))
            figures = [_cpu_ms(rows, k.poses_jacobians, qs) for k in kins] + [
                _cpu_ms(rows, k.poses, qs) for k in kins
            ]
            print(f"  {rows:5d}  " + " / ".join(f"{x:7.3f}" for x in figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
