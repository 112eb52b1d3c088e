#!/usr/bin/env python3
"""Reference orientations for the fusion stage's VQF, from the authors' own implementation.

The fusion stage (stages/fusion) runs VQF (D. Laidig and T. Seel, "VQF: Highly Accurate IMU
Orientation Estimation with Bias Estimation and Magnetic Disturbance Rejection", Information Fusion
91, 2023) through the Rust port `vqf-rs`. This script runs the authors' PyPI package `vqf`
(`vqf.VQF`, the Cython wrapper of their C++ code) on a committed input and writes the expected
quaternions, which the crate's test `tests/vqf_reference.rs` compares with its own, every
component within 1e-4 (sign-aligned).

Files (stages/fusion/tests/fixtures/):
  vqf_input.csv     t_s, gyr_x..z (rad/s), acc_x..z (m/s^2), mag_x..z (uT): 6 s at 100 Hz. A sensor
                    at rest (2 s), turning about all three axes (2.5 s), at rest again (1.5 s), with a
                    gyroscope bias of (0.6, -0.9, 0.5) deg/s, white noise, and a magnetic
                    disturbance from 3.0 s to 3.5 s. Made by --make-input (seeded, deterministic);
                    values are rounded to the decimals written, so both sides read the same
                    doubles.
  vqf_expected.csv  t_s and, for each configuration (default, custom), the 6D quaternion of a
                    filter fed without the magnetometer and the 9D quaternion of one fed with it,
                    each [w, x, y, z], after every second sample (t_s says which).

Configurations: `default` is VQF's defaults (tauAcc 3 s, tauMag 9 s, rest and motion bias
estimation, magnetic disturbance rejection), as the stage runs by default; `custom` is tauAcc
1.5 s, tauMag 5 s, restBiasEstEnabled False, magDistRejectionEnabled False, to check that the
stage's parameters reach the filter.

Usage:
  vqf_reference.py --make-input   regenerate vqf_input.csv (then regenerate the expectation)
  vqf_reference.py                write vqf_expected.csv from vqf_input.csv
  vqf_reference.py --check        recompute and compare with vqf_expected.csv; exit 1 on mismatch

Needs `pip install vqf` (2.1.2 made the committed fixture) and numpy.
"""

import argparse
import sys
from pathlib import Path

from importlib.metadata import version

import numpy as np
import vqf

FIXTURES = Path(__file__).resolve().parents[2] / "stages" / "fusion" / "tests" / "fixtures"
INPUT = FIXTURES / "vqf_input.csv"
EXPECTED = FIXTURES / "vqf_expected.csv"

RATE_HZ = 100.0
DURATION_S = 6.0
CONFIGS = {
    "default": {},
    "custom": {
        "tauAcc": 1.5,
        "tauMag": 5.0,
        "restBiasEstEnabled": False,
        "magDistRejectionEnabled": False,
    },
}
# Every second sample goes into the fixture (the filter is recursive: an error at any sample shows in
# the later rows), with 9 decimals; a recomputation differs by rounding only.
EVERY = 2
CHECK_TOL = 1e-8


def quat_mul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def quat_to_matrix(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def angular_rate(t):
    """The true body-frame angular rate, rad/s: zero at rest, smooth turns from 2.0 s to 4.5 s."""
    if t < 2.0 or t > 4.5:
        return np.zeros(3)
    u = (t - 2.0) / 2.5
    envelope = np.sin(np.pi * u) ** 2
    return envelope * np.array([
        2.5 * np.sin(2 * np.pi * 0.8 * (t - 2.0)),
        1.5 * np.sin(2 * np.pi * 0.5 * (t - 2.0) + 0.3),
        3.0,
    ])


def make_input():
    rng = np.random.RandomState(20230101)
    n = int(DURATION_S * RATE_HZ)
    ts = 1.0 / RATE_HZ
    # Start tilted 20 deg about (1, 1, 0) and heading 40 deg: R_ES with E = ENU.
    axis = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    q = quat_mul(
        np.array([np.cos(np.radians(20)), 0, 0, np.sin(np.radians(20))]),
        np.concatenate([[np.cos(np.radians(10))], np.sin(np.radians(10)) * axis]),
    )
    gravity_up = np.array([0.0, 0.0, 9.81])
    field = np.array([0.0, 18.0, -42.0])
    bias = np.radians([0.6, -0.9, 0.5])
    rows = []
    substeps = 20
    for k in range(n):
        t = k * ts
        r = quat_to_matrix(q)
        disturbance = np.array([15.0, -5.0, 0.0]) if 3.0 <= t < 3.5 else np.zeros(3)
        gyr = angular_rate(t) + bias + rng.normal(0.0, 0.003, 3)
        acc = r.T @ gravity_up + rng.normal(0.0, 0.02, 3)
        mag = r.T @ (field + disturbance) + rng.normal(0.0, 0.3, 3)
        rows.append((t, gyr, acc, mag))
        # Integrate the true motion to the next sample.
        h = ts / substeps
        for j in range(substeps):
            w = angular_rate(t + (j + 0.5) * h)
            angle = np.linalg.norm(w) * h
            if angle > 0:
                dq = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * w / np.linalg.norm(w)])
                q = quat_mul(q, dq)
        q /= np.linalg.norm(q)
    with open(INPUT, "w") as f:
        f.write("t_s,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z\n")
        for t, gyr, acc, mag in rows:
            values = [f"{t:.2f}"] + [f"{v:.6f}" for v in gyr] + [f"{v:.5f}" for v in acc]
            values += [f"{v:.4f}" for v in mag]
            f.write(",".join(values) + "\n")
    print(f"wrote {INPUT} ({n} samples)")


def read_input():
    data = np.loadtxt(INPUT, delimiter=",", skiprows=1)
    return data[:, 0], data[:, 1:4].copy(), data[:, 4:7].copy(), data[:, 7:10].copy()


def expected():
    t, gyr, acc, mag = read_input()
    ts = float(np.median(np.diff(t)))
    columns = [t]
    names = ["t_s"]
    for name, params in CONFIGS.items():
        six = vqf.VQF(ts, **params)
        nine = vqf.VQF(ts, **params)
        q6 = np.zeros((len(t), 4))
        q9 = np.zeros((len(t), 4))
        for k in range(len(t)):
            six.update(gyr[k], acc[k])
            nine.update(gyr[k], acc[k], mag[k])
            q6[k] = six.getQuat6D()
            q9[k] = nine.getQuat9D()
        for dim, q in (("6d", q6), ("9d", q9)):
            columns += [q[:, i] for i in range(4)]
            names += [f"{name}_{dim}_{c}" for c in "wxyz"]
    return names, np.column_stack(columns)[::EVERY]


def write_expected():
    names, table = expected()
    with open(EXPECTED, "w") as f:
        f.write(",".join(names) + "\n")
        for row in table:
            f.write(",".join([f"{row[0]:.2f}"] + [f"{v:.9f}" for v in row[1:]]) + "\n")
    print(f"wrote {EXPECTED} ({len(table)} rows, vqf {version('vqf')})")


def check():
    names, table = expected()
    with open(EXPECTED) as f:
        header = f.readline().strip().split(",")
    stored = np.loadtxt(EXPECTED, delimiter=",", skiprows=1)
    if header != names or stored.shape != table.shape:
        print(f"{EXPECTED}: columns or rows differ from the recomputation", file=sys.stderr)
        return 1
    diff = np.abs(stored - table)
    worst = np.unravel_index(np.argmax(diff), diff.shape)
    print(f"vqf {version('vqf')}: largest difference {diff[worst]:.2e} "
          f"(row {worst[0]}, {names[worst[1]]})")
    if diff[worst] > CHECK_TOL:
        print(f"{EXPECTED} does not match the reference (tolerance {CHECK_TOL})", file=sys.stderr)
        return 1
    return 0


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--make-input", action="store_true", help="regenerate the input")
    parser.add_argument("--check", action="store_true", help="compare with the fixture")
    args = parser.parse_args()
    if args.make_input:
        make_input()
        return 0
    if args.check:
        return check()
    write_expected()
    return 0


if __name__ == "__main__":
    sys.exit(main())
