#!/usr/bin/env python3
"""Independent check that two imuflow .rrd files hold the same data, read with the official rerun
SDK (rerun-sdk[datafusion]==0.36.3, RrdReader): every entity's every component value at every
(seq, capture_time), and the same static data. How the rows were cut into chunks, their row ids
and the `log_time`/`log_tick` timelines (wall clock and call counters, which differ between any
two runs) are ignored.

Used to check that the rerun-logger's column batching (`batch_frames`) writes what logging call
by call writes.

usage: same_rrd.py A.rrd B.rrd [--ignore ENTITY_PREFIX ...]
  --ignore: entities that measure the run rather than the motion (e.g. /plots/latency_ms, the
  time each frame took), which differ between any two runs.
  Exits non-zero, naming the first differences, when they differ.
"""
import sys

import rerun.experimental as rx

TIMELINES = ("seq", "capture_time")


def normalized(value):
    """A cell as a hashable value: lists (nested) become tuples."""
    if isinstance(value, list):
        return tuple(normalized(v) for v in value)
    if isinstance(value, dict):
        return tuple(sorted((k, normalized(v)) for k, v in value.items()))
    return value


def contents(path, ignored):
    """{(entity, component, seq, capture_time): value} and {(entity, component): value} (static)."""
    temporal, static = {}, {}
    for chunk in rx.RrdReader(path).stream().to_chunks():
        entity = str(chunk.entity_path)
        if entity.startswith(ignored) or entity.startswith("/__properties"):
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        columns = dict(zip(names, batch.columns))
        times = [columns.get(t) for t in TIMELINES]
        for name in names:
            if name in TIMELINES or name.startswith("rerun.") or name in ("log_time", "log_tick"):
                continue
            values = columns[name].to_pylist()
            for row, value in enumerate(values):
                if value is None:
                    continue
                if all(t is None for t in times):
                    static[(entity, name)] = normalized(value)
                    continue
                key = (entity, name) + tuple(None if t is None else str(t[row].as_py()) for t in times)
                temporal[key] = normalized(value)
    return temporal, static


def main():
    args = sys.argv[1:]
    ignored = tuple(args[i + 1] for i, a in enumerate(args) if a == "--ignore" and i + 1 < len(args))
    files = [a for i, a in enumerate(args) if a != "--ignore" and (i == 0 or args[i - 1] != "--ignore")]
    if len(files) != 2 or len(args) != 2 + 2 * len(ignored):
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    a, b = files
    (ta, sa), (tb, sb) = contents(a, ignored), contents(b, ignored)
    problems = []
    for what, x, y in (("temporal", ta, tb), ("static", sa, sb)):
        only_a = sorted(set(x) - set(y), key=str)
        only_b = sorted(set(y) - set(x), key=str)
        differ = sorted((k for k in set(x) & set(y) if x[k] != y[k]), key=str)
        for keys, say in ((only_a, f"only in {a}"), (only_b, f"only in {b}"), (differ, "values differ")):
            if keys:
                problems.append(f"{len(keys)} {what} cells {say}, e.g. {keys[:3]}")
    if problems:
        print("same_rrd: FAIL: " + "; ".join(problems), file=sys.stderr)
        sys.exit(1)
    entities = len({k[0] for k in ta})
    print(f"same_rrd: {a} and {b}: the same {len(ta)} temporal cells over {entities} entities and {len(sa)} static")


if __name__ == "__main__":
    main()
