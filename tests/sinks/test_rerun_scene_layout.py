"""Where the scene's grid, tick labels and axis titles go in the view (sinks.rerun_scene.SceneLayout):
the view has the default scene panel's shape whatever the scene's, so its edges are the panel's,
and the tick labels and titles sit in its bottom and left margins, inside it."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rerun")

from bnptrack.sinks.rerun_scene import SceneLayout, view_bounds  # noqa: E402


def test_a_tall_scene_is_widened_to_the_panel_shape():
    # grid w/h = 1.2 x (1 - 0.085 - 0.025) / (1 - 0.1 - 0.2) = 1.525714...: the 1000 x 2000 m box
    # widens about x = 500 to 3051.43 m; the view adds 8.5 % / 2.5 % of its width left / right and
    # 10 % / 20 % of its height below / above (3428.57 x 2857.14 m)
    lay = SceneLayout.of((0.0, 1000.0, 0.0, 2000.0))
    np.testing.assert_allclose(lay.grid, (-1025.714, 2025.714, 0.0, 2000.0), atol=1e-3)
    np.testing.assert_allclose(lay.view, (-1317.143, 2111.429, -285.714, 2571.429), atol=1e-3)
    assert view_bounds((0.0, 1000.0, 0.0, 2000.0)) == lay.view


@pytest.mark.parametrize("bounds", [(0.0, 1000.0, 0.0, 2000.0), (-2200.0, 2200.0, -100.0, 2100.0),
                                    (-180.0, 3900.0, -2100.0, 1500.0), (0.0, 10.0, 0.0, 10.0)])
def test_ticks_and_titles_sit_in_the_margins_inside_the_view(bounds):
    lay = SceneLayout.of(bounds)
    vx0, vx1, vy0, vy1 = lay.view
    gx0, gx1, gy0, gy1 = lay.grid
    assert (vx1 - vx0) / (vy1 - vy0) == pytest.approx(SceneLayout.ASPECT)
    assert gx0 <= bounds[0] and gx1 >= bounds[1] and gy0 <= bounds[2] and gy1 >= bounds[3]
    xs, ys = np.array([gx0, 0.5 * (gx0 + gx1), gx1]), np.array([gy0, gy1])
    pts, labels = lay.ticks(xs, ys)
    assert labels == [f"{v:g}" for v in (*xs, *ys)]
    bottom, left = pts[:3], pts[3:]
    np.testing.assert_allclose(bottom[:, 0], xs)
    assert (vy0 < bottom[:, 1]).all() and (bottom[:, 1] < gy0).all()  # under the grid, in the view
    assert (vx0 < left[:, 0]).all() and (left[:, 0] < gx0).all()  # left of the grid, in the view
    x_title, y_title = lay.titles()
    assert vy0 < x_title[1] < bottom[0, 1] and gx0 < x_title[0] < gx1  # under the x ticks
    assert y_title[0] == gx0 and gy1 < y_title[1] < vy1  # above the y ticks
