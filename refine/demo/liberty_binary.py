"""Polhemus Liberty binary tracker logs (``F1`` output mode): read and write.

A log is the byte stream the Liberty sends, one record per station and frame. Each record is an
8-byte header and a payload, all little-endian::

    offset  size  field
    0       2     "LY" (0x4C 0x59; the Patriot sends "PA", the Latus "LU")
    2       1     station number (1-based, binary)
    3       1     initiating command (ASCII code: 'C' continuous, 'P' single P&O record)
    4       1     error indicator (0, or an ASCII space, when there is no error)
    5       1     reserved
    6       2     response size: the payload's length in bytes (uint16)
    8       n     payload: the items of the station's output list, in the order of the list

Output list items (Liberty ``O`` command) that refine reads, with their binary sizes:
``2``/``3`` position x, y, z (3 x float32, inches, or centimetres after ``U1``), ``4``/``5`` Euler
angles azimuth, elevation, roll (3 x float32, degrees; ``R = Rz(az)·Ry(el)·Rx(roll)``), ``7``
orientation quaternion w, x, y, z (4 x float32), ``8`` timestamp [ms] (uint32), ``9`` frame count
(uint32), ``11`` distortion level (4 bytes, skipped), ``0`` a space (1 byte), ``1`` CR LF (2 bytes).
The Liberty's own default output list is ``2,4,1`` (position, Euler angles, CR LF).
Sources: the binary header structs of Polhemus' PDI SDK (``PDItracker.h``: preamble 0x594C "LY",
station, cmd, err, reserved, length) and of the TUM/IAS ``polhemus_ros_driver``
(``liberty_protocol.h``: header, then ``O*,8,9,11,3,7`` as timestamp, frame count, distortion,
x y z, quaternion w x y z; its default frame ``O*,2,4,1`` as x y z, azimuth elevation roll, CR LF;
the continuous-mode command byte 67, 'C'); VRPN's ``vrpn_Tracker_Liberty`` requests ``O*,2,7,8,0``
and reads x y z, w x y z, the uint32 millisecond timestamp and a space, taking an error byte other
than a space as a flag.

The record carries no position unit (the reserved byte is 0 on the Liberty), so the caller names
it: ``units`` ``"in"`` (the Liberty's default) or ``"cm"``. Without ``output_list`` the reader
recognises position + quaternion or Euler angles, with an optional uint32 timestamp first or last
and an optional trailing space or CR LF, by the response size and by the values being what they
must be: unit quaternions, angles within ±180/±90/±180 deg, no denormal position (a millisecond
timestamp read as a float32 is a tiny denormal for the first 2.3 hours after the tracker's clock
was reset), timestamps that mostly step forward by at most 10 s (float bits read as a timestamp jump
by days). Layouts that still fit alike are an error asking for ``output_list``.

Records of other stations, and records a command other than ``C``/``P`` initiated (replies to
configuration commands), are skipped (the station's are counted in a warning). An error indicator other than 0 or a space is kept per
sample (``TrackerLog.device_error``, the byte's value: the Liberty's real-time indicators are the
letters listed in :data:`refine.demo.quality.DEVICE_ERROR_MEANINGS`); the quality gate treats
those samples as a dropout and reports them (``demo_quality.device_errors``).

Time: from timestamps ``t = (ms - ms[0]) / 1000``; from frame counts ``(f - f[0]) / rate_hz``
(both uint32 counters, unwrapped); without either, sample ``k`` is at ``t = k / rate_hz``.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from refine.demo.liberty import METRES_PER_UNIT
from refine.errors import InputError
from refine.frames import (
    matrix_from_quaternion,
    matrix_from_tracker_angles,
    quaternion_from_matrix,
    tracker_angles_from_matrix,
)
from refine.paths import TrackerLog
from refine.plausible import DEMO_POSITION_LIMIT_M, check_coordinates, check_euler, check_times

logger = logging.getLogger(__name__)

HEADER = struct.Struct("<2sBBBBH")
PREAMBLE = b"LY"
#: Item number -> (struct format of its payload, name, number of values it unpacks to).
ITEMS = {
    0: ("1s", "space", 1),
    1: ("2s", "crlf", 1),
    2: ("3f", "position", 3),
    3: ("3f", "position", 3),
    4: ("3f", "euler", 3),
    5: ("3f", "euler", 3),
    7: ("4f", "quaternion", 4),
    8: ("I", "timestamp", 1),
    9: ("I", "frame", 1),
    11: ("4s", "distortion", 1),
}
_FILL = {"space": b" ", "crlf": b"\r\n", "distortion": bytes(4)}
#: Layouts tried, in this order, when no output list is given.
AUTO_LAYOUTS = tuple(
    (*ts_first, 2, ori, *ts_last, *end)
    for ori in (7, 4)
    for ts_first, ts_last in (((), ()), ((8,), ()), ((), (8,)))
    for end in ((), (0,), (1,))
)
_COMMANDS = {ord(c) for c in "CcPp"}
_NO_ERROR = {0, 0x20}
_PARTIAL = (
    " (a capture switched on or off while the device was sending, as Polhemus Tracker Terminal's "
    "capture does, starts or ends inside a record: cut the file at a record boundary)"
)


def _item_format(output_list: Sequence[int], where: str) -> struct.Struct:
    unknown = [i for i in output_list if i not in ITEMS]
    items = set(output_list)
    if unknown or len(items & {4, 5, 7}) != 1 or len(items & {2, 3}) != 1 or len(items) != len(output_list):
        raise InputError(
            f"{where}: output list {list(output_list)} must hold one position (2 or 3) and one "
            f"orientation (Euler angles 4 or 5, or the quaternion 7), each once, from items "
            f"{sorted(ITEMS)}; unsupported: {unknown}"
        )
    return struct.Struct("<" + "".join(ITEMS[i][0] for i in output_list))


def _decode(output_list: Sequence[int], payloads: list[bytes], where: str) -> dict[str, list]:
    """Payloads -> {item name: per-record value tuples}."""
    fmt = _item_format(output_list, where)
    rows = [fmt.unpack(p) for p in payloads]
    out, col = {}, 0
    for item in output_list:
        _, name, n = ITEMS[item]
        out[name] = [r[col : col + n] for r in rows]
        col += n
    return out


def _fits(output_list: Sequence[int], payloads: list[bytes]) -> bool:
    """Whether every payload reads as ``output_list`` with unit quaternions and its padding."""
    if _item_format(output_list, "").size != len(payloads[0]):
        return False
    fields = _decode(output_list, payloads, "")
    for name in ("space", "crlf"):
        if name in fields and any(v[0] != _FILL[name] for v in fields[name]):
            return False
    p = np.array(fields["position"], dtype=float)
    if not np.all(np.isfinite(p)) or np.any((p != 0.0) & (np.abs(p) < 1e-30)):
        return False
    if "quaternion" in fields:
        q = np.array(fields["quaternion"], dtype=float)
        if not np.all(np.abs(np.linalg.norm(q, axis=1) - 1.0) < 1e-3):
            return False
    else:
        a = np.array(fields["euler"], dtype=float)
        if not (np.all(np.isfinite(a)) and np.all(np.abs(a) <= np.array([180.0, 90.0, 180.0]) + 1e-3)):
            return False
    if "timestamp" in fields and len(payloads) > 1:
        steps = np.diff(np.array(fields["timestamp"], dtype=np.int64)[:, 0]) % 2**32
        if np.mean((steps > 0) & (steps <= 10_000)) < 0.5:  # most steps (a bad one is reported later)
            return False
    return True


def read_liberty_binary(
    path: str | Path,
    station: int = 1,
    rate_hz: float = 240.0,
    *,
    units: str = "in",
    output_list: Sequence[int] | None = None,
) -> TrackerLog:
    """Read one station's samples from a Liberty binary log (format in the module docstring).

    Args:
        path: the binary log.
        station: station (sensor) number to read; other stations' records are skipped.
        rate_hz: sample rate [Hz] for logs without timestamps (and for frame counts).
        units: position unit of the log, ``"in"`` or ``"cm"``.
        output_list: the station's output list items (e.g. ``(8, 2, 7)``), or None to recognise
            the layout (see the module docstring).

    Returns:
        The station's samples: times [s] from 0, positions [m], rotations R_S_E from the
        normalised quaternions.

    Raises:
        InputError: unreadable file; a bad header or truncated record (naming the byte offset);
            records of one station with different sizes; no records of ``station`` (listing the
            stations found); a layout that cannot be recognised; times that do not increase.
    """
    path = Path(path)
    if units not in METRES_PER_UNIT:
        raise InputError(f"{path}: unknown Liberty unit {units!r}; use 'in' or 'cm'")
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"{path}: rate_hz must be a number > 0 Hz, got {rate_hz!r}")
    try:
        data = path.read_bytes()
    except OSError as e:
        raise InputError(f"tracker log {str(path)!r} cannot be read: {e}") from e
    payloads: list[bytes] = []
    offsets: list[int] = []
    stations: set[int] = set()
    errors: list[int] = []
    replies: dict[int, int] = {}  # command byte -> records of the station it initiated
    offset = 0
    while offset < len(data):
        if len(data) - offset < HEADER.size:
            raise InputError(
                f"{path}: truncated record header at byte offset {offset} "
                f"({len(data) - offset} of {HEADER.size} bytes)" + _PARTIAL
            )
        preamble, st, cmd, err, _, size = HEADER.unpack_from(data, offset)
        if preamble != PREAMBLE:
            raise InputError(
                f"{path}: bad record header at byte offset {offset}: expected b'LY', got {preamble!r}"
                + (_PARTIAL if offset == 0 else "")
            )
        end = offset + HEADER.size + size
        if end > len(data):
            raise InputError(
                f"{path}: truncated record at byte offset {offset}: station {st}, response size "
                f"{size} bytes, only {len(data) - offset - HEADER.size} left" + _PARTIAL
            )
        stations.add(st)
        if st == station and cmd not in _COMMANDS:
            replies[cmd] = replies.get(cmd, 0) + 1
        if st == station and cmd in _COMMANDS:
            if payloads and size != len(payloads[0]):
                raise InputError(
                    f"{path}: record at byte offset {offset} has {size} payload bytes, the first "
                    f"record of station {station} (offset {offsets[0]}) has {len(payloads[0])}"
                )
            errors.append(0 if err in _NO_ERROR else err)
            payloads.append(data[offset + HEADER.size : end])
            offsets.append(offset)
        offset = end
    if replies:
        logger.warning(
            "%s: skipped %d record(s) of station %d that other commands initiated (replies, not P&O): %s",
            path,
            sum(replies.values()),
            station,
            ", ".join(f"{chr(c) if 32 < c < 127 else hex(c)} x{n}" for c, n in sorted(replies.items())),
        )
    if not payloads:
        found = ", ".join(str(s) for s in sorted(stations)) or "none"
        raise InputError(
            f"tracker log {str(path)!r}: no P&O records of station {station}; stations found: {found}"
        )
    if output_list is None:
        layouts = [lay for lay in AUTO_LAYOUTS if _fits(lay, payloads)]
        if len(layouts) != 1:
            raise InputError(
                f"{path}: cannot tell the output list of {len(payloads[0])}-byte records of station "
                f"{station} (candidates: {layouts or 'none'}); give it as output_list"
            )
        output_list = layouts[0]
    elif _item_format(output_list, str(path)).size != len(payloads[0]):
        raise InputError(
            f"{path}: output list {list(output_list)} needs {_item_format(output_list, '').size} "
            f"bytes, the records hold {len(payloads[0])}"
        )
    fields = {k: np.array(v) for k, v in _decode(output_list, payloads, str(path)).items()}
    positions = fields["position"].astype(float)

    def where(k: int) -> str:
        return f"{path}: record at byte offset {offsets[k]}"

    check_coordinates(positions * METRES_PER_UNIT[units], DEMO_POSITION_LIMIT_M, where, "position", units)
    if "quaternion" in fields:
        quats = fields["quaternion"].astype(float)
        norms = np.linalg.norm(quats, axis=1)
        bad = np.flatnonzero(~np.isfinite(positions).all(axis=1) | ~(np.abs(norms - 1.0) < 0.01))
        if bad.size:
            k = int(bad[0])
            raise InputError(
                f"{path}: record at byte offset {offsets[k]}: position {positions[k].tolist()} {units} "
                f"or quaternion {quats[k].tolist()} (norm {norms[k]:.4g}, expected 1) is invalid"
            )
        rotations = matrix_from_quaternion(quats)
    else:
        angles = fields["euler"].astype(float)
        bad = np.flatnonzero(~np.isfinite(positions).all(axis=1) | ~np.isfinite(angles).all(axis=1))
        if bad.size:
            k = int(bad[0])
            raise InputError(
                f"{path}: record at byte offset {offsets[k]}: position {positions[k].tolist()} {units} "
                f"or Euler angles {angles[k].tolist()} deg are not finite"
            )
        check_euler(angles, where)
        rotations = matrix_from_tracker_angles(angles[:, 0], angles[:, 1], angles[:, 2], degrees=True)
    device_error = np.array(errors, dtype=np.int16)
    if device_error.any():
        logger.warning(
            "%s: the device flagged %d of %d record(s) of station %d with an error indicator",
            path,
            int(np.count_nonzero(device_error)),
            len(device_error),
            station,
        )
    counter = fields.get("timestamp", fields.get("frame"))
    if counter is not None:
        steps = np.diff(counter[:, 0].astype(np.int64))
        steps[steps < -(2**31)] += 2**32  # the uint32 counter wrapped around
        ticks = np.concatenate([[0], np.cumsum(steps)])
        t = ticks / 1000.0 if "timestamp" in fields else ticks / rate_hz
    else:
        t = np.arange(len(payloads)) / rate_hz
    bad = np.flatnonzero(np.diff(t) <= 0.0)
    if bad.size:
        k = int(bad[0]) + 1
        raise InputError(
            f"{path}: record at byte offset {offsets[k]}: time {t[k]:.3f} s does not increase "
            f"after {t[k - 1]:.3f} s (offset {offsets[k - 1]})"
        )
    check_times(t, where)
    logger.debug("%s: %d records of station %d, output list %s", path, len(t), station, output_list)
    return TrackerLog(
        t=t,
        positions=positions * METRES_PER_UNIT[units],
        rotations=rotations,
        station=station,
        source=str(path),
        device_error=device_error if device_error.any() else None,
    )


def write_liberty_binary(
    path: str | Path,
    log: TrackerLog,
    with_timestamp: bool = False,
    *,
    units: str = "in",
    output_list: Sequence[int] | None = None,
    rate_hz: float = 240.0,
) -> None:
    """Write a tracker log as Liberty binary records that :func:`read_liberty_binary` reads.

    Records carry ``log.station``, command ``'C'`` (continuous), no error, and float32 values.

    Args:
        path: the file to write.
        log: samples to write; positions [m], rotations R_S_E.
        with_timestamp: write the output list ``(8, 2, 7)`` (timestamp ``round(t * 1000)`` [ms]
            first, as the TUM driver requests it) instead of ``(2, 7)``.
        units: position unit in the file, ``"in"`` or ``"cm"``.
        output_list: any layout of :data:`ITEMS` instead (overrides ``with_timestamp``).
        rate_hz: frame rate [Hz] for a frame count item (``round(t * rate_hz)``).

    Raises:
        InputError: an unknown unit or an unsupported output list.
    """
    path = Path(path)
    if units not in METRES_PER_UNIT:
        raise InputError(f"{path}: unknown Liberty unit {units!r}; use 'in' or 'cm'")
    if not 0 <= log.station <= 255:
        raise InputError(f"{path}: station {log.station} does not fit the record's station byte (0..255)")
    items = tuple(output_list) if output_list is not None else ((8, 2, 7) if with_timestamp else (2, 7))
    fmt = _item_format(items, str(path))
    positions = log.positions / METRES_PER_UNIT[units]
    quats = quaternion_from_matrix(log.rotations)
    ms = np.rint((log.t - log.t[0]) * 1000.0).astype(np.int64)
    frames = np.rint((log.t - log.t[0]) * rate_hz).astype(np.int64)
    columns = {
        "position": positions,
        "quaternion": quats,
        "euler": tracker_angles_from_matrix(log.rotations, degrees=True),
        "timestamp": ms[:, None],
        "frame": frames[:, None],
    }
    out = bytearray()
    for k in range(len(log.t)):
        values: list = []
        for item in items:
            name = ITEMS[item][1]
            values += [_FILL[name]] if name in _FILL else [v.item() for v in columns[name][k]]
        body = fmt.pack(*values)
        out += HEADER.pack(PREAMBLE, log.station, ord("C"), 0, 0, len(body)) + body
    path.write_bytes(bytes(out))
    logger.debug("%s: wrote %d records of station %d, output list %s", path, len(log.t), log.station, items)
