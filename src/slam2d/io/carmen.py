"""CARMEN logs: streaming reader (:class:`CarmenLog`) and writer (:func:`write_carmen`).

A CARMEN log is a text file, often gzipped, with one message per line: a
keyword followed by space-separated fields, the last three of which are
``timestamp host logger_timestamp``. The reader understands

* ``FLASER`` / ``RLASER`` (front / rear laser): ``n r1..rn x y theta odom_x
  odom_y odom_theta timestamp host logger_timestamp``. The line does not state
  its angles: the field of view is 180 deg starting at -90 deg unless ``PARAM
  laser_front_laser_fov`` / ``laser_front_laser_resolution`` (degrees) say
  otherwise. Without a resolution parameter, ``fov / (n - 1)`` is used when it
  is a SICK resolution (1, 0.5 or 0.25 deg, e.g. 181 or 361 beams), else
  ``fov / n`` (180 beams = 1 deg, 360 beams = 0.5 deg). The maximum range is
  not stated either: ``PARAM robot_front_laser_max`` (or
  ``laser_front_laser_max_range``) when present, else 81.83 m, because a SICK
  LMS reports its error codes (no return, dazzled...) as 81.83-81.91 m (the
  Intel log uses 81.83, the Freiburg logs 81.91); readings at or beyond the
  maximum are no return. Some lasers write "no return" as a lower fixed value
  (the aces log: exactly 50.00 m, 620 times). So when no PARAM states the
  maximum, the reader infers such a code from the log itself, in a cheap
  pre-pass over the file before the first scan (see
  :func:`infer_no_return_code` for the rule): the log's largest reading below
  81.83 m is the no-return code when it recurs at least 20 times and at least
  10 times as often as any other reading within 10 % below it. The maximum of
  those lines is then that value, so it and anything beyond are no return. A
  stated maximum (PARAM, ROBOTLASER1) is never overridden, ``--range-max``
  (``ReadOptions.range_max``) skips the inference, and what was inferred is
  listed by :meth:`CarmenLog.notes` (``slam2d info`` prints it).
  The mount comes from ``PARAM robot_frontlaser_offset``,
  ``..._side_offset``, ``..._angular_offset`` (zero without them; the rear
  laser faces backwards, angle pi, unless its parameters say otherwise).
* ``ROBOTLASER1``: states its own start angle, angular resolution (beam i is
  at ``start_angle + i * angular_resolution``) and maximum range, the laser's
  pose and the robot's pose; the mount is the laser pose seen from the robot.
* ``ODOM x y theta tv rv accel timestamp host logger_timestamp``.
* ``PARAM name value ...``: applies to the laser lines that follow it.

Every other keyword (``TRUEPOS``, ``NEFF``, ``SONAR``...) and ``#`` comments
are skipped and counted (see :meth:`CarmenLog.streams`). Only one laser feeds
the scan stream: ``ROBOTLASER1`` if the log has it, else ``FLASER``, else
``RLASER`` (decided from the first lines of the file, so the read stays one
streaming pass). Laser and ODOM lines that are not used are still checked:
a corrupt line is reported wherever it is.
"""

from __future__ import annotations

import gzip
import io
import math
import zlib
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

import slam2d
from slam2d.core import se2
from slam2d.core.frames import Frame, OdometryReading
from slam2d.core.scan import LaserScan, make_scan
from slam2d.errors import InputError
from slam2d.io.atomic import atomic_path
from slam2d.io.base import Message, ProgressCallback, ReadOptions, Recording, StreamInfo, far_coordinate

__all__ = ["CarmenLog", "NoReturnCode", "infer_no_return_code", "write_carmen", "DEFAULT_SICK_MAX_RANGE"]

#: Maximum range of FLASER/RLASER lines without a PARAM saying otherwise (m).
#: A SICK LMS encodes its error states as 81.83-81.91 m, so these are no return.
DEFAULT_SICK_MAX_RANGE = 81.83

# The rule that takes a log's largest reading for a "no return" code (infer_no_return_code).
# A real maximum is the far tail of a continuous quantity: on intel, fr079 and fr101 the
# largest reading below 81.83 m occurs once. A code piles up at one exact value: aces writes
# 50.00 m 620 times while no other reading in 45-50 m occurs more than 4 times.
NO_RETURN_MIN_COUNT = 20  #: the code must occur at least this often
NO_RETURN_DOMINANCE = 10.0  #: ... and this many times as often as any reading in the band below it
NO_RETURN_BAND = 0.10  #: the band: readings within this fraction below the candidate (at least one)

_GZIP_MAGIC = b"\x1f\x8b"
_READ_CHUNK = 1 << 20
_MAX_LINE_BYTES = 64 << 20  # a 10,000-beam scan is ~100 kB; anything this long is not a log
_SICK_RESOLUTIONS_DEG = (1.0, 0.5, 0.25)
_LASER_KEYWORDS = ("ROBOTLASER1", "FLASER", "RLASER")  # in order of preference
_PEEK_LINES_AFTER_LASER = 2000
_PEEK_MAX_BYTES = 16 << 20

_KIND = {
    "FLASER": "front laser scan",
    "RLASER": "rear laser scan",
    "ROBOTLASER1": "laser scan with laser and robot poses",
    "ODOM": "odometry",
    "PARAM": "parameter",
    "#": "comment",
}

_FLASER_POSE_FIELDS = ("x", "y", "theta", "odom_x", "odom_y", "odom_theta", "timestamp")
_ROBOTLASER_HEAD_FIELDS = (
    "start_angle",
    "field_of_view",
    "angular_resolution",
    "maximum_range",
    "accuracy",
    "remission_mode",
)
_ROBOTLASER_TAIL_FIELDS = (
    "laser_x",
    "laser_y",
    "laser_theta",
    "robot_x",
    "robot_y",
    "robot_theta",
    "tv",
    "rv",
    "forward_safety_dist",
    "side_safety_dist",
    "turn_axis",
    "timestamp",
)
_ODOM_FIELDS = ("x", "y", "theta", "tv", "rv", "accel", "timestamp")

# PARAM names per laser side; the first one present wins.
_MAX_RANGE_PARAMS = {
    "front": ("robot_front_laser_max", "robot_frontlaser_max", "laser_front_laser_max_range"),
    "rear": ("robot_rear_laser_max", "robot_rearlaser_max", "laser_rear_laser_max_range"),
}
#: slam2d's own parameter, written by :func:`write_carmen` so range_min round-trips.
_MIN_RANGE_PARAM = "laser_front_laser_min_range"


@dataclass(frozen=True)
class NoReturnCode:
    """A "no return" code inferred from a FLASER/RLASER log that states no maximum range."""

    keyword: str  #: FLASER or RLASER
    value: float  #: the code (m); readings at or beyond it are no return
    count: int  #: how often it occurs
    band_count: int  #: the most any other reading within NO_RETURN_BAND below it occurs
    readings: int  #: readings looked at (lines of this laser without a stated maximum)

    def note(self) -> str:
        return (
            f"{self.keyword}: no-return code inferred: {self.value:g} m ({self.count} of {self.readings} "
            f"readings, the log's largest value; no other reading within {NO_RETURN_BAND:.0%} below it "
            f"occurs more than {self.band_count} times); no PARAM states the maximum, so readings at or "
            f"beyond {self.value:g} m are no return (--range-max overrides)"
        )


def infer_no_return_code(counts: dict[float, int], keyword: str = "FLASER") -> NoReturnCode | None:
    """The no-return code among a laser's readings (value -> how often), or None.

    The candidate is the largest reading above 0 and below
    :data:`DEFAULT_SICK_MAX_RANGE` (readings at or beyond that are no return
    anyway). It is a code when it occurs at least :data:`NO_RETURN_MIN_COUNT`
    times, other readings exist within :data:`NO_RETURN_BAND` below it (the
    laser does see that far, so the pile-up is not just the farthest wall),
    and it occurs at least :data:`NO_RETURN_DOMINANCE` times as often as any
    of them.
    """
    readings = sum(counts.values())
    values = np.fromiter(counts.keys(), dtype=np.float64, count=len(counts))
    hits = np.fromiter(counts.values(), dtype=np.int64, count=len(counts))
    ok = np.isfinite(values) & (values > 0.0) & (values < DEFAULT_SICK_MAX_RANGE)
    values, hits = values[ok], hits[ok]
    if values.size < 2:
        return None
    top = int(np.argmax(values))
    value, count = float(values[top]), int(hits[top])
    band = (values >= (1.0 - NO_RETURN_BAND) * value) & (values < value)
    if count < NO_RETURN_MIN_COUNT or not band.any():
        return None
    band_count = int(hits[band].max())
    if count < NO_RETURN_DOMINANCE * band_count:
        return None
    return NoReturnCode(keyword, value, count, band_count, readings)


_BOM = b"\xef\xbb\xbf"  # UTF-8 byte-order mark, which some editors put first in a text file


class _BadLine(Exception):
    """A line that cannot be read; becomes an InputError or a skipped-line count."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(message)
        self.field = field
        self.message = message


class _StreamBroken(Exception):
    """The byte stream ended badly (truncated or corrupt gzip, unreadable file)."""

    def __init__(self, after_line: int, reason: str) -> None:
        super().__init__(reason)
        self.after_line = after_line
        self.reason = reason


def _count(token: str, field: str) -> int:
    try:
        value = int(token)
    except ValueError:
        raise _BadLine(field, f"{token!r} is not a whole number") from None
    if value < 0:
        raise _BadLine(field, f"{value} is negative")
    return value


def _floats(tokens: list[str], start: int, stop: int, name_of: object) -> NDArray[np.float64]:
    """``tokens[start:stop]`` as float64 in one numpy call; on failure name the first bad field."""
    try:
        return np.array(tokens[start:stop], dtype=np.float64)
    except ValueError:
        # Slow path, only for a bad line: find which field it was.
        for i, tok in enumerate(tokens[start:stop]):
            try:
                float(tok)
            except ValueError:
                raise _BadLine(name_of(i), f"{tok!r} is not a number") from None  # type: ignore[operator]
        raise


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _odd_ranges(ranges: NDArray[np.float64]) -> int:
    """A laser line's ranges that are NaN, infinite or negative: no CARMEN writer produces them, and they are read
    as no return (a file that holds them was made or edited by hand, or is corrupt)."""
    with np.errstate(invalid="ignore"):
        return int(np.count_nonzero(~np.isfinite(ranges) | (ranges < 0.0)))


def _finite_pose(values: NDArray[np.float64], fields: list[str]) -> NDArray[np.float64]:
    bad = ~np.isfinite(values)
    if bad.any():
        i = int(np.argmax(bad))
        raise _BadLine(fields[i], f"{float(values[i])!r} is not a finite number")
    for field, value in zip(fields[:2], values[:2]):  # the position; the heading wraps
        problem = far_coordinate(value)
        if problem:
            raise _BadLine(field, problem)
    return values


class CarmenLog(Recording):
    """A CARMEN log (plain text or gzip, recognised by its first bytes), streamed line by line.

    Odometry (``options.odometry``): ``auto`` and ``embedded`` use the pose
    written in each laser line (FLASER ``odom_x odom_y odom_theta``,
    ROBOTLASER1 ``robot_x robot_y robot_theta``), which is exact at the scan's
    time; ``odom`` uses the ``ODOM`` lines (interpolated to the scans by
    :meth:`frames`); ``none`` gives scans only; ``tf`` is a ROS notion and is
    refused. A corrupt line stops the read with an :class:`InputError` naming
    ``file:line`` and the field, or with ``options.skip_bad_records`` is skipped
    and counted in :attr:`problems`.
    """

    def __init__(self, path: str | Path, options: ReadOptions | None = None) -> None:
        super().__init__(path, options)
        mode = self.options.odometry
        if mode == "tf":
            raise InputError(
                "'tf' applies to ROS bags only; a CARMEN log has odometry embedded in its laser "
                "lines ('embedded', the default) or as ODOM lines ('odom')",
                path=self.path,
                field="odometry",
            )
        if mode not in ("auto", "embedded", "odom", "none"):
            raise InputError(
                f"{mode!r} is not one of auto, embedded, odom, none", path=self.path, field="odometry"
            )
        self._odometry_mode = "embedded" if mode == "auto" else mode
        p = self.path
        if not p.exists():
            raise InputError("no such file", path=p)
        if p.is_dir():
            raise InputError("is a folder, not a CARMEN log file", path=p)
        try:
            with open(p, "rb") as f:
                head = f.read(2)
        except OSError as exc:
            raise InputError(f"cannot be read: {exc.strerror or exc}", path=p) from None
        if not head:
            raise InputError("file is empty", path=p)
        self._gzip = head == _GZIP_MAGIC
        self.format = "CARMEN log (gzip)" if self._gzip else "CARMEN log"
        self._counts: dict[str, int] = {}
        self._laser_params_seen = False
        self._laser_keyword = self._choose_laser()
        self._no_return: dict[str, NoReturnCode] | None = None  # from the pre-pass, once

    # ------------------------------------------------------------------ public

    @property
    def laser_keyword(self) -> str | None:
        """The message type that feeds the scan stream (None until one is seen)."""
        return self._laser_keyword

    @property
    def odometry_source(self) -> str:
        if self._odometry_mode == "none":
            return "none"
        if self._odometry_mode == "odom":
            return "ODOM lines"
        return f"pose embedded in {self._laser_keyword or 'laser'} lines"

    @property
    def no_return_codes(self) -> dict[str, NoReturnCode]:
        """The inferred no-return code per laser keyword (empty until a read, or with ``--range-max``)."""
        return dict(self._no_return or {})

    def notes(self) -> list[str]:
        """What the reader inferred rather than read; complete after a full read."""
        if not self._no_return:
            return []
        return [code.note() for kw, code in self._no_return.items() if kw == self._laser_keyword]

    def streams(self) -> list[StreamInfo]:
        """One entry per keyword seen, with its count; complete after a full read."""
        out = []
        for name, count in self._counts.items():
            used = ""
            if name == self._laser_keyword:
                used = "scans, odometry" if self._odometry_mode == "embedded" else "scans"
            elif name == "ODOM" and self._odometry_mode == "odom":
                used = "odometry"
            elif name == "PARAM" and self._laser_params_seen and self._laser_keyword in ("FLASER", "RLASER"):
                used = "laser mount"
            out.append(StreamInfo(name, _KIND.get(name, "other (skipped)"), count, used))
        return out

    def messages(self, progress: ProgressCallback | None = None) -> Iterator[Message]:
        """Scans and odometry readings in file order, cleaned, in constant memory.

        With embedded odometry each scan is preceded by an
        :class:`OdometryReading` with the same timestamp (source ``FLASER``,
        ``ROBOTLASER1``...), except for a scan that steps back in time, whose
        pose cannot join a time-ordered odometry stream (counted in
        :attr:`problems`; :meth:`frames` still pairs it with its own pose).
        """
        return self._read(progress, pair_embedded=False)  # type: ignore[return-value]

    def frames(self, progress: ProgressCallback | None = None) -> Iterator[Frame]:
        """Scans paired with the odometry pose at their timestamps.

        With embedded odometry every scan gets the pose written on its own
        line (exact, no interpolation); with ODOM lines the pose is
        interpolated at the scan's time.
        """
        if self._odometry_mode != "embedded":
            return super().frames(progress)
        return (
            Frame(index, scan, pose.copy())
            for index, (scan, pose) in enumerate(self._read(progress, pair_embedded=True))  # type: ignore[misc]
        )

    def _read(
        self, progress: ProgressCallback | None, *, pair_embedded: bool
    ) -> Iterator[Message | tuple[LaserScan, NDArray[np.float64]]]:
        """The one streaming pass behind :meth:`messages` and :meth:`frames`.

        ``pair_embedded`` yields ``(scan, embedded pose)`` tuples instead of
        an odometry reading followed by the scan.
        """
        self._counts = {}
        self._laser_params_seen = False
        self.problems.clear()
        check = self.timestamp_check()
        skip = self.options.skip_bad_records
        mode = self._odometry_mode
        counts = self._counts
        params: dict[str, float] = {}
        geometry: dict[tuple[str, int], tuple[float, float, float, float, NDArray[np.float64]]] = {}
        if self._no_return is None:
            self._no_return = self._infer_no_return_codes()
        scans = odoms = 0
        lineno = 0
        lines = self._raw_lines(progress)
        try:
            for lineno, raw in lines:
                keyword = ""
                try:
                    try:
                        line = raw.decode("utf-8")
                    except UnicodeDecodeError as exc:
                        raise _BadLine(
                            "text",
                            f"byte 0x{raw[exc.start]:02x} at column {exc.start + 1} is not UTF-8 "
                            "text (is this a CARMEN log?)",
                        ) from None
                    tokens = line.split()
                    if not tokens:
                        continue
                    keyword = tokens[0]
                    if keyword.startswith("#"):
                        counts["#"] = counts.get("#", 0) + 1
                        continue
                    counts[keyword] = counts.get(keyword, 0) + 1
                    if keyword == "PARAM":
                        if self._apply_param(tokens, params):
                            geometry.clear()
                            self._laser_params_seen = True
                    elif keyword in _LASER_KEYWORDS:
                        if self._laser_keyword is None:
                            self._laser_keyword = keyword
                        if keyword == "ROBOTLASER1":
                            scan, pose, odd = self._parse_robotlaser(tokens, params)
                        else:
                            scan, pose, odd = self._parse_flaser(keyword, tokens, params, geometry)
                        if odd:
                            self.problems.add("ranges NaN, infinite or negative (read as no return)",
                                              f"line {lineno}: {keyword}, {odd} of {scan.num_beams} beams")
                        if keyword != self._laser_keyword:
                            continue  # another laser: checked like the others, not used
                        if mode == "embedded":
                            pose_fields = (
                                ["robot_x", "robot_y", "robot_theta"]
                                if keyword == "ROBOTLASER1"
                                else ["odom_x", "odom_y", "odom_theta"]
                            )
                            _finite_pose(pose, [f"{keyword} {f}" for f in pose_fields])
                        t = scan.timestamp
                        if not check.scan(t, lineno, f"{keyword} timestamp"):
                            continue
                        scans += 1
                        if mode == "embedded":
                            if pair_embedded:
                                yield scan, pose
                                continue
                            # A scan stepping back in time is kept, but its pose cannot
                            # join the odometry stream (counted by the check).
                            if check.odometry(t, lineno, f"{keyword} timestamp"):
                                yield OdometryReading(t, pose, keyword)
                                odoms += 1
                        yield scan
                    elif keyword == "ODOM":
                        # Checked even when unused: a corrupt line means a corrupt log.
                        t, pose = self._parse_odom(tokens)
                        if mode == "odom" and check.odometry(t, lineno, "ODOM timestamp"):
                            yield OdometryReading(t, pose, "ODOM")
                            odoms += 1
                except _BadLine as bad:
                    if not skip:
                        raise InputError(bad.message, path=self.path, where=lineno, field=bad.field) from None
                    self.problems.add(
                        f"skipped bad {keyword or 'undecodable'} line",
                        f"line {lineno}: {bad.field}: {bad.message}",
                    )
        except _StreamBroken as broken:
            what = "truncated or corrupt gzip stream" if self._gzip else "read error"
            message = f"{what} after line {broken.after_line}: {broken.reason}"
            if not skip:
                raise InputError(message, path=self.path, field="gzip" if self._gzip else None) from None
            self.problems.add(f"{what} (kept the lines before it)", message)
        if scans == 0:
            if lineno == 0:
                raise InputError("file is empty", path=self.path)
            words = sorted(counts.items(), key=lambda kv: -kv[1])
            seen = ", ".join(f"{k[:20] if k.isprintable() else ascii(k[:20])} x{n}" for k, n in words[:5])
            if len(words) > 5:
                seen += f" and {len(words) - 5} other first words"
            if words and all(_is_number(k) for k, _ in words[:5]):
                seen += " (lines that start with a number: a TUM trajectory or another table, not a CARMEN log?)"
            raise InputError(
                f"no laser scans found (FLASER, RLASER or ROBOTLASER1 lines); the log holds: {seen or 'nothing readable'}",
                path=self.path,
            )
        if mode == "odom" and odoms == 0:
            self.problems.add("no odometry", "the log has no usable ODOM lines")

    def _infer_no_return_codes(self) -> dict[str, NoReturnCode]:
        """The pre-pass: count every FLASER/RLASER reading not covered by a stated maximum.

        Skipped (nothing inferred) with ``--range-max`` or when ROBOTLASER1
        feeds the scans (it states its maximum). Readings are counted as
        their text, which is cheap (about 0.2 s CPU for fr079's 1.7 million);
        only the distinct values are parsed. Malformed lines are left to the
        main pass, which reports them.
        """
        if self.options.range_max is not None or self._laser_keyword == "ROBOTLASER1":
            return {}
        text: dict[str, Counter[bytes]] = {"FLASER": Counter(), "RLASER": Counter()}
        stated_names = {
            kw: {name.encode() for name in _MAX_RANGE_PARAMS["front" if kw == "FLASER" else "rear"]}
            for kw in text
        }
        stated: set[str] = set()  # lines after a PARAM stating the maximum are not counted
        lines = self._raw_lines()
        try:
            for _lineno, line in lines:
                if line.startswith((b"FLASER", b"RLASER")):
                    tokens = line.split()
                    kw = tokens[0].decode("ascii", "replace")
                    if kw not in text or kw in stated or len(tokens) < 2 or not tokens[1].isdigit():
                        continue
                    text[kw].update(tokens[2 : 2 + int(tokens[1])])
                elif line.startswith(b"PARAM"):
                    tokens = line.split()
                    if len(tokens) >= 3:
                        stated.update(kw for kw, names in stated_names.items() if tokens[1] in names)
        except _StreamBroken:
            pass  # the main pass reports it
        finally:
            lines.close()
        codes = {}
        for kw, counter in text.items():
            values: dict[float, int] = {}
            for token, n in counter.items():
                try:
                    value = float(token)
                except ValueError:
                    continue  # the main pass names the bad field
                values[value] = values.get(value, 0) + n
            code = infer_no_return_code(values, kw)
            if code is not None:
                codes[kw] = code
        return codes

    # ------------------------------------------------------------------ bytes to lines

    def _raw_lines(self, progress: ProgressCallback | None = None) -> Iterator[tuple[int, bytes]]:
        """``(line number, bytes without the newline)``, read in chunks in constant memory.

        Raises :class:`_StreamBroken` after the last complete line when the
        stream is cut short; the partial line before the cut is dropped.
        """
        try:
            size = self.path.stat().st_size
            raw = open(self.path, "rb")
        except OSError as exc:
            raise InputError(f"cannot be read: {exc.strerror or exc}", path=self.path) from None
        lineno = 0
        with raw:
            stream: io.BufferedIOBase = raw
            if self._gzip:
                stream = gzip.GzipFile(fileobj=raw, mode="rb")
            pending = b""
            while True:
                try:
                    chunk = stream.read1(_READ_CHUNK)
                except (EOFError, zlib.error, OSError) as exc:
                    raise _StreamBroken(lineno, str(exc) or type(exc).__name__) from None
                if not chunk:
                    break
                lines = (pending + chunk).split(b"\n")
                pending = lines.pop()
                if len(pending) > _MAX_LINE_BYTES:
                    raise InputError(
                        f"longer than {_MAX_LINE_BYTES >> 20} MB without a line break (not a CARMEN log?)",
                        path=self.path,
                        where=lineno + 1,
                    )
                if lineno == 0 and lines and lines[0].startswith(_BOM):
                    lines[0] = lines[0][len(_BOM):]  # an editor's byte-order mark is not part of the keyword
                for line in lines:
                    lineno += 1
                    yield lineno, line
                if progress is not None:
                    progress(raw.tell(), size)
            if pending:
                if lineno == 0 and pending.startswith(_BOM):
                    pending = pending[len(_BOM):]
                lineno += 1
                yield lineno, pending
        if progress is not None:
            progress(size, size)

    def _choose_laser(self) -> str | None:
        """Which laser keyword feeds the scans, from the first lines of the file.

        Stops at the first ROBOTLASER1, or a little after the first FLASER or
        RLASER, so opening stays cheap; None when no laser line is seen early
        (the first laser line of the read then decides).
        """
        seen: set[str] = set()
        after_laser = 0
        read = 0
        lines = self._raw_lines()
        try:
            for lineno, line in lines:
                read += len(line) + 1
                head = line.split(None, 1)
                keyword = head[0].decode("ascii", "replace") if head else ""
                if keyword in _LASER_KEYWORDS:
                    seen.add(keyword)
                    if keyword == "ROBOTLASER1":
                        break
                if seen:
                    after_laser += 1
                if after_laser > _PEEK_LINES_AFTER_LASER or read > _PEEK_MAX_BYTES:
                    break
        except _StreamBroken as broken:
            if broken.after_line == 0:
                raise InputError(
                    f"not a readable gzip file: {broken.reason}", path=self.path, field="gzip"
                ) from None
        finally:
            lines.close()
        if read == 0:
            detail = " (the gzip stream holds no data)" if self._gzip else ""
            raise InputError(f"file is empty{detail}", path=self.path)
        for keyword in _LASER_KEYWORDS:
            if keyword in seen:
                return keyword
        return None

    # ------------------------------------------------------------------ messages

    def _apply_param(self, tokens: list[str], params: dict[str, float]) -> bool:
        """Record a PARAM that affects laser geometry; True when one changed."""
        if len(tokens) < 3:
            return False
        name = tokens[1]
        if not (name.startswith("robot_") or name.startswith("laser_")) or "laser" not in name:
            return False
        try:
            value = float(tokens[2])
        except ValueError:
            # Laser parameters that are not numbers (device names, "on"...) do not affect geometry.
            if any(key in name for key in ("offset", "max", "fov", "resolution", "min_range")):
                raise _BadLine(f"PARAM {name}", f"{tokens[2]!r} is not a number") from None
            return False
        params[name] = value
        return True

    @staticmethod
    def _side_geometry(
        side: str, n: int, params: dict[str, float], code: NoReturnCode | None = None
    ) -> tuple[float, float, float, float, NDArray[np.float64]]:
        """(angle_min, angle_increment, range_min, range_max, mount) of a FLASER/RLASER laser.

        ``code``, the laser's inferred no-return code, lowers the maximum
        only when no PARAM states it.
        """
        fov = params.get(f"laser_{side}_laser_fov", 180.0)
        resolution = params.get(f"laser_{side}_laser_resolution")
        if resolution is None:
            resolution = fov / n
            if n > 1 and any(abs(fov / (n - 1) - r) < 1e-9 for r in _SICK_RESOLUTIONS_DEG):
                resolution = fov / (n - 1)
        range_max = DEFAULT_SICK_MAX_RANGE
        for name in _MAX_RANGE_PARAMS[side]:
            if name in params:
                range_max = params[name]
                break
        else:
            if code is not None:
                range_max = min(range_max, code.value)
        range_min = params.get(_MIN_RANGE_PARAM.replace("front", side), 0.0)
        mount = np.array(
            [
                params.get(f"robot_{side}laser_offset", 0.0),
                params.get(f"robot_{side}laser_side_offset", 0.0),
                params.get(f"robot_{side}laser_angular_offset", 0.0 if side == "front" else math.pi),
            ]
        )
        return -math.radians(fov) / 2.0, math.radians(resolution), range_min, range_max, mount

    def _parse_flaser(
        self,
        keyword: str,
        tokens: list[str],
        params: dict[str, float],
        geometry: dict[tuple[str, int], tuple[float, float, float, float, NDArray[np.float64]]],
    ) -> tuple[LaserScan, NDArray[np.float64], int]:
        """The scan, the odometry pose and how many ranges were odd (:func:`_odd_ranges`)."""
        if len(tokens) < 2:
            raise _BadLine(keyword, "the line ends after its keyword (truncated line?)")
        n = _count(tokens[1], f"{keyword} num_readings")
        expected = n + 11
        if len(tokens) != expected:
            hint = "truncated line?" if len(tokens) < expected else "more values than the beam count says"
            raise _BadLine(
                keyword, f"line has {len(tokens)} fields, {expected} expected for {n} beams ({hint})"
            )

        def name_of(i: int) -> str:
            return f"{keyword} range {i + 1}" if i < n else f"{keyword} {_FLASER_POSE_FIELDS[i - n]}"

        values = _floats(tokens, 2, n + 9, name_of)
        key = (keyword, n)
        geo = geometry.get(key)
        if geo is None:
            geo = geometry[key] = self._side_geometry(
                "front" if keyword == "FLASER" else "rear", n, params, (self._no_return or {}).get(keyword)
            )
        angle_min, increment, range_min, range_max, mount = geo
        try:
            scan = make_scan(
                values[n + 6], values[:n], angle_min, increment, self.range_min(range_min), self.range_max(range_max), mount=mount
            )
        except ValueError as exc:
            raise _BadLine(keyword, str(exc)) from None
        return scan, values[n + 3 : n + 6], _odd_ranges(values[:n])

    def _parse_robotlaser(
        self, tokens: list[str], params: dict[str, float]
    ) -> tuple[LaserScan, NDArray[np.float64], int]:
        """The scan, the robot pose and how many ranges were odd (:func:`_odd_ranges`)."""
        kw = "ROBOTLASER1"
        if len(tokens) < 10:
            raise _BadLine(kw, f"line has {len(tokens)} fields, at least 24 expected (truncated line?)")
        n = _count(tokens[8], f"{kw} num_readings")
        if len(tokens) < n + 24:
            raise _BadLine(
                f"{kw} num_readings",
                f"header says {n} beams but the line has {len(tokens)} fields, at least {n + 24} "
                "expected (truncated line or wrong beam count?)",
            )
        try:
            k = _count(tokens[9 + n], f"{kw} num_remissions")
        except _BadLine as bad:
            raise _BadLine(
                f"{kw} num_readings",
                f"header says {n} beams but the field after them, num_remissions, is "
                f"{tokens[9 + n]!r}: {bad.message} (wrong beam count?)",
            ) from None
        expected = n + k + 24
        if len(tokens) != expected:
            raise _BadLine(
                f"{kw} num_readings",
                f"header says {n} beams and {k} remissions, so {expected} fields are expected, but the "
                f"line has {len(tokens)} (truncated line or wrong beam count?)",
            )
        head = _floats(tokens, 2, 8, lambda i: f"{kw} {_ROBOTLASER_HEAD_FIELDS[i]}")

        def name_of(i: int) -> str:
            if i < n:
                return f"{kw} range {i + 1}"
            if i == n:
                return f"{kw} num_remissions"
            if i <= n + k:
                return f"{kw} remission {i - n}"
            return f"{kw} {_ROBOTLASER_TAIL_FIELDS[i - n - k - 1]}"

        body = _floats(tokens, 9, len(tokens) - 2, name_of)
        tail = body[n + k + 1 :]
        laser_pose = _finite_pose(tail[0:3], [f"{kw} laser_x", f"{kw} laser_y", f"{kw} laser_theta"])
        robot_pose = tail[3:6]
        _finite_pose(robot_pose, [f"{kw} robot_x", f"{kw} robot_y", f"{kw} robot_theta"])
        mount = se2.relative(robot_pose, laser_pose)
        intensities = None
        if k:
            if k == n:
                intensities = body[n + 1 : n + 1 + k]
            else:
                self.problems.add(
                    "ROBOTLASER1 remissions ignored (count differs from beams)", f"{k} for {n} beams"
                )
        start_angle, _fov, resolution, maximum_range = head[0], head[1], head[2], head[3]
        try:
            scan = make_scan(
                tail[11],
                body[:n],
                start_angle,
                resolution,
                self.range_min(params.get(_MIN_RANGE_PARAM, 0.0)),
                self.range_max(maximum_range),
                mount=mount,
                intensities=intensities,
            )
        except ValueError as exc:
            raise _BadLine(kw, str(exc)) from None
        return scan, robot_pose, _odd_ranges(body[:n])

    @staticmethod
    def _parse_odom(tokens: list[str]) -> tuple[float, NDArray[np.float64]]:
        if len(tokens) != 10:
            raise _BadLine(
                "ODOM",
                f"line has {len(tokens)} fields, 10 expected: ODOM x y theta tv rv accel timestamp host "
                "logger_timestamp" + (" (truncated line?)" if len(tokens) < 10 else ""),
            )
        values = _floats(tokens, 1, 8, lambda i: f"ODOM {_ODOM_FIELDS[i]}")
        pose = _finite_pose(values[:3], ["ODOM x", "ODOM y", "ODOM theta"])
        return float(values[6]), pose


# ---------------------------------------------------------------------- writer


def _repr_floats(values: NDArray[np.float64]) -> str:
    # repr of a Python float is the shortest string that parses back to the same bits.
    return " ".join(map(repr, values.tolist()))


def _robotlaser_line(
    scan: LaserScan, robot_pose: NDArray[np.float64], laser_type: int, host: str
) -> str:
    ranges = scan.ranges.copy()
    no_return = np.isnan(ranges)
    # The reader turns readings >= maximum_range, and 0, back into "no return".
    ranges[no_return] = scan.range_max if math.isfinite(scan.range_max) else 0.0
    n = scan.num_beams
    laser_pose = se2.compose(robot_pose, scan.mount)
    if scan.intensities is not None:
        remissions = f"{n} {_repr_floats(scan.intensities)}"
        remission_mode = 1
    else:
        remissions = "0"
        remission_mode = 0
    t = repr(float(scan.timestamp))
    fields = [
        "ROBOTLASER1",
        str(int(laser_type)),
        repr(float(scan.angle_min)),
        repr(float(scan.angle_increment * (n - 1))),
        repr(float(scan.angle_increment)),
        repr(float(scan.range_max)),
        "0.0",  # accuracy: unknown
        str(remission_mode),
        str(n),
        _repr_floats(ranges),
        remissions,
        _repr_floats(laser_pose),
        _repr_floats(np.asarray(robot_pose, dtype=np.float64)),
        "0.0 0.0 0.0 0.0 0.0",  # tv rv forward_safety_dist side_safety_dist turn_axis
        t,
        host,
        t,
    ]
    return " ".join(fields)


def _odom_line(t: float, pose: NDArray[np.float64], host: str) -> str:
    ts = repr(float(t))
    return f"ODOM {_repr_floats(np.asarray(pose, dtype=np.float64))} 0.0 0.0 0.0 {ts} {host} {ts}"


def write_carmen(
    path: str | Path,
    frames_or_messages: Iterable[Frame | LaserScan | OdometryReading],
    *,
    laser_type: int = 0,
    host: str = "slam2d",
) -> Path:
    """Write frames, or scans and odometry readings, as a CARMEN log; return its path.

    Scans become ``ROBOTLASER1`` lines (they state their own angles and
    maximum range, so any laser round-trips) whose robot pose is the frame's
    odometry pose (for bare scans: the pose of an odometry reading with the
    same timestamp just before it, else zeros) and whose laser pose is the
    robot pose composed with the scan's mount. Odometry becomes ``ODOM``
    lines; a frame with odometry gets one with its scan's timestamp. No
    return is written as the scan's ``range_max`` (0 when it is infinite).
    A ``range_min`` other than 0 is stated by a ``PARAM
    laser_front_laser_min_range`` line (slam2d's own; other readers ignore it).
    Floats are written with their shortest exact representation, so reading
    the file back gives the same bits. The file is gzipped when its name ends
    in ``.gz`` and appears only when complete.
    """
    path = Path(path)
    if not host or any(c.isspace() for c in host):
        raise ValueError(f"host: {host!r} must be a non-empty word without spaces")
    with atomic_path(path) as tmp, open(tmp, "wb") as raw:
        binary: io.BufferedIOBase
        if path.name.endswith(".gz"):
            # No file name or time in the gzip header: the same input gives the same bytes.
            binary = gzip.GzipFile(filename="", mode="wb", fileobj=raw, compresslevel=6, mtime=0)
        else:
            binary = raw
        with io.TextIOWrapper(binary, encoding="utf-8", newline="\n") as out:
            out.write(f"# CARMEN log written by slam2d {slam2d.__version__}\n")
            out.write("# message formats: ODOM x y theta tv rv accel timestamp host logger_timestamp\n")
            out.write(
                "#   ROBOTLASER1 laser_type start_angle field_of_view angular_resolution maximum_range "
                "accuracy remission_mode num_readings r1..rn num_remissions rem1..remk laser_x laser_y "
                "laser_theta robot_x robot_y robot_theta tv rv forward_safety_dist side_safety_dist "
                "turn_axis timestamp host logger_timestamp\n"
            )
            range_min = 0.0
            last_odom: OdometryReading | None = None
            for item in frames_or_messages:
                if isinstance(item, Frame):
                    scan = item.scan
                    if item.odometry is not None:
                        robot_pose = np.asarray(item.odometry, dtype=np.float64)
                        out.write(_odom_line(scan.timestamp, robot_pose, host) + "\n")
                    else:
                        robot_pose = np.zeros(3)
                elif isinstance(item, LaserScan):
                    scan = item
                    if last_odom is not None and last_odom.timestamp == scan.timestamp:
                        robot_pose = np.asarray(last_odom.pose, dtype=np.float64)
                    else:
                        robot_pose = np.zeros(3)
                elif isinstance(item, OdometryReading):
                    out.write(_odom_line(item.timestamp, item.pose, host) + "\n")
                    last_odom = item
                    continue
                else:
                    raise TypeError(f"cannot write {type(item).__name__} to a CARMEN log")
                if scan.range_min != range_min:
                    range_min = scan.range_min
                    t = repr(float(scan.timestamp))
                    out.write(f"PARAM {_MIN_RANGE_PARAM} {range_min!r} {host} {t} {t}\n")
                out.write(_robotlaser_line(scan, robot_pose, laser_type, host) + "\n")
        if binary is not raw:
            binary.close()
    return path
