"""Pictures of an anatomy with matplotlib (Agg, no display needed).

    plot_anatomy(anatomy, "face.png", displacement=face.u, title="OOP 50 %")

draws two panels, a three-quarter front view and a side view from the subject's left, of
the outer skin (see skin_faces) as a light translucent surface, the muscle fibres coloured
by muscle, the fixed nodes faintly and the lip landmarks. With a displacement everything
is drawn deformed (the fibres carried by the mesh: solver.app.io.fibre_displacements). Takes
about half a second for the reference face. matplotlib comes with the package's `plot`
extra (solver.app.extras).
"""

from pathlib import Path

import numpy as np

from solver.face.anatomy.base import MUSCLE_FULL_NAMES, MUSCLE_NAMES
from solver.app.extras import need
from solver.app.io.export import fibre_displacements

MUSCLE_COLOURS = dict(zip(MUSCLE_NAMES, (
    "#1f77b4", "#17becf", "#2ca02c", "#bcbd22", "#9467bd",
    "#8c564b", "#ff7f0e", "#e377c2", "#d62728", "#7f0000")))
SKIN, FIXED = "#f2c9a8", "#5b6b7c"
# (label, elev, azim) degrees: from the subject's left (x < 0), which a half face keeps
VIEWS = (("three-quarter front, left", 18, 125), ("left side", 0, 180))


def plot_anatomy(anatomy, path, displacement=None, title=None, rigid=()):
    """Write a PNG of anatomy (optionally deformed by displacement (n, 3) mm) to path;
    rigid: (vertices (p, 3), triangles (t, 3)) surfaces drawn in grey (the teeth, as
    posed)."""
    need("matplotlib", "plot", "solver.app.plot")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    mesh = anatomy.mesh
    u = np.zeros_like(mesh.nodes) if displacement is None else np.asarray(displacement)
    x = mesh.nodes + u
    fibres = [f.points + d for f, d in zip(anatomy.fibres, _fibre_moves(anatomy, displacement))]
    skin = x[skin_faces(mesh)]
    fig = Figure(figsize=(13, 6.4), dpi=110)
    FigureCanvasAgg(fig)
    for i, (label, elev, azim) in enumerate(VIEWS):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d", computed_zorder=False,
                             proj_type="ortho")
        for v, t in rigid:
            ax.add_collection3d(Poly3DCollection(np.asarray(v)[np.asarray(t)],
                                                 facecolors=(0.55, 0.55, 0.6, 0.35),
                                                 edgecolors=(0.3, 0.3, 0.35, 0.15),
                                                 linewidths=0.2, zorder=0))
        _draw(ax, anatomy, x, skin, fibres, _camera(elev, azim))
        _frame(ax, x, elev, azim, label)
    _legend(fig, anatomy)
    fig.suptitle(title or _default_title(anatomy, displacement), fontsize=14)
    fig.subplots_adjust(left=0.0, right=1.0, top=0.93, bottom=0.11, wspace=0.0)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path


def skin_faces(mesh):
    """(k, 4) node ids of the outer skin: the boundary faces of mesh that are not on bone
    (not all four nodes fixed) and face away from the mesh's centroid (outward normal),
    which leaves out the inside of the mouth, cheeks and nostrils of a face shell."""
    faces = mesh.boundary_faces()
    fixed = np.zeros(mesh.n_nodes, dtype=bool)
    fixed[mesh.node_sets.get("fixed", [])] = True
    quad = mesh.nodes[faces]
    normal = np.cross(quad[:, 2] - quad[:, 0], quad[:, 3] - quad[:, 1])
    away = np.einsum("kj,kj->k", normal, quad.mean(axis=1) - mesh.nodes.mean(axis=0)) > 0
    return faces[away & ~fixed[faces].all(axis=1)]


def _fibre_moves(anatomy, displacement):
    """Per-fibre point displacements (k, 3)."""
    if displacement is None or not anatomy.fibres:
        return [np.zeros_like(f.points) for f in anatomy.fibres]
    return fibre_displacements(anatomy, np.asarray(displacement, dtype=np.float64))


def _camera(elev, azim):
    """(3,) unit vector from the scene towards matplotlib's camera."""
    e, a = np.radians(elev), np.radians(azim)
    return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def _skin_colours(skin, camera):
    """(k, 4) RGBA of the skin quads (k, 4, 3) seen from camera (3,): front faces lit by a
    lamp above the camera, both sides alike; back faces (the far side) fainter."""
    from matplotlib.colors import to_rgb

    normal = np.cross(skin[:, 2] - skin[:, 0], skin[:, 3] - skin[:, 1])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    lamp = camera + np.array([0.0, 0.0, 0.6])
    lit = np.abs(normal @ (lamp / np.linalg.norm(lamp)))
    front = normal @ camera > 0
    rgba = np.empty((len(skin), 4))
    rgba[:, :3] = np.asarray(to_rgb(SKIN)) * (0.62 + 0.38 * lit)[:, None]
    rgba[:, 3] = np.where(front, 0.30, 0.06)
    return rgba


def _draw(ax, anatomy, x, skin, fibres, camera):
    """Skin, fixed nodes, fibres and landmarks on one 3D axes, back to front."""
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    ax.add_collection3d(Poly3DCollection(skin, facecolors=_skin_colours(skin, camera),
                                         edgecolors=(0.45, 0.3, 0.2, 0.10), linewidths=0.3,
                                         zorder=1))
    fixed = x[anatomy.mesh.node_sets.get("fixed", [])]
    ax.scatter(*fixed.T, s=4, c=FIXED, alpha=0.45, linewidths=0, zorder=2)
    for m in MUSCLE_NAMES:
        segs = [p for f, p in zip(anatomy.fibres, fibres) if f.muscle == m]
        if segs:
            ax.add_collection3d(Line3DCollection(segs, colors=MUSCLE_COLOURS[m],
                                                 linewidths=2.2, zorder=3))
    lm = x[list(anatomy.landmarks.values())]
    ax.scatter(*lm.T, s=28, c="white", edgecolors="black", linewidths=1.0, zorder=4,
               depthshade=False)


def _frame(ax, x, elev, azim, label):
    """Equal-aspect limits around x (n, 3), the view, and a quiet frame."""
    lo, hi = x.min(axis=0), x.max(axis=0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2 * 1.02
    for set_lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        set_lim(c - half, c + half)
    ax.set_box_aspect((1, 1, 1), zoom=_zoom(x, half, elev, azim))
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()
    ax.set_title(label, y=1.0, fontsize=11, color="0.3")


def _zoom(x, half, elev, azim):
    """matplotlib zoom that fills 82 % of the (square) panel with x (n, 3), the limits
    being a cube of half-side half: an orthographic panel shows 0.185 of the projected
    box, whose side is 1.1003 zoom (mpl_toolkits.mplot3d.Axes3D.get_proj, set_box_aspect)."""
    e, a = np.radians(elev), np.radians(azim)
    screen = np.array([[-np.sin(a), np.cos(a), 0.0],
                       [-np.sin(e) * np.cos(a), -np.sin(e) * np.sin(a), np.cos(e)]])
    span = np.ptp(x @ screen.T, axis=0).max()
    return 0.82 * 0.185 * 10 / 1.1003 * 2 * half / span


def _legend(fig, anatomy):
    """Muscles present (short and full names), landmarks and fixed nodes, below the panels."""
    from matplotlib.lines import Line2D

    present = [m for m in MUSCLE_NAMES if anatomy.muscle_fibres(m)]
    handles = [Line2D([], [], color=MUSCLE_COLOURS[m], lw=3,
                      label=f"{m}  {MUSCLE_FULL_NAMES[m]}") for m in present]
    handles += [Line2D([], [], ls="", marker="o", mfc="white", mec="black", label="lip landmarks"),
                Line2D([], [], ls="", marker=".", color=FIXED, label="fixed nodes (bone)")]
    fig.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.5, 0.01), ncol=4,
               frameon=False, fontsize=9, handlelength=2.2, columnspacing=1.6)


def _default_title(anatomy, displacement):
    """'<name> face (rest|deformed): counts'."""
    mesh = anatomy.mesh
    state = "deformed" if displacement is not None else "rest"
    side = ", half" if anatomy.half else ""
    return (f"{anatomy.name} face{side} ({state}): {mesh.n_nodes} nodes, {mesh.n_bricks} "
            f"bricks, {len(anatomy.fibres)} fibres")
