"""`refine serve` as a program: prints its address, answers, and stops cleanly on Ctrl-C."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("host", [None, "127.0.0.1"])
def test_ctrl_c_stops_the_server_without_a_traceback(tmp_path, host):
    folder = tmp_path / "glass_adhesive"
    shutil.copytree(ROOT / "problems" / "glass_adhesive", folder)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    extra = [] if host is None else ["--host", host]
    proc = subprocess.Popen(
        [sys.executable, "-m", "refine.cli", "serve", str(folder), "--port", "0", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        line = proc.stdout.readline()  # the address, once the socket is bound
        found = re.search(r"at (http://127\.0\.0\.1:\d+/)(\?token=[\w-]{20,})?$", line.strip())
        assert found, line
        address = found.group(1)
        if host is not None:  # --host: the address carries the token, and nothing is answered without it
            assert found.group(2), line
            with pytest.raises(urllib.error.HTTPError) as refused:
                urllib.request.urlopen(address, timeout=60)
            assert refused.value.code == 403
            address += found.group(2)
        with urllib.request.urlopen(address, timeout=60) as page:
            assert page.status == 200 and b"refine serve: glass_adhesive" in page.read()
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)  # while the first solve runs
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "Traceback" not in err, err
    assert "refine serve: stopped" in out
