import numpy as np
import pytest

from featmap.geo import GeoFrame, latlon_to_mercator


def test_local_to_wgs84_and_back_within_a_millimetre():
    frame = GeoFrame(49.0123, 8.4321)
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-3000, 3000, 100), rng.uniform(-3000, 3000, 100)
    lat, lon = frame.to_wgs84(x, y)
    x2, y2 = frame.to_local(lat, lon)
    assert np.abs(x2 - x).max() < 1e-3 and np.abs(y2 - y).max() < 1e-3


def test_matches_pykitti_projection():
    from pykitti.utils import OxtsPacket, pose_from_oxts_packet

    lat0, lon0 = 49.015, 8.434
    scale = np.cos(np.deg2rad(lat0))
    vals = [0.0] * 30
    vals[0], vals[1] = lat0 + 0.001, lon0 - 0.002
    _, t = pose_from_oxts_packet(OxtsPacket(*vals), scale)
    _, t0 = pose_from_oxts_packet(OxtsPacket(*([lat0, lon0] + [0.0] * 28)), scale)
    x, y = GeoFrame(lat0, lon0).to_local(lat0 + 0.001, lon0 - 0.002)
    assert x == pytest.approx(t[0] - t0[0], abs=1e-6) and y == pytest.approx(t[1] - t0[1], abs=1e-6)
    mx, _ = latlon_to_mercator(lat0, lon0, scale)
    assert mx == pytest.approx(t0[0])
