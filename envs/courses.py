"""Cone courses: ISO 3888-1 double lane change, ISO 3888-2 obstacle avoidance, slalom.

A :class:`Course` holds the cone-bounded lanes (``gates``), the cone positions and a smooth
centreline for the path-following driver. The course starts at X = 0 (entry of section 1),
lane 1 centred on Y = 0, the lane change goes to the left (+Y), as drawn in the standards.

Layouts (w = vehicle width [m]):

* ISO 3888-1:1999 (severe lane change): sections 15 / 30 / 25 / 25 / 15 m long; lanes 1, 3
  and 5 are 1.1w+0.25, 1.2w+0.25 and 1.3w+0.25 m wide; lane 3 is offset 3.5 m to the left.
  We read the 3.5 m offset between the right-hand cone rows of lanes 1 and 3 (the standard's
  figure dimensions the cone rows); lane 5 shares lane 1's right-hand row.
* ISO 3888-2:2011 (obstacle avoidance): sections 12 / 13.5 / 11 / 12.5 / 12 m; lane 1 is
  1.1w+0.25 wide, lane 3 is w+1 wide with its right-hand row 1 m to the left of lane 1's
  left-hand row, lane 5 is 1.3w+0.25 but at least 3 m wide (Table 1; for this car 3 m) and shares
  lane 1's right-hand row (docs/decisions/0009-courses-and-path-following-driver.md).

Cones stand along the lane edges (their bases' inner edges on the edge line) at each end of a
lane and every ~3 m in between (the standards prescribe cone spacing per section; the count
only matters for counting hits). The driver's centreline is the least-curvature line that
keeps the car's body inside the lanes (:func:`_least_curvature_path`), the line a skilled test
driver takes; the driver model (:class:`envs.driver.PathFollower`) follows it. It is not a
lane-centre line: the lanes of ISO 3888-2 are too short for that at any useful speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import sparse
from scipy.optimize import linprog

from fourwis.core.checks import is_integer, is_number
from fourwis.envs.vehicle import VehicleParams

CONE_SPACING = 3.0  #: largest distance between cones along a lane edge [m]
CONE_RADIUS = 0.15  #: cone base radius [m]; cone centres stand this far outside the lane edge
PATH_MARGIN = 0.05  #: least clearance of the driver's line from each lane edge [m]
_CAR = VehicleParams()  #: the default car, whose body extents the courses' driver line assumes unless given


@dataclass(frozen=True)
class Gate:
    """A cone-bounded lane section from ``x_start`` to ``x_end`` [m] between ``y_right`` < ``y_left`` [m]."""

    x_start: float
    x_end: float
    y_right: float
    y_left: float

    @property
    def width(self) -> float:
        return self.y_left - self.y_right

    @property
    def centre(self) -> float:
        return 0.5 * (self.y_left + self.y_right)


@dataclass(frozen=True)
class Course:
    """A cone course: ``gates`` (lanes), ``cones`` (M, 2) [m] and driver ``centreline`` (N, 2) [m]."""

    name: str
    gates: tuple[Gate, ...]
    cones: np.ndarray
    centreline: np.ndarray

    @property
    def length(self) -> float:
        """Distance from the course entry to its exit [m]."""
        return float(self.centreline[-1, 0] - self.centreline[0, 0])


def stack_polylines(paths) -> tuple[np.ndarray, np.ndarray]:
    """Polylines (N_b, 2) of B cars (None: none) in one array: (points (sum N_b, 2), offsets
    (B + 1,) int64), car b's polyline being ``points[offsets[b]:offsets[b + 1]]``; for compiled
    kernels over a batch."""
    polylines = [np.zeros((0, 2)) if path is None else np.asarray(path, dtype=float) for path in paths]
    points = np.ascontiguousarray(np.concatenate([np.zeros((0, 2)), *polylines]))
    return points, np.concatenate([[0], np.cumsum([len(path) for path in polylines])]).astype(np.int64)


def _check_width(width: float) -> float:
    if not (is_number(width) and math.isfinite(width) and 1.0 <= width <= 3.0):
        raise ValueError(f"vehicle width must be in [1, 3] m, got {width!r}")
    return float(width)


def _gate_cones(gate: Gate) -> np.ndarray:
    n = max(2, int(math.ceil((gate.x_end - gate.x_start) / CONE_SPACING)) + 1)
    xs = np.linspace(gate.x_start, gate.x_end, n)
    return np.concatenate(
        [
            np.column_stack([xs, np.full(n, gate.y_right - CONE_RADIUS)]),
            np.column_stack([xs, np.full(n, gate.y_left + CONE_RADIUS)]),
        ]
    )


def _minimum_jerk(s: np.ndarray) -> np.ndarray:
    """Quintic 0 -> 1 on s in [0, 1] with zero slope and curvature at both ends."""
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


def _difference_operator(n: int, order: int, dx: float) -> sparse.csr_array:
    coefficients = {2: [1.0, -2.0, 1.0], 3: [-1.0, 3.0, -3.0, 1.0]}[order]
    return sparse.diags_array(coefficients, offsets=list(range(order + 1)), shape=(n - order, n)) / dx**order


def _least_curvature_path(
    gates: tuple[Gate, ...],
    vehicle_width: float,
    front_extent: float,
    rear_extent: float,
    margin: float = PATH_MARGIN,
    lead: float = 10.0,
    tail: float = 30.0,
    dx: float = 0.5,
) -> np.ndarray:
    """Driver's line through ``gates``: the CG path y(x) whose largest curvature is least while the
    car's whole body stays inside every lane (with ``margin`` [m] to spare), entering and leaving
    straight on the first lane's centre line; among such paths (peak curvature within 5% of the
    least), the one with the least total |jerk| (smooth steering).

    The body is the rectangle ``front_extent`` ahead of and ``rear_extent`` behind the CG [m],
    ``vehicle_width`` wide, aligned with the path tangent. Its edge crosses the line X = x_e at
    ``y(x_g) + (x_e - x_g) y'(x_g) +/- w / (2 cos psi)``: linear in y, so each (lane-edge point,
    CG position under the body) pair is one linear constraint; 1/cos(psi) is bounded by its
    value at 0.3 rad. Two linear programs (HiGHS) on a ``dx`` grid; y'' ~ curvature."""
    x = np.arange(gates[0].x_start - lead, gates[-1].x_end + tail + dx / 2, dx)
    n = len(x)
    half = vehicle_width / 2 / math.cos(0.3) + margin
    rows, cols, vals, rhs = [], [], [], []
    for gate in gates:
        if gate.width <= 2 * half:
            raise ValueError(f"a vehicle {vehicle_width} m wide does not fit a {gate.width:.2f} m lane")
        for x_edge in np.arange(gate.x_start, gate.x_end + dx / 2, dx):
            for g in np.flatnonzero((x >= x_edge - front_extent) & (x <= x_edge + rear_extent)):
                g = min(max(g, 1), n - 2)
                lever = (x_edge - x[g]) / (2 * dx)  # y(x_e) ~ y_g + lever * (y_{g+1} - y_{g-1})
                for sign, bound in ((-1.0, gate.y_right + half), (1.0, gate.y_left - half)):
                    r = len(rhs)
                    rows += [r, r, r]
                    cols += [g, g + 1, g - 1]
                    vals += [sign, sign * lever, -sign * lever]
                    rhs.append(sign * bound)
    body = sparse.csr_array((vals, (rows, cols)), shape=(len(rhs), n))
    rhs = np.asarray(rhs)
    bounds = [(None, None)] * n
    straight = sparse.csr_array(
        ([1.0, -1.0, 1.0, -1.0, 1.0, -1.0], ([0, 0, 1, 1, 2, 2], [0, 1, 1, 2, n - 1, n - 2])), shape=(3, n)
    )
    entry = sparse.csr_array(([1.0], ([0], [0])), shape=(1, n))
    d2, d3 = _difference_operator(n, 2, dx), _difference_operator(n, 3, dx)
    m2, m3 = d2.shape[0], d3.shape[0]

    # 1: least peak curvature t: minimise t s.t. -t <= D2 y <= t
    column = sparse.csr_array(np.ones((m2, 1)))
    a_ub = sparse.vstack(
        [
            sparse.hstack([d2, -column]),
            sparse.hstack([-d2, -column]),
            sparse.hstack([body, sparse.csr_array((body.shape[0], 1))]),
        ]
    )
    a_eq = sparse.hstack([sparse.vstack([straight, entry]), sparse.csr_array((4, 1))])
    b_eq = np.array([0.0, 0.0, 0.0, gates[0].centre])
    first = linprog(
        np.r_[np.zeros(n), 1.0],
        A_ub=a_ub,
        b_ub=np.r_[np.zeros(2 * m2), rhs],
        A_eq=a_eq,
        b_eq=b_eq,
        bounds=bounds + [(0.0, None)],
        method="highs",
    )
    if first.status != 0:
        raise ValueError(f"no path through the course for a vehicle {vehicle_width} m wide: {first.message}")

    # 2: least total |jerk| s with the peak curvature within 5% of the least:
    #    minimise sum s  s.t. -s <= D3 y <= s, |D2 y| <= peak, body <= rhs
    peak = 1.05 * first.x[-1] + 1e-6
    eye = sparse.identity(m3, format="csr")
    zeros2 = sparse.csr_array((m2, m3))
    a_ub = sparse.vstack(
        [
            sparse.hstack([d3, -eye]),
            sparse.hstack([-d3, -eye]),
            sparse.hstack([d2, zeros2]),
            sparse.hstack([-d2, zeros2]),
            sparse.hstack([body, sparse.csr_array((body.shape[0], m3))]),
        ]
    )
    b_ub = np.r_[np.zeros(2 * m3), np.full(2 * m2, peak), rhs]
    a_eq = sparse.hstack([sparse.vstack([straight, entry]), sparse.csr_array((4, m3))])
    second = linprog(
        np.r_[np.zeros(n), np.full(m3, dx)],
        A_ub=a_ub,
        b_ub=b_ub,
        A_eq=a_eq,
        b_eq=b_eq,
        bounds=bounds + [(0.0, None)] * m3,
        method="highs",
    )
    y = second.x[:n] if second.status == 0 else first.x[:n]
    return np.column_stack([x, y])


def _lane_change(
    name: str,
    lengths: tuple[float, ...],
    widths: tuple[float, float, float],
    lane3_right: float,
    width: float,
    front_extent: float,
    rear_extent: float,
) -> Course:
    x = np.concatenate([[0.0], np.cumsum(lengths)])
    w1, w3, w5 = widths
    gates = (
        Gate(x[0], x[1], -w1 / 2, w1 / 2),
        Gate(x[2], x[3], lane3_right, lane3_right + w3),
        Gate(x[4], x[5], -w1 / 2, -w1 / 2 + w5),
    )
    cones = np.concatenate([_gate_cones(g) for g in gates])
    return Course(name, gates, cones, _least_curvature_path(gates, width, front_extent, rear_extent))


def iso3888_1(width: float, front_extent: float = _CAR.front_extent, rear_extent: float = _CAR.rear_extent) -> Course:
    """ISO 3888-1 double lane change for a vehicle ``width`` [m] wide whose body reaches
    ``front_extent`` ahead of and ``rear_extent`` behind its CG [m] (for the driver's line)."""
    return replace(lane_change(width, front_extent=front_extent, rear_extent=rear_extent), name="iso3888_1")


def lane_change(
    width: float,
    scale: float = 1.0,
    offset: float = 3.5,
    direction: int = 1,
    front_extent: float = _CAR.front_extent,
    rear_extent: float = _CAR.rear_extent,
) -> Course:
    """A double lane change of ISO 3888-1's lane widths with its section lengths times
    ``scale`` and lane 3's right-hand cone row ``offset`` [m] from lane 1's, to the left
    (``direction`` 1) or mirrored to the right (-1): the family the randomised training scenario
    draws its course episodes from (``iso3888_1`` is scale 1, offset 3.5, to the left)."""
    w = _check_width(width)
    if not (math.isfinite(scale) and scale > 0 and math.isfinite(offset) and offset > 0 and direction in (1, -1)):
        raise ValueError(
            f"lane_change needs scale > 0, offset > 0 [m] and direction +-1, got {scale!r}, {offset!r}, {direction!r}"
        )
    w1 = 1.1 * w + 0.25
    course = _lane_change(
        "lane_change",
        tuple(scale * n for n in (15.0, 30.0, 25.0, 25.0, 15.0)),
        (w1, 1.2 * w + 0.25, 1.3 * w + 0.25),
        lane3_right=-w1 / 2 + offset,
        width=w,
        front_extent=front_extent,
        rear_extent=rear_extent,
    )
    if direction == 1:
        return course
    mirror = np.array([1.0, -1.0])
    gates = tuple(Gate(g.x_start, g.x_end, -g.y_left, -g.y_right) for g in course.gates)
    return Course(course.name, gates, course.cones * mirror, course.centreline * mirror)


def iso3888_2(width: float, front_extent: float = _CAR.front_extent, rear_extent: float = _CAR.rear_extent) -> Course:
    """ISO 3888-2 obstacle-avoidance lane change for a vehicle ``width`` [m] wide whose body
    reaches ``front_extent`` ahead of and ``rear_extent`` behind its CG [m]."""
    w = _check_width(width)
    w1 = 1.1 * w + 0.25
    return _lane_change(
        "iso3888_2",
        (12.0, 13.5, 11.0, 12.5, 12.0),
        (w1, w + 1.0, max(1.3 * w + 0.25, 3.0)),
        lane3_right=w1 / 2 + 1.0,
        width=w,
        front_extent=front_extent,
        rear_extent=rear_extent,
    )


def slalom(spacing: float, amplitude: float, n_cones: int) -> Course:
    """``n_cones`` cones on Y = 0 every ``spacing`` [m] from X = 0; the centreline passes them
    alternately at +/-``amplitude`` [m] (a cosine), faded in over the spacing before the first
    cone and out over the spacing after the last."""
    for name, value in (("spacing", spacing), ("amplitude", amplitude)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"slalom {name} must be a finite number > 0, got {value!r}")
    if not (is_integer(n_cones) and n_cones >= 2):
        raise ValueError(f"slalom n_cones must be a whole number >= 2, got {n_cones!r}")
    last = (n_cones - 1) * spacing
    x = np.arange(-spacing, last + 2 * spacing + 0.125, 0.25)
    fade = _minimum_jerk((x + spacing) / spacing) * _minimum_jerk((last + spacing - x) / spacing)
    y = amplitude * np.cos(math.pi * x / spacing) * fade
    cones = np.column_stack([np.arange(n_cones) * spacing, np.zeros(n_cones)])
    return Course("slalom", (), cones, np.column_stack([x, y]))
