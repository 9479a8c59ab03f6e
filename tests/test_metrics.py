"""FMVSS 126 and ISO 3888 metrics on synthetic signals with known answers, and the SWD series."""

import math

import numpy as np
import pytest

from envs.fmvss126 import amplitudes, characterise, run_series
from envs.metrics import (cone_hits, mae, path_deviation, phaseless_butterworth, rmse, sine_with_dwell_metrics,
                          spin_out, steering_angle_at_lateral_acceleration)

FS = 500.0
T = np.arange(0.0, 6.0, 1 / FS)
START = 1.0
F = 0.7


def swd(amplitude, t=T, start=START):
    """Exact FMVSS 126 profile: sine to the 2nd peak, 0.5 s dwell, last quarter."""
    tau = t - start
    s = amplitude * np.sin(2 * np.pi * F * tau)
    dwell = (tau >= 0.75 / F) & (tau < 0.75 / F + 0.5)
    s[dwell] = -amplitude
    late = tau >= 0.75 / F + 0.5
    s[late] = amplitude * np.sin(2 * np.pi * F * (tau[late] - 0.5))
    s[(tau < 0) | (tau >= 1 / F + 0.5)] = 0.0
    return s


def test_phaseless_filter_has_no_delay_and_half_gain_at_cutoff():
    t = np.arange(0, 20, 1 / FS)
    slow = np.sin(2 * np.pi * 1.0 * t)
    np.testing.assert_allclose(phaseless_butterworth(slow, FS, 6.0)[2000:-2000], slow[2000:-2000], atol=1e-3)
    at_cut = phaseless_butterworth(np.sin(2 * np.pi * 6.0 * t), FS, 6.0)[2000:-2000]
    assert np.abs(at_cut).max() == pytest.approx(0.5, abs=0.01)  # |H|^2 of the one-way filter


@pytest.mark.parametrize("amplitude_deg", [180.0, 20.0])
def test_bos_and_cos_match_the_analytic_times(amplitude_deg):
    a = math.radians(amplitude_deg)
    steer = swd(a)
    r = np.zeros_like(T)
    res = sine_with_dwell_metrics(T, steer, r + 1e-3 * steer, np.zeros_like(T))
    assert res.bos_time == pytest.approx(START + math.asin(5.0 / amplitude_deg) / (2 * np.pi * F), abs=0.01)
    assert res.cos_time == pytest.approx(START + 1.9286, abs=0.02)
    assert res.steering_amplitude == pytest.approx(a, rel=0.01)


def test_yaw_ratios_follow_the_signal():
    steer = swd(math.radians(150.0))
    # yaw rate: dwell-side peak then an exponential decay from COS with a 0.5 s time constant
    cos = START + 1.9286
    r = -0.5 * np.sin(np.pi * np.clip((T - START - 0.714) / 1.2, 0, 1))
    r = np.where(T > cos, r[np.searchsorted(T, cos)] * np.exp(-(T - cos) / 0.5), r)
    res = sine_with_dwell_metrics(T, steer, r, np.zeros_like(T))
    peak = np.abs(r).max()
    assert res.first_peak_yaw_rate == pytest.approx(peak, rel=0.02)
    expected = abs(r[np.searchsorted(T, cos)]) * np.exp(-1.0 / 0.5) / peak
    assert res.yaw_rate_ratio_1000 == pytest.approx(expected, abs=0.02)
    assert res.passed_yaw == (res.yaw_rate_ratio_1000 <= 0.35 and res.yaw_rate_ratio_1750 <= 0.20)


def test_lateral_displacement_is_the_double_integral_from_bos():
    steer = swd(math.radians(150.0))
    a0 = 4.0
    res0 = sine_with_dwell_metrics(T, steer, 1e-3 * steer, np.zeros_like(T))
    ay = np.where(T >= res0.bos_time, a0, 0.0)
    res = sine_with_dwell_metrics(T, steer, 1e-3 * steer, ay)
    # the 6 Hz filter smears the step symmetrically; the double integral is ~0.5 a0 1.07^2
    assert res.lateral_displacement == pytest.approx(0.5 * a0 * 1.07**2, rel=0.03)


def test_mirror_symmetry():
    steer = swd(math.radians(120.0))
    r = -0.3 * np.sin(np.pi * np.clip((T - START) / 2.5, 0, 1)) + 0.1 * np.sin(3 * T) * (T > START)
    ay = 3.0 * np.sin(np.pi * np.clip((T - START) / 1.5, 0, 1))
    a = sine_with_dwell_metrics(T, steer, r, ay)
    b = sine_with_dwell_metrics(T, -steer, -r, -ay)
    assert a.yaw_rate_ratio_1000 == pytest.approx(b.yaw_rate_ratio_1000, abs=1e-12)
    assert a.lateral_displacement == pytest.approx(b.lateral_displacement, abs=1e-12)


def test_A_is_recovered_from_a_linear_ramp():
    t = np.arange(0, 10, 1 / FS)
    steer = np.radians(13.5) * np.clip(t - 1.0, 0, None)
    gain = 9.80665 * 0.3 / math.radians(20.0)  # 0.3 g at 20 deg
    assert math.degrees(steering_angle_at_lateral_acceleration(t, steer, gain * steer)) == pytest.approx(20.0, rel=1e-3)


def test_path_deviation_of_a_parallel_line_is_the_offset():
    path = np.column_stack([np.linspace(0, 100, 11), np.zeros(11)])
    x = np.linspace(5, 95, 50)
    rms_dev, max_dev = path_deviation(x, np.full(50, 0.7), path)
    assert rms_dev == pytest.approx(0.7) and max_dev == pytest.approx(0.7)


def test_cone_hits():
    x = np.linspace(-10, 10, 400)
    gate = np.array([[0.0, 1.2], [0.0, -1.2]])
    assert cone_hits(x, np.zeros_like(x), np.zeros_like(x), gate, 1.6, 1.8, 1.7) == 0
    assert cone_hits(x, np.full_like(x, 0.9), np.zeros_like(x), gate, 1.6, 1.8, 1.7) == 1


def test_generic_metrics_and_bad_input():
    assert rmse(np.array([1.0, 3.0]), np.array([0.0, 0.0])) == pytest.approx(math.sqrt(5))
    assert mae(np.array([1.0, -3.0]), np.array([0.0, 0.0])) == pytest.approx(2.0)
    assert spin_out(np.radians([0, 5, 25])) and not spin_out(np.radians([0, 5, 15]))
    with pytest.raises(ValueError, match="NaN"):
        rmse(np.array([np.nan, 1.0]), np.zeros(2))
    with pytest.raises(ValueError, match="samples"):
        sine_with_dwell_metrics(T, swd(1.0), np.zeros(10), np.zeros_like(T))
    with pytest.raises(ValueError, match="uniformly"):
        sine_with_dwell_metrics(np.r_[T[:-1], T[-1] + 1], swd(1.0), np.zeros_like(T), np.zeros_like(T))


def test_amplitude_series_follows_the_regulation():
    A = math.radians(16.0)
    series = np.degrees(amplitudes(A))
    assert series[0] == pytest.approx(24.0) and np.allclose(np.diff(series)[:-1], 8.0)
    assert series[-1] == pytest.approx(270.0) and series.max() <= 300.0
    big = np.degrees(amplitudes(math.radians(50.0)))  # 6.5A = 325 deg: capped at 300
    assert big[-1] == pytest.approx(300.0)


def test_uncontrolled_car_is_characterised_and_fails_the_yaw_criterion_on_dry_road():
    A = characterise()
    # neutral steer at 0.3 g would need 12.8 deg; load transfer and tyre lag add a little
    assert 10.0 < math.degrees(A) < 25.0
    left, right = run_series(A, mu=1.0, amplitude_list=np.array([5.5 * A]))
    assert not left.result.passed_yaw and left.result.spun_out
    assert left.result.yaw_rate_ratio_1000 == pytest.approx(right.result.yaw_rate_ratio_1000, abs=1e-6)
