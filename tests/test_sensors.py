"""Sensors: seeded noise and bias, fault injection exactly where configured, bad input."""

import math
import re

import numpy as np
import pytest

from fourwis.core.types import CHANNELS
from fourwis.envs.sensors import SENSORS, Fault, SensorModel, SensorParams
from fourwis.envs.simulation import DT


def run(faults=(), seed=0, n=2000, batch=2, params=SensorParams()):
    """n readings of a constant truth: values and valid (n, batch, 17) per sensor, the truth, the model."""
    model = SensorModel(params, tuple(faults), batch, np.random.default_rng(seed))
    truth = np.tile(np.linspace(1.0, 17.0, len(SENSORS)), (batch, 1))
    readings = [model.read(truth, k * DT) for k in range(n)]
    values = np.stack([r.values for r in readings])
    valid = np.stack([r.valid for r in readings])
    return values, valid, truth, model


def test_the_cars_sensors_fill_the_channel_layout():
    """Each axle's one steer sensor fills both its wheels' channels; each wheel's torque channel is
    its motor torque less the brake gain times its brake pressure, invalid while the pressure
    sensor is out; the car has no forward-speed sensor, whose channel is NaN and invalid; every
    other channel is its sensor's reading."""
    faults = (Fault("delta_f", "dropout", start=0.0, end=1.0), Fault("brake_rr", "dropout", start=0.0, end=1.0))
    gain = 2.0e-4
    model = SensorModel(SensorParams().scaled(0.0), faults, 1, np.random.default_rng(0), brake_gain=gain)
    truth = np.linspace(1.0, 17.0, len(SENSORS))
    truth[-4:] = [1e5, 2e5, 3e5, 4e5]  # brake pressures [Pa]
    reading = model.measure(truth[None], 0.0)
    assert reading.values.shape == reading.valid.shape == (1, len(CHANNELS)) == (1, 16)
    row, ok = reading.values[0], reading.valid[0]
    for name in SENSORS:
        if not name.startswith(("delta_", "torque_", "brake_")):
            assert row[CHANNELS.index(name)] == 1.0 + SENSORS.index(name), name
    for wheel in ("fl", "fr", "rl", "rr"):
        motor = truth[SENSORS.index(f"torque_{wheel}")]
        # (the rr pressure is held at 0: never valid yet)
        held = 0.0 if wheel == "rr" else truth[SENSORS.index(f"brake_{wheel}")]
        assert row[CHANNELS.index(f"torque_{wheel}")] == pytest.approx(motor - gain * held, abs=1e-12)
        assert ok[CHANNELS.index(f"torque_{wheel}")] == (wheel != "rr")
    assert row[CHANNELS.index("delta_fl")] == row[CHANNELS.index("delta_fr")] == 0.0  # (held: never valid yet)
    assert row[CHANNELS.index("delta_rl")] == row[CHANNELS.index("delta_rr")] == 9.0
    assert np.isnan(row[CHANNELS.index("speed")]) and not ok[CHANNELS.index("speed")]
    assert not ok[CHANNELS.index("delta_fl")] and not ok[CHANNELS.index("delta_fr")]  # (the front sensor is out)
    assert ok[CHANNELS.index("delta_rl")] and ok[CHANNELS.index("ax")]


def test_same_seed_same_stream_different_seed_different_stream():
    a, _, _, _ = run(seed=5)
    b, _, _, _ = run(seed=5)
    c, _, _, _ = run(seed=6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_a_reading_is_truth_plus_bias_plus_the_vehicles_own_draws_across_block_refills():
    """One car's stream, redrawn from its generator: for the 13 sensors other than the brake
    pressures a bias draw, then blocks of NOISE_BLOCK normal and uniform draws (the stream the car
    had before it had brake sensors); for the brake pressures the same from the generator jumped
    ahead. The compiled noise step must follow both sample for sample."""
    from fourwis.envs.sensors import NOISE_BLOCK, S_BRAKE_SENSOR

    params = SensorParams()
    n = 2 * NOISE_BLOCK + 10
    values, _, truth, _ = run(seed=11, n=n, batch=1, params=params)
    rng = np.random.default_rng(11)
    brakes = np.random.Generator(rng.bit_generator.jumped())
    first = slice(0, S_BRAKE_SENSOR)
    assert S_BRAKE_SENSOR == 13 and len(SENSORS) == 17
    bias = np.concatenate([rng.standard_normal(13), brakes.standard_normal(4)]) * np.array(params.bias_std)
    normal = []
    for _ in range(3):
        block = rng.standard_normal((NOISE_BLOCK, 13))
        rng.random((NOISE_BLOCK, 2))
        normal.append(np.column_stack([block, brakes.standard_normal((NOISE_BLOCK, 4))]))
    expected = truth[0] + bias + np.concatenate(normal)[:n] * np.array(params.noise_std)
    np.testing.assert_array_equal(values[:, 0, first], expected[:, first])
    np.testing.assert_array_equal(values[:, 0], expected)


def test_a_released_brakes_pressure_noise_stays_out_of_the_net_torque():
    """Below the released-brake pressure a pressure reading adds no brake torque: with the brakes
    released the torque channels read the motor torque sensors exactly; applied, the net torque."""
    from fourwis.envs.sensors import BRAKE_RELEASED_PRESSURE

    gain = 2.0e-4
    model = SensorModel(SensorParams(), (), 1, np.random.default_rng(3), brake_gain=gain)
    torque, brake = slice(SENSORS.index("torque_fl"), SENSORS.index("torque_fl") + 4), slice(-4, None)
    channels = slice(CHANNELS.index("torque_fl"), CHANNELS.index("torque_fl") + 4)
    for k in range(3000):  # a released brake: true pressure 0, its readings noise and bias
        truth = np.full((1, len(SENSORS)), 50.0)
        truth[0, brake] = 0.0
        sensed = model.read(truth, k * DT)
        assert np.all(np.abs(sensed.values[0, brake]) < BRAKE_RELEASED_PRESSURE)
        np.testing.assert_array_equal(model.channels(sensed, k * DT).values[0, channels], sensed.values[0, torque])
    truth[0, brake] = 3.0e6  # applied: 30 bar
    sensed = model.read(truth, 1.0)
    np.testing.assert_allclose(
        model.channels(sensed, 1.0).values[0, channels], sensed.values[0, torque] - gain * sensed.values[0, brake]
    )


def test_noise_and_bias_have_the_configured_statistics():
    params = SensorParams()
    values, valid, truth, model = run(n=20000, batch=1)
    error = values[:, 0, :] - truth[0]
    np.testing.assert_allclose(error.std(axis=0), params.noise_std, rtol=0.05)
    # the mean error is the run's drawn turn-on bias, up to each channel's own standard error
    # (4 sigma), and the bias is there: over the channels with a bias std, the mean errors in
    # standard errors, squared and summed, lie far beyond chi-square's 99.99% point for no bias
    # (35.9 for 11 channels; a single channel's draw can fall near zero)
    noise_std, bias_std = np.asarray(params.noise_std), np.asarray(params.bias_std)
    standard_error = noise_std / math.sqrt(20000)
    assert np.all(np.abs(error.mean(axis=0) - model.bias[0]) <= 4 * standard_error)
    assert np.all(model.bias[0][bias_std == 0.0] == 0.0)
    biased = bias_std > 0.0
    assert biased.sum() == 11
    assert np.sum((error.mean(axis=0)[biased] / standard_error[biased]) ** 2) > 10 * 35.9
    assert valid.all()
    # the turn-on biases across 4,000 cars: N(0, bias_std) per channel (standard error of a
    # standard deviation from 4,000 draws: 1.1%; of the mean: bias_std / sqrt(4000))
    fleet = SensorModel(params, (), 4000, np.random.default_rng(1)).bias
    biased = bias_std > 0.0
    np.testing.assert_allclose(fleet.std(axis=0)[biased], bias_std[biased], rtol=0.05)
    assert np.all(np.abs(fleet.mean(axis=0)) <= 5 * bias_std / math.sqrt(4000))
    assert np.all(fleet[:, ~biased] == 0.0)


def test_perfect_sensors_read_the_truth():
    values, _, truth, _ = run(params=SensorParams().scaled(0.0), n=50)
    np.testing.assert_array_equal(values, np.broadcast_to(truth, values.shape))


def test_faults_appear_exactly_where_configured():
    faults = (
        Fault("yaw_rate", "spike", start=1.0, end=2.0, magnitude=1.0, rate=50.0),
        Fault("ay", "dropout", start=0.5, end=0.8),
        Fault("omega_fl", "stuck", start=3.0),
        Fault("ax", "bias_step", start=2.0, end=2.5, magnitude=0.7),
    )
    values, valid, truth, _ = run(faults, params=SensorParams().scaled(0.0), n=2000)
    t = np.arange(2000) * DT
    r = values[:, :, SENSORS.index("yaw_rate")] - truth[0, SENSORS.index("yaw_rate")]
    spikes = np.abs(r) > 0.5
    assert spikes.any() and np.all((t[spikes.any(axis=1)] >= 1.0) & (t[spikes.any(axis=1)] < 2.0))
    assert spikes.sum() == pytest.approx(50.0 * 1.0 * 2, rel=0.4)  # Poisson, 50/s over 1 s, 2 cars
    iy = SENSORS.index("ay")
    window = (t >= 0.5) & (t < 0.8)
    assert not valid[window, :, iy].any() and valid[~window, :, iy].all()
    assert np.isfinite(values).all()
    ax_error = values[:, 0, 0] - truth[0, 0]
    np.testing.assert_allclose(ax_error[(t >= 2.0) & (t < 2.5)], 0.7)
    np.testing.assert_allclose(ax_error[(t < 2.0) | (t >= 2.5)], 0.0)


def test_spike_faults_on_two_channels_arrive_independently():
    """Each spike fault draws its own Poisson arrivals and signs: on two channels at 20/s each
    (p = 0.04 per sample) about p^2 of the samples carry both, not every spike of either."""
    faults = (Fault("ax", "spike", magnitude=5.0, rate=20.0), Fault("yaw_rate", "spike", magnitude=1.0, rate=20.0))
    values, _, truth, _ = run(faults, params=SensorParams().scaled(0.0), n=5000)
    ax = np.abs(values[..., SENSORS.index("ax")] - truth[:, SENSORS.index("ax")]) > 1.0
    gyro = np.abs(values[..., SENSORS.index("yaw_rate")] - truth[:, SENSORS.index("yaw_rate")]) > 0.5
    assert ax.sum() == pytest.approx(0.04 * ax.size, rel=0.2) and gyro.sum() == pytest.approx(0.04 * gyro.size, rel=0.2)
    assert (ax & gyro).sum() < 4 * 0.04**2 * ax.size  # ~16 expected in 10,000 samples; 400 if they were shared


def test_a_dropout_holds_the_last_valid_reading_and_ends_with_a_fresh_one():
    """A noisy sensor on a moving truth: inside the window every sample repeats the last reading
    before it (flagged invalid), and the first sample after it reads the truth again."""
    model = SensorModel(SensorParams(), (Fault("ay", "dropout", start=0.1, end=0.2),), 1, np.random.default_rng(0))
    i = CHANNELS.index("ay")
    readings = [model.measure(np.full((1, len(SENSORS)), float(k)), k * DT) for k in range(150)]
    values = np.array([r.values[0, i] for r in readings])
    valid = np.array([r.valid[0, i] for r in readings])
    assert not valid[50:100].any() and valid[:50].all() and valid[100:].all()
    assert np.all(values[50:100] == values[49]) and values[49] == pytest.approx(49.0, abs=0.2)
    assert values[100] == pytest.approx(100.0, abs=0.2)


def test_stuck_sensor_freezes_while_the_truth_moves():
    model = SensorModel(SensorParams(), (Fault("omega_fl", "stuck", start=0.1, end=0.2),), 1, np.random.default_rng(0))
    i = CHANNELS.index("omega_fl")
    out = []
    for k in range(150):
        truth = np.full((1, len(SENSORS)), float(k))
        out.append(model.measure(truth, k * DT).values[0, i])
    out = np.array(out)
    frozen = out[50:100]
    assert np.all(frozen == frozen[0])
    assert frozen[0] == pytest.approx(
        50.0, abs=4 * SensorParams().noise_std[SENSORS.index("omega_fl")]
    )  # the reading at the window start
    assert abs(out[120] - 120.0) < 1.0


@pytest.mark.parametrize(
    "kwargs, bad",
    [
        ({"channel": "speedometer", "kind": "spike"}, "speedometer"),
        ({"channel": "ax", "kind": "melt"}, "melt"),
        ({"channel": "ax", "kind": "bias_step", "start": 2.0, "end": 1.0}, "1.0"),
        ({"channel": "ax", "kind": "spike", "rate": 0.0, "magnitude": 1.0}, "rate"),
    ],
)
def test_bad_faults_raise(kwargs, bad):
    with pytest.raises(ValueError, match=bad):
        Fault(**kwargs)


def test_faults_other_than_fault_objects_are_refused():
    with pytest.raises(ValueError, match="'x'"):
        SensorModel(SensorParams(), ("x",), 1, np.random.default_rng(0))


def test_bad_truth_raises_naming_the_channel():
    model = SensorModel(SensorParams(), (), 1, np.random.default_rng(0))
    truth = np.zeros((1, len(SENSORS)))
    truth[0, 2] = np.nan
    with pytest.raises(ValueError, match="yaw_rate"):
        model.measure(truth, 0.0)
    with pytest.raises(ValueError, match="shape"):
        model.measure(np.zeros((2, len(SENSORS))), 0.0)
    with pytest.raises(ValueError, match=r"noise_std must be 17 .*, got \[1. 1. 1. 1. 1. 1. 1. 1. 1. 1. 1. 1.\]"):
        SensorParams(noise_std=(1.0,) * 12)


@pytest.mark.parametrize("members", [[7], [2], [-1], [0, 0]])
def test_bad_members_raise_instead_of_reading_outside_the_batch(members):
    model = SensorModel(SensorParams(), (), 2, np.random.default_rng(0))
    before = model._cursor.copy()
    with pytest.raises(ValueError, match=f"members must be .*, got {re.escape(str(members))}"):
        model.measure(np.zeros((len(members), len(SENSORS))), 0.0, members)
    np.testing.assert_array_equal(model._cursor, before)  # no stream advanced
