#!/usr/bin/env python3
"""Independent check of an imuflow .rrd's layout, read with the official rerun SDK
(rerun-sdk[datafusion]==0.36.3, RrdReader): the recording carries a blueprint with the views a user
should see first, and no time series under /plots is constant (a flat line is screen space that says
nothing).

usage: verify_layout.py RRD VIEW [VIEW ...]
  VIEW: the display name of a view or container the blueprint must have, e.g. scene follow legend
  errors; '!NAME': one it must not have (e.g. '!errors' for a recording without a truth). Exits
  non-zero with a message on any mismatch.

A recording can carry several blueprints (imuflow's logger sends its layout before the first frame
and again when the first truth pose adds the errors tab); the viewer shows the last one sent, and
that one is checked: the blueprint whose rows were logged last (row ids grow with time).
"""
import sys

import rerun.experimental as rx


def fail(msg):
    print(f"verify_layout: FAIL: {msg}", file=sys.stderr)
    sys.exit(1)


def cell_values(column):
    """Every row of an Arrow column as a Python value, lists flattened to tuples."""
    for value in column.to_pylist():
        yield tuple(value) if isinstance(value, list) else value


def display_names(reader, path):
    """The display names of the blueprint the viewer shows (the last sent), and how many the
    recording has."""
    blueprints = reader.blueprints()
    if not blueprints:
        fail(f"{path}: no blueprint (the viewer would fall back to its automatic layout)")
    shown = None
    for blueprint in blueprints:
        names, last_row = set(), b""
        for chunk in reader.stream(store=blueprint).to_chunks():
            batch = chunk.to_record_batch()
            for field, column in zip(batch.schema, batch.columns):
                if field.name == "rerun.controls.RowId":
                    last_row = max([last_row, *(v for v in column.to_pylist() if v)])
                if field.name.endswith(":display_name"):
                    names.update(v[0] if isinstance(v, tuple) else v for v in cell_values(column) if v)
        if shown is None or last_row > shown[0]:
            shown = (last_row, names)
    return shown[1], len(blueprints)


def constant_series(reader):
    """Entity paths under /plots whose Scalars never change."""
    values = {}
    for chunk in reader.stream().to_chunks():
        entity = str(chunk.entity_path)
        if not entity.startswith("/plots/"):
            continue
        batch = chunk.to_record_batch()
        for field, column in zip(batch.schema, batch.columns):
            if field.name.endswith("Scalars:scalars"):
                values.setdefault(entity, set()).update(v for v in cell_values(column) if v is not None)
    return sorted(e for e, seen in values.items() if len(seen) < 2), len(values)


def main():
    if len(sys.argv) < 3:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    path, wanted = sys.argv[1], sys.argv[2:]
    reader = rx.RrdReader(path)
    names, blueprints = display_names(reader, path)
    missing = [w for w in wanted if not w.startswith("!") and w not in names]
    if missing:
        fail(f"{path}: the blueprint has no view or container named {missing} (it has {sorted(names)})")
    unwanted = [w[1:] for w in wanted if w.startswith("!") and w[1:] in names]
    if unwanted:
        fail(f"{path}: the blueprint has a view or container named {unwanted} (it has {sorted(names)})")
    constant, series = constant_series(reader)
    if constant:
        fail(f"{path}: constant time series logged: {constant}")
    print(f"verify_layout: {path}: OK (blueprint, the last of {blueprints}, with {', '.join(wanted)}; "
          f"{series} time series, none constant)")


if __name__ == "__main__":
    main()
