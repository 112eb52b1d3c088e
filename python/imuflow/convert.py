"""Converts DIP-IMU and TotalCapture sequences into imuflow recordings (imuflow/datasets.py).

    python -m imuflow.convert dip DIP_IMU/s_09/01.pkl out/dip/s_09-01.mcap
    python -m imuflow.convert dip DIP_IMU out/dip                       # every .pkl below DIP_IMU
    python -m imuflow.convert totalcapture TC_DIP out/tc --gt-translation TotalCapture/official

A folder INPUT converts every `.pkl` below it into the same relative path under OUTPUT (`.mcap`),
one line per file; a file that fails is reported and the others still convert. Exit status: 0 all
converted, 1 some failed, 2 nothing to do (bad arguments, no .pkl found).
"""

import argparse
import os
import sys

from .datasets import DEFAULT_TRANSLATION_JOINT, DatasetError, convert_dip, convert_totalcapture


def main(argv=None):
    args = _parser().parse_args(argv)
    if args.dataset == "dip" and args.gt_translation is not None:
        return _usage("--gt-translation is for totalcapture (DIP-IMU has no translation)")
    jobs = _jobs(args.input, args.output)
    if isinstance(jobs, str):
        return _usage(jobs)
    if (len(jobs) > 1 or os.path.isdir(args.input)) and args.gt_translation \
            and not os.path.isdir(args.gt_translation):
        return _usage("with a folder INPUT, --gt-translation must be the folder of the official "
                      "TotalCapture ground truth (S1/acting1/gt_skel_gbl_pos.txt, ...)")
    failed = []
    for k, (source, target) in enumerate(jobs, start=1):
        label = os.path.relpath(source, _base(args.input))
        if os.path.isdir(args.input):
            label = f"[{k}/{len(jobs)}] {label}"
        try:
            if args.dataset == "dip":
                done = convert_dip(source, target)
            else:
                done = convert_totalcapture(source, target, args.gt_translation, args.gt_joint)
        except (DatasetError, OSError) as e:
            failed.append(source)
            print(f"{label}: error: {e}", file=sys.stderr, flush=True)
            continue
        print(f"{label} -> {target}: {done.summary()}", flush=True)
    if failed:
        print(f"converted {len(jobs) - len(failed)} of {len(jobs)}; failed: {len(failed)}",
              file=sys.stderr)
        return 1
    if len(jobs) > 1:
        print(f"converted {len(jobs)} files into {args.output}")
    return 0


def _parser():
    p = argparse.ArgumentParser(
        prog="python -m imuflow.convert",
        description="Convert DIP-IMU or TotalCapture (DIP's preprocessed pickles) into imuflow "
                    "recordings (mcap) that `imuflow compare --input` and the imu-source "
                    "stage's replay mode read. Use calibration method `none` on them.")
    p.add_argument("dataset", choices=["dip", "totalcapture"])
    p.add_argument("input", help="a .pkl sequence, or a folder: every .pkl below it")
    p.add_argument("output", help="the .mcap to write (a folder when INPUT is one)")
    p.add_argument("--gt-translation", metavar="PATH",
                   help="totalcapture: the sequence's official gt_skel_gbl_pos.txt, or the folder "
                        "of the official ground truth (S1/acting1/gt_skel_gbl_pos.txt, ...); "
                        "without it the truth's root stays at zero")
    p.add_argument("--gt-joint", default=DEFAULT_TRANSLATION_JOINT, metavar="JOINT",
                   help="totalcapture: the official skeleton's joint whose path is the "
                        "translation: Hips (default; PNP, GlobalPose) or Spine (TransPose, PIP)")
    return p


def _jobs(source, target):
    """(input, output) pairs, or why there are none."""
    if os.path.isfile(source):
        if os.path.isdir(target) or target.endswith(os.sep):
            stem = os.path.splitext(os.path.basename(source))[0]
            target = os.path.join(target, stem + ".mcap")
        return [(source, target)]
    if not os.path.isdir(source):
        return f"{source}: no such file or folder"
    if os.path.isfile(target):
        return f"{target}: is a file; with a folder INPUT, OUTPUT is a folder"
    jobs = []
    for folder, subfolders, files in os.walk(source):
        subfolders.sort()
        for name in sorted(files):
            if name.lower().endswith(".pkl"):
                relative = os.path.relpath(os.path.join(folder, name), source)
                jobs.append((os.path.join(folder, name),
                             os.path.join(target, os.path.splitext(relative)[0] + ".mcap")))
    return jobs or f"{source}: no .pkl files in it"


def _base(source):
    return source if os.path.isdir(source) else os.path.dirname(source) or "."


def _usage(message):
    print(f"python -m imuflow.convert: error: {message}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
