"""LiDAR sensor presets: beam elevations, azimuth step, range, mounting height."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class SensorPreset:
    """A spinning multi-beam LiDAR.

    Attributes:
        name: preset name.
        elevations_deg: (B,) beam elevation angles, degrees, positive up (velodyne frame).
        azimuth_step_deg: horizontal angle between two firings of one beam.
        max_range_m: returns beyond this are lost.
        min_range_m: returns closer than this are lost (the sensor's blind zone).
        height_m: mounting height of the velodyne origin above flat ground.
        rate_hz: scans per second.
    """

    name: str
    elevations_deg: tuple[float, ...]
    azimuth_step_deg: float
    max_range_m: float
    min_range_m: float
    height_m: float
    rate_hz: float = 10.0

    @property
    def n_beams(self) -> int:
        return len(self.elevations_deg)

    @property
    def n_azimuths(self) -> int:
        return int(round(360.0 / self.azimuth_step_deg))

    def ray_directions(self) -> np.ndarray:
        """(B * A, 3) unit ray directions in the velodyne frame (x forward, y left, z up), beam-major."""
        elev = np.deg2rad(np.asarray(self.elevations_deg))[:, None]
        azim = np.deg2rad(np.arange(self.n_azimuths) * self.azimuth_step_deg)[None, :]
        d = np.stack(np.broadcast_arrays(np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim),
                                         np.sin(elev)), axis=-1)
        return d.reshape(-1, 3)

    def with_azimuth_step(self, azimuth_step_deg: float) -> "SensorPreset":
        """The same sensor firing every ``azimuth_step_deg`` (e.g. a different spin rate)."""
        if not (0.01 <= azimuth_step_deg <= 5.0):
            raise ValueError(f"azimuth step {azimuth_step_deg} deg: expected 0.01-5")
        return replace(self, azimuth_step_deg=float(azimuth_step_deg))


def _hdl64_elevations() -> tuple[float, ...]:
    # The HDL-64E has two laser blocks: the upper 32 beams from +2.0 to -8.33 deg in 1/3 deg steps,
    # the lower 32 from -8.83 to -24.8 deg in ~1/2 deg steps.
    upper = np.linspace(2.0, -8.33, 32)
    lower = np.linspace(-8.83, -24.8, 32)
    return tuple(float(v) for v in np.concatenate([upper, lower]))


def _vls128_elevations() -> tuple[float, ...]:
    # Velodyne VLS-128 (Alpha Prime): +15 to -25 deg, densest (~0.11 deg) around the horizon.
    # Approximated as 16 beams from +15 to +3 deg, 64 from +2.9 to -4.0 deg (0.11 deg apart) and
    # 48 from -4.4 to -25 deg.
    upper = np.linspace(15.0, 3.0, 16)
    centre = np.linspace(2.9, -4.0, 64)
    lower = np.linspace(-4.4, -25.0, 48)
    return tuple(float(v) for v in np.concatenate([upper, centre, lower]))


SENSORS: dict[str, SensorPreset] = {
    # KITTI's Velodyne HDL-64E: 64 beams, +2.0 to -24.8 deg, 120 m, 1.73 m above the ground, 10 Hz.
    "hdl64": SensorPreset("hdl64", _hdl64_elevations(), azimuth_step_deg=0.17, max_range_m=120.0,
                          min_range_m=0.9, height_m=1.73),
    # The paper's PreScan sensor: 32 beams, 150 m range (elevations as a VLP-32-like +15 to -25 deg fan).
    "vlp32": SensorPreset("vlp32", tuple(float(v) for v in np.linspace(15.0, -25.0, 32)), azimuth_step_deg=0.2,
                          max_range_m=150.0, min_range_m=1.0, height_m=1.73),
    # Velodyne VLS-128: 128 beams, +15 to -25 deg (dense near the horizon), 0.2 deg at 10 Hz, 245 m.
    "vls128": SensorPreset("vls128", _vls128_elevations(), azimuth_step_deg=0.2, max_range_m=245.0,
                           min_range_m=1.0, height_m=1.73),
    # Velodyne VLP-16 (Puck): 16 beams, +15 to -15 deg in 2 deg steps, 0.2 deg at 10 Hz, 100 m.
    "vlp16": SensorPreset("vlp16", tuple(float(v) for v in np.arange(15.0, -15.5, -2.0)), azimuth_step_deg=0.2,
                          max_range_m=100.0, min_range_m=0.5, height_m=1.73),
}
