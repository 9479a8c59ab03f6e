"""Recorded logs: the format (docs/logs.md), reading it from CSV, Parquet and MATLAB files,
writing it, and the logs fourwis ships.

A log is a table of samples: a time column ``t`` and named channels, each with its unit. In a
CSV file (optionally gzip-compressed, ``.csv.gz``) the header row names every column
``name [unit]``, e.g. ``yaw_rate [deg/s]``; lines before it that start with ``#`` hold
metadata, ``# key: value``. A Parquet file's columns are named the same way (its key-value
metadata ``fourwis`` may hold the metadata as a JSON object); a MATLAB (v5-v7) file holds one
numeric vector per channel, named by the channel, and a struct ``units`` with a unit string
per channel (and optionally a struct ``metadata``). An empty field or NaN is a sample a sensor
did not deliver: a measurement is then skipped, an input holds its last value; a run of them
longer than ``max_missing`` seconds (MAX_MISSING) is an error, as is one in the first row of an input.

Channels (:data:`SCHEMA`): required are ``ax``, ``ay``, ``yaw_rate``; a speed source (the four
``wheel_speed_*``, or ``speed``, a measured forward speed at the CG); a steering source
(``steer_fl`` and ``steer_fr``, the front road-wheel angles; or ``steer``, one road-wheel angle,
each wheel's then from the vehicle's Ackermann geometry; or ``handwheel``, the steering-wheel
angle over the vehicle's steering ratio). Optional: rear steer (``steer_rl`` and ``steer_rr``,
or ``steer_rear``), per-wheel drive torques ``torque_*``, brake pressures ``brake_pressure_*``
(or one ``brake_pressure`` for all four) times the vehicle's brake gains, ``engine_torque``
with ``gear_ratio`` (or ``gear`` and the vehicle's ratios). Reference channels, which score the
estimators and never reach them: ``ref_vx``, ``ref_vy``, ``ref_beta``, ``ref_yaw_rate``,
``ref_mu`` (or ``ref_mu_*`` per wheel). Other columns are ignored (and listed in the report).
Metadata keys fourwis reads: ``name``, ``description``, ``source``, ``license``, ``vehicle``
(a vehicle file, relative to the log), ``initial_speed`` [m/s] (where the estimators start).
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import math
import re
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from fourwis.core.constants import GRAVITY
from fourwis.training.io import atomic_write

WHEELS = ("fl", "fr", "rl", "rr")
DEG = math.pi / 180.0
#: the units each kind of quantity accepts, and the factor to SI
UNITS = {
    "time": {"s": 1.0, "ms": 1e-3},
    "acceleration": {"m/s^2": 1.0, "m/s2": 1.0, "g": GRAVITY},
    "angular_rate": {"rad/s": 1.0, "deg/s": DEG},
    "angle": {"rad": 1.0, "deg": DEG},
    "speed": {"m/s": 1.0, "km/h": 1.0 / 3.6},
    # a wheel's angular speed, or its linear speed at the wheel centre (R omega: m/s, km/h)
    "wheel_speed": {"rad/s": 1.0, "rpm": 2.0 * math.pi / 60.0, "m/s": 1.0, "km/h": 1.0 / 3.6},
    "torque": {"N m": 1.0, "Nm": 1.0, "kN m": 1e3},
    "pressure": {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "bar": 1e5},
    "dimensionless": {"-": 1.0, "1": 1.0},
}
LINEAR_WHEEL_SPEED = ("m/s", "km/h")  #: wheel-speed units of a linear speed (the replay divides by the radius)


def _wheeled(stem: str, kind: str, what: str) -> dict[str, tuple[str, str]]:
    return {f"{stem}_{w}": (kind, f"{what}, {w.upper()}") for w in WHEELS}


#: every channel of the format: name -> (kind of quantity, what it is)
SCHEMA: dict[str, tuple[str, str]] = {
    "t": ("time", "sample time, strictly increasing"),
    "ax": ("acceleration", "longitudinal accelerometer (specific force, body x)"),
    "ay": ("acceleration", "lateral accelerometer (specific force, body y, left positive)"),
    "yaw_rate": ("angular_rate", "gyro yaw rate (counter-clockwise positive)"),
    "speed": ("speed", "measured forward speed at the CG (GNSS-aided INS, optical sensor)"),
    **_wheeled("wheel_speed", "wheel_speed", "wheel speed"),
    **_wheeled("steer", "angle", "road-wheel steer angle (left positive)"),
    "steer": ("angle", "one front road-wheel angle (each wheel's from the Ackermann geometry)"),
    "steer_rear": ("angle", "one rear road-wheel angle (both rear wheels)"),
    "handwheel": ("angle", "steering-wheel angle (over the vehicle's steering ratio)"),
    **_wheeled("torque", "torque", "drive torque at the wheel"),
    **_wheeled("brake_pressure", "pressure", "brake pressure"),
    "brake_pressure": ("pressure", "brake pressure of all four wheels"),
    "engine_torque": ("torque", "engine torque (times the overall gear ratio to the driven wheels)"),
    "gear_ratio": ("dimensionless", "overall ratio engine to driven wheels"),
    "gear": ("dimensionless", "engaged gear (1, 2, ...; the vehicle file's gear_ratios)"),
    "ref_vx": ("speed", "reference forward speed at the CG"),
    "ref_vy": ("speed", "reference lateral speed at the CG"),
    "ref_beta": ("angle", "reference sideslip at the CG"),
    "ref_yaw_rate": ("angular_rate", "reference yaw rate"),
    "ref_mu": ("dimensionless", "reference road friction (all wheels)"),
    **_wheeled("ref_mu", "dimensionless", "reference road friction"),
}
#: channels whose missing samples hold the last value (the estimators' model inputs)
INPUTS = tuple(
    name
    for name in SCHEMA
    if name.startswith(("wheel_speed_", "steer", "torque_", "brake_pressure"))
    or name in ("handwheel", "engine_torque", "gear_ratio", "gear")
)
#: groups that come whole or not at all
GROUPS = {
    "wheel_speed": tuple(f"wheel_speed_{w}" for w in WHEELS),
    "front steer": ("steer_fl", "steer_fr"),
    "rear steer": ("steer_rl", "steer_rr"),
    "torque": tuple(f"torque_{w}" for w in WHEELS),
    "brake_pressure": tuple(f"brake_pressure_{w}" for w in WHEELS),
    "ref_mu": tuple(f"ref_mu_{w}" for w in WHEELS),
}
MAX_MISSING = 0.5  #: [s] the longest run of missing samples a channel may have (a sensor out for longer: an error)
_HEADER = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*\[([^\]]*)\]\s*$")


@dataclass(frozen=True)
class Log:
    """A recorded log in SI units: times ``t`` (T,) [s]; ``channels`` name -> (T,) of the
    :data:`SCHEMA` channels it has (NaN: a sample not delivered); the ``units`` it gave each;
    its ``metadata``; where it came from; the columns it had that the format does not know."""

    name: str
    t: np.ndarray
    channels: dict[str, np.ndarray]
    units: dict[str, str]
    metadata: dict[str, str] = field(default_factory=dict)
    source: str = ""
    ignored: tuple[str, ...] = ()

    def __contains__(self, name: str) -> bool:
        return name in self.channels

    def __getitem__(self, name: str) -> np.ndarray:
        return self.channels[name]

    @property
    def duration(self) -> float:
        """[s] from the first sample to the last."""
        return float(self.t[-1] - self.t[0])

    def linear_wheel_speed(self) -> bool:
        """Whether the wheel speeds are linear speeds at the wheel centre (m/s, km/h), not rad/s."""
        return self.units.get("wheel_speed_fl") in LINEAR_WHEEL_SPEED

    def part(self, start: int, stop: int) -> Log:
        """Samples [start, stop) as a log of their own."""
        return Log(
            self.name,
            self.t[start:stop],
            {k: v[start:stop] for k, v in self.channels.items()},
            self.units,
            self.metadata,
            self.source,
            self.ignored,
        )


# ---- reading -------------------------------------------------------------------------------
def _columns(names: list[str], path) -> list[tuple[str, str]]:
    """(channel, unit) of each header ``name [unit]`` (ValueError naming a header without a unit)."""
    out = []
    for name in names:
        match = _HEADER.match(name)
        if not match:
            raise ValueError(
                f"log {path}: column {name.strip()!r} has no unit: head every column 'name [unit]', e.g. 'ax [m/s^2]'"
            )
        out.append((match.group(1), match.group(2).strip()))
    return out


def _read_csv(path: Path) -> tuple[dict, dict, dict, int]:
    """Columns (name -> unit, name -> values), metadata and the number of lines before the first data row."""
    opener = gzip.open if path.suffix == ".gz" else open
    try:
        with opener(path, "rt", encoding="utf-8", newline="") as handle:
            text = handle.read()
    except (OSError, UnicodeDecodeError, EOFError) as err:
        raise ValueError(f"log {path}: cannot be read ({err})") from None
    lines = text.splitlines()
    metadata, k = {}, 0
    while k < len(lines) and (lines[k].startswith("#") or not lines[k].strip()):
        key, sep, value = lines[k].lstrip("#").partition(":")
        if sep and key.strip():
            metadata[key.strip()] = value.strip()
        k += 1
    if k == len(lines):
        raise ValueError(f"log {path}: no header row (columns 'name [unit]')")
    rows = list(csv.reader(lines[k:]))
    header = _columns(rows[0], path)
    width = len(header)
    data = np.full((len(rows) - 1, width), np.nan)
    for i, row in enumerate(rows[1:]):
        if len(row) != width:
            raise ValueError(f"log {path}: row {i + 1} (line {k + i + 2}) has {len(row)} fields, the header {width}")
        for j, cell in enumerate(row):
            cell = cell.strip()
            if cell and cell.lower() != "nan":
                try:
                    data[i, j] = float(cell)
                except ValueError:
                    raise ValueError(
                        f"log {path}: channel {header[j][0]!r}, row {i + 1} (line {k + i + 2}): "
                        f"{cell!r} is not a number"
                    ) from None
    return _by_name(header, data.T, path), metadata, k + 1


def _by_name(header: list[tuple[str, str]], columns, path) -> tuple[dict, dict]:
    names = [name for name, _ in header]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise ValueError(f"log {path}: column(s) {repeated} given more than once")
    return {name: unit for name, unit in header}, {
        name: np.asarray(c, dtype=float) for (name, _), c in zip(header, columns)
    }


def _read_parquet(path: Path) -> tuple[dict, dict, dict, int]:
    try:
        import pyarrow.parquet as pq
    except ModuleNotFoundError as err:
        raise ModuleNotFoundError("Parquet logs need pyarrow: pip install 'fourwis[logs]'") from err
    try:
        table = pq.read_table(path)
    except Exception as err:  # (pyarrow's own error types: a damaged or foreign file)
        raise ValueError(f"log {path}: cannot be read as Parquet ({type(err).__name__}: {err})") from None
    header = _columns(table.column_names, path)
    columns = []
    for name, (channel, _) in zip(table.column_names, header):
        try:
            columns.append(table.column(name).to_numpy(zero_copy_only=False).astype(float))
        except (TypeError, ValueError):
            raise ValueError(f"log {path}: channel {channel!r} is not numeric") from None
    raw = (table.schema.metadata or {}).get(b"fourwis")
    metadata = {str(k): str(v) for k, v in json.loads(raw).items()} if raw else {}
    return _by_name(header, columns, path), metadata, 1


def _read_mat(path: Path) -> tuple[dict, dict, dict, int]:
    from scipy.io import loadmat

    try:
        data = loadmat(path, squeeze_me=True, struct_as_record=False)
    except NotImplementedError:  # (v7.3 files are HDF5)
        raise ValueError(f"log {path}: a MATLAB v7.3 file: save it with -v7 (scipy reads v5-v7)") from None
    except (ValueError, OSError, TypeError) as err:
        raise ValueError(f"log {path}: cannot be read as a MATLAB file ({err})") from None
    units_struct = data.get("units")
    if units_struct is None:
        raise ValueError(f"log {path}: no 'units' struct (a unit string per channel, e.g. units.ax = 'm/s^2')")
    units = {name: str(getattr(units_struct, name)) for name in getattr(units_struct, "_fieldnames", [])}
    meta_struct = data.get("metadata")
    metadata = {k: str(getattr(meta_struct, k)) for k in getattr(meta_struct, "_fieldnames", [])} if meta_struct else {}
    values = {}
    for name, value in data.items():
        if name.startswith("__") or name in ("units", "metadata"):
            continue
        array = np.asarray(value)
        if array.dtype.kind not in "fiub" or array.ndim != 1:
            raise ValueError(f"log {path}: variable {name!r} is not a numeric vector (shape {array.shape})")
        if name not in units:
            raise ValueError(f"log {path}: channel {name!r} has no unit: give units.{name}")
        values[name] = array.astype(float)
    return {name: units[name] for name in values}, values, metadata, 1


def shipped_logs() -> dict[str, Path]:
    """The logs fourwis ships (name -> file): training/data/logs/<name>/<name>.csv.gz."""
    root = resources.files("fourwis.training").joinpath("data/logs")
    if not root.is_dir():
        return {}
    return {
        p.name: Path(str(p.joinpath(f"{p.name}.csv.gz")))
        for p in sorted(root.iterdir(), key=lambda p: p.name)
        if p.is_dir() and p.joinpath(f"{p.name}.csv.gz").is_file()
    }


def log_path(name_or_path: str | Path) -> Path:
    """The file of a shipped log's name, or the path given (FileNotFoundError naming both kinds)."""
    shipped = shipped_logs()
    if str(name_or_path) in shipped:
        return shipped[str(name_or_path)]
    path = Path(name_or_path)
    if not path.is_file():
        raise FileNotFoundError(f"no log {str(name_or_path)!r}: give a file or a shipped log ({', '.join(shipped)})")
    return path


def read_log(name_or_path: str | Path, max_missing: float = MAX_MISSING) -> Log:
    """Read and check the log ``name_or_path`` (a file, or a shipped log's name; module
    docstring). ValueError names the channel and row of bad input: a column without a unit or
    with one its quantity does not take, a missing required channel or an incomplete group, a
    time that is not finite or does not increase, a non-number, a channel missing for longer
    than ``max_missing`` [s] or in the first row of an input."""
    path = log_path(name_or_path)
    suffixes = "".join(path.suffixes[-2:]).lower()
    if suffixes.endswith((".csv", ".csv.gz")):
        (units, values), metadata, first_line = _read_csv(path)
    elif path.suffix.lower() in (".parquet", ".pq"):
        (units, values), metadata, first_line = _read_parquet(path)
    elif path.suffix.lower() == ".mat":
        units, values, metadata, first_line = _read_mat(path)
    else:
        raise ValueError(f"log {path}: unknown format {path.suffix!r}: give .csv, .csv.gz, .parquet or .mat")
    if not (math.isfinite(max_missing) and max_missing > 0):
        raise ValueError(f"max_missing must be a time > 0 [s], got {max_missing!r}")

    def where(k: int) -> str:
        return f"row {k + 1}" + (f" (line {first_line + k + 1})" if suffixes.endswith((".csv", ".csv.gz")) else "")

    known = {n: v for n, v in values.items() if n in SCHEMA}
    ignored = tuple(n for n in values if n not in SCHEMA)
    for name in known:
        kind = SCHEMA[name][0]
        if units[name] not in UNITS[kind]:
            raise ValueError(
                f"log {path}: channel {name!r} has unknown unit {units[name]!r}; its quantity "
                f"({kind.replace('_', ' ')}) takes {list(UNITS[kind])}"
            )
    if "t" not in known:
        raise ValueError(f"log {path}: no time column 't' (e.g. 't [s]')")
    lengths = {len(v) for v in known.values()}
    if len(lengths) != 1:
        raise ValueError(f"log {path}: channels of different lengths {sorted(lengths)}")
    t = known["t"] * UNITS["time"][units["t"]]
    if len(t) < 2:
        raise ValueError(f"log {path}: {len(t)} sample(s); a log needs at least two")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise ValueError(f"log {path}: time 't' is missing or not finite at {where(int(bad[0]))}")
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        k = int(back[0]) + 1
        raise ValueError(
            f"log {path}: time 't' does not increase at {where(k)}: {float(t[k])!r} s after {float(t[k - 1])!r} s "
            "(times must be strictly increasing)"
        )
    channels = {}
    for name, column in known.items():
        if name == "t":
            continue
        factor = UNITS[SCHEMA[name][0]][units[name]]
        channels[name] = column * factor
    _check_required(path, channels)
    for name, column in channels.items():
        missing = ~np.isfinite(column)
        if not missing.any():
            continue
        if missing.all():
            raise ValueError(f"log {path}: channel {name!r} has no sample at all")
        if name in INPUTS and missing[0]:
            raise ValueError(
                f"log {path}: channel {name!r} is missing at {where(0)}: an input needs a first value to hold"
            )
        edges = np.diff(np.concatenate([[0], missing.astype(np.int8), [0]]))
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        # a run's length: from the last sample before it to the first after it
        before = t[np.maximum(starts - 1, 0)]
        after = t[np.minimum(stops, len(t) - 1)]
        span = np.where(stops < len(t), after, t[-1]) - before
        long = np.flatnonzero(span > max_missing)
        if long.size:
            k = int(starts[long[0]])
            raise ValueError(
                f"log {path}: channel {name!r} is NaN (missing) from {where(k)} (t = {float(t[k])!r} s) for "
                f"{int(stops[long[0]] - k)} samples, {float(span[long[0]]):.3g} s: longer than "
                f"max_missing = {max_missing:g} s"
            )
    name = metadata.get("name") or path.name.split(".")[0]
    return Log(name, t, channels, {n: units[n] for n in known}, metadata, str(path), ignored)


def _check_required(path, channels: dict) -> None:
    """ValueError naming what a log lacks: ax, ay, yaw_rate, a speed source, a steering source,
    or part of a group."""
    for name in ("ax", "ay", "yaw_rate"):
        if name not in channels:
            raise ValueError(f"log {path}: required channel {name!r} is missing (have: {sorted(channels)})")
    for group, names in GROUPS.items():
        given = [n for n in names if n in channels]
        if given and len(given) != len(names):
            raise ValueError(
                f"log {path}: the {group} channels come together: {sorted(set(names) - set(given))} missing "
                f"beside {given}"
            )
    if "speed" not in channels and "wheel_speed_fl" not in channels:
        raise ValueError(
            f"log {path}: no speed source: give the four wheel_speed_fl/fr/rl/rr or a measured forward speed 'speed'"
        )
    if not ({"steer_fl", "steer", "handwheel"} & set(channels)):
        raise ValueError(
            f"log {path}: no steering: give steer_fl and steer_fr (the front road-wheel angles), 'steer' "
            "(one road-wheel angle) or 'handwheel' (the steering-wheel angle)"
        )
    if "engine_torque" in channels and not ({"gear_ratio", "gear"} & set(channels)):
        raise ValueError(f"log {path}: engine_torque needs a 'gear_ratio' (overall) or 'gear' channel")
    if "steer_rear" in channels and "steer_rl" in channels:
        raise ValueError(f"log {path}: give the rear steer once: steer_rl and steer_rr, or steer_rear")


# ---- writing -------------------------------------------------------------------------------
def log_text(t: np.ndarray, channels: dict[str, np.ndarray], units: dict[str, str], metadata: dict) -> str:
    """The CSV text of a log: metadata lines, the header ``name [unit]`` (``t [s]`` first),
    one row per sample, each number as Python's repr (it reads back to the same float), NaN as
    an empty field. ``channels`` in the units ``units`` gives (SI if not given)."""
    names = ["t", *channels]
    columns = [np.asarray(t, dtype=float)] + [np.asarray(channels[n], dtype=float) for n in channels]
    for name, column in zip(names, columns):
        if name not in SCHEMA:
            raise ValueError(f"unknown log channel {name!r}; known: {sorted(SCHEMA)}")
        if column.shape != columns[0].shape:
            raise ValueError(f"channel {name!r} has {column.shape} samples, t {columns[0].shape}")
    buf = io.StringIO()
    for key, value in metadata.items():
        if "\n" in str(value) or ":" in str(key):
            raise ValueError(f"metadata {key!r}: {value!r} must fit on one line (and the key has no ':')")
        buf.write(f"# {key}: {value}\n")
    si = {kind: next(iter(u)) for kind, u in UNITS.items()}
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow([f"{n} [{units.get(n, si[SCHEMA[n][0]])}]" for n in names])
    table = np.column_stack(columns)
    for row in table.tolist():
        writer.writerow(["" if v != v else repr(v) for v in row])
    return buf.getvalue()


def write_log(path: str | Path, t, channels: dict, units: dict | None = None, metadata: dict | None = None) -> Path:
    """Write a log as CSV to ``path`` atomically (gzip-compressed for a ``.gz`` name): see :func:`log_text`."""
    text = log_text(t, channels, units or {}, metadata or {})
    path = Path(path)
    if path.suffix == ".gz":
        return atomic_write(path, lambda tmp: tmp.write_bytes(gzip.compress(text.encode("utf-8"), mtime=0)))
    return atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


# ---- simulated runs as logs ----------------------------------------------------------------
#: the log channel of each reading channel of a simulated run (the car's sensors; it has no
#: forward-speed sensor)
SIMULATED_CHANNELS = {
    "ax": "ax",
    "ay": "ay",
    "yaw_rate": "yaw_rate",
    **{f"wheel_speed_{w}": f"omega_{w}" for w in WHEELS},
    **{f"steer_{w}": f"delta_{w}" for w in WHEELS},
    **{f"torque_{w}": f"torque_{w}" for w in WHEELS},
}


def simulated_log(traj, name: str, vehicle_file: str | None = None) -> tuple[np.ndarray, dict, dict, dict]:
    """A simulated run (an envs.simulation.Trajectory) in the log format, as :func:`write_log`
    takes it: (t, channels, units (SI: none given), metadata). The channels are its sensor
    readings exactly (NaN where a sensor was out) and
    the truth as references (ref_vx, ref_vy, ref_beta, ref_yaw_rate, ref_mu_*); the metadata
    name the run, its ``vehicle_file`` and the speed its estimator started from, so that a
    replay of the log reproduces the run's estimates."""
    from fourwis.core.types import CHANNELS

    channels = {}
    for log_name, channel in SIMULATED_CHANNELS.items():
        c = CHANNELS.index(channel)
        channels[log_name] = np.where(traj.sensor_valid[:, c], traj.sensors[:, c], np.nan)
    truth = traj.truth
    channels.update(ref_vx=truth.u, ref_vy=truth.v, ref_beta=truth.beta, ref_yaw_rate=truth.r)
    for i, w in enumerate(WHEELS):
        channels[f"ref_mu_{w}"] = truth.mu[:, i]
    metadata = {
        "name": name,
        "description": f"fourwis simulate {name}: the simulated car's sensor readings and the truth as references",
        "source": "fourwis simulation",
        "initial_speed": repr(float(traj.scenario.speed)),
    }
    if vehicle_file is not None:
        metadata["vehicle"] = vehicle_file
    return traj.t, channels, {}, metadata
