"""The KITTI raw file formats, as ``read_x`` / ``write_x`` pairs (the simulator writes, the loader checks).

Layout of a drive::

    ROOT/DATE/calib_imu_to_velo.txt, calib_velo_to_cam.txt, calib_cam_to_cam.txt
    ROOT/DATE/DATE_drive_NNNN_sync/velodyne_points/data/%010d.bin   (N x 4 float32: x y z reflectance)
    ROOT/DATE/DATE_drive_NNNN_sync/velodyne_points/timestamps.txt
    ROOT/DATE/DATE_drive_NNNN_sync/oxts/data/%010d.txt              (30 space-separated fields)
    ROOT/DATE/DATE_drive_NNNN_sync/oxts/timestamps.txt

Every reader raises a one-line :class:`DatasetError` naming the file.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np

from featmap.errors import DatasetError
from featmap.io.atomic import atomic_write_bytes, atomic_write_text

OXTS_FIELDS = ("lat", "lon", "alt", "roll", "pitch", "yaw", "vn", "ve", "vf", "vl", "vu", "ax", "ay", "az",
               "af", "al", "au", "wx", "wy", "wz", "wf", "wl", "wu", "pos_accuracy", "vel_accuracy",
               "navstat", "numsats", "posmode", "velmode", "orimode")
MAX_RETURN_M = 10_000.0
"""No LiDAR return lies farther than this from its sensor (metres): a file with such points is not a scan."""
CALIB_FILES = ("calib_imu_to_velo.txt", "calib_velo_to_cam.txt", "calib_cam_to_cam.txt")
TIMESTAMP_FORMAT = "%Y-%m-%d %H:%M:%S.%f"


def _read_text(path: Path, what: str) -> str:
    """The text of a KITTI text file; a one-line DatasetError naming the file when it is missing or unreadable."""
    try:
        return path.read_text()
    except FileNotFoundError:
        raise DatasetError(f"{path}: {what} not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: cannot read {what} ({exc})") from None


# --- velodyne scans ---------------------------------------------------------------------------------

def write_velo_bin(path: str | Path, points: np.ndarray) -> Path:
    """Write (N, 4) x y z reflectance (velodyne frame) as little-endian float32."""
    pts = np.ascontiguousarray(np.asarray(points, dtype="<f4").reshape(-1, 4))
    return atomic_write_bytes(path, pts.tobytes())


def read_velo_bin(path: str | Path, allow_empty: bool = False) -> np.ndarray:
    """Read a ``.bin`` scan as (N, 4) float32; truncated files, NaNs and (by default) empty scans fail."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise DatasetError(f"{path}: scan file not found") from None
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read scan ({exc.strerror})") from None
    if len(raw) % 16:
        raise DatasetError(f"{path}: truncated scan ({len(raw)} bytes is not a multiple of 16 = 4 float32 per point)")
    points = np.frombuffer(raw, dtype="<f4").reshape(-1, 4)
    if len(points) == 0 and not allow_empty:
        raise DatasetError(f"{path}: empty scan (0 points)")
    if not np.isfinite(points).all():
        bad = int((~np.isfinite(points).all(axis=1)).sum())
        raise DatasetError(f"{path}: {bad} point(s) with NaN or inf coordinates")
    # (Bounds of the whole contiguous array first, reflectance included: 0.06 ms instead of 5 ms a scan
    # for the per-row test, which runs only when some value is that large.)
    if len(points) and max(float(points.max()), -float(points.min())) > MAX_RETURN_M:
        far = np.abs(points[:, :3]).max(axis=1) > MAX_RETURN_M
        if far.any():
            raise DatasetError(f"{path}: {int(far.sum())} point(s) farther than {MAX_RETURN_M:.0f} m from the sensor: "
                               "not a velodyne scan (x, y, z, reflectance as float32)?")
    return points


# --- OXTS -------------------------------------------------------------------------------------------

def format_oxts_packet(values: dict[str, float]) -> str:
    """One OXTS line: the 30 fields of ``OXTS_FIELDS`` in order (the last five as integers)."""
    parts = []
    for name in OXTS_FIELDS[:-5]:
        parts.append(repr(float(values.get(name, 0.0))))
    parts += [str(int(values.get(name, 0))) for name in OXTS_FIELDS[-5:]]
    return " ".join(parts) + "\n"


def write_oxts_packet(path: str | Path, values: dict[str, float]) -> Path:
    return atomic_write_text(path, format_oxts_packet(values))


def read_oxts_packet(path: str | Path) -> dict[str, float]:
    """Parse one OXTS file (one line of 30 numbers) into a dict keyed by ``OXTS_FIELDS``."""
    path = Path(path)
    fields = _read_text(path, "OXTS file").split()
    if len(fields) != len(OXTS_FIELDS):
        raise DatasetError(f"{path}: OXTS packet has {len(fields)} fields, expected {len(OXTS_FIELDS)} "
                           "(see oxts/dataformat.txt)")
    try:
        values = [float(f) for f in fields]
    except ValueError:
        raise DatasetError(f"{path}: OXTS packet has a non-numeric field") from None
    if not np.isfinite(values).all():
        raise DatasetError(f"{path}: OXTS packet has NaN or inf values")
    lat, lon = values[0], values[1]
    if not (-90.0 < lat < 90.0 and -180.0 <= lon <= 180.0):
        raise DatasetError(f"{path}: OXTS latitude {lat:g} / longitude {lon:g} out of range "
                           "(-90 < lat < 90, -180 <= lon <= 180 degrees)")
    roll, pitch, yaw = values[3:6]
    if max(abs(roll), abs(pitch), abs(yaw)) > 2 * np.pi:
        raise DatasetError(f"{path}: OXTS roll {roll:g} / pitch {pitch:g} / yaw {yaw:g} beyond a full turn "
                           "(radians, -pi..pi)")
    return dict(zip(OXTS_FIELDS, values))


# --- timestamps -------------------------------------------------------------------------------------

def write_timestamps(path: str | Path, seconds: np.ndarray, start: dt.datetime) -> Path:
    """KITTI timestamps (nine fractional digits, one per line) at ``start + seconds`` (start: whole seconds)."""
    start = start.replace(microsecond=0)
    lines = []
    for s in np.asarray(seconds, float):
        whole, ns = divmod(int(round(float(s) * 1e9)), 1_000_000_000)
        stamp = start + dt.timedelta(seconds=whole)
        lines.append(stamp.strftime("%Y-%m-%d %H:%M:%S") + f".{ns:09d}\n")
    return atomic_write_text(path, "".join(lines))


def read_timestamps(path: str | Path) -> np.ndarray:
    """Seconds (float64) since the first timestamp of a KITTI ``timestamps.txt``."""
    path = Path(path)
    lines = [line.strip() for line in _read_text(path, "timestamps file").splitlines() if line.strip()]
    stamps = []
    for n, line in enumerate(lines, start=1):
        try:
            date, frac = line.rsplit(".", 1)
            if not (frac.isascii() and frac.isdigit()):     # float() would take "1e5", "1_5" or other digits
                raise ValueError(frac)
            base = dt.datetime.strptime(date, "%Y-%m-%d %H:%M:%S")
            stamps.append(base.timestamp() + float("0." + frac))
        except ValueError:
            raise DatasetError(f"{path}:{n}: not a KITTI timestamp: {line!r}") from None
    arr = np.asarray(stamps)
    return arr - arr[0] if len(arr) else arr


# --- calibration ------------------------------------------------------------------------------------

def write_calib_file(path: str | Path, entries: dict[str, np.ndarray | str]) -> Path:
    """Write ``key: v1 v2 ...`` lines (strings are written as they are, e.g. calib_time)."""
    lines = []
    for key, value in entries.items():
        if isinstance(value, str):
            lines.append(f"{key}: {value}")
        else:
            lines.append(f"{key}: " + " ".join(f"{float(v):.6e}" for v in np.asarray(value).reshape(-1)))
    return atomic_write_text(path, "\n".join(lines) + "\n")


def read_calib_file(path: str | Path) -> dict[str, np.ndarray]:
    """Parse a KITTI calibration file into arrays (non-numeric entries such as calib_time are skipped)."""
    path = Path(path)
    text = _read_text(path, "calibration file")
    data = {}
    for n, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        if ":" not in line:
            raise DatasetError(f"{path}:{n}: expected 'key: values', got {line.strip()[:40]!r}")
        key, value = line.split(":", 1)
        try:
            data[key.strip()] = np.array([float(x) for x in value.split()])
        except ValueError:
            continue
    return data


def read_rigid_calib(path: str | Path) -> np.ndarray:
    """A 4x4 transform from a calibration file with ``R`` (9 values) and ``T`` (3 values)."""
    data = read_calib_file(path)
    if "R" not in data or "T" not in data or data["R"].size != 9 or data["T"].size != 3:
        raise DatasetError(f"{path}: expected 'R:' with 9 values and 'T:' with 3 values")
    R, T = data["R"].reshape(3, 3), data["T"]
    if not (np.isfinite(R).all() and np.isfinite(T).all()):
        raise DatasetError(f"{path}: 'R' and 'T' must be finite numbers (found NaN or inf)")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-2 or abs(np.linalg.det(R) - 1.0) > 1e-2:
        raise DatasetError(f"{path}: 'R' is not a rotation matrix (R R^T != I or det(R) != 1)")
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = T
    return out


def drive_paths(root: str | Path, date: str, drive_id: str) -> tuple[Path, Path]:
    """(calibration folder ``ROOT/DATE``, drive folder ``ROOT/DATE/DATE_drive_ID_sync``)."""
    calib_dir = Path(root) / date
    return calib_dir, calib_dir / f"{date}_drive_{drive_id}_sync"
