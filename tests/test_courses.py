"""Cone courses: the standards' dimensions and a driver's line that fits the car."""

import numpy as np
import pytest

from fourwis.envs.courses import CONE_RADIUS, iso3888_1, iso3888_2, lane_change, slalom

WIDTH = 1.60  # the paper car's body width [m]


def test_iso3888_2_gates_match_the_standard_for_this_car():
    g1, g3, g5 = iso3888_2(WIDTH).gates
    assert (
        g1.x_end - g1.x_start,
        g3.x_start - g1.x_end,
        g3.x_end - g3.x_start,
        g5.x_start - g3.x_end,
        g5.x_end - g5.x_start,
    ) == pytest.approx((12.0, 13.5, 11.0, 12.5, 12.0))
    assert g1.width == pytest.approx(1.1 * WIDTH + 0.25)
    assert g3.width == pytest.approx(WIDTH + 1.0)
    assert g5.width == pytest.approx(3.0)  # 1.3 w + 0.25 = 2.33 m, but at least 3 m
    assert g3.y_right - g1.y_left == pytest.approx(1.0)  # lane 3 starts 1 m beyond lane 1's edge
    assert g5.y_right == pytest.approx(g1.y_right)


def test_iso3888_2_lane5_width_grows_with_a_wide_car():
    assert iso3888_2(2.5).gates[2].width == pytest.approx(1.3 * 2.5 + 0.25)


def test_iso3888_1_gates_match_the_standard_for_this_car():
    g1, g3, g5 = iso3888_1(WIDTH).gates
    assert (g1.x_end, g3.x_start, g3.x_end, g5.x_start, g5.x_end) == pytest.approx((15.0, 45.0, 70.0, 95.0, 110.0))
    assert (g1.width, g3.width, g5.width) == pytest.approx((1.1 * WIDTH + 0.25, 1.2 * WIDTH + 0.25, 1.3 * WIDTH + 0.25))
    assert g3.y_right - g1.y_right == pytest.approx(3.5)


@pytest.mark.parametrize(
    "course", [iso3888_1(WIDTH), iso3888_2(WIDTH), lane_change(WIDTH, 0.8, 1.5, -1), lane_change(WIDTH, 2.0, 3.5, 1)]
)
def test_drivers_line_keeps_the_body_inside_every_lane(course):
    x, y = course.centreline.T
    psi = np.arctan(np.gradient(y, x))
    front, rear, half = 1.77, 1.67, WIDTH / 2
    for gate in course.gates:
        for s in np.linspace(-rear, front, 8):  # points along the body's sides
            for side in (-1.0, 1.0):
                px = x + s * np.cos(psi) - side * half * np.sin(psi)
                py = y + s * np.sin(psi) + side * half * np.cos(psi)
                inside = (px >= gate.x_start) & (px <= gate.x_end)
                assert np.all(py[inside] >= gate.y_right - 1e-6) and np.all(py[inside] <= gate.y_left + 1e-6)


def test_a_lane_change_scales_its_sections_shifts_its_lane_and_mirrors():
    """lane_change: ISO 3888-1 at scale 1 and offset 3.5; the sections stretch with ``scale``,
    lane 3's right-hand row sits ``offset`` from lane 1's, and direction -1 mirrors everything."""
    iso, same = iso3888_1(WIDTH), lane_change(WIDTH)
    assert iso.gates == same.gates and np.array_equal(iso.centreline, same.centreline)
    left, right = lane_change(WIDTH, 1.5, 2.5, 1), lane_change(WIDTH, 1.5, 2.5, -1)

    def extent(course):
        return course.gates[-1].x_end - course.gates[0].x_start

    assert extent(left) == pytest.approx(1.5 * extent(iso))
    assert left.gates[1].y_right - left.gates[0].y_right == pytest.approx(2.5)
    np.testing.assert_array_equal(right.centreline, left.centreline * [1.0, -1.0])
    np.testing.assert_array_equal(right.cones, left.cones * [1.0, -1.0])
    assert [(g.y_right, g.y_left) for g in right.gates] == [(-g.y_left, -g.y_right) for g in left.gates]


def test_drivers_line_enters_and_leaves_straight():
    line = iso3888_2(WIDTH).centreline
    slope = np.gradient(line[:, 1], line[:, 0])
    assert abs(slope[0]) < 1e-9 and abs(slope[-1]) < 1e-9 and abs(line[0, 1]) < 1e-9


def test_cones_stand_just_outside_the_lane_edges():
    course = iso3888_2(WIDTH)
    g1 = course.gates[0]
    first_lane = course.cones[(course.cones[:, 0] >= g1.x_start) & (course.cones[:, 0] <= g1.x_end)]
    np.testing.assert_allclose(
        np.sort(np.unique(first_lane[:, 1])), [g1.y_right - CONE_RADIUS, g1.y_left + CONE_RADIUS]
    )


def test_slalom_line_passes_cones_alternately_at_the_amplitude():
    course = slalom(18.0, 1.5, 6)
    x, y = course.centreline.T
    at_cones = np.interp(course.cones[:, 0], x, y)
    np.testing.assert_allclose(at_cones, 1.5 * (-1.0) ** np.arange(6), atol=1e-9)


@pytest.mark.parametrize(
    "call, bad",
    [
        (lambda: iso3888_2(float("nan")), "nan"),
        (lambda: iso3888_1(0.2), "0.2"),
        (lambda: slalom(-3.0, 1.0, 5), "-3.0"),
        (lambda: slalom(18.0, 1.0, 1), "n_cones must be a whole number >= 2, got 1"),
        (lambda: lane_change(WIDTH, direction=0), "direction"),
        (lambda: lane_change(WIDTH, offset=-1.0), "-1.0"),
    ],
)
def test_bad_course_arguments_raise(call, bad):
    with pytest.raises(ValueError, match=bad):
        call()
