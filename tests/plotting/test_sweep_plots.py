"""Sweep plots take every value a grid may hold (null, true/false, names) and curves of shared keys."""

import matplotlib

matplotlib.use("Agg")

from featmap.plotting.sweep_plots import _curve_axis, curve, plot_sweep  # noqa: E402


def test_curve_axis_orders_numbers_and_places_other_values_as_categories():
    assert _curve_axis([3, 1.5, 3]) == ([1.5, 3], [1.5, 3], None)
    xs, positions, labels = _curve_axis([3.0, None, 0.5])
    assert xs == [None, 0.5, 3.0] and positions == [0, 1, 2] and labels == ["null", "0.5", "3.0"]
    assert _curve_axis([True, False])[2] == ["False", "True"]


def test_plot_sweep_with_null_values_and_a_shared_section_key(tmp_path):
    rows = []
    for method in ("proposed", "density"):
        for support in (None, 3.0):
            for gap in (0.0, 0.3):
                rows.append({"method": method, "fusion.proposed.min_support_length_m": support,
                             "fusion.refine.split_gap_m": gap, "count": 10 + (gap > 0) + (support is None),
                             "f1": 0.9, "count_ratio": 1.1})
    rows[0]["count"] = 20                                   # proposed, support null, gap 0
    keys = ["fusion.proposed.min_support_length_m", "fusion.refine.split_gap_m"]
    # a method's key: its own rows only; a shared section's key: every method's rows
    assert curve(rows, "fusion.proposed.min_support_length_m", "count") == ([0, 1], [16.0, 10.5], ["null", "3.0"])
    assert curve(rows, "fusion.refine.split_gap_m", "count") == ([0.0, 0.3], [12.75, 11.5], None)
    paths = plot_sweep(rows, keys, tmp_path, "f1")
    assert {p.name for p in paths} == {"curves.png", "pareto.png"}
    assert all(p.stat().st_size > 0 for p in paths)


def test_plots_that_fail_half_way_leave_the_earlier_plots_whole(tmp_path, monkeypatch):
    """A sweep stopped while plotting (an error, Ctrl-C) after it drew some plots: the folder keeps the
    earlier sweep's plots, byte for byte, none of the new ones, and no staging folder."""
    import pytest

    import featmap.plotting.sweep_plots as sweep_plots

    rows = [{"method": "proposed", "fusion.proposed.delta_deg": d, "fusion.proposed.gamma": g, "count": 10 + d,
             "f1": 0.5 + 0.1 * g} for d in (1.0, 2.0) for g in (1.0, 2.0)]
    keys = ["fusion.proposed.delta_deg", "fusion.proposed.gamma"]
    first = plot_sweep(rows, keys, tmp_path, "f1")
    assert sorted(p.name for p in first) == ["curves.png", "heatmap_delta_gamma.png", "pareto.png"]
    assert all(p.parent == tmp_path for p in first)
    (tmp_path / "notes.txt").write_text("mine")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}

    def interrupted(points):                                  # the heatmap and the curves are drawn by now
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep_plots, "pareto_front", interrupted)
    other = [dict(r, count=r["count"] * 3, f1=r["f1"] / 2) for r in rows]
    with pytest.raises(KeyboardInterrupt):
        plot_sweep(other, keys, tmp_path, "f1")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
