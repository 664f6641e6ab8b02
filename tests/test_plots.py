"""Picture helpers: boundary faces, cluster colours, the state a picture shows; PNGs are written."""
import numpy as np

import skfem_affine as sa
from skfem_affine.lab import plots


def test_boundary_faces():
    one = np.array([[0], [1], [2], [3]])
    faces, owner = plots.boundary_faces(one)
    assert faces.shape == (4, 3) and np.all(owner == 0)
    two = np.array([[0, 1], [1, 2], [2, 3], [3, 4]])  # share the face (1, 2, 3)
    faces, owner = plots.boundary_faces(two)
    assert faces.shape == (6, 3) and sorted(np.bincount(owner)) == [3, 3]
    assert not any(set(f) == {1, 2, 3} for f in faces)
    mesh = sa.scenes.beam_mesh(1)   # 4 x 1 x 1 cubes: 2 (4 + 4 + 1) squares of 2 triangles
    assert plots.boundary_faces(mesh.t)[0].shape[0] == 2 * 2 * (4 + 4 + 1)


def test_cluster_colors_and_picked_state():
    rgb = plots.cluster_colors(np.array([-1, 0, 1, 0]))
    assert np.allclose(rgb[0], plots.ELASTIC) and np.allclose(rgb[1], rgb[3]) and not np.allclose(rgb[1], rgb[2])
    x = np.zeros((2, 3))
    states = [sa.State(x + d, x, frame=i, clusters=np.array(c)) for i, (d, c) in
              enumerate([(0.0, [0, 0]), (0.1, [0, -1]), (1.0, [0, 0]), (2.0, [-1, -1])])]
    assert plots.pick_state(states).frame == 2            # moved and reduced
    assert plots.pick_state(states, frame=1).frame == 1


def test_pictures_are_written(tmp_path):
    sim = sa.scenes.cantilever(resolution=1, reducer=sa.Affinification(tau_a=1.0, tau_e=2.0), E=1e5, damping=None)
    states = [sim.state.copy()] + [s for s in sim.run(4)]
    png = plots.clusters_picture([("affinification", sim, states[-1])], str(tmp_path / "c.png"))
    gif = plots.animation("affinification", sim, states, str(tmp_path / "a.gif"))
    from PIL import Image
    assert Image.open(png).size[0] > 300
    im = Image.open(gif)
    assert im.n_frames == len(states)


def test_pareto_front_keeps_the_points_nothing_beats():
    # (error, speedup): the second is slower and less accurate than the first; None is left out
    pts = [(1e-3, 2.0), (2e-3, 1.5), (5e-3, 3.0), (1e-4, 0.8), (None, 9.0), (1e-2, 3.0)]
    assert plots.pareto_front(pts) == [3, 0, 2]


def test_trade_plot_is_written(tmp_path):
    points = [{"error": 1e-3, "speedup": 1.4, "label": "0.1, 0.2"}, {"error": 2e-2, "speedup": 3.0, "label": "0.3, 0.6"},
              {"error": 4e-3, "speedup": 2.0, "label": "budget 0.01", "budget": 0.01, "method": "budget"},
              {"error": None, "speedup": 2.0, "label": "failed"}]
    path = plots.trade_plot(points, str(tmp_path / "trade.png"), budgets=[0.01])
    assert (tmp_path / "trade.png").stat().st_size > 1000 and path.endswith("trade.png")


def test_trade_plot_of_several_scenes_is_written_and_checks_its_points(tmp_path):
    import pytest
    pts = [{"scene": sc, "method": m, "speedup": s, "error": e}
           for sc in ("drop", "stack") for m, s, e in (("adaptive subspace", 1.5, 1e-3), ("adaptive subspace", 3.0, 1e-2),
                                                      ("affinification", 2.0, 5e-3))]
    out = plots.trade_plot(pts, str(tmp_path / "trade" / "picture.png"), title="t")
    assert out.endswith("picture.png") and (tmp_path / "trade" / "picture.png").stat().st_size > 1000
    with pytest.raises(ValueError, match=r"points\[1\] must be a dict with 'error' and 'speedup'"):
        plots.trade_plot([pts[0], {"scene": "a", "method": "b", "speedup": 1.0}], str(tmp_path / "x.png"))


def _overlap(a, b):
    return not (a.x1 <= b.x0 or b.x1 <= a.x0 or a.y1 <= b.y0 or b.y1 <= a.y0)


def test_trade_figure_draws_the_front_through_measured_non_dominated_points_and_keeps_labels_apart():
    # crowded points: several within a factor 1.1 in error and 0.05 in speedup, two dominated
    pts = [{"error": e, "speedup": v, "label": f"affinification {e:g}", "method": "affinification"}
           for e, v in [(2e-4, 0.9), (1.1e-3, 1.3), (3.0e-3, 1.6), (3.3e-3, 1.55), (3.1e-3, 1.5),
                        (8e-3, 2.1), (2.5e-2, 2.0), (2.7e-2, 2.9)]]
    fig = plots.trade_figure(pts, budgets=[0.01])
    ax = fig.axes[0]
    (front,) = [line for line in ax.lines if line.get_gid() == "pareto front"]
    measured = {(p["error"], p["speedup"]) for p in pts}
    drawn = list(zip(*front.get_data()))
    assert set(drawn) <= measured                                   # the front only joins measured points
    assert [pts[i]["error"] for i in plots.pareto_front([(p["error"], p["speedup"]) for p in pts])] == \
        [e for e, _ in drawn] == [2e-4, 1.1e-3, 3.0e-3, 8e-3, 2.7e-2]  # and exactly the non-dominated ones
    renderer = fig.canvas.get_renderer()
    from matplotlib.text import Text
    labels = [Text.get_window_extent(t, renderer) for t in ax.texts]   # the text, not its leader line
    assert len(labels) == len(pts)
    assert not any(_overlap(a, b) for i, a in enumerate(labels) for b in labels[i + 1:])
    ticks = [t.get_window_extent(renderer) for t in ax.get_xticklabels() if t.get_text()]
    assert len(ticks) >= 3 and not any(_overlap(a, b) for i, a in enumerate(ticks) for b in ticks[i + 1:])
    assert all(t.get_text().endswith("%") for t in ax.get_xticklabels() if t.get_text())


def test_trade_figure_of_one_point_claims_no_front():
    fig = plots.trade_figure([{"error": 1e-3, "speedup": 1.2, "label": "budget 1 %"}], budgets=[0.01])
    ax = fig.axes[0]
    assert not [line for line in ax.lines if line.get_gid() == "pareto front"]
    assert not any("Pareto" in t.get_text() for t in ax.get_legend().get_texts())


def test_clusters_picture_has_no_empty_band(tmp_path):
    from PIL import Image
    sim = sa.scenes.cantilever(resolution=1)
    png = plots.clusters_picture([("full", sim, sim.state)], str(tmp_path / "c.png"))
    image = np.asarray(Image.open(png).convert("L"))
    rows = np.flatnonzero((image < 250).any(axis=1))              # rows with anything drawn
    gaps = np.diff(rows)
    assert image.shape[1] > 2 * image.shape[0]                     # a 4 x 1 m beam: a wide picture
    assert gaps.max() < 0.15 * image.shape[0]                      # no blank band across it
