"""Figures of the trade, written as PNG (and GIF) with matplotlib's Agg backend (no display needed).

- :func:`speedup_per_frame`: speedup of each frame and its mean (paper Fig. 1);
- :func:`dofs_over_time`: elastic and solved DOFs per frame;
- :func:`phase_breakdown`: stacked wall time per phase (paper Fig. 12);
- :func:`error_over_time`: distance and step distance error per frame;
- :func:`clusters_picture`, :func:`animation`: the bodies with clusters coloured, one frame or a GIF;
- :func:`sweep_heatmaps`: every metric over the tau_a x tau_e grid (paper Fig. 6);
- :func:`scaling_plot`: speedup and time per frame against the number of elements (paper Table 2);
- :func:`trade_plot`: speedup against max distance error, one point per setting (several methods
  and scenes), the Pareto front of one scene.
"""
import os

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import LogNorm, to_rgb
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.text import Text

from skfem_affine.simulation import Stats

COLORS = {"full": "#444444", "affinification": "#d95f02", "rigidification": "#1b9e77"}
ELASTIC = np.array([0.82, 0.82, 0.82])


def _color(name, i=0):
    return COLORS.get(name, f"C{(i + 3) % 10}")


def _figure(width, height):
    fig = Figure(figsize=(width, height), dpi=110)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path):
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path)
    return path


def _finish_over_time(fig, ax, ylabel, title, path):
    """Label a per-frame plot (time axis in seconds), put the legend on the right, save it."""
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    fig.tight_layout()
    return _save(fig, path)


def _times(run):
    return np.array([r["time"] for r in run.records])


def speedup_per_frame(runs, path, reference="full"):
    """Per-frame speedup (reference frame wall / method frame wall) with the run's mean (Fig. 1)."""
    ref = np.array([r["wall"] for r in runs[reference].records])
    fig = _figure(9.5, 3.6)
    ax = fig.add_subplot()
    for i, (name, run) in enumerate(runs.items()):
        if name == reference or not run.records:
            continue
        wall = np.array([r["wall"] for r in run.records])
        per_frame = ref[:wall.size] / wall
        t = _times(run)
        ax.plot(t, per_frame, lw=0.6, color=_color(name, i), alpha=0.35, label=f"{name}, per frame")
        k = min(9, wall.size)
        if k > 2:  # the ratio of 9-frame sums: readable at a glance, still a ratio of times
            window = np.ones(k)
            smooth = np.convolve(ref[:wall.size], window, "valid") / np.convolve(wall, window, "valid")
            ax.plot(t[k // 2: k // 2 + smooth.size], smooth, lw=1.6, color=_color(name, i),
                    label=f"{name}, over {k} frames")
        mean = run.summary["speedup"]
        ax.axhline(mean, color=_color(name, i), lw=2, ls="--", label=f"{name}, mean {mean:.2f}x")
    ax.axhline(1.0, color="k", lw=0.8, ls=":")
    ax.set_yscale("log")
    return _finish_over_time(fig, ax, "speedup over full space (x)",
                             "Speedup per frame (mean = total full time / total time)", path)


def dofs_over_time(runs, path):
    """Elastic DOFs (solid) and all DOFs solved (dashed) per frame."""
    fig = _figure(9.5, 3.6)
    ax = fig.add_subplot()
    for i, (name, run) in enumerate(runs.items()):
        t = _times(run)
        ax.plot(t, [r.get("elastic_dofs", r["dofs"]) for r in run.records], color=_color(name, i), lw=1.5,
                label=f"{name}: elastic DOFs")
        if name != "full":
            ax.plot(t, [r["dofs"] for r in run.records], color=_color(name, i), lw=1, ls="--",
                    label=f"{name}: DOFs solved (elastic + bodies)")
    ax.set_ylim(bottom=0)
    return _finish_over_time(fig, ax, "degrees of freedom", "DOFs per frame", path)


def phase_breakdown(runs, path):
    """Stacked wall time per phase and frame, one panel per method (Fig. 12), in milliseconds."""
    fig = _figure(4.2 * len(runs), 3.8)
    axes = fig.subplots(1, len(runs), sharey=True, squeeze=False)[0]
    phases = [p for p in Stats.PHASES if any(p in r for run in runs.values() for r in run.records)]
    colors = {p: f"C{i}" for i, p in enumerate(phases + ["other"])}
    for ax, (name, run) in zip(axes, runs.items()):
        t = _times(run)
        data = np.array([[r.get(p, 0.0) for p in phases] for r in run.records]).reshape(len(t), len(phases))
        wall = np.array([r["wall"] for r in run.records])
        other = np.maximum(wall - data.sum(axis=1), 0.0)
        stacks = 1e3 * np.column_stack([data, other]).T
        ax.stackplot(t, stacks, labels=phases + ["other"], colors=[colors[p] for p in phases + ["other"]],
                     linewidth=0)
        ax.set_title(f"{name}: {1e3 * wall.mean():.1f} ms/frame")
        ax.set_xlabel("simulated time (s)")
    axes[0].set_ylabel("wall time per frame (ms)")
    handles, labels = axes[-1].get_legend_handles_labels()
    fig.legend(handles[::-1], labels[::-1], fontsize=8, loc="center right")
    fig.tight_layout(rect=(0, 0, 1 - 1.3 / fig.get_figwidth(), 1))
    return _save(fig, path)


def error_over_time(runs, path):
    """Distance error (solid) and step distance error (dashed) per frame, relative to the scene size."""
    fig = _figure(9.5, 3.6)
    ax = fig.add_subplot()
    plotted = False
    for i, (name, run) in enumerate(runs.items()):
        if name == "full" or not run.records:
            continue
        t = _times(run)
        for key, ls, what in (("distance_error", "-", "distance"), ("step_error", "--", "step distance")):
            y = np.array([r.get(key, np.nan) for r in run.records], dtype=float)
            if np.any(y > 0):
                ax.plot(t, np.where(y > 0, y, np.nan), ls=ls, color=_color(name, i), lw=1.2, label=f"{name}: {what}")
                plotted = True
    if plotted:
        ax.set_yscale("log")
        top = ax.get_ylim()[1]
        ax.set_ylim(bottom=max(ax.get_ylim()[0], top * 1e-6))
    return _finish_over_time(fig, ax, "max vertex distance / scene size", "Error against the full-space reference",
                             path)


# ---------------------------------------------------------------- pictures of the bodies
def boundary_faces(t):
    """Faces on the boundary of a tetrahedral mesh ``t`` (4, m): (k, 3) vertex indices and their element."""
    t = np.asarray(t)
    local = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    faces = t[local].transpose(2, 0, 1).reshape(-1, 3)
    _, inverse, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    once = counts[inverse.ravel()] == 1
    return faces[once], np.repeat(np.arange(t.shape[1]), 4)[once]


def cluster_colors(clusters):
    """RGB per element: light grey for elastic (-1), a qualitative colour per cluster id."""
    clusters = np.asarray(clusters)
    palette = np.array([to_rgb(f"tab:{c}") for c in ("blue", "orange", "green", "red", "purple", "brown", "pink",
                                                      "olive", "cyan")] +
                       [to_rgb(c) for c in ("gold", "navy", "teal", "maroon", "lime", "magenta", "darkorange")])
    rgb = np.tile(ELASTIC, (clusters.size, 1))
    body = clusters >= 0
    rgb[body] = palette[(clusters[body] * 7) % len(palette)]
    return rgb


AXES = "xyz"


def _draw_bodies(ax, sim, x, clusters, faces, owner, limits):
    """Orthographic view along the scene's thinnest axis, faces painted far to near, shaded."""
    from matplotlib.collections import PolyCollection
    lo, hi = limits
    depth = int(np.argmin(hi - lo))
    u, w = [i for i in range(3) if i != depth]
    toward_viewer = -1.0 if depth == 1 else 1.0  # look from -y (x right, z up), from +z, from +x
    clusters = np.full(sim.system.m, -1) if clusters is None else np.asarray(clusters)
    tri = x[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    light = np.zeros(3)
    light[depth], light[w] = 0.8, 0.6
    shade = 0.55 + 0.45 * np.abs(normal @ light)
    order = np.argsort(toward_viewer * tri[:, :, depth].mean(axis=1))  # far first
    colors = np.clip(cluster_colors(clusters)[owner] * shade[:, None], 0, 1)
    ax.add_collection(PolyCollection(tri[order][:, :, [u, w]], facecolors=colors[order],
                                     edgecolors=(0, 0, 0, 0.25), linewidths=0.25))
    ax.set_xlim(lo[u], hi[u])
    ax.set_ylim(lo[w], hi[w])
    ax.set_aspect("equal")
    ax.set_xlabel(f"{AXES[u]} (m)", fontsize=8)
    ax.set_ylabel(f"{AXES[w]} (m)", fontsize=8)
    ax.tick_params(labelsize=7)


def _limits(xs):
    lo = np.min([x.min(axis=0) for x in xs], axis=0)
    hi = np.max([x.max(axis=0) for x in xs], axis=0)
    pad = 0.02 * np.max(hi - lo)
    return lo - pad, hi + pad


def _panel_width(limits, height):
    """Width (inches) of a picture panel of ``height`` that fits the scene's in-view extent."""
    extent = limits[1] - limits[0]
    u, w = [i for i in range(3) if i != int(np.argmin(extent))]
    return float(np.clip(height * extent[u] / max(extent[w], 1e-300), 0.45 * height, 2.2 * height)) + 0.9


def _caption(name, sim, state):
    clusters = state.clusters
    if clusters is None or not np.any(np.asarray(clusters) >= 0):
        return f"{name}\nall {sim.system.m} elements elastic"
    clusters = np.asarray(clusters)
    n = int(clusters.max()) + 1
    return (f"{name}\n{n} {'body' if n == 1 else 'bodies'}, "
            f"{100 * np.mean(clusters >= 0):.0f}% of elements reduced")


def clusters_picture(panels, path, title=None):
    """One PNG, a 3D panel per ``(name, sim, state)``: elastic elements grey, each body its own colour."""
    faces, owner = boundary_faces(panels[0][1].system.t)
    limits = _limits([state.x for _, _, state in panels])
    width = max(_panel_width(limits, 3.6) * len(panels), 6.5)
    # the figure as tall as the bodies drawn at that width (no empty bands): the panels' axes, their
    # two-line titles and the title above, the x label and the legend below
    extent = limits[1] - limits[0]
    u, w = [i for i in range(3) if i != int(np.argmin(extent))]
    axes_height = float(np.clip((width / len(panels) - 0.9) * extent[w] / max(extent[u], 1e-300), 1.0, 5.0))
    top, bottom = 0.55 + (0.3 if title else 0.0), 0.85
    height = axes_height + top + bottom
    fig = _figure(width, height)
    for i, (name, sim, state) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), i + 1)
        _draw_bodies(ax, sim, state.x, state.clusters, faces, owner, limits)
        ax.set_title(_caption(name, sim, state), fontsize=9)
    fig.legend(handles=[Patch(color=ELASTIC, label="elastic element"),
                        Patch(color="tab:blue", label="one colour per reduced body")],
               loc="lower center", ncol=2, fontsize=8, frameon=False)
    if title:
        fig.suptitle(title, fontsize=10, x=0.02, ha="left")
    fig.tight_layout(rect=(0, 0.3 / height, 1, 1.0 - (0.05 if title else 0.0) / height))
    return _save(fig, path)


def animation(name, sim, states, path, fps=12):
    """An animated GIF of ``states`` (e.g. ``Run.states``) with clusters coloured."""
    from PIL import Image
    if not states:
        raise ValueError("animation needs at least one state")
    faces, owner = boundary_faces(sim.system.t)
    limits = _limits([s.x for s in states])
    images = []
    for state in states:
        fig = _figure(_panel_width(limits, 3.6), 4.2)
        ax = fig.add_subplot()
        _draw_bodies(ax, sim, state.x, state.clusters, faces, owner, limits)
        ax.set_title(f"{_caption(name, sim, state)}, t = {state.time:.2f} s", fontsize=9)
        fig.tight_layout()
        fig.canvas.draw()
        images.append(Image.fromarray(np.asarray(fig.canvas.buffer_rgba())[..., :3]).quantize(colors=128))
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return path


# ---------------------------------------------------------------- sweep and scaling
SWEEP_METRICS = (("max_distance_error", "max distance error / size", True),
                 ("max_step_error", "max step distance error / size", True),
                 ("max_residual", "max residual ||A dv - b|| / ||b||", True),
                 ("max_energy_error", "max strain-energy difference\n/ max reference strain energy", True),
                 ("dof_ratio", "DOF ratio (solved / full)", False),
                 ("mean_clusters", "mean number of bodies", False),
                 ("speedup", "speedup over full (x)", False),
                 ("wall_s", "wall time of the run (s)", False))


def _edges(values):
    v = np.log10(values)
    if v.size == 1:
        return 10.0 ** np.array([v[0] - 0.5, v[0] + 0.5])
    mid = 0.5 * (v[1:] + v[:-1])
    return 10.0 ** np.concatenate([[2 * v[0] - mid[0]], mid, [2 * v[-1] - mid[-1]]])


def sweep_heatmaps(rows, path, title=None):
    """Every metric over the tau_a x tau_e grid (paper Fig. 6); failed cells are crossed out."""
    ta = np.unique([float(r["tau_a"]) for r in rows])
    te = np.unique([float(r["tau_e"]) for r in rows])
    ia = {v: i for i, v in enumerate(ta)}
    ie = {v: i for i, v in enumerate(te)}
    metrics = [m for m in SWEEP_METRICS if any(r.get(m[0]) is not None for r in rows)]
    ncol = 4
    nrow = -(-len(metrics) // ncol)
    fig = _figure(4.1 * ncol, 3.5 * nrow)
    failed = [(float(r["tau_a"]), float(r["tau_e"])) for r in rows if r.get("status") != "ok"]
    for k, (key, label, log) in enumerate(metrics):
        ax = fig.add_subplot(nrow, ncol, k + 1)
        grid = np.full((te.size, ta.size), np.nan)
        for r in rows:
            v = r.get(key)
            if r.get("status") == "ok" and v is not None and np.isfinite(float(v)):
                grid[ie[float(r["tau_e"])], ia[float(r["tau_a"])]] = float(v)
        ok = grid[np.isfinite(grid)]
        norm = None
        if log and np.any(ok > 0):
            norm = LogNorm(vmin=ok[ok > 0].min(), vmax=max(ok.max(), ok[ok > 0].min() * 1.0001))
            grid = np.where(grid > 0, grid, np.nan)
        ax.set_facecolor("0.9")
        mesh = ax.pcolormesh(_edges(ta), _edges(te), np.ma.masked_invalid(grid), norm=norm, cmap="viridis")
        fig.colorbar(mesh, ax=ax).ax.tick_params(labelsize=7, which="both")
        if failed:
            ax.plot(*zip(*failed), "x", color="red", ms=7, mew=2, label="diverged / failed")
        lims = _edges(ta)[[0, -1]]
        ax.plot(lims, lims, color="w", lw=0.8, ls=":")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("tau_a (1/s)", fontsize=8)
        ax.set_ylabel("tau_e (1/s)", fontsize=8)
        ax.set_title(label, fontsize=9)
        ax.tick_params(labelsize=7)
        if failed and k == 0:
            ax.legend(fontsize=7, loc="lower right")
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return _save(fig, path)


def scaling_plot(rows, path, title=None):
    """Speedup and wall time per frame against the number of elements (paper Table 2)."""
    rows = [r for r in rows if r.get("speedup") is not None]
    m = np.array([r["elements"] for r in rows], dtype=float)
    frames = np.array([r["frames"] for r in rows], dtype=float)
    fig = _figure(10, 3.8)
    ax1, ax2 = fig.subplots(1, 2)
    ax1.plot(m, [r["speedup"] for r in rows], "o-", color=_color("affinification"))
    for r in rows:
        if r.get("max_distance_error") is not None:
            ax1.annotate(f"err {r['max_distance_error']:.1e}", (r["elements"], r["speedup"]), fontsize=7,
                         textcoords="offset points", xytext=(4, 6))
    ax1.axhline(1.0, color="k", lw=0.8, ls=":")
    ax1.set_xscale("log")
    ax1.set_xlabel("elements (tetrahedra)")
    ax1.set_ylabel("speedup over full space (x)")
    ax1.set_title("Speedup (labels: max distance error / size)", fontsize=9)
    ax2.plot(m, 1e3 * np.array([r["time_full_s"] for r in rows]) / frames, "o-", color=_color("full"),
             label="full space")
    ax2.plot(m, 1e3 * np.array([r["time_reduced_s"] for r in rows]) / frames, "s-",
             color=_color(rows[0]["method"] if rows else "affinification"),
             label=rows[0]["method"] if rows else "reduced")
    ax2.set_xscale("log")
    ax2.set_yscale("log")
    ax2.set_xlabel("elements (tetrahedra)")
    ax2.set_ylabel("wall time per frame (ms)")
    ax2.set_title("Cost per frame", fontsize=9)
    ax2.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def compare_plots(runs, out, frame=None, stem="compare"):
    """All compare figures into ``out``; returns their paths. ``frame`` picks the clusters picture's frame."""
    paths = [speedup_per_frame(runs, os.path.join(out, f"{stem}_speedup.png")),
             dofs_over_time(runs, os.path.join(out, f"{stem}_dofs.png")),
             phase_breakdown(runs, os.path.join(out, f"{stem}_phases.png")),
             error_over_time(runs, os.path.join(out, f"{stem}_error.png"))]
    kept = {name: run for name, run in runs.items() if run.states}
    if frame is None and kept:
        reduced = [run for name, run in kept.items() if name != "full"] or list(kept.values())
        frame = pick_state(reduced[0].states).frame
    panels = [(name, run.sim, pick_state(run.states, frame)) for name, run in kept.items()]
    if panels:
        shown = panels[0][2]
        title = f"Frame {shown.frame} (t = {shown.time:.2f} s): elastic grey, bodies coloured"
        paths.append(clusters_picture(panels, os.path.join(out, f"{stem}_clusters.png"), title=title))
    return paths


def pick_state(states, frame=None):
    """The kept state at ``frame`` (or nearest).

    Default: the state that shows most of the method, the largest product of the
    fraction of reduced elements and the largest displacement from the first state.
    """
    if frame is None:
        moved = [np.abs(s.x - states[0].x).max() for s in states]
        reduced = [np.mean(np.asarray(s.clusters) >= 0) if s.clusters is not None else 0.0 for s in states]
        score = np.array(moved) * np.array(reduced)
        return states[int(np.argmax(score))] if score.max() > 0 else states[int(np.argmax(moved))]
    return min(states, key=lambda s: abs(s.frame - frame))


def pareto_front(points):
    """Indices of the points (error, speedup) that no other point beats on both, by increasing error.

    A point is on the front when every point with an error as small or smaller is slower.
    """
    pts = [(e, v, i) for i, (e, v) in enumerate(points) if e is not None and v is not None
           and np.isfinite(e) and np.isfinite(v)]
    front, best = [], -np.inf
    for e, v, i in sorted(pts, key=lambda p: (p[0], -p[1])):
        if v > best:
            front.append(i)
            best = v
    return front


TRADE_MARKERS = "osD^v<>ph*"
TRADE_COLORS = {"adaptive subspace": "#7570b3"}
#: Where a point's label may go, tried in turn: offset (points) and alignment.
LABEL_SPOTS = [(6, 4, "left", "bottom"), (6, -4, "left", "top"), (-6, 4, "right", "bottom"),
               (-6, -4, "right", "top"), (0, 8, "center", "bottom"), (0, -8, "center", "top"),
               (10, 16, "left", "bottom"), (10, -16, "left", "top"), (-10, 16, "right", "bottom"),
               (-10, -16, "right", "top"), (0, 26, "center", "bottom"), (0, -26, "center", "top"),
               (24, 30, "left", "bottom"), (24, -30, "left", "top"), (-24, 30, "right", "bottom"),
               (-24, -30, "right", "top"), (0, 44, "center", "bottom"), (0, -44, "center", "top")]


def log_ticks(axis, fmt):
    """Readable ticks on a log ``axis``: 1-2-5 (or fewer) per decade, labelled by ``fmt``, bare minors."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter
    lo, hi = sorted(axis.get_view_interval())
    decades = np.log10(max(hi, 1e-300) / max(lo, 1e-300))
    subs = (1.0,) if decades > 3.5 else (1.0, 3.0) if decades > 1.8 else (1.0, 2.0, 5.0) if decades > 0.8 \
        else (1.0, 1.5, 2.0, 3.0, 5.0, 7.0)
    axis.set_major_locator(LogLocator(base=10.0, subs=subs))
    axis.set_major_formatter(FuncFormatter(lambda v, _: fmt(v)))
    axis.set_minor_locator(LogLocator(base=10.0, subs=np.arange(2.0, 10.0)))
    axis.set_minor_formatter(NullFormatter())


def _percent(v):
    return f"{100 * v:.3g} %"


def _place_labels(fig, ax, items):
    """Annotate ``(x, y, text)`` items without overlaps: each label takes the first free spot.

    Free means inside the axes and clear of the labels already placed and of every point; a label
    that finds no free spot goes to the least crowded one, with a leader line.
    """
    renderer = fig.canvas.get_renderer()
    frame = ax.get_window_extent(renderer)
    marks = [ax.transData.transform((x, y)) for x, y, _ in items]
    taken = [(m[0] - 5, m[1] - 5, m[0] + 5, m[1] + 5) for m in marks]

    def clash(b):
        return sum(not (b.x1 < t[0] or b.x0 > t[2] or b.y1 < t[1] or b.y0 > t[3]) for t in taken)

    for x, y, text in sorted(items, key=lambda it: (it[0], it[1])):
        if not text:
            continue
        best = None
        for dx, dy, ha, va in LABEL_SPOTS:
            far = abs(dy) > 10
            t = ax.annotate(text, (x, y), textcoords="offset points", xytext=(dx, dy), ha=ha, va=va, fontsize=7,
                            zorder=5, arrowprops=dict(arrowstyle="-", color="0.5", lw=0.5) if far else None,
                            bbox=dict(boxstyle="round,pad=0.1", fc="white", ec="none", alpha=0.75))
            t.update_positions(renderer)
            b = Text.get_window_extent(t, renderer).padded(1.5)  # the text alone, not its leader line
            outside = b.x0 < frame.x0 or b.x1 > frame.x1 or b.y0 < frame.y0 or b.y1 > frame.y1
            score = clash(b) + (10 if outside else 0)
            if best is None or score < best[0]:
                if best is not None:
                    best[1].remove()
                best = (score, t, b)
            else:
                t.remove()
            if score == 0:
                break
        taken.append((best[2].x0, best[2].y0, best[2].x1, best[2].y1))


def _short_label(point):
    """A point's label without its method's name (the colour and the legend say it)."""
    label, method = point.get("label", "") or "", point.get("method", "") or ""
    if method and label.startswith(method) and label[len(method):].strip(" ,:"):
        return label[len(method):].strip(" ,:")
    return label


#: The trade picture's error axis per unit of the errors (``trade_plot(unit=...)``).
ERROR_AXIS = {"size": "max vertex distance to the full-space run (% of the scene size)",
              "response": "max vertex distance to the full-space run (% of the response: largest displacement from rest)",
              "metre": "max vertex distance to the full-space run (m)"}


def trade_plot(points, path, budgets=(), title=None, unit="size"):
    """The trade at a glance: speedup over full space against max distance error / size.

    Parameters
    ----------
    points : list of dict
        One per measured setting: ``error`` (max distance error / size), ``speedup``, and
        optionally ``label`` (its settings, written beside the point), ``method`` (the colour),
        ``scene`` (the marker; the points of one method on one scene are joined in order of
        error) and ``budget`` (an error budget: drawn as a short vertical tick at the budget,
        joined to the point). Points without a finite error and speedup (failed runs) are left
        out.
    path : str
        The PNG to write.
    budgets : sequence of float
        Error budgets to mark as vertical dashed lines.
    title : str, optional
        The title (default: what the axes mean).

    Returns
    -------
    str
        ``path``.

    Notes
    -----
    Every point drawn is a measured run. On one scene, the points that no other point beats on
    both speed and error (:func:`pareto_front`) are ringed and, when there are two or more,
    joined: the Pareto front, through measured points only (a front across scenes would compare
    runs of different problems). 1x (no gain) is a dotted line. The error axis is logarithmic,
    in percent of the scene size; labels are placed clear of each other and of the points.
    """
    return _save(trade_figure(points, budgets, title, unit), path)


def trade_figure(points, budgets=(), title=None, unit="size"):
    """The :func:`trade_plot` figure itself (a matplotlib ``Figure``, drawn, not saved)."""
    points = list(points)
    for i, p in enumerate(points):
        if not isinstance(p, dict) or not {"error", "speedup"} <= set(p):
            raise ValueError(f"points[{i}] must be a dict with 'error' and 'speedup'")
    pts = [p for p in points if p["error"] is not None and p["speedup"] is not None
           and np.isfinite(p["error"]) and np.isfinite(p["speedup"])]
    fig = _figure(7.5, 4.8)
    ax = fig.subplots()
    methods = list(dict.fromkeys(p.get("method", "affinification") for p in pts))
    scenes = list(dict.fromkeys(p.get("scene") for p in pts))
    for i, name in enumerate(methods):
        color = TRADE_COLORS.get(name, _color(name, i))
        for j, scene in enumerate(scenes):
            mine = sorted(((max(p["error"], 1e-12), p["speedup"]) for p in pts
                           if p.get("method", "affinification") == name and p.get("scene") == scene))
            if not mine:
                continue
            e, v = np.array(mine).T
            label = name if scene is None else f"{name}, {scene}"
            marker = TRADE_MARKERS[j % len(TRADE_MARKERS)]
            if len(scenes) > 1:
                ax.plot(e, v, "-", marker=marker, color=color, lw=0.8, ms=6, zorder=3, label=label)
            else:
                ax.scatter(e, v, s=28, marker=marker, zorder=3, color=color, label=label)
    for p in pts:
        if p.get("budget") is not None:
            ax.plot([p["budget"], max(p["error"], 1e-12)], [p["speedup"]] * 2, color="0.6", lw=0.8, zorder=1)
            ax.plot([p["budget"]], [p["speedup"]], marker="|", ms=10, color="0.3", zorder=2)
    front = [pts[i] for i in pareto_front([(p["error"], p["speedup"]) for p in pts])] \
        if len(scenes) == 1 and len(pts) > 1 else []
    if front:
        xs = [max(p["error"], 1e-12) for p in front]
        ys = [p["speedup"] for p in front]
        if len(front) > 1:
            ax.plot(xs, ys, "-", color="k", lw=1.0, alpha=0.6, zorder=2, gid="pareto front")
        ax.scatter(xs, ys, s=90, facecolors="none", edgecolors="k", lw=0.9, zorder=4,
                   label="Pareto front (none faster and more accurate)" if len(front) > 1
                   else "best: faster and more accurate than the rest")
    ax.axhline(1.0, color="k", lw=0.8, ls=":", label="1x (full space)")
    for j, b in enumerate(budgets):
        ax.axvline(b, color="C3", lw=0.9, ls="--", label="error budget" if j == 0 else None)
    ax.set_xscale("log")
    xs = [max(p["error"], 1e-12) for p in pts] + [float(b) for b in budgets]
    if xs:  # room for the labels around the points
        ax.set_xlim(min(xs) / 3, max(xs) * 5)
    ax.set_xlabel(ERROR_AXIS[unit])
    ax.set_ylabel("speedup over full space (x)")
    ax.set_title(title or "Speed against accuracy (up and left is better)", fontsize=10)
    if len(scenes) > 1:
        ax.set_yscale("log")
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    else:
        ys = [p["speedup"] for p in pts] + [1.0]
        lo, hi = min(ys), max(ys)
        pad = 0.12 * max(hi - lo, 0.2)
        ax.set_ylim(max(lo - pad, 0.0), hi + 2 * pad)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=3, frameon=False)
    log_ticks(ax.xaxis, (lambda v: f"{v:g}") if unit == "metre" else _percent)
    if len(scenes) > 1:
        log_ticks(ax.yaxis, lambda v: f"{v:g}x")
    fig.tight_layout()
    _place_labels(fig, ax, [(max(p["error"], 1e-12), p["speedup"], _short_label(p)) for p in pts])
    return fig
