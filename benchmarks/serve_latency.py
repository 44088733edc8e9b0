"""The time from a change in refine serve to its verdict on the glass cell, and the server's memory.

Starts the app on a copy of the glass cell (uvicorn on a free port, in this process), connects a
websocket as the page does and sends changes one at a time, each after the verdict of the one
before: the orientation cone alternating 2.9 / 3.0 deg, then the workpiece moved by 1 mm steps
along x and back. The latency of a change is from sending it to receiving its verdict message;
its CPU time is the whole process's (server and client) over the same span, which a shared
machine's load does not stretch. Prints the median and 95th percentile of each kind, the load
average beside them; then a drag (20 changes sent at once: the time to the last one's verdict, and
how many solves were stopped when overtaken); the process's resident memory after the first
solve and after ``--memory-changes`` changes; and (``--no-out-of-reach`` leaves it out) the time of
a change that moves the part out of reach from an ok answer (320 to 400 mm along x: the warm
attempt fails, the cold solve repairs and diagnoses).

    nice python3 benchmarks/serve_latency.py [--changes 50] [--memory-changes 500] [--no-out-of-reach]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import uvicorn
import websockets

from refine.serve.app import create_app
from refine.serve.session import Session

ROOT = Path(__file__).resolve().parents[1]


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


async def first_scene(url: str) -> None:
    """Wait for the scene of the problem as loaded (its first solve)."""
    async with websockets.connect(url, max_size=None) as ws:
        while json.loads(await ws.recv()).get("type") != "scene":
            pass


async def answer(ws: websockets.ClientConnection, change: dict) -> dict:
    """Send ``change`` and wait for its verdict message (the verdict a newly opened socket is sent
    first, of the change before, is not it: only the verdict of the revision the change's
    ``pending`` names is)."""
    await ws.send(json.dumps({"type": "change", "changes": change}))
    revision = None
    while True:
        msg = json.loads(await ws.recv())
        if msg["type"] == "error":
            raise RuntimeError(msg["message"])
        if msg["type"] == "pending" and revision is None:
            revision = msg["revision"]
        if msg["type"] == "verdict" and revision is not None and msg["revision"] == revision == msg["latest"]:
            if msg["error"]:
                raise RuntimeError(msg["error"])
            return msg


async def changes(url: str, kinds: list[dict]) -> tuple[list[float], list[float]]:
    """Send each change after the verdict of the one before; the latencies and CPU times [s]."""
    out, cpu = [], []
    async with websockets.connect(url, max_size=None) as ws:
        for change in kinds:
            t0, c0 = time.perf_counter(), time.process_time()
            await answer(ws, change)
            out.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
    return out, cpu


async def verdict_of(url: str, change: dict) -> tuple[str, float, float]:
    """Send one change; its verdict's status, latency and CPU time [s]."""
    async with websockets.connect(url, max_size=None) as ws:
        t0, c0 = time.perf_counter(), time.process_time()
        msg = await answer(ws, change)
        return msg["status"], time.perf_counter() - t0, time.process_time() - c0


async def drag(url: str, kinds: list[dict]) -> float:
    """Send every change at once, as a slider dragged fast; the time to the verdict of the last [s]."""
    async with websockets.connect(url, max_size=None) as ws:
        t0 = time.perf_counter()
        for change in kinds:
            await ws.send(json.dumps({"type": "change", "changes": change}))
        latest = None
        while True:
            msg = json.loads(await ws.recv())
            if msg["type"] == "pending":
                latest = msg["revision"]
            if msg["type"] == "verdict" and msg["revision"] == msg["latest"] == latest:
                return time.perf_counter() - t0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--changes", type=int, default=50)
    parser.add_argument("--memory-changes", type=int, default=500)
    parser.add_argument(
        "--out-of-reach",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="at the end, the time of a change that moves the part out of reach from an ok answer",
    )
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp()) / "glass_adhesive"
    shutil.copytree(ROOT / "problems" / "glass_adhesive", folder)
    session = Session(folder)
    server = uvicorn.Server(uvicorn.Config(create_app(session, folder / "out"), port=0, log_level="warning"))
    threading.Thread(target=server.run, daemon=True).start()
    while not server.started:
        time.sleep(0.05)
    url = f"ws://127.0.0.1:{server.servers[0].sockets[0].getsockname()[1]}/ws"
    n = args.changes
    cone = [{"tolerances.orientation_deg": 2.9 if k % 2 == 0 else 3.0} for k in range(n)]
    out = (n + 1) // 2  # 1 mm steps out and back, never the same move twice in a row (that is no change)
    steps = list(range(1, out + 1)) + list(range(out - 1, 2 * out - n - 1, -1))
    move = [{"move": {"xyz": [s * 1e-3, 0.0, 0.0], "rpy_deg": [0.0, 0.0, 0.0]}} for s in steps]
    asyncio.run(first_scene(url))
    after_first = rss_mb()
    t_cone, c_cone = asyncio.run(changes(url, cone))
    load_cone = os.getloadavg()[0]
    t_move, c_move = asyncio.run(changes(url, move))
    load_move = os.getloadavg()[0]
    for label, t, c, load in (
        ("cone 2.9/3.0 deg", t_cone, c_cone, load_cone),
        ("part moved 1 mm steps", t_move, c_move, load_move),
    ):
        a, b = np.asarray(t), np.asarray(c)
        print(
            f"{label:24s} {len(a)} changes: median {np.median(a):.3f} s, p95 {np.percentile(a, 95):.3f} s, "
            f"max {a.max():.3f} s; CPU of the process median {np.median(b):.3f} s, p95 "
            f"{np.percentile(b, 95):.3f} s (load average {load:.2f})"
        )
    before, stopped = session.solver.solved, session.solver.cancelled
    steps20 = [{"move": {"xyz": [k * 1e-3, 0.0, 0.0], "rpy_deg": [0.0, 0.0, 0.0]}} for k in range(1, 21)]
    t_drag = asyncio.run(drag(url, steps20))
    print(
        f"a drag of 20 changes sent at once: the last one's verdict after {t_drag:.3f} s, "
        f"{session.solver.solved - before} solved, {session.solver.cancelled - stopped} solves stopped when superseded"
    )
    done = 2 * n + len(steps20)
    extra = max(0, args.memory_changes - done)
    if extra:
        last = cone[-1]["tolerances.orientation_deg"]  # each change another cone than the one before
        other = 2.9 if last == 3.0 else 3.0
        more = [{"tolerances.orientation_deg": other if k % 2 == 0 else last} for k in range(extra)]
        asyncio.run(changes(url, more))
    import gc

    gc.collect()
    print(
        f"resident memory: {after_first:.0f} MB after the first solve, {rss_mb():.0f} MB after "
        f"{done + extra} changes; solver: {session.solver.solved} solved, {session.solver.dropped} dropped"
    )
    if args.out_of_reach:  # from an ok answer near the edge of the reach, 80 mm beyond it (a warm start)
        steps = [
            {"move": {"xyz": [x, 0.0, 0.0], "rpy_deg": [0.0, 0.0, 0.0]}} for x in (0.08, 0.16, 0.24, 0.32)
        ]
        asyncio.run(changes(url, steps))
        status, wall, cpu = asyncio.run(
            verdict_of(url, {"move": {"xyz": [0.40, 0.0, 0.0], "rpy_deg": [0.0] * 3}})
        )
        print(
            f"the part moved from 320 to 400 mm along x (out of reach): {status} after {wall:.2f} s, "
            f"{cpu:.2f} s of CPU (load average {os.getloadavg()[0]:.2f})"
        )
    server.should_exit = True
    session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
