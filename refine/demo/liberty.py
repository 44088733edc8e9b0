"""Polhemus Liberty ASCII tracker logs: read and write.

The format, as the Liberty prints it in ASCII mode and as refine reads and writes it::

    # Polhemus Liberty ASCII            <- comment lines start with '#'
    # units: in                          <- optional: position unit, 'in' or 'cm'
    # rate_hz: 240                       <- optional: sample rate [Hz]
    01    12.3456   -4.5678    9.8765   -12.345    45.678   170.123
    02    ...                            <- other stations' lines are skipped

* Blank lines are ignored; comments are ignored except ``# units: ...`` and ``# rate_hz: ...``
  (``:`` or ``=``, any case), which set the position unit and sample rate for the whole file.
* A data line is a record: the record header, then the values, whitespace separated, in one of
  these layouts (all lines of one station alike): ``x y z azimuth elevation roll`` (the Liberty's
  default output list ``2,4,1``), ``frame_count x y z azimuth elevation roll`` (list ``9,2,4,1``),
  or ``x y z qw qx qy qz`` (list ``2,7``; told from the frame-count layout by its unit
  quaternions; 7 values that fit both are refused).
* The record header is the one the Liberty puts before every record (User Manual URM03PH156
  Rev. H, section 2, "Response format", Table 2-1 for ASCII and Table 2-2 for binary; the fields
  as Polhemus's PDI SDK declares them in ``PDItracker.h``): the station number (two digits,
  ``01``..``16``), the initiating command (one letter: ``P`` a single record, ``C`` continuous
  output) and the error indicator (one byte, a space when there is no error). Accepted: ``01``
  alone (no command, no indicator), ``01P``/``01C`` followed by a blank indicator, ``01Cu``
  with an indicator, and a value written straight after the indicator (``01Cu-1.2345``).
  Records captured as the device sends them (a serial or USB terminal log) therefore read
  unchanged; a file in any other layout (column titles, other output items) is refused with its
  line named, never guessed. A non-blank indicator is kept per sample
  (``TrackerLog.device_error``); the quality gate treats such samples as dropouts and reports
  them (``demo_quality.device_errors``: counts, sample runs and the SDK's meaning per
  indicator); they are never silently dropped.
* Records of the station that another command initiated (the device's replies to configuration
  commands, e.g. ``01B`` for the boresight) are refused with their line: one with six numbers
  would otherwise read as a sample. Other stations' lines are skipped whatever they hold.
* Files saved by Polhemus's own software: Polhemus Tracker Terminal (PiTerm 1.0.3, its "Capture
  Data" switch) appends the bytes the device sends to the capture file unchanged, with no header
  line, time column or separators of its own, so its captures are read as above (or by
  :mod:`refine.demo.liberty_binary` after ``F1``). Switched on or off while the device is
  sending, it leaves a partial record as the first or last line: a first line that is not a
  record, or a last line without a line end shorter than the record before it, is refused with
  a message saying so. Sessions appended to one file restart the frame count: refused (the count
  does not increase). For PiMgr (Windows) and the PDI SDK no description or example of a saved
  file was found (the SDK's ``CPDIdev`` offers raw P&O export over a pipe, TCP or UDP, which is
  this record stream, and an I/O trace log ``PICMDIF.LOG``, hex by default): such files are read
  only when they hold the device's records, and refused with the line named otherwise.
* At most :data:`MAX_SAMPLES` samples of the station are read.
* Every value is checked against :mod:`refine.plausible`: positions within ±10 m, azimuth and roll
  within ±180 deg, elevation within ±90 deg, unit quaternions, times within a day.
* Positions are in inches (default) or centimetres, angles in degrees; the orientation is
  ``R = Rz(azimuth)·Ry(elevation)·Rx(roll)`` (:func:`refine.frames.matrix_from_tracker_angles`).
* Time: with frame counts ``t = (frame - first_frame) / rate_hz`` (counts must increase); without,
  sample ``k`` is at ``t = k / rate_hz``.

The writer prints fixed-width columns like the Liberty: station as two digits, frame count in 9
characters, positions with 4 decimals in 10 characters, angles with 3 decimals in 9 characters.
"""

from __future__ import annotations

import logging
import re
from array import array
from pathlib import Path

import numpy as np

from refine.errors import InputError
from refine.frames import matrix_from_quaternion, matrix_from_tracker_angles, tracker_angles_from_matrix
from refine.paths import TrackerLog
from refine.plausible import (
    DEMO_POSITION_LIMIT_M,
    check_coordinates,
    check_euler,
    check_quaternions,
    check_times,
)

logger = logging.getLogger(__name__)

MAX_SAMPLES = 4_000_000
"""Most samples of one station read from a log (4.6 hours at 240 Hz)."""
BYTES_PER_SAMPLE = 600
"""Peak memory per sample of the demonstration stage, measured (docs/problem-file.md, "Limits")."""
#: Length of one Liberty position unit [m].
METRES_PER_UNIT = {"in": 0.0254, "cm": 0.01}
#: The sample rates accepted [Hz] (the same range as ``demonstration.rate_hz``).
MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 10_000.0
_HEADER = re.compile(r"^#\s*(units|rate_hz)\s*[:=]\s*(\S+)\s*$", re.IGNORECASE)


def _unit_scale(units: str, where: str) -> float:
    if units not in METRES_PER_UNIT:
        raise InputError(f"{where}: unknown Liberty unit {units!r}; use 'in' or 'cm'")
    return METRES_PER_UNIT[units]


def _parse_rate(text: str, where: str) -> float:
    try:
        rate = float(text)
    except ValueError:
        rate = float("nan")
    if not (np.isfinite(rate) and MIN_RATE_HZ <= rate <= MAX_RATE_HZ):
        raise InputError(
            f"{where}: rate_hz must be a number in [{MIN_RATE_HZ:g}, {MAX_RATE_HZ:g}] Hz, got {text!r}"
        )
    return rate


_RECORD_HEADER = re.compile(r"(\d{1,2})([A-Za-z])?([!-~])?")
# the header with the first value glued on (no blank error byte between): station, command, an
# error indicator that cannot start a number, then the value
_GLUED = re.compile(r"(\d{1,2})([A-Za-z])([!-*,/:-~])?([-+.0-9]\S*)")
_CHUNK_LINES = 65536  # lines parsed at once: memory stays linear in the samples kept


_PARTIAL = (
    " (a capture switched on or off while the device was sending leaves a partial record as the "
    "file's first or last line: delete that line)"
)
#: Initiating commands of position and orientation records: single record and continuous output.
P_AND_O_COMMANDS = frozenset("PCpc")


def _parse_header(token: str, where: str, line: str, hint: str) -> tuple[int, str, str]:
    """Station, error indicator and initiating command of a record's first token (module docstring)."""
    m = _RECORD_HEADER.fullmatch(token)
    if m is None:
        raise InputError(
            f"{where}: a record must start with the station number (optionally followed by the "
            f"initiating command letter and the error indicator, as in '01P'), got {message_line(line)}"
            + hint
        )
    return int(m.group(1)), m.group(3) or "", m.group(2) or ""


def _quaternion_layout(data: np.ndarray, path: Path, linenos: array) -> bool:
    """Whether 7-value records are ``x y z qw qx qy qz`` (output list 2,7), not with a frame count.

    They are when the last four values of every record are a unit quaternion (to the printed 4
    decimals); ``frame_count x y z azimuth elevation roll`` needs an increasing integer first.

    Raises:
        InputError: both readings fit (naming the file), so the layout cannot be told.
    """
    q = data[:, 3:7]
    unit = bool(np.all(np.abs(np.linalg.norm(q, axis=1) - 1.0) < 2e-3) and np.all(np.abs(q) <= 1.0 + 1e-4))
    if not unit:
        return False
    f = data[:, 0]
    counts = bool(np.all(f == np.round(f)) and np.all(np.diff(f) > 0))
    if counts:
        raise InputError(
            f"{path}:{linenos[0]}: 7 values per record read both as a frame count with Euler angles "
            "and as a position with a unit quaternion; write the records with 6 values "
            "(x y z azimuth elevation roll) or a different output list"
        )
    return True


def message_line(line: str) -> str:
    """A line quoted in an error message: at most 80 characters, escapes for the unprintable."""
    return repr(line[:80] + ("..." if len(line) > 80 else ""))


class _Rows:
    """The kept records of one station, parsed to numbers a chunk of lines at a time."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.tokens: list[list[str]] = []
        self.linenos: list[int] = []
        self.lines: list[str] = []
        self.blocks: list[np.ndarray] = []
        self.errors: list[str] = []
        self.all_linenos = array("l")
        self.count = 0

    def add(self, tokens: list[str], lineno: int, line: str, error: str) -> None:
        self.tokens.append(tokens)
        self.linenos.append(lineno)
        self.lines.append(line)
        self.errors.append(error)
        self.count += 1
        if self.count > MAX_SAMPLES:
            raise InputError(
                f"{self.path}:{lineno}: more than {MAX_SAMPLES} samples of this station; cut the log "
                f"(the limit keeps memory under about {MAX_SAMPLES * BYTES_PER_SAMPLE / 1e9:.1f} GB)"
            )
        if len(self.tokens) >= _CHUNK_LINES:
            self.flush()

    def flush(self) -> None:
        if not self.tokens:
            return
        try:
            block = np.array(self.tokens, dtype=float)
        except ValueError:
            for tokens, lineno, line in zip(self.tokens, self.linenos, self.lines, strict=True):
                try:
                    [float(v) for v in tokens]
                except ValueError as e:
                    raise InputError(
                        f"{self.path}:{lineno}: not a number in {message_line(line)} ({e})"
                    ) from e
            raise
        bad = np.flatnonzero(~np.all(np.isfinite(block), axis=1))
        if bad.size:
            k = int(bad[0])
            raise InputError(
                f"{self.path}:{self.linenos[k]}: non-finite value in {message_line(self.lines[k])}"
            )
        self.blocks.append(block)
        self.all_linenos.extend(self.linenos)
        self.tokens, self.linenos, self.lines = [], [], []


def read_liberty_ascii(
    path: str | Path, units: str | None = "in", station: int = 1, rate_hz: float = 240.0
) -> TrackerLog:
    """Read one station's samples from a Liberty ASCII log (format in the module docstring).

    The file is read line by line and parsed a block of lines at a time, so memory grows with the
    samples kept (about :data:`BYTES_PER_SAMPLE` each), not with the file.

    Args:
        path: the log file.
        units: position unit the caller expects, ``"in"`` or ``"cm"``; None takes the file's
            ``# units:`` header, or inches without one.
        station: station (sensor) number to read.
        rate_hz: sample rate [Hz], unless the file's ``# rate_hz:`` header says otherwise.

    Returns:
        The station's samples: times [s] from 0, positions [m], rotations R_S_E, and the
        device's error indicator per sample (``device_error``, 0 where there is none).

    Raises:
        InputError: unreadable or non-UTF-8 file; a header unit differing from ``units`` (naming
            both); a malformed line (naming file, line number and text); frame counts that do not
            increase; more than :data:`MAX_SAMPLES` samples; no samples of ``station`` (listing
            the stations found).
    """
    path = Path(path)
    file_units: str | None = None
    rows = _Rows(path)
    layout: int | None = None
    stations: set[int] = set()
    headers: dict[str, tuple[int, str, str]] = {}
    first_line: int | None = None  # the file's first data line
    previous_length: int | None = None  # characters of the station's record before
    try:
        f = open(path, encoding="utf-8-sig", errors="strict", newline=None)  # noqa: SIM115
    except OSError as e:
        raise InputError(f"tracker log {str(path)!r} cannot be read: {e.strerror}") from e
    with f:
        lineno = 0
        try:
            for raw in f:
                lineno += 1
                line = raw.strip()
                if not line:
                    continue
                if line[0] == "#":
                    where = f"{path}:{lineno}"
                    m = _HEADER.match(line)
                    if m and m.group(1).lower() == "units":
                        file_units = m.group(2).lower()
                        _unit_scale(file_units, where)
                    elif m:
                        rate_hz = _parse_rate(m.group(2), where)
                    continue
                first_line = first_line or lineno
                terminated = raw.endswith("\n")
                hint = _PARTIAL if lineno == first_line or not terminated else ""
                tokens = line.split()
                head = headers.get(tokens[0])
                if head is None:
                    glued = _GLUED.fullmatch(tokens[0])
                    if glued:  # "01Cu-12.3456": the first value right after the error indicator
                        head = (int(glued[1]), glued[3] or "", glued[2])
                        tokens = [tokens[0][: glued.start(4)], glued[4], *tokens[1:]]
                    else:
                        head = headers[tokens[0]] = _parse_header(tokens[0], f"{path}:{lineno}", line, hint)
                st, error, command = head
                stations.add(st)
                if st != station:
                    continue
                if command and command not in P_AND_O_COMMANDS:
                    raise InputError(
                        f"{path}:{lineno}: the device's reply to the '{command}' command, not a position "
                        f"and orientation record (initiating command P or C): {message_line(line)}; "
                        "delete the replies to commands sent while recording"
                    )
                n = len(tokens) - 1
                if n != layout and (layout is not None or n not in (6, 7)):
                    where = f"{path}:{lineno}"
                    expected = "6 or 7" if layout is None else str(layout)
                    raise InputError(
                        f"{where}: expected {expected} values after the record header "
                        f"(x y z azimuth elevation roll, frame_count x y z azimuth elevation roll, or "
                        f"x y z qw qx qy qz), got {n}: {message_line(line)}" + hint
                    )
                if not terminated and previous_length is not None and len(line) < previous_length:
                    raise InputError(
                        f"{path}:{lineno}: the last record has {len(line)} characters and no line end, "
                        f"the one before {previous_length}: {message_line(line)}"
                        + _PARTIAL
                        + "; if the record is whole, end the file with a line break"
                    )
                previous_length = len(line)
                layout = n
                rows.add(tokens[1:], lineno, line, error)
        except UnicodeDecodeError as e:
            raise InputError(f"{path}:{lineno + 1}: not UTF-8 text ({e.reason})") from e
    rows.flush()

    if units is not None and file_units is not None and units != file_units:
        raise InputError(
            f"tracker log {str(path)!r}: the file says '# units: {file_units}' but the settings "
            f"say units = {units!r}"
        )
    scale = _unit_scale(file_units or units or "in", str(path))
    if not rows.blocks:
        found = ", ".join(str(s) for s in sorted(stations)) or "none"
        raise InputError(
            f"tracker log {str(path)!r}: no samples of station {station}; stations found: {found}"
        )
    data = rows.blocks[0] if len(rows.blocks) == 1 else np.concatenate(rows.blocks)
    rows.blocks = []
    quaternions = layout == 7 and _quaternion_layout(data, path, rows.all_linenos)
    if layout == 7 and not quaternions:
        f_count = data[:, 0]
        if np.any(f_count != np.round(f_count)):
            k = int(np.flatnonzero(f_count != np.round(f_count))[0])
            raise InputError(f"{path}:{rows.all_linenos[k]}: frame count {f_count[k]} is not an integer")
        bad = np.flatnonzero(np.diff(f_count) <= 0)
        if bad.size:
            k = int(bad[0]) + 1
            raise InputError(
                f"{path}:{rows.all_linenos[k]}: frame count {int(f_count[k])} does not increase after "
                f"{int(f_count[k - 1])} (line {rows.all_linenos[k - 1]})"
            )
        t = (f_count - f_count[0]) / rate_hz  # increasing counts: steps of 1 / rate_hz or more
        data = data[:, 1:]
    else:
        t = np.arange(len(data)) / rate_hz

    def where(k: int) -> str:
        return f"{path}:{rows.all_linenos[k]}"

    positions = data[:, :3] * scale
    check_coordinates(positions, DEMO_POSITION_LIMIT_M, where, "position", file_units or units or "in")
    if quaternions:
        check_quaternions(data[:, 3:7], where)
    else:
        check_euler(data[:, 3:6], where)
    check_times(t, where)
    rotations = np.empty((len(data), 3, 3))
    for a in range(0, len(data), _CHUNK_LINES):  # in blocks: the conversion's temporaries stay small
        rows_ = data[a : a + _CHUNK_LINES]
        if quaternions:
            rotations[a : a + _CHUNK_LINES] = matrix_from_quaternion(rows_[:, 3:7])
        else:
            rotations[a : a + _CHUNK_LINES] = matrix_from_tracker_angles(
                rows_[:, 3], rows_[:, 4], rows_[:, 5], degrees=True
            )
    device_error = np.array([ord(e) if e else 0 for e in rows.errors], dtype=np.int16)
    if device_error.any():
        logger.warning(
            "%s: the device flagged %d of %d samples with an error indicator (%s)",
            path,
            int(np.count_nonzero(device_error)),
            len(t),
            ", ".join(sorted({chr(c) for c in device_error if c})),
        )
    logger.debug("%s: %d samples of station %d at %g Hz", path, len(t), station, rate_hz)
    return TrackerLog(
        t=t.astype(float),
        positions=positions,
        rotations=rotations,
        station=station,
        source=str(path),
        device_error=device_error if device_error.any() else None,
    )


def write_liberty_ascii(
    path: str | Path,
    log: TrackerLog,
    units: str = "in",
    with_frame_count: bool = False,
    rate_hz: float | None = None,
) -> None:
    """Write a tracker log in the Liberty ASCII format that :func:`read_liberty_ascii` reads.

    Args:
        path: the file to write.
        log: samples to write; positions [m], rotations R_S_E.
        units: position unit in the file, ``"in"`` or ``"cm"`` (written as ``# units:``).
        with_frame_count: write the frame counter column, ``round(t * rate_hz)``.
        rate_hz: sample rate [Hz] written as ``# rate_hz:``; None takes 1 / median step of
            ``log.t``.

    Raises:
        InputError: an unknown unit or a non-positive rate.
    """
    path = Path(path)
    scale = _unit_scale(units, str(path))
    if rate_hz is None:
        rate_hz = 1.0 / float(np.median(np.diff(log.t)))
    rate_hz = _parse_rate(str(rate_hz), str(path))
    frames = np.rint(log.t * rate_hz).astype(np.int64)
    uniform = np.allclose(log.t - log.t[0], np.arange(len(log.t)) / rate_hz, atol=1e-6)
    if not with_frame_count and not uniform:
        logger.warning("%s: sample times are not uniform at %g Hz; times will be lost", path, rate_hz)
    positions = np.round(log.positions / scale, 4) + 0.0  # + 0.0 turns -0.0 into 0.0
    angles = np.round(tracker_angles_from_matrix(log.rotations, degrees=True), 3) + 0.0
    out = [
        "# Polhemus Liberty ASCII records written by refine",
        f"# units: {units}",
        f"# rate_hz: {rate_hz:.10g}",
    ]
    for k in range(len(log.t)):
        line = f"{log.station:02d}"
        if with_frame_count:
            line += f" {frames[k]:9d}"
        line += "".join(f" {v:10.4f}" for v in positions[k])
        line += "".join(f" {a:9.3f}" for a in angles[k])
        out.append(line)
    path.write_text("\n".join(out) + "\n", encoding="utf-8")
