#!/usr/bin/env python3
"""Means of one metric per content group of a compare batch (clips.jsonl), for docs/results.

    python3 scripts/eval/group_clips.py out/full-test/clips.jsonl ["joint position error"]

The group of a Bandai clip is its content: dataset-2 names are dataset-2_<content>_<style>_<n>,
dataset-1 clips are grouped as one (17 contents, few clips each). Standard library only.
"""
import json
import sys
from collections import defaultdict


def group_of(clip: str) -> str:
    name = clip.rsplit("/", 1)[-1]
    if name.startswith("dataset-2_"):
        return name.split("_")[1]
    return "dataset-1 (all contents)"


def main() -> None:
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    path = sys.argv[1]
    metric = sys.argv[2] if len(sys.argv) > 2 else "joint position error"
    with open(path, encoding="utf-8") as f:
        header = json.loads(f.readline())
        records = [json.loads(line) for line in f if line.strip()]
    variants = header["variants"]
    groups = defaultdict(list)
    for r in records:
        if r.get("error"):
            continue
        row = next((x for x in r["rows"] if x["name"] == metric), None)
        if row and all(v is not None for v in row["values"]):
            groups[group_of(r["clip"])].append(row["values"])
    if not groups:
        sys.exit(f"{path}: no scored clip has '{metric}'")
    print(f"| content | clips | " + " | ".join(variants) + " |")
    print("|---|---:|" + "---:|" * len(variants))
    for name, rows in sorted(groups.items(), key=lambda g: -sum(r[0] for r in g[1]) / len(g[1])):
        means = [sum(r[k] for r in rows) / len(rows) for k in range(len(variants))]
        print(f"| {name} | {len(rows)} | " + " | ".join(f"{m:.2f}" for m in means) + " |")


if __name__ == "__main__":
    main()
