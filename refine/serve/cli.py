"""``refine serve PROBLEM [--port 8000] [--host H] [--out DIR]``: the app on a local web server."""

from __future__ import annotations

import argparse
import secrets
import threading
import time
from pathlib import Path
from typing import Any

from refine.errors import InputError

DEFAULT_PORT = 8000
"""The port the app listens on unless ``--port`` says otherwise."""
LOOPBACK = "127.0.0.1"
"""The interface the app listens on unless ``--host`` says otherwise."""


def add_parser(sub: Any) -> None:
    """Add ``serve`` to the ``refine`` command's subcommands."""
    p = sub.add_parser(
        "serve",
        help="open a problem in the browser: the cell in 3D, the verdict, live re-solves, write",
        description=(
            "Serve a web app on the problem: change frames, tolerances, margins and the part's "
            "placement, see the verdict re-solved, save problem.toml and write the outputs as "
            "`refine run` would. Listens on 127.0.0.1 unless --host is given; then every request "
            "needs the access token printed at start."
        ),
    )
    p.add_argument("problem", type=Path, help="problem folder or its problem.toml")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT}; 0 picks a free one)")
    p.add_argument(
        "--host",
        default=None,
        help="listen on this interface instead of 127.0.0.1 (e.g. 0.0.0.0); requires the printed access token",
    )
    p.add_argument("--out", type=Path, default=None, help="output folder of 'write' (default: out/ in the problem folder)")
    p.set_defaults(handler=serve_command)


def serve_command(args: argparse.Namespace) -> int:
    """Run the app until Ctrl-C (or SIGTERM); the exit status (0)."""
    try:
        import starlette  # noqa: F401
        import tomlkit  # noqa: F401
        import uvicorn
        import websockets  # noqa: F401
    except ImportError as e:
        raise InputError(
            f"refine serve needs the serve extra ({e.name} is missing): pip install -e '.[serve]'"
        ) from e

    from refine.serve.app import create_app
    from refine.serve.session import Session

    if not 0 <= args.port <= 65535:
        raise InputError(f"--port must be in [0, 65535], got {args.port}")
    host = args.host or LOOPBACK
    token = secrets.token_urlsafe(24) if args.host is not None else None
    session = Session(args.problem)
    out = args.out if args.out is not None else session.folder / "out"
    app = create_app(session, out, token=token)
    config = uvicorn.Config(app, host=host, port=args.port, log_level="warning", lifespan="on")
    server = uvicorn.Server(config)
    shown = f"[{host}]" if ":" in host else host

    def say() -> None:  # once the socket is bound: the port 0 asks for is known then
        while not server.started:
            time.sleep(0.05)
        port = server.servers[0].sockets[0].getsockname()[1] if server.servers else args.port
        address = f"http://{shown}:{port}/" + (f"?token={token}" if token else "")
        print(f"refine serve: {session.problem.name} at {address}", flush=True)
        if token:
            print("refine serve: every request needs the token above; share it only with who may change the problem", flush=True)
        print(f"refine serve: 'write' saves {session.path} and writes into {out}/; Ctrl-C stops", flush=True)

    threading.Thread(target=say, daemon=True).start()
    try:
        server.run()  # Ctrl-C: uvicorn closes the connections, then raises it again here
    except KeyboardInterrupt:
        pass
    finally:
        session.close()
    print("refine serve: stopped", flush=True)
    return 0
