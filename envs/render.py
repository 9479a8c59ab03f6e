"""Top-down frames of a closed loop for the Gymnasium envs, and human mode's window (matplotlib, imported lazily).

A frame (FRAME_HEIGHT, FRAME_WIDTH, 3) uint8 shows, on the left, a 30 m x 24 m window
centred on the car: the road's friction map (grey scale: dark = grippy, white = ice), the
scenario's path and cones, the car body and its four wheels, each filled by its tyre force
utilisation (green 0 to red 1) and outlined by the local mu; on the right, strip charts of
the last 3 s of yaw rate (with its reference) and sideslip.
"""

from __future__ import annotations

import math
import os
import warnings

import numpy as np

from fourwis.envs.layout import A_MU, A_USAGE, S_DELTA_F, S_DELTA_R, S_PSI, S_U, S_X, S_Y
from fourwis.envs.road import contact_points

FRAME_WIDTH, FRAME_HEIGHT = 640, 480  #: frame size [pixels]
VIEW_HALF_X, VIEW_HALF_Y = 15.0, 12.0  #: half extents of the top-down window [m]
STRIP_SECONDS = 3.0  #: history shown in the strip charts [s]
MU_GRID = 48  #: friction-map samples per axis of the window
WHEEL_LENGTH, WHEEL_WIDTH = 0.56, 0.18  #: drawn tyre footprint [m]


def _box(cx: float, cy: float, length: float, width: float, heading: float) -> np.ndarray:
    """Corners (4, 2) of a rectangle centred at (cx, cy) [m] turned by ``heading`` [rad]."""
    c, s = math.cos(heading), math.sin(heading)
    local = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [length / 2, width / 2]
    return np.column_stack([cx + c * local[:, 0] - s * local[:, 1], cy + s * local[:, 0] + c * local[:, 1]])


class Renderer:
    """Draws frames of one vehicle of a :class:`envs.simulation.ClosedLoop`; keeps its figure."""

    def __init__(self):
        try:
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure
        except ModuleNotFoundError as err:  # optional dependency
            raise ModuleNotFoundError("rendering needs matplotlib: pip install 'fourwis[plots]'") from err

        self.figure = Figure(figsize=(FRAME_WIDTH / 100, FRAME_HEIGHT / 100), dpi=100)
        self.canvas = FigureCanvasAgg(self.figure)
        grid = self.figure.add_gridspec(
            2, 2, width_ratios=(3, 2), left=0.02, right=0.98, top=0.95, bottom=0.08, wspace=0.25, hspace=0.35
        )
        self.road_axes = self.figure.add_subplot(grid[:, 0])
        self.yaw_axes = self.figure.add_subplot(grid[0, 1])
        self.beta_axes = self.figure.add_subplot(grid[1, 1])

    def frame(self, loop, b: int, trace: np.ndarray) -> np.ndarray:
        """The frame of vehicle ``b`` of ``loop`` (a ClosedLoop, or anything with its state, aux,
        t, scenarios and params: a moment of one); ``trace`` (n, 4) rows t, r, r_ref, beta of
        its episode."""
        import matplotlib.patches as mpatches

        state, aux, scenario, params = loop.state[b], loop.aux[b], loop.scenarios[b], loop.params
        x, y, psi = state[S_X], state[S_Y], state[S_PSI]
        ax = self.road_axes
        ax.clear()
        xs = np.linspace(x - VIEW_HALF_X, x + VIEW_HALF_X, MU_GRID)
        ys = np.linspace(y - VIEW_HALF_Y, y + VIEW_HALF_Y, MU_GRID)
        gx, gy = np.meshgrid(xs, ys)
        mu = scenario.road.mu_at(gx, gy)
        ax.imshow(
            mu,
            origin="lower",
            extent=(xs[0], xs[-1], ys[0], ys[-1]),
            cmap="Greys",
            vmin=0.0,
            vmax=1.4,
            interpolation="nearest",
        )
        if scenario.reference_path is not None:
            path = scenario.reference_path
            ax.plot(path[:, 0], path[:, 1], "--", color="tab:blue", lw=0.8)
        if scenario.course is not None:
            cones = np.asarray(scenario.course.cones)
            ax.plot(cones[:, 0], cones[:, 1], "^", color="tab:orange", ms=4)
        body_length = params.front_extent + params.rear_extent
        centre_offset = params.front_extent - body_length / 2
        ax.add_patch(
            mpatches.Polygon(
                _box(
                    x + centre_offset * math.cos(psi), y + centre_offset * math.sin(psi), body_length, params.width, psi
                ),
                closed=True,
                fc="tab:blue",
                ec="k",
                alpha=0.35,
            )
        )
        wx, wy = contact_points(state[None, :], params)
        steer = (state[S_DELTA_F], state[S_DELTA_F], state[S_DELTA_R], state[S_DELTA_R])
        usage_colours = _colormap("RdYlGn_r")
        mu_colours = _colormap("Blues")
        for i in range(4):
            usage = float(np.clip(aux[A_USAGE + i], 0.0, 1.0))
            ax.add_patch(
                mpatches.Polygon(
                    _box(wx[0, i], wy[0, i], WHEEL_LENGTH, WHEEL_WIDTH, psi + steer[i]),
                    closed=True,
                    fc=usage_colours(usage),
                    ec=mu_colours(min(aux[A_MU + i] / 1.2, 1.0)),
                    lw=2.0,
                )
            )
        ax.set_xlim(x - VIEW_HALF_X, x + VIEW_HALF_X)
        ax.set_ylim(y - VIEW_HALF_Y, y + VIEW_HALF_Y)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"{scenario.name}  t = {loop.t[b]:.2f} s  u = {state[S_U] * 3.6:.0f} km/h", fontsize=8)
        recent = trace[trace[:, 0] >= trace[-1, 0] - STRIP_SECONDS] if len(trace) else trace
        for axes, columns, labels, ylabel in (
            (self.yaw_axes, (1, 2), ("r", "r_ref"), "yaw rate [deg/s]"),
            (self.beta_axes, (3,), ("beta",), "sideslip [deg]"),
        ):
            axes.clear()
            for column, label in zip(columns, labels):
                axes.plot(recent[:, 0], np.degrees(recent[:, column]), label=label, lw=1.0)
            axes.set_ylabel(ylabel, fontsize=7)
            axes.tick_params(labelsize=6)
            axes.legend(fontsize=6, loc="upper left")
        self.beta_axes.set_xlabel("t [s]", fontsize=7)
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()


def _colormap(name: str):
    import matplotlib

    return matplotlib.colormaps[name]


def close_window(window) -> None:
    """Close a human-mode window of :func:`show_frame` (if one opened); returns the cleared handle."""
    if isinstance(window, tuple):
        import matplotlib.pyplot as plt

        plt.close(window[0])
    return None


def show_frame(frame: np.ndarray, window):
    """Draw ``frame`` in a matplotlib window (human mode); warns once where there is no display."""
    import matplotlib

    if matplotlib.get_backend().lower() == "agg" or (
        os.name == "posix" and not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY")
    ):
        if window != "no-display":
            warnings.warn("render_mode='human' needs a display; none found, frames are not shown", stacklevel=3)
        return "no-display"
    import matplotlib.pyplot as plt

    if window is None:
        plt.ion()
        fig, ax = plt.subplots(figsize=(frame.shape[1] / 100, frame.shape[0] / 100), dpi=100)
        ax.set_axis_off()
        window = (fig, ax.imshow(frame))
    window[1].set_data(frame)
    window[0].canvas.draw_idle()
    plt.pause(0.001)
    return window
