"""Convert the Revs run of MBDS/sideslip-angle-vehicle-estimation into fourwis's log format.

The source: the public MIT-licensed repository https://github.com/MBDS/sideslip-angle-vehicle-estimation
(Copyright 2021 Jose Luis Blanco-Claraco), commit 0446c7659152c4064ea6f520369d3c5b56d222df, folder
datasets/20140222_01_01_03_250lm: one text file of 55001 samples per channel, 100 Hz from t = 149.99 s
to 699.99 s, in SI units (its datasets/mat2txt.m converted the Revs Program's MATLAB file: yaw rate
and angles to rad). The channels taken: t, axCG, ayCG, yawRate (the INS's raw ones; the *Filt files
are filtered copies, not used), deltaFL, deltaFR (the front road-wheel angles, decimated from 1 kHz
by the source), delta (the road-wheel angle), vxCG, vyCG and beta_true (the INS's velocity and
sideslip at the CG: the references; vx also as the measured speed, the only speed source the run
has). The values are written as read (the source prints 8 significant digits).

Run: python convert_revs.py DATASET_DIR [OUT] (default OUT: revs.csv.gz beside this script).
"""

import sys
from pathlib import Path

import numpy as np

from fourwis.training.logs import write_log

SOURCE = "https://github.com/MBDS/sideslip-angle-vehicle-estimation"
COMMIT = "0446c7659152c4064ea6f520369d3c5b56d222df"
#: log channel -> (source file, unit)
CHANNELS = {
    "ax": ("axCG", "m/s^2"),
    "ay": ("ayCG", "m/s^2"),
    "yaw_rate": ("yawRate", "rad/s"),
    "steer_fl": ("deltaFL", "rad"),
    "steer_fr": ("deltaFR", "rad"),
    "steer": ("delta", "rad"),
    "speed": ("vx", "m/s"),
    "ref_vx": ("vx", "m/s"),
    "ref_vy": ("vy", "m/s"),
    "ref_beta": ("beta_true", "rad"),
}


def main(argv: list[str]) -> None:
    folder = Path(argv[0])
    out = Path(argv[1]) if len(argv) > 1 else Path(__file__).with_name("revs.csv.gz")
    t = np.loadtxt(folder / "t.txt")
    channels = {name: np.loadtxt(folder / f"{source}.txt") for name, (source, _) in CHANNELS.items()}
    metadata = {
        "name": "revs",
        "description": "Revs Program (Stanford) Ferrari 250 LM track run 20140222_01_01_03_250lm, 100 Hz, "
        "550 s: INS accelerations and yaw rate, front road-wheel angles, INS velocity and sideslip",
        "source": f"{SOURCE} (commit {COMMIT}, datasets/20140222_01_01_03_250lm)",
        "license": "MIT, Copyright 2021 Jose Luis Blanco-Claraco (LICENSE beside this file)",
        "vehicle": "vehicle.toml",
    }
    print(write_log(out, t, channels, {n: u for n, (_, u) in CHANNELS.items()}, metadata))


if __name__ == "__main__":
    main(sys.argv[1:])
