"""All-or-nothing outputs: a run writes into a staging folder and moves the finished set into place.

The output folder holds either the previous complete set, or no ``result.json`` at all (for the
milliseconds of the move), or the new complete set; never a ``result.json`` beside files it does not
describe. ``result.json`` lists every other file of its set with its size and SHA-256
(``files``), so anyone can check the claim.

How a set is committed (:meth:`StagedOutputs.commit`), with SIGINT/SIGTERM held back throughout when
the caller opted in (:func:`refine.interrupt.guarded`, as the ``refine`` command does):

1. every file, ``result.json`` last, is written into ``<out>/.refine-staging-<pid>-<random>/``;
2. the old ``result.json`` is renamed to ``.refine-previous.json`` (from here on no set is claimed);
3. the old set's files that the new set does not have are deleted (only names the old
   ``result.json`` listed, only regular files, never an input of the problem);
4. each new file is moved into place with ``os.replace`` (atomic per file);
5. the new ``result.json`` is moved into place, then ``.refine-previous.json`` is deleted.

Then :func:`refine.interrupt.outputs_complete` records that the run is complete: a Ctrl-C from
here on stops nothing (the command exits with the run's own status).

A library call touches no signal: a host's handler that raises during steps 2-5 (its Ctrl-C) leaves
the folder with no ``result.json`` (no set claimed, never a wrong one); the next run in the folder
cleans it (below). A run that fails or is interrupted before step 2 leaves the previous set untouched and its staging
folder removed. A process killed outright (SIGKILL) may leave a staging folder; the next run in the
same folder removes those of processes that no longer run (and their ``.result.json.<pid>.tmp``),
and cleans the files listed by a leftover ``.refine-previous.json``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import secrets
import shutil
from collections.abc import Callable
from pathlib import Path
from types import TracebackType

from refine.errors import InputError, option
from refine.interrupt import critical, outputs_complete

log = logging.getLogger(__name__)

STAGING_PREFIX = ".refine-staging-"
PREVIOUS = ".refine-previous.json"
RESULT = "result.json"
OUTPUT_SUFFIXES = (".json", ".csv", ".aml", ".mod", ".src", ".dat", ".script", ".html")
"""Suffixes of the files refine writes; an old set's other files are never deleted."""


def file_digest(path: Path) -> dict[str, int | str]:
    """Size [bytes] and SHA-256 (hex) of a file."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return {"bytes": path.stat().st_size, "sha256": h.hexdigest()}


def describe_files(outputs: dict[str, Path]) -> dict[str, dict[str, int | str]]:
    """``name -> {bytes, sha256}`` of every output but ``result.json`` (for its ``files`` key)."""
    return {p.name: file_digest(p) for p in outputs.values() if p.name != RESULT and p.is_file()}


def _claimed_names(doc_path: Path) -> set[str]:
    """The plain file names a ``result.json`` (or the previous one) says belong to its set."""
    try:
        doc = json.loads(doc_path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return set()
    if not isinstance(doc, dict) or "schema_version" not in doc:
        return set()  # not a refine result: claims nothing
    names = set()
    for group in (doc.get("outputs"), doc.get("files")):
        if isinstance(group, dict):
            names |= {v for v in group.values() if isinstance(v, str)} | {
                k for k in group if isinstance(k, str)
            }
    return {
        n
        for n in names
        if "/" not in n
        and "\\" not in n
        and not n.startswith(".")
        and n != RESULT
        and n.endswith(OUTPUT_SUFFIXES)
    }


def _status_of(text: bytes) -> str:
    """The ``status`` a ``result.json`` text states ("" when it states none)."""
    try:
        doc = json.loads(text)
    except ValueError:
        return ""
    return str(doc.get("status", "")) if isinstance(doc, dict) else ""


def _fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale(out_dir: Path) -> None:
    """Remove staging folders of processes that no longer run, and files a broken commit left."""
    for d in out_dir.glob(STAGING_PREFIX + "*"):
        try:
            pid = int(d.name[len(STAGING_PREFIX) :].split("-")[0])
        except ValueError:
            continue
        if d.is_dir() and not d.is_symlink() and not _pid_alive(pid):
            shutil.rmtree(d, ignore_errors=True)
    for f in out_dir.glob(f".{RESULT}.*.tmp"):  # a result.json rewrite cut short (refine.export.result_json)
        try:
            pid = int(f.name.split(".")[-2])
        except ValueError:
            continue
        if f.is_file() and not f.is_symlink() and not _pid_alive(pid):
            f.unlink()
    previous = out_dir / PREVIOUS
    if previous.is_file() and not (out_dir / RESULT).exists():
        for name in _claimed_names(previous):
            target = out_dir / name
            if target.is_file() and not target.is_symlink():
                target.unlink()
        previous.unlink()


class StagedOutputs:
    """A staging folder inside ``out_dir`` whose files become the output set on :meth:`commit`.

    Use as a context manager: leaving the block without a commit (an error, Ctrl-C) removes the
    staging folder and leaves ``out_dir`` as it was.

    Args:
        out_dir: the output folder (created, with its parents, if missing).
        protected: files that must never be replaced or deleted (the problem's inputs).
    """

    def __init__(self, out_dir: Path, protected: tuple[Path, ...] = ()) -> None:
        self.out_dir = Path(out_dir)
        self.protected = {p.resolve() for p in protected}
        self.dir = self.out_dir / f"{STAGING_PREFIX}{os.getpid()}-{secrets.token_hex(4)}"
        self.committed = False

    def __enter__(self) -> StagedOutputs:
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            remove_stale(self.out_dir)
            self.dir.mkdir()
        except OSError as e:
            raise InputError(
                f"{option('--out', 'out_dir')} {str(self.out_dir)!r}: cannot write there: {e.strerror}",
                key="out_dir",
                value=str(self.out_dir),
                expected="a folder refine may write in",
            ) from e
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        with critical():
            shutil.rmtree(self.dir, ignore_errors=True)
            if not self.committed and not any(self.out_dir.iterdir()):
                with contextlib.suppress(OSError):
                    self.out_dir.rmdir()  # made by this run and left empty: leave nothing behind

    def commit(self, outputs: dict[str, Path], write_result: Callable[[Path], object]) -> dict[str, Path]:
        """Write ``result.json`` last into the staging folder and move the whole set into place.

        Args:
            outputs: kind -> staged file, every one inside the staging folder.
            write_result: writes ``result.json`` to the path it is given (it may read ``outputs``).

        Returns:
            kind -> final path in ``out_dir`` (``result`` included).

        Raises:
            InputError: an output would replace an input file or something that is not a file.
        """
        out = self.out_dir
        staged = dict(outputs)
        staged["result"] = self.dir / RESULT
        for path in staged.values():
            if path.parent != self.dir:
                raise InputError(f"output {path} was not written into the staging folder")
            target = out / path.name
            if (
                target.resolve() in self.protected
                or target.is_symlink()
                or (target.exists() and not target.is_file())
            ):
                raise InputError(
                    f"output {path.name!r} would replace {target.resolve()}; nothing was written"
                )
        with critical():
            write_result(staged["result"])
            with open(staged["result"], "rb") as f:
                os.fsync(f.fileno())
                f.seek(0)
                status = _status_of(f.read())
            old = _claimed_names(out / RESULT) | _claimed_names(out / PREVIOUS)
            if (out / RESULT).exists():
                os.replace(out / RESULT, out / PREVIOUS)
                _fsync_dir(out)
            new = {p.name for p in staged.values()}
            for name in sorted(old - new):
                target = out / name
                if target.is_file() and not target.is_symlink() and target.resolve() not in self.protected:
                    target.unlink()
            for path in staged.values():
                if path.name != RESULT:
                    os.replace(path, out / path.name)
            _fsync_dir(out)
            os.replace(staged["result"], out / RESULT)
            _fsync_dir(out)
            with contextlib.suppress(FileNotFoundError):
                (out / PREVIOUS).unlink()
            self.committed = True
            outputs_complete(status)  # from here on an interrupt has nothing left to stop
        log.info("moved %d file(s) into %s", len(staged), out)
        return {kind: out / p.name for kind, p in staged.items()}
