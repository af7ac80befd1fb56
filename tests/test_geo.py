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


def test_reproject_moves_points_between_two_drives_frames():
    from featmap.geo import reproject, reproject_segments

    a = GeoFrame(49.0100, 8.4200)
    lat, lon = a.to_wgs84(np.array([250.0]), np.array([-120.0]))
    b = GeoFrame(float(lat[0]), float(lon[0]))         # b's origin is at (250, -120) of a
    pts = np.array([[250.0, -120.0], [260.0, -100.0], [0.0, 0.0]])
    moved = reproject(pts, a, b)
    assert np.abs(moved[0]).max() < 1e-6
    # lengths change only by the ratio of the two frames' Mercator scales, cos(lat_b) / cos(lat_a)
    ratio = np.linalg.norm(moved[1] - moved[2]) / np.linalg.norm(pts[1] - pts[2])
    assert ratio == pytest.approx(b.scale / a.scale, rel=1e-7) and abs(ratio - 1) < 1e-4
    assert np.abs(reproject(moved, b, a) - pts).max() < 1e-6
    segs = np.array([[250.0, -120.0, 0.0, 0.0]])
    assert np.allclose(reproject_segments(segs, a, b), np.r_[moved[0], moved[2]][None])
    assert np.array_equal(reproject(pts, a, GeoFrame(49.0100, 8.4200, 300.0)), pts)   # same origin: unchanged


def test_open_ring_counts_each_vertex_once_and_drops_the_closing_one():
    from featmap.geo import open_ring

    assert open_ring([[0, 0], [1, 0], [1, 0], [1, 1], [0, 0]]) == [(0, 0), (1, 0), (1, 1)]
    assert open_ring([(0, 0), (1, 0), (1, 1)]) == [(0, 0), (1, 0), (1, 1)]      # already open
    assert open_ring([(2, 2), (2, 2)]) == [(2, 2)] and open_ring([]) == []
