"""Simulated drives as a scan source: a world name (or world file), simulated on first use.

``featmap run`` without ``--drive`` opens the embedded default, the ``residential`` world, simulated into
``data/sim/residential`` with the HDL-64E preset (about 20 s) and reused afterwards. The drive is a KITTI
raw drive with a ``truth/`` folder beside its scans, read through :class:`KittiRawDataset`.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from featmap.datasets.kitti_raw import KittiRawDataset
from featmap.io.atomic import atomic_write_text
from featmap.reporting import NullReporter, Reporter, track

DEFAULT_WORLD = "residential"
DEFAULT_SIM_ROOT = Path("data/sim")
SIM_DRIVE_ID = "0001"
STAMP_FILE = "world.json"
"""Beside a simulated drive: the fingerprint of what it was simulated from."""


def ensure_simulated_drive(world_name: str = DEFAULT_WORLD, sim_root: str | Path = DEFAULT_SIM_ROOT,
                           reporter: Reporter = NullReporter(), sensor_name: str = "hdl64",
                           pose_noise: tuple[float, float] = (0.0, 0.0), folder: str | None = None) -> tuple[Path, str]:
    """Return (KITTI raw root, drive name) of the simulated drive of ``world_name``, simulating it if missing.

    ``world_name`` is a built-in world or a world file; its drive lives in ``sim_root/<world stem>`` (or
    ``sim_root/<folder>``) with a stamp (``world.json``) of what it was simulated from: the world's content,
    the sensor (``sensor_name``, a key of :data:`~featmap.simulation.sensors.SENSORS`), the OXTS pose noise
    (position std in metres, yaw std in degrees; see :func:`~featmap.simulation.simulate.simulate_drive`)
    and the simulator's source. A drive whose stamp differs or is missing (the world file was edited,
    another file of the same name was simulated there, the simulator changed, or an older featmap wrote it)
    is simulated again; the same world read from another path (a moved checkout) is not.
    """
    from featmap.simulation.sensors import SENSORS
    from featmap.simulation.simulate import SIM_DATE, simulate_drive, simulation_fingerprint
    from featmap.simulation.worlds import load_world

    stem = folder or Path(world_name).stem
    data_dir = Path(sim_root) / stem
    drive = f"{SIM_DATE}_drive_{SIM_DRIVE_ID}"
    world = load_world(world_name)
    sensor = SENSORS[sensor_name]
    # (What the world is, not where its file lies: a moved checkout or a second copy of the same world
    # reuses the drive. Exact poses add nothing to the spec, so the stamps of such drives stay as they were.)
    spec = {"world": world.model_dump(mode="json", exclude={"source"}), "sensor": sensor.__dict__,
            "drive_id": SIM_DRIVE_ID}
    if any(pose_noise):
        spec["pose_noise"] = [float(v) for v in pose_noise]
    fingerprint = simulation_fingerprint(spec)
    stamp = data_dir / STAMP_FILE
    done = (data_dir / SIM_DATE / f"{drive}_sync" / "truth" / "simulation.json").exists()
    stamped = _stamped(stamp)
    if done and stamped == fingerprint:
        return data_dir, drive
    if done:
        why = "the world, its sensor or pose noise, or the simulator changed since" if stamped else "nothing says what made"
        reporter.info(f"{world_name}: {why} {data_dir}; simulating it again")
        shutil.rmtree(data_dir / SIM_DATE)
    else:
        reporter.info(f"first run: simulating the {stem} drive into {data_dir} (reused afterwards)")
    simulate_drive(world, data_dir, sensor, drive_id=SIM_DRIVE_ID, pose_noise=pose_noise,
                   progress=lambda it, n: track(reporter, it, n, f"simulating {stem}"))
    atomic_write_text(stamp, json.dumps({"world": str(world_name), "fingerprint": fingerprint}) + "\n")
    return data_dir, drive


def _stamped(stamp: Path) -> str | None:
    """The fingerprint in a drive's stamp file (None when missing or unreadable)."""
    try:
        return json.loads(stamp.read_text()).get("fingerprint")
    except (OSError, ValueError, AttributeError):
        return None


def open_world(location: str, frames: str | None = None, skip_bad_scans: bool = False,
               reporter: Reporter = NullReporter(), sim_root: str | Path = DEFAULT_SIM_ROOT) -> KittiRawDataset:
    """The simulated drive of a world (the registry's opener); ``location`` is a world name or file, and
    the drive lives in (or is simulated into) ``sim_root/<world stem>``."""
    data_dir, drive = ensure_simulated_drive(location or DEFAULT_WORLD, sim_root, reporter=reporter)
    source = KittiRawDataset(data_dir, drive, frames, skip_bad_scans)
    source.name = Path(location or DEFAULT_WORLD).stem
    return source
