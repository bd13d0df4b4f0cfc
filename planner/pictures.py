"""Pictures of plans a person understands without the source: ``plan.png`` (``loggrasp plan
--png``, a trial's ``plan/plan.png``) and an evaluation's ``examples.png``.

Both draw the render the planner saw, with numbered log outlines (numbers placed apart from each
other), the grasps as rectangles with their claws, a legend, a 1 m scale bar and a north arrow.
A georeferenced pile is drawn north-up in SWEREF 99 TM metres (the axes of ``grasp_map.png``);
a pile without a georeference in its own frame (x right, y up) and says so. ``plan.png`` lists
the ranked grasps beside the map and explains the score Q of the chosen objective.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from planner.inference import OBSTACLE_CODE_BASE
from synth.common.files import atomic_write_bytes
from synth.geometry.grasp import RECT_WIDTH_M

TARGET_FILL = "#f0a030"
LOG_EDGE = "#55a0ff"
TARGET_EDGE = "#ff8c00"
CHOSEN = "#e00000"
OTHER = "#00c8c8"
OBSTACLE = "#b02020"

#: the objectives' formulas and what their terms mean (planner.inference.Objective)
SCORE_TERMS = ("U  graspability (0-1): the network's chance that a grasp here",
               "   holds the target logs",
               "τ  number of target logs of the subset",
               "B  balance cos β of the load (1 = hangs level)",
               "Q ranks the grasps; only #1 is sent to the crane")


def score_formula(objective: Any) -> str:
    """The objective's quality ``Q`` as a formula (``objective``: a planner.inference.Objective)."""
    kind = getattr(objective, "kind", "f1")
    mu = getattr(objective, "mu", 1 / 3)
    if kind == "f1":
        return "Q = U   (objective f1)"
    mu_txt = "1/3" if abs(mu - 1 / 3) < 1e-9 else f"{mu:g}"
    if kind == "f2":
        return f"Q = U · τ^{mu_txt}   (objective f2)"
    source = ", B from the hang model" if getattr(objective, "balance", "network") == "hang" else ""
    return (f"Q = U · τ^{mu_txt} · exp(−(B − {getattr(objective, 'b_opt', 1.0):g})² / "
            f"{getattr(objective, 'sigma_b', 0.25):g}²)   (objective f3{source})")


# -- frames ---------------------------------------------------------------------------------------
class MapFrame:
    """Pile frame -> the picture's map frame: SWEREF 99 TM (grid north up) for a georeferenced pile,
    else the pile frame itself. Over a pile patch the mapping is affine to well below a millimetre."""

    def __init__(self, pile: Any = None, z_m: float = 0.0):
        self.georeferenced = pile is not None and getattr(pile, "georef", None) is not None
        self.matrix = np.eye(3)
        self.gamma_deg = 0.0
        if self.georeferenced:
            from synth.geometry.geodesy import meridian_convergence_deg, pile_to_geodetic, pile_to_sweref_tm

            p = np.array([[0.0, 0.0, z_m], [1.0, 0.0, z_m], [0.0, 1.0, z_m]])
            e, n, _ = pile_to_sweref_tm(pile.georef, p)
            o = np.array([e[0], n[0]])
            ex, ey = np.array([e[1], n[1]]) - o, np.array([e[2], n[2]]) - o
            self.matrix = np.array([[ex[0], ey[0], o[0]], [ex[1], ey[1], o[1]], [0.0, 0.0, 1.0]])
            lat, lon, _ = pile_to_geodetic(pile.georef, p[:1])
            self.gamma_deg = float(np.ravel(meridian_convergence_deg(lat, lon))[0])

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        return xy @ self.matrix[:2, :2].T + self.matrix[:2, 2]

    def transform(self, ax):
        from matplotlib.transforms import Affine2D

        return Affine2D(self.matrix) + ax.transData

    def axis_labels(self) -> tuple[str, str]:
        if self.georeferenced:
            return "Easting [m], SWEREF 99 TM (EPSG:3006)", "Northing [m], SWEREF 99 TM"
        return "x [m], pile frame (not georeferenced)", "y [m], pile frame"


# -- drawing helpers ------------------------------------------------------------------------------
def _figure(size: tuple[float, float], dpi: int):
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def _png(fig, path: str | Path, dpi: int, description: str) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": "loggrasp planner.pictures",
                                                      "Description": description})
    path = Path(path)
    atomic_write_bytes(path, buf.getvalue())
    return path


def _pixel_centres(obs) -> tuple[np.ndarray, np.ndarray]:
    n = obs.depth.shape[0]
    e = obs.extent_m
    c = -e / 2 + (np.arange(n) + 0.5) * e / n
    return np.meshgrid(c, -c)  # x along columns, y down the rows (north-up picture)


def label_positions(obs, avoid_xy: Sequence[Sequence[float]] = (), min_sep_m: float = 0.45) -> dict[int, np.ndarray]:
    """Where to write each log's number (pile frame): on the log, at least ``min_sep_m`` from the
    other numbers and from ``avoid_xy`` (e.g. grasp centres) where the log allows, else as far as
    it can be; near the log's middle among the points that qualify."""
    from synth.geometry.frames import OrthoGrid

    grid = OrthoGrid(obs.depth.shape[0], obs.extent_m)
    placed = [np.asarray(p, dtype=float) for p in avoid_xy]
    out: dict[int, np.ndarray] = {}
    sizes = {i: int((obs.instance == i + 1).sum()) for i in range(obs.n_logs)}
    for i in sorted((i for i in sizes if sizes[i]), key=lambda j: sizes[j]):
        rows, cols = np.nonzero(obs.instance == i + 1)
        step = max(1, len(rows) // 300)
        x, y = grid.pixel_to_pile(rows[::step], cols[::step])
        cand = np.column_stack([x, y]).astype(float)
        mid = np.median(cand, axis=0)
        d = (np.min(np.linalg.norm(cand[:, None, :] - np.array(placed)[None, :, :], axis=2), axis=1)
             if placed else np.full(len(cand), np.inf))
        ok = d >= min_sep_m
        k = int(np.argmin(np.where(ok, np.linalg.norm(cand - mid, axis=1), np.inf))) if ok.any() else int(np.argmax(d))
        out[i] = cand[k]
        placed.append(cand[k])
    return out


def _draw_scene(ax, obs, frame: MapFrame, targets: Sequence[int], grasps: Sequence[tuple[Any, str, str, float]],
                number_logs: bool = True, render: int = 0) -> np.ndarray:
    """The render, log and obstacle outlines, target fill, grasps ``(grasp, colour, label, lw)``
    and log numbers on ``ax``; returns the map-frame points the view must include."""
    half = obs.extent_m / 2
    inten = np.asarray(obs.intensity)
    grey = np.clip(inten[render] if inten.ndim == 3 else inten, 0, 1)
    tr = frame.transform(ax)
    ax.imshow(grey, cmap="gray", vmin=0.0, vmax=1.0, extent=(-half, half, -half, half), origin="upper",
              interpolation="nearest", transform=tr, alpha=0.9)
    X, Y = _pixel_centres(obs)
    inst = np.asarray(obs.instance)
    tset = {int(t) for t in targets}
    pts = []
    for i in range(obs.n_logs):
        m = inst == i + 1
        if not m.any():
            continue
        if i in tset:
            ax.contourf(X, Y, m.astype(float), levels=[0.5, 1.5], colors=[TARGET_FILL], alpha=0.45, transform=tr)
        ax.contour(X, Y, m.astype(float), levels=[0.5], colors=[TARGET_EDGE if i in tset else LOG_EDGE],
                   linewidths=1.6 if i in tset else 1.0, transform=tr)
        rows, cols = np.nonzero(m)
        pts.append(frame(np.column_stack([X[rows, cols], Y[rows, cols]])))
    obst = inst >= OBSTACLE_CODE_BASE
    if obst.any():
        ax.contour(X, Y, obst.astype(float), levels=[0.5], colors=[OBSTACLE], linewidths=1.0, linestyles="--",
                   transform=tr)
    centres = []
    for grasp, colour, label, lw in reversed(list(grasps)):
        rect = frame(grasp.rectangle(RECT_WIDTH_M))
        ax.fill(rect[:, 0], rect[:, 1], fc="none", ec="k", lw=lw + 1.6, zorder=4)
        ax.fill(rect[:, 0], rect[:, 1], fc=(1, 1, 1, 0.12), ec=colour, lw=lw, zorder=5)
        for a, b in ((0, 3), (1, 2)):  # the claws: the rectangle's short sides
            ax.plot(rect[[a, b], 0], rect[[a, b], 1], color=colour, lw=lw + 2.2, solid_capstyle="butt", zorder=6)
        c = frame(np.array([[grasp.x_m, grasp.y_m]]))[0]
        centres.append((grasp.x_m, grasp.y_m))
        if label:
            ax.text(c[0], c[1], label, ha="center", va="center", fontsize=7.5, weight="bold", color="k", zorder=8,
                    bbox={"boxstyle": "round,pad=0.15", "fc": colour, "ec": "k", "lw": 0.5, "alpha": 0.9})
        pts.append(rect)
    if number_logs:
        for i, xy in label_positions(obs, avoid_xy=centres).items():
            p = frame(xy[None])[0]
            ax.text(p[0], p[1], str(i), ha="center", va="center", fontsize=8, weight="bold", zorder=7,
                    color="k", bbox={"boxstyle": "circle,pad=0.18", "fc": "white",
                                     "ec": TARGET_EDGE if i in tset else LOG_EDGE, "lw": 1.0})
    return np.concatenate(pts) if pts else frame(np.array([[-half, -half], [half, half]]))


def _frame_axes(ax, frame: MapFrame, pts: np.ndarray, min_half_m: float = 1.5, margin_m: float = 0.5,
                ticks: bool = True, compact: bool = False) -> None:
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = (lo + hi) / 2
    half = max(min_half_m, float(np.max(hi - lo)) / 2 + margin_m)
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_aspect("equal")
    ax.set_facecolor("0.85")
    if ticks:
        step = 1.0 if half <= 4 else 2.0 if half <= 8 else 5.0
        metre_ticks(ax, step)
        xl, yl = frame.axis_labels()
        ax.set_xlabel(xl, fontsize=8)
        ax.set_ylabel(yl, fontsize=8)
        ax.grid(True, lw=0.3, color="0.6", alpha=0.6)
    else:
        ax.set_xticks([])
        ax.set_yticks([])
    ax.add_artist(AnchoredSizeBar(ax.transData, 1.0, "1 m", "lower left", pad=0.4, sep=3, frameon=True,
                                  size_vertical=half * 0.012, fontproperties={"size": 8}))
    _north_arrow(ax, frame, compact)


def _north_arrow(ax, frame: MapFrame, compact: bool = False) -> None:
    """Grid north (up) for a georeferenced map, with true north's offset; else the pile's +y
    (``compact``: the arrow and its letter only)."""
    if frame.georeferenced:
        side = "W" if frame.gamma_deg > 0 else "E"
        head, note = "N", f"grid north\n(true north\n{abs(frame.gamma_deg):.1f}° {side} of it)"
    else:
        head, note = "+y", "no north:\nnot georeferenced"
    box = {"boxstyle": "round,pad=0.15", "fc": "white", "ec": "0.5", "alpha": 0.85}
    ax.annotate(head, xy=(0.94, 0.97), xytext=(0.94, 0.86), xycoords="axes fraction", ha="center", va="top",
                fontsize=8, weight="bold", arrowprops={"arrowstyle": "-|>", "lw": 1.8, "color": "k"}, bbox=box)
    if not compact:
        ax.text(0.94, 0.80, note, transform=ax.transAxes, ha="center", va="top", fontsize=6.5, bbox=box)


def _legend_handles(targets: bool = True, alternatives: bool = True, obstacles: bool = True, others: bool = True):
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    h = [Line2D([], [], color=CHOSEN, lw=2.2, label="chosen grasp (#1)"),
         Line2D([], [], color="0.35", lw=5, solid_capstyle="butt", label="claws: the thick short sides\n"
                                                                             "(they close across the long side)")]
    if alternatives:
        h.append(Line2D([], [], color=OTHER, lw=1.4, label="next-best grasps (#2, #3, …)"))
    if targets:
        h.append(Patch(fc=TARGET_FILL, ec=TARGET_EDGE, alpha=0.7, label="target logs of the chosen grasp"))
    if others:
        h.append(Patch(fc="none", ec=LOG_EDGE, label="other logs"))
    h.append(Line2D([], [], ls="none", marker="o", mfc="white", mec="k", ms=9, label="log number (index)"))
    if obstacles:
        h.append(Line2D([], [], color=OBSTACLE, ls="--", lw=1.0, label="stump / rock"))
    return h


# -- plan.png ---------------------------------------------------------------------------------------
def draw_plan(obs, plan, path: str | Path, *, pile: Any = None, objective: Any = None, constraints: Any = None,
              top: int = 5, dpi: int = 110, title: str | None = None) -> Path:
    """``plan.png``: the map (north-up where georeferenced) with the chosen and the next-best
    grasps, numbered logs, legend, scale and north; beside it the ranked table and what the score
    Q means. ``plan``: a :class:`planner.inference.Plan`; ``pile``: its PileSpec when known."""
    grasps = list(plan.grasps)[:max(1, top)]
    z = 0.0
    if pile is not None and getattr(pile, "terrain", None) is not None:
        try:
            z = float(pile.terrain.height_at(0.0, 0.0))
        except Exception:  # a picture must not fail a plan: the frame at z = 0 is as good to a mm
            z = 0.0
    frame = MapFrame(pile, z)
    fig = _figure((13.0, 7.6), dpi)
    ax = fig.add_axes((0.06, 0.10, 0.52, 0.80))
    best_targets = grasps[0].targets if grasps else ()
    drawn = [(g.grasp, CHOSEN if k == 0 else OTHER, f"#{k + 1}", 2.4 if k == 0 else 1.3) for k, g in enumerate(grasps)]
    pts = _draw_scene(ax, obs, frame, best_targets, drawn)
    _frame_axes(ax, frame, pts)
    n_logs = obs.n_logs
    where = "north-up, SWEREF 99 TM" if frame.georeferenced else "pile frame, not georeferenced"
    ax.set_title(title or (f"Plan: grasp #1 takes logs {', '.join(map(str, best_targets))} "
                           f"({len(best_targets)} of {n_logs}) — {where}" if grasps else
                           f"No grasp found ({n_logs} logs) — {where}"), fontsize=10.5, loc="left")
    # right: legend, ranked table, the score explained
    shown = {int(c) - 1 for c in np.unique(np.asarray(obs.instance)) if 0 < c < OBSTACLE_CODE_BASE}
    obstacles = bool((np.asarray(obs.instance) >= OBSTACLE_CODE_BASE).any())
    fig.legend(handles=_legend_handles(bool(best_targets), len(grasps) > 1, obstacles, bool(shown - set(best_targets))),
               loc="upper left", bbox_to_anchor=(0.61, 0.91), fontsize=8, frameon=True, title="legend",
               title_fontsize=8.5)
    head = f"{'#':>2}  {'target logs':<14}{'Q':>6}{'U':>7}{'B':>7}{'width m':>9}"
    rows = [f"{k + 1:>2}  {','.join(map(str, g.targets)):<14}{g.quality:>6.3f}{g.graspability:>7.3f}"
            f"{g.balance:>7.3f}{g.grasp.width_m:>9.2f}" for k, g in enumerate(grasps)]
    text = ["ranked grasps (the best grasp of each target subset;", f"{plan.subsets_evaluated} subsets evaluated, "
            "#1 is sent)", "", head, *rows, "", "score", score_formula(objective), *SCORE_TERMS]
    removed = [r for r in (getattr(plan, "rejected", None) or []) if r.get("action") == "removed"]
    if removed:
        text += ["", f"{len(removed)} subset(s) without a grasp:"]
        text += [f"  logs {','.join(map(str, r['targets']))}: {r['constraint']} ({r['detail']})" for r in removed[:4]]
        if len(removed) > 4:
            text.append(f"  … and {len(removed) - 4} more (plan.json)")
    fig.text(0.61, 0.60, "\n".join(text), ha="left", va="top", fontsize=7.6, family="monospace")
    return _png(fig, path, dpi, "loggrasp plan: ranked grasps over the render")


# -- examples.png ------------------------------------------------------------------------------------
def draw_examples(records: list[dict], cfg: Any, path: str | Path, planner: str, n: int = 4,
                  render_pile: Callable[[dict], Any] | None = None, dpi: int = 100) -> Path:
    """An evaluation's examples: up to ``n`` successes (top row) and ``n`` failures (bottom row) of
    ``planner``, each titled with the planner, the outcome and the pile; a row without examples
    says so instead of showing empty panels. ``render_pile(record)`` gives the observation (the
    test pile regenerated from its seed by default)."""
    mine = [r for r in records if r["planner"] == planner and r.get("grasp")]
    rows = [("successes", [r for r in mine if r["outcome"] == "success"][:n]),
            ("failures", [r for r in mine if r["outcome"] != "success"][:n])]
    cols = max(2, max(len(r) for _, r in rows))  # at least two panels wide: the titles and legend fit
    fig = _figure((3.2 * cols + 0.4, 7.4), dpi)
    render = render_pile or (lambda r: _eval_observation(r, cfg))
    for ri, (what, recs) in enumerate(rows):
        if not recs:
            ax = fig.add_axes((0.02, 0.49 - 0.41 * ri, 0.96, 0.34))
            ax.axis("off")
            total = sum(1 for r in records if r["planner"] == planner)
            ax.text(0.5, 0.5, f"no {what} of {planner} among its {total} pile(s)", ha="center", va="center",
                    fontsize=11, color="0.3")
            continue
        for ci, r in enumerate(recs):
            from synth.geometry.grasp import Grasp

            ax = fig.add_axes((0.02 + ci * (0.96 / cols), 0.49 - 0.41 * ri, 0.96 / cols - 0.01, 0.34))
            obs = render(r)
            g = Grasp(**r["grasp"])
            frame = MapFrame(None)
            pts = _draw_scene(ax, obs, frame, r["targets"], [(g, CHOSEN, "", 2.0)])
            _frame_axes(ax, frame, pts, min_half_m=1.2, ticks=False, compact=True)
            held = len(r.get("grasped") or [])
            ax.set_title(f"{planner}: {r['outcome'].replace('_', ' ')}\n"
                         f"held {held} of {len(r['targets'])} target log(s); {r['n_logs']} logs, "
                         f"{'obstacles' if r['obstacles'] else 'no obstacles'}", fontsize=8)
    trial = getattr(cfg, "trial", "")
    fig.suptitle(f"Evaluation examples of planner {planner} (trial preset {trial})\nsuccesses (top row), "
                 "failures (bottom row); each pile in its own frame (+y up, not georeferenced), 1 m scale bar",
                 fontsize=10)
    fig.legend(handles=_legend_handles(True, False, True), loc="lower center", ncol=3 if cols < 4 else 6,
               fontsize=7.5, frameon=False)
    return _png(fig, path, dpi, f"loggrasp evaluation examples of {planner}")


def _eval_observation(r: dict, cfg: Any):
    """The evaluation's test pile of record ``r``, regenerated from its seed and rendered."""
    from synth.scene.generate import GenerationConfig, generate_pile
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.physics.world import World

    rng = np.random.default_rng([r["seed"], 77])
    n_obst = int(rng.integers(1, cfg.max_obstacles + 1)) if r["obstacles"] else 0
    pile, _ = generate_pile(r["seed"], GenerationConfig(n_logs=r["n_logs"], n_obstacles=n_obst))
    with World(pile) as world:
        return render_ortho(world, OrthoRenderConfig(size_px=cfg.size_px, n_renders=1), seed=r["seed"])


def metre_ticks(ax, step_m: float) -> None:
    """Plain metre tick labels (no offset, no exponent: site coordinates read as they are) every
    ``step_m`` on both axes of ``ax``, small, the x ones slanted."""
    from matplotlib.ticker import MultipleLocator, ScalarFormatter

    for axis in (ax.xaxis, ax.yaxis):
        fmt = ScalarFormatter(useOffset=False)
        fmt.set_scientific(False)
        axis.set_major_formatter(fmt)
        axis.set_major_locator(MultipleLocator(step_m))
    ax.tick_params(axis="x", labelrotation=30, labelsize=7)
    ax.tick_params(axis="y", labelsize=7)
