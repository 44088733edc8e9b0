"""Interrupting ``refine run`` at random moments never leaves a result.json that lies.

The output folder first receives one complete set. Then ``--tries`` runs of each signal (SIGINT,
SIGKILL) are started into the same folder, alternately with and without ``--no-report`` (so an old
and a new set differ in their file names as well as their contents), and each is sent the signal
at a random moment: half drawn uniformly over the time of a complete run, half within 1 s after
the run starts writing its outputs (its staging folder appears: the writing, the move into place,
the summary and the exit). After each try the folder is checked on its own terms:

* if ``result.json`` exists, every file its ``files`` lists exists with that size and SHA-256, and
  no other output-like file (``.csv .aml .mod .src .dat .script .html``) lies beside it;
* if it does not, the folder is "nothing claimed" (allowed);
* the exit status: SIGINT gives 130 with the previous set kept, or the run's own status (0) with
  the new set complete (the signal came after the move into place: docs/outputs.md); never a
  death by the signal (-2) or a traceback. SIGKILL gives -9 (or 0 when the run had ended).
  The time from the signal to the exit is recorded.

Every try that breaks one of these rules counts as a disagreement; the script exits 1 if any did.

    PYTHONPATH=. python3 benchmarks/interrupt_experiment.py [--problem problems/glass_adhesive] [--tries 20]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import random
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

OUTPUT_LIKE = (".csv", ".aml", ".mod", ".src", ".dat", ".script", ".html")


def disagreements(out: Path) -> list[str]:
    """What the folder's result.json says that is not so (empty when it is the truth)."""
    result = out / "result.json"
    if not result.exists():
        return []
    doc = json.loads(result.read_text())
    problems = []
    for name, meta in doc["files"].items():
        f = out / name
        if not f.is_file():
            problems.append(f"{name} listed but missing")
        elif (
            hashlib.sha256(f.read_bytes()).hexdigest() != meta["sha256"] or f.stat().st_size != meta["bytes"]
        ):
            problems.append(f"{name} differs from its listed SHA-256")
    listed = set(doc["files"]) | {"result.json"}
    for f in out.iterdir():
        if f.is_file() and f.suffix in OUTPUT_LIKE and f.name not in listed:
            problems.append(f"{f.name} present but not listed")
    return problems


def start(problem: str, out: Path, no_report: bool) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "refine.cli", "run", problem, "--out", str(out)]
    return subprocess.Popen(
        cmd + (["--no-report"] if no_report else []),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # not ignored, as in a terminal
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problem", default="problems/glass_adhesive")
    ap.add_argument("--out", type=Path, default=Path("/tmp/refine-interrupt"))
    ap.add_argument("--tries", type=int, default=20)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    t0 = time.perf_counter()
    first = start(args.problem, args.out, False)
    assert first.wait() == 0, first.stderr.read().decode()
    run_s = time.perf_counter() - t0
    print(f"complete run: {run_s:.1f} s; folder {args.out}: {sorted(p.name for p in args.out.iterdir())}")
    assert not disagreements(args.out)
    bad = {"SIGINT": 0, "SIGKILL": 0}
    stop_s, outcomes = [], {"old set": 0, "new set": 0, "nothing claimed": 0}
    for sig in (signal.SIGINT, signal.SIGKILL):
        for k in range(args.tries):
            before = (args.out / "result.json").read_bytes() if (args.out / "result.json").exists() else None
            p = start(args.problem, args.out, no_report=k % 2 == 1)
            begun = time.perf_counter()
            if k % 2 == 0:
                time.sleep(rng.uniform(0.0, run_s))
            else:  # late: once the outputs are being written (a staging folder appears), within 1 s
                while p.poll() is None and not any(args.out.glob(f".refine-staging-{p.pid}-*")):
                    time.sleep(0.002)
                time.sleep(rng.uniform(0.0, 1.0))
            sent = time.perf_counter()
            delay = sent - begun
            p.send_signal(sig)
            rc = p.wait()
            waited = time.perf_counter() - sent
            after = (args.out / "result.json").read_bytes() if (args.out / "result.json").exists() else None
            outcome = "nothing claimed" if after is None else "old set" if after == before else "new set"
            outcomes[outcome] += 1
            problems = disagreements(args.out)
            err = p.stderr.read().decode()
            traceback = "Traceback" in err
            if sig == signal.SIGINT:
                stop_s.append(waited)
                ok_rc = (rc == 130 and outcome == "old set") or (rc == 0 and outcome == "new set")
            else:
                ok_rc = rc == -9 or (rc == 0 and outcome == "new set")
            bad[sig.name] += bool(problems) or traceback or not ok_rc
            print(
                f"{sig.name:7s} try {k + 1:2d} at {delay:5.1f} s: exit {rc:4d} after {waited:.2f} s, "
                f"{outcome}{'; ' + '; '.join(problems) if problems else ''}{'; TRACEBACK' if traceback else ''}"
            )
    print(
        f"tries: SIGINT {args.tries}, SIGKILL {args.tries}; disagreements (folder vs result.json, "
        f"wrong exit status, traceback): SIGINT {bad['SIGINT']}, SIGKILL {bad['SIGKILL']}"
    )
    print(f"outcomes: {outcomes}")
    print(f"SIGINT to exit [s]: median {statistics.median(stop_s):.2f}, max {max(stop_s):.2f}")
    sys.exit(1 if any(bad.values()) else 0)


if __name__ == "__main__":
    main()
