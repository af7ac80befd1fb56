"""featmap.plotting.explain: the pieces a scan's extraction dropped, by the first test each failed."""

import numpy as np

from featmap.extraction.explain import explain_scan
from featmap.plotting.explain import plot_explanation
from featmap.plotting.style import new_figure
from tests.extraction.test_vertical_structure import building, cast_scan


def test_the_fence_is_drawn_under_its_first_failed_test_and_the_front_as_a_wall():
    scan = cast_scan([building(30, -25, 45, 25, 12.0), {"kind": "fence", "line": [[8, 3], [8, 15]], "height": 1.4}])
    explanation = explain_scan(scan)
    fig, ax = new_figure()
    plot_explanation(ax, scan, explanation)
    labels = {c.get_label(): c for c in ax.collections if not c.get_label().startswith("_")}
    assert "walls (1)" in labels
    np.testing.assert_allclose(labels["walls (1)"].get_segments()[0], explanation.result.segments[0].reshape(2, 2))
    (top,) = [c for label, c in labels.items() if label.startswith("height: top (")]
    assert any(np.allclose(np.sort(s[:, 1]), [3, 15], atol=0.3) and np.allclose(s[:, 0], 8, atol=0.1) for s in top.get_segments())
    assert ax.get_xlim()[1] >= 35 and ax.get_xlim()[0] <= -5                # every piece and the sensor, plus 5 m
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_a_scan_without_pieces_draws_its_points_and_no_wall():
    scan = np.array([[10.0, 0.0, 0.5]] * 5)
    fig, ax = new_figure()
    plot_explanation(ax, scan, explain_scan(scan), view=(0, 20, -10, 10))
    assert ax.get_xlim() == (0, 20)
    import matplotlib.pyplot as plt

    plt.close(fig)
