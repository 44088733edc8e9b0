"""Polhemus Liberty ASCII tracker logs: read and write.

The format, as the Liberty prints it in ASCII mode and as refine reads and writes it::

    # Polhemus Liberty ASCII            <- comment lines start with '#'
    # units: in                          <- optional: position unit, 'in' or 'cm'
    # rate_hz: 240                       <- optional: sample rate [Hz]
    01    12.3456   -4.5678    9.8765   -12.345    45.678   170.123
    02    ...                            <- other stations' lines are skipped

* Blank lines are ignored; comments are ignored except ``# units: ...`` and ``# rate_hz: ...``
  (``:`` or ``=``, any case), which set the position unit and sample rate for the whole file.
* A data line is whitespace separated: the station number (an integer, leading zero allowed,
  ``01``), then either six values ``x y z azimuth elevation roll`` or seven values
  ``frame_count x y z azimuth elevation roll``. All lines of one station use the same layout.
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
from pathlib import Path

import numpy as np

from refine.errors import InputError
from refine.frames import matrix_from_tracker_angles, tracker_angles_from_matrix
from refine.paths import TrackerLog

logger = logging.getLogger(__name__)

#: Length of one Liberty position unit [m].
METRES_PER_UNIT = {"in": 0.0254, "cm": 0.01}
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
    if not (np.isfinite(rate) and rate > 0.0):
        raise InputError(f"{where}: rate_hz must be a number > 0 Hz, got {text!r}")
    return rate


def read_liberty_ascii(
    path: str | Path, units: str | None = "in", station: int = 1, rate_hz: float = 240.0
) -> TrackerLog:
    """Read one station's samples from a Liberty ASCII log (format in the module docstring).

    Args:
        path: the log file.
        units: position unit the caller expects, ``"in"`` or ``"cm"``; None takes the file's
            ``# units:`` header, or inches without one.
        station: station (sensor) number to read.
        rate_hz: sample rate [Hz], unless the file's ``# rate_hz:`` header says otherwise.

    Returns:
        The station's samples: times [s] from 0, positions [m], rotations R_S_E.

    Raises:
        InputError: unreadable file; a header unit differing from ``units`` (naming both); a
            malformed line (naming file, line number and text); frame counts that do not
            increase; no samples of ``station`` (listing the stations found).
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8-sig", errors="strict").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"tracker log {str(path)!r} cannot be read: {e}") from e
    file_units: str | None = None
    rows: list[list[float]] = []
    frames: list[int] = []
    linenos: list[int] = []
    layout: int | None = None
    stations: set[int] = set()
    for lineno, raw in enumerate(lines, start=1):
        line = raw.strip()
        where = f"{path}:{lineno}"
        if not line:
            continue
        if line.startswith("#"):
            m = _HEADER.match(line)
            if m and m.group(1).lower() == "units":
                file_units = m.group(2).lower()
                _unit_scale(file_units, where)
            elif m:
                rate_hz = _parse_rate(m.group(2), where)
            continue
        tokens = line.split()
        try:
            st = int(tokens[0])
        except ValueError as e:
            raise InputError(f"{where}: station number must be an integer, got {line!r}") from e
        stations.add(st)
        if st != station:
            continue
        n = len(tokens) - 1
        if n not in (6, 7) or (layout is not None and n != layout):
            expected = "6 or 7" if layout is None else str(layout)
            raise InputError(
                f"{where}: expected {expected} values after the station number "
                f"([frame_count] x y z azimuth elevation roll), got {n}: {line!r}"
            )
        layout = n
        try:
            if n == 7:
                frames.append(int(tokens[1]))
            values = [float(v) for v in tokens[n - 5 :]]
        except ValueError as e:
            raise InputError(f"{where}: not a number in {line!r} ({e})") from e
        if not np.all(np.isfinite(values)):
            raise InputError(f"{where}: non-finite value in {line!r}")
        rows.append(values)
        linenos.append(lineno)

    if units is not None and file_units is not None and units != file_units:
        raise InputError(
            f"tracker log {str(path)!r}: the file says '# units: {file_units}' but the settings "
            f"say units = {units!r}"
        )
    scale = _unit_scale(file_units or units or "in", str(path))
    if not rows:
        found = ", ".join(str(s) for s in sorted(stations)) or "none"
        raise InputError(
            f"tracker log {str(path)!r}: no samples of station {station}; stations found: {found}"
        )
    data = np.asarray(rows, dtype=float)
    if layout == 7:
        f = np.asarray(frames, dtype=np.int64)
        bad = np.flatnonzero(np.diff(f) <= 0)
        if bad.size:
            k = int(bad[0]) + 1
            raise InputError(
                f"{path}:{linenos[k]}: frame count {f[k]} does not increase after {f[k - 1]} "
                f"(line {linenos[k - 1]})"
            )
        t = (f - f[0]) / rate_hz
    else:
        t = np.arange(len(data)) / rate_hz
    rotations = matrix_from_tracker_angles(data[:, 3], data[:, 4], data[:, 5], degrees=True)
    logger.debug("%s: %d samples of station %d at %g Hz", path, len(t), station, rate_hz)
    return TrackerLog(
        t=t.astype(float),
        positions=data[:, :3] * scale,
        rotations=rotations,
        station=station,
        source=str(path),
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
