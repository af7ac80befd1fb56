"""The embedded default drive: the ``residential`` world, simulated on first use into ``data/sim``."""

from __future__ import annotations

from pathlib import Path

DEFAULT_WORLD = "residential"
DEFAULT_SIM_ROOT = Path("data/sim")


def ensure_default_drive(sim_root: Path = DEFAULT_SIM_ROOT, world_name: str = DEFAULT_WORLD, echo=print) -> tuple[Path, str]:
    """Return (KITTI raw root, drive name) of the default drive, simulating it (with a progress bar) if missing."""
    from featmap.progress import track
    from featmap.simulation.sensors import SENSORS
    from featmap.simulation.simulate import SIM_DATE, simulate_drive
    from featmap.simulation.worlds import load_world

    data_dir = Path(sim_root) / world_name
    drive = f"{SIM_DATE}_drive_0001"
    if not (data_dir / SIM_DATE / f"{drive}_sync" / "truth" / "simulation.json").exists():
        echo(f"first run: simulating the default drive ({world_name}) into {data_dir} (reused afterwards)")
        world = load_world(world_name)
        simulate_drive(world, data_dir, SENSORS["hdl64"], progress=lambda it, n: track(it, n, f"simulating {world_name}"))
    return data_dir, drive
