"""Reader of CARMEN 2D laser logs (``.log``, ``.clf``, optionally gzip- or bz2-compressed).

One log line is one message; the first word is its type. What is read:

``FLASER n r_0 .. r_{n-1} x y theta odom_x odom_y odom_theta timestamp [host logger_timestamp]``
    a front-laser scan. ``x y theta`` is the laser pose (in SLAM-corrected logs the corrected one),
    ``odom_*`` the robot's odometry pose at that time. Beam ``k`` points at
    ``-pi/2 + k * increment`` in the laser frame (x forward, y left, angles counter-clockwise), with
    CARMEN's own rule for the increment (``carmen_laser_guess_angle_increment``: 1 deg for 180 or
    181 beams, 0.5 deg for 360 or 361, 0.25 deg for 400 or 401, otherwise ``pi / (n - 1)``).
``ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode n r_0 .. r_{n-1}``
``m rem_0 .. rem_{m-1} laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv fsd ssd turn_axis timestamp [host logger_timestamp]``
    a laser scan with its own geometry: beam ``k`` at ``start_angle + k * resolution``. ROBOTLASER1
    carries no separate odometry; its robot pose is reported as the odometry pose.
``ODOM x y theta tv rv accel timestamp [host logger_timestamp]``
    the robot's odometry: raw wheel odometry in the raw ``.clf`` logs; in the Radish ``*-corrected`` logs
    the corrected path, with a copy of each scan's pose (timestamp 0) after it.

Everything else (``PARAM``, ``NEFF``, ``RLASER``, ``SYNC``, comments starting with ``#``, ...) is
skipped and counted; ``NEFF`` records (a particle filter's effective sample size, one per scan in the
``*-corrected`` logs) mark a log whose scan poses are a SLAM result (:attr:`CarmenLog.slam_poses`).

A max-range reading means "no return": FLASER has no max-range field, so it is taken as the largest
range in the log when that value repeats (the Radish logs use 81.83, 50 and 51.1 m, hundreds of times
each), and every reading within ``NO_RETURN_MARGIN_M`` of it is a no-return; ROBOTLASER1 gives its max
range explicitly.

Also :func:`read_relations` reads the ``.relations`` files of the Freiburg SLAM benchmark
(``t1 t2 x y z roll pitch yaw``: the pose at ``t2`` in the frame at ``t1``).
"""

from __future__ import annotations

import bz2
import gzip
import math
import re
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from featmap.errors import InputFileError
from featmap.geometry import MAX_COORDINATE_M

NO_RETURN_MARGIN_M = 0.1
"""Readings within this of a FLASER log's maximum range are no-returns (51.05 and 51.1 m in fhw)."""
MAX_RANGE_M = 10_000.0
"""No 2D laser return lies farther than this (metres): a longer reading that is not a no-return is a corrupt record."""

_MESSAGE_TYPE = re.compile(r"[A-Z][A-Z0-9_]*\Z")
_FLASER = "FLASER"
_ROBOTLASER = "ROBOTLASER1"
_ODOM = "ODOM"
_NEFF = "NEFF"


@dataclass(frozen=True)
class CarmenLog:
    """The laser scans and odometry of one CARMEN log, in the log's own metric frame.

    ``S`` scans (FLASER and ROBOTLASER1 records in file order), ``n`` beams (the largest beam count
    of any scan; shorter scans are padded with ``valid == False`` and NaN), ``K`` ODOM records.

    Attributes:
        path: the file read.
        ranges: (S, n) range per beam, metres, as written in the log (no-returns included).
        angles: (S, n) beam angle in the laser frame, radians (x forward, y left, counter-clockwise).
        valid: (S, n) a real return: finite, > 0 and not a max-range reading.
        max_range: (S,) the range of a no-return for each scan, metres.
        pose: (S, 3) ``x, y, theta`` of the laser in the world frame (the first pose of the record:
            the SLAM-corrected one in Radish's ``*-corrected`` logs).
        odometry: (S, 3) the odometry pose of each record (the second pose of FLASER, the robot pose
            of ROBOTLASER1).
        timestamp: (S,) the record's ``ipc_timestamp``, seconds.
        logger_timestamp: (S,) the logger's timestamp, seconds (NaN where absent).
        line: (S,) 1-based line number of each record.
        message: (S,) ``"FLASER"`` or ``"ROBOTLASER1"``.
        odom_pose: (K, 3) ``x, y, theta`` of every ODOM record.
        odom_velocity: (K, 2) ``tv, rv`` (m/s, rad/s) of every ODOM record.
        odom_timestamp: (K,) their ``ipc_timestamp``.
        odom_line: (K,) their line numbers.
        skipped: ``((message type, count), ...)`` of the records that were not read.
    """

    path: str
    ranges: np.ndarray
    angles: np.ndarray
    valid: np.ndarray
    max_range: np.ndarray
    pose: np.ndarray
    odometry: np.ndarray
    timestamp: np.ndarray
    logger_timestamp: np.ndarray
    line: np.ndarray
    message: np.ndarray
    odom_pose: np.ndarray
    odom_velocity: np.ndarray
    odom_timestamp: np.ndarray
    odom_line: np.ndarray
    skipped: tuple = ()

    def __len__(self) -> int:
        return len(self.ranges)

    @property
    def slam_poses(self) -> bool:
        """Whether the scans' poses are a SLAM result rather than the robot's odometry: the log carries
        ``NEFF`` records (the effective sample size of the particle filter that corrected it, one per scan
        in Radish's ``*-corrected`` logs), or it has ODOM records and every one of them is all zeros (the
        odometry was dropped, as :func:`flaser_log_text` writes by default). Raw logs carry real ODOM
        records and no NEFF."""
        if dict(self.skipped).get(_NEFF, 0) > 0:
            return True
        return len(self.odom_pose) > 0 and not np.any(self.odom_pose)

    def points(self, scan: int) -> np.ndarray:
        """(k, 2) valid returns of one scan in the laser frame, in beam order."""
        keep = self.valid[scan]
        r, a = self.ranges[scan, keep], self.angles[scan, keep]
        return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)

    def world_points(self, scans=None) -> tuple[np.ndarray, np.ndarray]:
        """All valid returns in the world frame with the first (corrected) pose.

        Returns (points (P, 2), scan index of each point (P,)), scans in order, beams in beam order.
        """
        idx = np.arange(len(self)) if scans is None else np.asarray(scans, dtype=np.int64)
        keep = self.valid[idx]
        heading = self.pose[idx, 2:3] + self.angles[idx]
        r = self.ranges[idx]
        x = self.pose[idx, 0:1] + r * np.cos(heading)
        y = self.pose[idx, 1:2] + r * np.sin(heading)
        scan = np.broadcast_to(idx[:, None], keep.shape)
        return np.stack([x[keep], y[keep]], axis=1), scan[keep]


def carmen_beam_angles(n_beams: int) -> np.ndarray:
    """(n,) FLASER beam angles, radians: ``-pi/2 + k * increment`` with CARMEN's increment rule."""
    if n_beams in (180, 181):
        step = math.pi / 180.0
    elif n_beams in (360, 361):
        step = math.pi / 360.0
    elif n_beams in (400, 401):
        step = math.pi / 720.0
    else:
        step = math.pi / max(n_beams - 1, 1)
    return -0.5 * math.pi + step * np.arange(n_beams)


def flaser_log_text(ranges: np.ndarray, poses: np.ndarray, stamps: np.ndarray, odometry: np.ndarray | None = None,
                    comment: str = "") -> str:
    """A CARMEN log (what :func:`read_carmen` reads) of FLASER records, each followed by an ODOM record.

    Args:
        ranges: (S, n) metres per beam (beam ``k`` at :func:`carmen_beam_angles`); a no-return is the
            largest value, written for every beam that hit nothing.
        poses: (S, 3) ``x, y, theta`` of the laser in the log's frame (metres, radians).
        stamps: (S,) seconds.
        odometry: (S, 3) the odometry pose of each scan (FLASER's second pose and the ODOM record), or None
            for zeros (as in the Radish "corrected" logs).
        comment: written as ``#`` lines at the top.
    """
    poses = np.asarray(poses, float)
    odometry = np.zeros_like(poses) if odometry is None else np.asarray(odometry, float)
    lines = [f"# {line}" for line in comment.splitlines()]
    for r, pose, odom, t in zip(np.asarray(ranges, float), poses, odometry, np.asarray(stamps, float)):
        laser, wheels = " ".join(f"{v:.6f}" for v in pose), " ".join(f"{v:.6f}" for v in odom)
        lines.append(f"FLASER {len(r)} {' '.join(f'{v:.3f}' for v in r)} {laser} {wheels} {t:.3f} sim {t:.3f}")
        lines.append(f"ODOM {wheels} 0 0 0 {t:.3f} sim {t:.3f}")
    return "\n".join(lines) + "\n"


def _open_text(path: Path):
    """Open ``path`` for text reading, decompressing gzip or bz2 by their magic bytes."""
    with open(path, "rb") as fh:
        magic = fh.read(3)
    if magic[:2] == b"\x1f\x8b":
        return gzip.open(path, "rt", encoding="latin-1", newline=None), "gzip"
    if magic == b"BZh":
        return bz2.open(path, "rt", encoding="latin-1", newline=None), "bz2"
    return open(path, "rt", encoding="latin-1", newline=None), None


def _numbers(path, lineno: int, tokens: list[str], what: str) -> np.ndarray:
    try:
        values = np.array(tokens, dtype=np.float64)
    except ValueError:
        bad = next(t for t in tokens if not _is_number(t))
        raise InputFileError(path, f"{what}: '{bad[:20]}' is not a number", lineno) from None
    if not np.all(np.isfinite(values)):
        raise InputFileError(path, f"{what}: NaN or infinite value", lineno)
    return values


def _check_positions(path, xy: np.ndarray, lines: np.ndarray, messages: np.ndarray) -> None:
    """Pose coordinates (metres) beyond ``MAX_COORDINATE_M`` fail (the geometry would overflow), naming the
    first such record in the file: ``xy`` (K, M) coordinates of K records, ``lines`` (K,) their line
    numbers, ``messages`` (K,) their message types."""
    far = np.flatnonzero(np.abs(xy).max(axis=1, initial=0.0) > MAX_COORDINATE_M) if len(xy) else []
    if len(far):
        k = int(far[np.argmin(lines[far])])
        raise InputFileError(path, f"{messages[k]}: pose coordinate {np.abs(xy[k]).max():.3g} m is beyond "
                                   f"{MAX_COORDINATE_M:g} m (poses are metres in the log's frame)", int(lines[k]))


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _count(path, lineno: int, token: str, what: str) -> int:
    try:
        value = int(token)
    except ValueError:
        raise InputFileError(path, f"{what}: beam count '{token[:20]}' is not an integer", lineno) from None
    if value <= 0:
        raise InputFileError(path, f"{what}: beam count {value} must be positive", lineno)
    return value


def _check_not_too_many(path, lineno: int, tokens: list[str], need: int, n: int, what: str) -> None:
    """A record may end with ``host logger_timestamp`` after its ``need`` tokens, nothing more: more values
    mean its beam count is wrong (the ranges would be read as poses and timestamps)."""
    if len(tokens) > need + 2:
        raise InputFileError(path, f"{what} declares {n} beams but has {len(tokens) - 1} values after the type "
                                   f"(expected {need - 1}, or {need + 1} with host and logger timestamp): "
                                   "is its beam count wrong?", lineno)


def _parse_flaser(path, lineno: int, tokens: list[str]) -> dict:
    if len(tokens) < 2:
        raise InputFileError(path, "FLASER without a beam count", lineno)
    n = _count(path, lineno, tokens[1], "FLASER")
    need = 2 + n + 7                       # ranges, two poses, timestamp
    if len(tokens) < need:
        raise InputFileError(path, f"FLASER with {n} beams needs at least {need - 1} values after the type, "
                                   f"got {len(tokens) - 1}", lineno)
    _check_not_too_many(path, lineno, tokens, need, n, "FLASER")
    values = _numbers(path, lineno, tokens[2:need], "FLASER")
    logger = _optional_float(tokens, need + 1)
    return dict(ranges=values[:n], angles=carmen_beam_angles(n), max_range=None, pose=values[n:n + 3],
                odometry=values[n + 3:n + 6], timestamp=values[n + 6], logger_timestamp=logger,
                line=lineno, message=_FLASER)


def _parse_robotlaser(path, lineno: int, tokens: list[str]) -> dict:
    # type start fov resolution max_range accuracy remission_mode n ranges m remissions 6 poses 5 extras ts
    if len(tokens) < 9:
        raise InputFileError(path, f"ROBOTLASER1 needs at least 8 header values, got {len(tokens) - 1}", lineno)
    header = _numbers(path, lineno, tokens[1:8], "ROBOTLASER1")
    n = _count(path, lineno, tokens[8], "ROBOTLASER1")
    if len(tokens) < 9 + n + 1:
        raise InputFileError(path, f"ROBOTLASER1 with {n} beams has too few values ({len(tokens) - 1})", lineno)
    ranges = _numbers(path, lineno, tokens[9:9 + n], "ROBOTLASER1")
    try:
        m = int(tokens[9 + n])
    except ValueError:
        raise InputFileError(path, f"ROBOTLASER1: remission count '{tokens[9 + n][:20]}' is not an integer",
                             lineno) from None
    start = 10 + n + max(m, 0)
    need = start + 12                      # laser pose, robot pose, tv rv fsd ssd turn_axis, timestamp
    if m < 0 or len(tokens) < need:
        raise InputFileError(path, f"ROBOTLASER1 with {n} beams and {m} remissions has too few values "
                                   f"({len(tokens) - 1})", lineno)
    _check_not_too_many(path, lineno, tokens, need, n, "ROBOTLASER1")
    tail = _numbers(path, lineno, tokens[start:need], "ROBOTLASER1")
    if not (abs(header[1]) <= 2 * np.pi and abs(header[3]) <= 2 * np.pi):
        raise InputFileError(path, f"ROBOTLASER1: start angle {header[1]:g} and angular resolution {header[3]:g} "
                                   "must be radians within +-2 pi", lineno)
    angles = header[1] + header[3] * np.arange(n)
    return dict(ranges=ranges, angles=angles, max_range=float(header[4]), pose=tail[0:3], odometry=tail[3:6],
                timestamp=tail[11], logger_timestamp=_optional_float(tokens, need + 1), line=lineno,
                message=_ROBOTLASER)


def _parse_odom(path, lineno: int, tokens: list[str]) -> np.ndarray:
    if len(tokens) < 8:
        raise InputFileError(path, f"ODOM needs at least 7 values (x y theta tv rv accel timestamp), "
                                   f"got {len(tokens) - 1}", lineno)
    return _numbers(path, lineno, tokens[1:8], "ODOM")


def _optional_float(tokens: list[str], index: int) -> float:
    if index < len(tokens):
        try:
            return float(tokens[index])
        except ValueError:
            return math.nan
    return math.nan


def read_carmen(path: str | Path, max_range_m: float | None = None) -> CarmenLog:
    """Read the laser scans and odometry of a CARMEN log.

    Args:
        path: ``.log`` / ``.clf`` file, plain, gzip or bz2 (recognised by content, not name).
        max_range_m: range of a FLASER no-return (readings at or above it are no-returns); None =
            the largest FLASER range in the log if it occurs more than once (readings within
            ``NO_RETURN_MARGIN_M`` of it are no-returns), else none. ROBOTLASER1 records always
            use their own max-range field.
    Raises:
        InputFileError: one line naming the file and line: truncated or corrupt compressed data, a
            laser or ODOM record with too few or non-numeric values, a laser record with more values than
            its beam count allows, NaN or infinite values, a return farther than ``MAX_RANGE_M``, a line
            that is not a CARMEN message, or a log without any laser record.
    """
    path = Path(path)
    try:
        handle, kind = _open_text(path)
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    except IsADirectoryError:
        raise InputFileError(path, "is a directory, not a CARMEN log") from None
    except OSError as exc:
        raise InputFileError(path, f"cannot read ({exc.strerror})") from None

    scans: list[dict] = []
    odom: list[np.ndarray] = []
    odom_lines: list[int] = []
    skipped: dict[str, int] = {}
    lineno = 0
    with handle:
        try:
            for lineno, text in enumerate(handle, 1):
                tokens = text.split()
                if not tokens or tokens[0].startswith("#"):
                    continue
                head = tokens[0]
                if head == _FLASER:
                    scans.append(_parse_flaser(path, lineno, tokens))
                elif head == _ODOM:
                    odom.append(_parse_odom(path, lineno, tokens))
                    odom_lines.append(lineno)
                elif head == _ROBOTLASER:
                    scans.append(_parse_robotlaser(path, lineno, tokens))
                elif _MESSAGE_TYPE.match(head):
                    skipped[head] = skipped.get(head, 0) + 1
                else:
                    shown = head[:20].encode("unicode_escape").decode("ascii")   # control bytes as \x00, not raw
                    raise InputFileError(path, f"not a CARMEN log: line starts with '{shown}' "
                                               "instead of a message type such as FLASER", lineno)
        except (EOFError, zlib.error, gzip.BadGzipFile, OSError) as exc:
            what = f"truncated or corrupt {kind} data" if kind else f"cannot read ({exc})"
            raise InputFileError(path, f"{what} after line {lineno}", lineno + 1) from None
        except UnicodeDecodeError:  # pragma: no cover - latin-1 decodes every byte
            raise InputFileError(path, "not a text file", lineno + 1) from None
    if not scans:
        raise InputFileError(path, f"no FLASER or ROBOTLASER1 record in {lineno} lines: not a CARMEN laser log",
                             max(lineno, 1))
    return _assemble(path, scans, odom, odom_lines, skipped, max_range_m)


def _assemble(path: Path, scans: list[dict], odom: list[np.ndarray], odom_lines: list[int],
              skipped: dict[str, int], max_range_m: float | None) -> CarmenLog:
    n_beams = max(len(s["ranges"]) for s in scans)
    n_scans = len(scans)
    ranges = np.full((n_scans, n_beams), np.nan)
    angles = np.full((n_scans, n_beams), np.nan)
    for k, s in enumerate(scans):
        ranges[k, :len(s["ranges"])] = s["ranges"]
        angles[k, :len(s["angles"])] = s["angles"]
    flaser = np.array([s["max_range"] is None for s in scans])
    if max_range_m is None:
        flaser_max, threshold = _inferred_max_range(ranges[flaser])
    else:
        flaser_max = threshold = float(max_range_m)
    max_range = np.array([flaser_max if s["max_range"] is None else s["max_range"] for s in scans])
    limit = np.where(flaser, threshold, max_range)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(ranges) & (ranges > 0) & (ranges < limit[:, None])
    stack = lambda key: np.array([s[key] for s in scans], dtype=np.float64)  # noqa: E731
    odom_arr = np.array(odom, dtype=np.float64).reshape(-1, 7)
    pose, odometry = stack("pose").reshape(-1, 3), stack("odometry").reshape(-1, 3)
    line, message = np.array([s["line"] for s in scans], dtype=np.int64), np.array([s["message"] for s in scans])
    odom_line = np.array(odom_lines, dtype=np.int64)
    far = np.flatnonzero((valid & (ranges > MAX_RANGE_M)).any(axis=1))
    if len(far):
        k = int(far[0])
        raise InputFileError(path, f"{message[k]}: a range of {ranges[k][valid[k]].max():g} m is farther than any "
                                   f"laser reaches ({MAX_RANGE_M:g} m): a corrupt record?", int(line[k]))
    _check_positions(path, np.vstack([np.hstack([pose[:, :2], odometry[:, :2]]), np.tile(odom_arr[:, :2], 2)]),
                     np.r_[line, odom_line], np.r_[message, np.full(len(odom_line), "ODOM")])
    return CarmenLog(
        path=str(path), ranges=ranges, angles=angles, valid=valid, max_range=max_range,
        pose=pose, odometry=odometry, timestamp=stack("timestamp"), logger_timestamp=stack("logger_timestamp"),
        line=line, message=message,
        odom_pose=odom_arr[:, 0:3], odom_velocity=odom_arr[:, 3:5], odom_timestamp=odom_arr[:, 6],
        odom_line=odom_line, skipped=tuple(sorted(skipped.items())))


def _inferred_max_range(ranges: np.ndarray) -> tuple[float, float]:
    """(max range, no-return threshold) of FLASER ranges (F, n): the largest reading, if it repeats.

    A sensor writes its max-range value for every beam without a return, so it occurs many times
    (hundreds in the Radish logs); a largest reading that occurs once is a real return and the log
    has no recognisable no-return value (then (inf, inf)).
    """
    finite = ranges[np.isfinite(ranges)]
    if finite.size == 0:
        return math.inf, math.inf
    largest = float(finite.max())
    if np.count_nonzero(finite == largest) < 2:
        return math.inf, math.inf
    return largest, largest - NO_RETURN_MARGIN_M


@dataclass(frozen=True)
class PoseRelations:
    """Reference relative poses of the Freiburg SLAM benchmark (``*.relations``), R rows.

    Attributes:
        t1, t2: (R,) timestamps (the laser records' ``ipc_timestamp``).
        delta: (R, 3) ``x, y, yaw`` of the pose at ``t2`` in the robot frame at ``t1`` (m, m, rad).
    """

    t1: np.ndarray
    t2: np.ndarray
    delta: np.ndarray


def read_relations(path: str | Path) -> PoseRelations:
    """Read a ``.relations`` file: lines ``t1 t2 x y z roll pitch yaw`` (z, roll, pitch ignored)."""
    path = Path(path)
    rows = []
    try:
        with open(path, encoding="latin-1") as fh:
            for lineno, text in enumerate(fh, 1):
                tokens = text.split()
                if not tokens or tokens[0].startswith("#"):
                    continue
                if len(tokens) < 8:
                    raise InputFileError(path, f"expected 8 values (t1 t2 x y z roll pitch yaw), got {len(tokens)}",
                                         lineno)
                rows.append(_numbers(path, lineno, tokens[:8], "relation"))
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    if not rows:
        raise InputFileError(path, "no relations in the file")
    arr = np.array(rows)
    return PoseRelations(t1=arr[:, 0], t2=arr[:, 1], delta=arr[:, [2, 3, 7]])
