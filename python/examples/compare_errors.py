"""Error curves of an `imuflow compare` run, from its recording (notebook-style).

    imuflow compare configs/pip.toml configs/globalpose.toml configs/no-physics.toml
    python python/examples/compare_errors.py out/compare/compare.mcap [errors.png]

For every variant's estimate (`<variant>-opt.motion`) against the truth (`source.truth`), frame by
frame: the mean rotation error of the joints' local rotations (deg) and the root's horizontal
distance (m). Needs numpy, mcap and matplotlib (`pip install ./python matplotlib`).
"""
import sys

import numpy as np

import imuflow


def angle_deg(q, r):
    """Angle between unit quaternions (…, 4), in degrees (q and −q are the same rotation)."""
    dot = np.abs(np.sum(q * r, axis=-1)).clip(0.0, 1.0)
    return np.degrees(2.0 * np.arccos(dot))


def main():
    if len(sys.argv) < 2:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    rec = imuflow.open_recording(sys.argv[1])
    truth_seq, truth_rot, truth_root = rec.poses("source.truth")
    by_seq = {int(s): i for i, s in enumerate(truth_seq)}
    variants = sorted(t[: -len("-opt.motion")] for t in rec.topics if t.endswith("-opt.motion"))
    if not variants:
        sys.exit(f"{sys.argv[1]}: no <variant>-opt.motion topics (is it a compare recording?)")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_rot, ax_root) = plt.subplots(2, 1, sharex=True, figsize=(10, 6))
    for variant in variants:
        seq, rot, root = rec.poses(f"{variant}-opt.motion")
        keep = np.array([int(s) in by_seq for s in seq])
        seq, rot, root = seq[keep], rot[keep], root[keep]
        rows = np.array([by_seq[int(s)] for s in seq])
        # Joints 1.. (the root's own rotation carries the heading, compared by the root distance).
        rotation_error = angle_deg(rot[:, 1:], truth_rot[rows, 1:]).mean(axis=1)
        root_error = np.linalg.norm((root - truth_root[rows])[:, [0, 2]], axis=1)
        ax_rot.plot(seq, rotation_error, label=variant)
        ax_root.plot(seq, root_error, label=variant)
        print(f"{variant:<14} mean local rotation error {rotation_error.mean():6.2f}°  "
              f"mean root distance {root_error.mean():5.2f} m  ({len(seq)} frames)")
    ax_rot.set_ylabel("local rotation error (°)")
    ax_root.set_ylabel("root distance (m)")
    ax_root.set_xlabel("seq (60 Hz frames)")
    ax_rot.legend()
    out = sys.argv[2] if len(sys.argv) > 2 else "errors.png"
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
