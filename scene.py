"""The scene from above: the road network, every vehicle, the humans in the game, the planner's path and
who drives the ego. One piece of drawing code for DrivingEnv.render() (Renderer), Figs. 6-7
(bench/figures.py) and the videos (bench/video.py).

    network(net_file)           the lanes and junctions as SUMO has them, read from the .net.xml
    lane_polygon, boxes         a lane's area; vehicles as rectangles of their size and heading
    ego_color(beta), ego_style  the ego's colour: the actor's (beta = 1), the planner's (beta = 0), between
    legend_handles              what the colours mean
    draw_network, Layers        the network on an Axes; the moving part of a scene, updated from a snapshot
    Renderer                    (H, W, 3) uint8 frames of snapshots, a few ms each (blitting)

A snapshot is DrivingEnv.snapshot()'s plain data: "ego" (x, y, heading), "ids" and "vehicles" (M, 3) of
every other vehicle, "game" {id: "cross" | "yield"}, "plan" (K, 2), "t" [s], "v" [m/s], "zone", "T",
"beta" (None: nobody told the env who drives), "length", "width" and "perception" [m]. Positions are
vehicle centres [m], headings [rad] CCW from +x. This module imports nothing of the project (world.py
imports it inside render()), and matplotlib without pyplot: figures are drawn on their own Agg canvas.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from functools import lru_cache

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PolyCollection
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

ROAD, ROAD_EDGE = "#e6e6e6", "#bdbdbd"  # lanes and junction areas
NEAR, NEAR_EDGE = "#8c8c8c", "#404040"  # other vehicles within d_max of the ego (Eq. (27)): perceived
FAR, FAR_EDGE = "#d0d0d0", "#a0a0a0"  # other vehicles beyond
GAME = {"cross": "#d95f02", "yield": "#984ea3"}  # the outline of a human in the level-k game with the ego, by its choice
PLAN = "#d62728"  # the base planner's planned path of the ego's centre
ACTOR, PLANNER = "#1f77b4", "#2ca02c"  # who drives the ego: Fig. 6's colours of the actor's and the planner's action
BACKGROUND = "white"
WINDOW, MARGIN = 120.0, 10.0  # [m] the view's side, centred on the junction; the ego is kept this far inside


# ---- The network and the shapes, as pure functions ---------------------------------------------------


def _points(shape: str) -> np.ndarray:
    """SUMO's "x1,y1 x2,y2 ..." -> (N, 2) [m]."""
    return np.array([[float(v) for v in p.split(",")[:2]] for p in shape.split()], dtype=float).reshape(-1, 2)


def network(net_file) -> dict:
    """The road network as SUMO has it, read from its .net.xml (once per file): "lanes", a list of
    (shape (N, 2) [m], width [m], internal: inside a junction, its id starting ':'), and "junctions",
    the outlines (N, 2) [m] of the junctions that are not internal. The same as libsumo's lane.getShape,
    lane.getWidth and junction.getShape (tests/test_render.py)."""
    return _network(str(net_file))


@lru_cache(maxsize=8)
def _network(net_file: str) -> dict:
    root = ET.parse(net_file).getroot()
    lanes = [(_points(lane.get("shape")), float(lane.get("width", 3.2)), lane.get("id").startswith(":"))  # SUMO's default width
             for edge in root.iter("edge") for lane in edge.iter("lane")]
    junctions = [_points(j.get("shape")) for j in root.iter("junction")
                 if not j.get("id").startswith(":") and j.get("type") != "internal" and j.get("shape")]
    closed = [j if np.array_equal(j[0], j[-1]) else np.vstack([j, j[:1]]) for j in junctions]  # as libsumo gives them
    return {"lanes": lanes, "junctions": [j for j in closed if len(j) >= 3]}


def junction_centre(net: dict) -> np.ndarray:
    """The centre [m] of the bounding box of the internal lanes: the junction's (or the ring's)."""
    inner = np.vstack([shape for shape, _, internal in net["lanes"] if internal])
    return (inner.min(0) + inner.max(0)) / 2


def view_centre(centre, ego_xy, window: float = WINDOW, margin: float = MARGIN) -> np.ndarray:
    """The centre [m] of a window-square view: `centre`, moved just enough to keep the ego margin inside."""
    half = window / 2 - margin
    return np.clip(np.asarray(centre, dtype=float), np.asarray(ego_xy) - half, np.asarray(ego_xy) + half)


def lane_polygon(shape: np.ndarray, width: float) -> np.ndarray:
    """The lane's area: its polyline widened by width / 2 to both sides."""
    keep = np.r_[True, np.hypot(*np.diff(shape, axis=0).T) > 1e-6]
    p = shape[keep]
    if len(p) < 2:
        return np.zeros((0, 2))
    d = np.diff(p, axis=0)
    n = np.c_[-d[:, 1], d[:, 0]] / np.hypot(d[:, 0], d[:, 1])[:, None]
    vn = np.vstack([n[:1], n[:-1] + n[1:], n[-1:]])
    vn /= np.maximum(np.hypot(vn[:, 0], vn[:, 1]), 1e-9)[:, None]
    return np.vstack([p + vn * width / 2, (p - vn * width / 2)[::-1]])


def boxes(xyh: np.ndarray, length: float, width: float) -> np.ndarray:
    """(M, 3) centre x, y, heading -> (M, 4, 2) the corners of length x width rectangles."""
    xyh = np.asarray(xyh, dtype=float).reshape(-1, 3)
    local = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) * [length / 2, width / 2]
    c, s = np.cos(xyh[:, 2]), np.sin(xyh[:, 2])
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], 1)  # (M, 2, 2)
    return xyh[:, None, :2] + np.einsum("mij,kj->mki", rot, local)


def ego_color(beta: float | None) -> tuple[float, float, float]:
    """The ego's RGB by who drives: the actor's colour at beta = 1, the planner's at 0, linear between
    (Eq. (12)'s blend); None (nobody told the env: a plain Gymnasium agent) is the actor's."""
    b = 1.0 if beta is None else min(max(float(beta), 0.0), 1.0)
    return tuple(b * np.array(to_rgb(ACTOR)) + (1.0 - b) * np.array(to_rgb(PLANNER)))


def ego_style(beta: float | None) -> dict:
    """The ego's face and edge colours by who drives (ego_color), the edge a darker shade of the same hue."""
    color = ego_color(beta)
    return dict(facecolor=color, edgecolor=tuple(0.5 * np.array(color)))


def legend_handles(perception: float, short: bool = False) -> list:
    """What the colours of a scene mean, for a legend: the ego by who drives, the planner's path, the other
    vehicles within d_max [m] of the ego and beyond, the humans in the game by their choice. short: brief labels."""
    labels = (("ego: the actor drives", "the planner drives", "their blend", "planned path", f"within {perception:.0f} m",
               "beyond", "in the game: crosses", "yields") if short else
              ("ego (5 x 2 m): the actor drives", "... the planner drives", r"... between: the blend, by $\beta$",
               "base planner's planned trajectory", f"other vehicle within {perception:.0f} m of the ego",
               "other vehicle beyond", "in the level-k game with the ego: crosses", "... yields"))
    game = 1.5 if short else 1.8  # [pt] the outline of a human in the game
    return [Patch(**ego_style(1.0), label=labels[0]), Patch(**ego_style(0.0), label=labels[1]),
            Patch(**ego_style(0.5), label=labels[2]), Line2D([], [], color=PLAN, lw=1.6, label=labels[3]),
            Patch(facecolor=NEAR, edgecolor=NEAR_EDGE, label=labels[4]),
            Patch(facecolor=FAR, edgecolor=FAR_EDGE, label=labels[5]),
            Patch(facecolor=NEAR, edgecolor=GAME["cross"], lw=game, label=labels[6]),
            Patch(facecolor=NEAR, edgecolor=GAME["yield"], lw=game, label=labels[7])]


def driver_text(T, beta) -> str:
    """Who drives, in a few words: "T = 2, beta = 0.50 (blend)", "(actor)" or "(planner)" alone; "the agent" if unknown."""
    if beta is None:
        return "the agent drives"
    who = "actor" if beta == 1.0 else "planner" if beta == 0.0 else "blend"
    return (f"T = {T}, " if T else "") + f"\u03b2 = {beta:.2f} ({who})"


def heads_up(snap: dict) -> str:
    """The heads-up text of a frame, three short lines (the view's top-left corner, off the roads): time and
    speed, the zone, who drives (T and beta)."""
    zone = ("entry road", "conflict area", "exit road")[snap["zone"]] if snap.get("zone") is not None else ""
    return f"t = {snap['t']:.1f} s  v = {snap['v']:.1f} m/s\n{zone}\n{driver_text(snap.get('T'), snap.get('beta'))}"


# ---- Drawing on a matplotlib Axes --------------------------------------------------------------------


def draw_network(ax, net: dict, **kw) -> list:
    """The roads and the junction areas (internal lanes and junction outlines) onto ax."""
    roads = [p for p in (lane_polygon(s, w) for s, w, internal in net["lanes"] if not internal) if len(p)]
    inner = [p for p in (lane_polygon(s, w) for s, w, internal in net["lanes"] if internal) if len(p)]
    return [ax.add_collection(PolyCollection(roads, facecolor=ROAD, edgecolor=ROAD_EDGE, lw=0.5, **kw)),
            ax.add_collection(PolyCollection(inner + net["junctions"], facecolor=ROAD, edgecolor="none", **kw))]


class Layers:
    """The moving part of a scene on an Axes, made once and updated from each snapshot (update): the other
    vehicles (darker within d_max of the ego), the outlines of the humans in the game, the planner's path,
    the ego in the colour of who drives. animated=True keeps them out of canvas.draw() (Renderer blits them)."""

    def __init__(self, ax, animated: bool = False):
        kw = dict(animated=animated)
        poly = lambda z, **style: ax.add_collection(PolyCollection([], zorder=z, **style, **kw))  # noqa: E731
        self.far = poly(2, facecolor=FAR, edgecolor=FAR_EDGE, lw=0.5)
        self.near = poly(2, facecolor=NEAR, edgecolor=NEAR_EDGE, lw=0.6)
        self.game = {k: poly(3, facecolor="none", edgecolor=color, lw=1.8) for k, color in GAME.items()}
        self.plan, = ax.plot([], [], color=PLAN, lw=1.6, alpha=0.9, zorder=4, **kw)
        self.ego = poly(5, lw=0.8)
        self.artists = [self.far, self.near, *self.game.values(), self.plan, self.ego]

    def update(self, snap: dict):
        ego, (L, W) = np.asarray(snap["ego"], dtype=float), (snap["length"], snap["width"])
        xyh = np.asarray(snap["vehicles"], dtype=float).reshape(-1, 3)
        corners = boxes(xyh, L, W)
        near = np.hypot(*(xyh[:, :2] - ego[:2]).T) <= snap["perception"]
        self.far.set_verts(corners[~near])
        self.near.set_verts(corners[near])
        for choice, layer in self.game.items():
            layer.set_verts(corners[[snap["game"].get(vid) == choice for vid in snap["ids"]]].reshape(-1, 4, 2))
        plan = np.asarray(snap["plan"], dtype=float).reshape(-1, 2)
        self.plan.set_data(plan[:, 0], plan[:, 1])
        style = ego_style(snap.get("beta"))
        self.ego.set_verts(boxes(ego, L, W))
        self.ego.set_facecolor(style["facecolor"])
        self.ego.set_edgecolor(style["edgecolor"])


# ---- Frames: blitting onto a background drawn once ----------------------------------------------------


class Renderer:
    """Frames (size, size, 3) uint8 of snapshots: a window-square view [m] centred on the junction, moved
    just enough to keep the ego margin [m] inside (Fig. 6's panels), and a heads-up line (heads_up).

    The network is drawn once, for its whole extent at the frame's scale (pixels per metre); each frame
    copies the view's crop of it into the canvas (the view moves by whole pixels) and draws the moving
    artists over it (Layers, the heads-up text): no full redraw, a few ms a frame.
    """

    def __init__(self, net_file, size: int = 480, window: float = WINDOW, margin: float = MARGIN, dpi: int = 100):
        self.net, self.size, self.window, self.margin = network(net_file), int(size), float(window), float(margin)
        self.ppm = self.size / self.window  # [px/m]
        self.centre = junction_centre(self.net)
        # the background: every place a view can reach (the network's extent, widened by a window), once
        points = np.vstack([s for s, _, _ in self.net["lanes"]])
        self.origin = np.floor(points.min(0) - self.window)  # [m] x, y of the background's lower-left corner
        cols, rows = np.ceil((points.max(0) + self.window - self.origin) * self.ppm).astype(int)
        fig = Figure(figsize=(cols / dpi, rows / dpi), dpi=dpi, facecolor=BACKGROUND)
        (x0, y0), (x1, y1) = self.origin, self.origin + np.array([cols, rows]) / self.ppm  # [m]
        ax = self._axes(fig, (x0, x1), (y0, y1))
        draw_network(ax, self.net)
        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        self.background = np.asarray(canvas.buffer_rgba()).copy()  # (rows, cols, 4), row 0 at the top
        # the frame: one Axes filling the canvas, its moving artists made once
        self.fig = Figure(figsize=(self.size / dpi, self.size / dpi), dpi=dpi, facecolor=BACKGROUND)
        self.ax = self._axes(self.fig, (0, self.window), (0, self.window))
        self.layers = Layers(self.ax, animated=True)
        self.hud = self.ax.text(0.01, 0.99, "", transform=self.ax.transAxes, ha="left", va="top", fontsize=8,
                                family="monospace", animated=True, zorder=6,
                                bbox=dict(boxstyle="round,pad=0.25", fc="white", ec="0.6", alpha=0.85))
        self.canvas = FigureCanvasAgg(self.fig)
        self.canvas.draw()  # makes the renderer the frames are drawn with
        self.buffer = np.asarray(self.canvas.buffer_rgba())  # the canvas's own pixels, written in place

    @staticmethod
    def _axes(fig, xlim, ylim):
        ax = fig.add_axes((0, 0, 1, 1))
        ax.set_axis_off()
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        return ax

    def view(self, ego_xy) -> tuple[int, int]:
        """The view's top-left pixel (column, row) in the background, for the ego at ego_xy [m]."""
        c = view_centre(self.centre, ego_xy, self.window, self.margin)
        col = round((c[0] - self.window / 2 - self.origin[0]) * self.ppm)
        row = self.background.shape[0] - round((c[1] + self.window / 2 - self.origin[1]) * self.ppm)
        return (int(np.clip(col, 0, self.background.shape[1] - self.size)),
                int(np.clip(row, 0, self.background.shape[0] - self.size)))

    def frame(self, snap: dict) -> np.ndarray:
        """The snapshot drawn: (size, size, 3) uint8."""
        col, row = self.view(np.asarray(snap["ego"])[:2])
        x0 = self.origin[0] + col / self.ppm  # [m] the view's left edge and top edge, on whole pixels
        y1 = self.origin[1] + (self.background.shape[0] - row) / self.ppm
        self.ax.set_xlim(x0, x0 + self.window)
        self.ax.set_ylim(y1 - self.window, y1)
        self.buffer[:] = self.background[row:row + self.size, col:col + self.size]
        self.layers.update(snap)
        self.hud.set_text(heads_up(snap))
        for artist in (*self.layers.artists, self.hud):
            self.ax.draw_artist(artist)
        return self.buffer[..., :3].copy()
