"""Every number of two output trees side by side (scripts/compare_commits.sh): the JSON results and the CSV
training logs; dates, commands, paths, timings and machine load are not compared. Exit 1 when any differ."""

from __future__ import annotations

import json
import sys
from pathlib import Path

IGNORED = ("date", "command", "machine", "checkpoint", "dataset", "path", "created_utc", "updated_utc")
TIMINGS = ("_s", "seconds")


def flat(value: object, prefix: str = "") -> dict[str, object]:
    if isinstance(value, dict):
        out: dict[str, object] = {}
        for k, v in value.items():
            if str(k).startswith(IGNORED) or str(k).endswith(TIMINGS):
                continue
            out |= flat(v, f"{prefix}{k}.")
        return out
    if isinstance(value, list):
        return {k: v for i, x in enumerate(value) for k, v in flat(x, f"{prefix}{i}.").items()}
    return {prefix[:-1]: value}


def main(before: Path, after: Path) -> int:
    differing = 0
    files = sorted({p.relative_to(before) for p in before.rglob("*") if p.suffix in (".json", ".csv")})
    for rel in files:
        a, b = before / rel, after / rel
        if not b.exists():
            print(f"{rel}: missing after")
            differing += 1
            continue
        if rel.suffix == ".csv":
            same = a.read_text() == b.read_text()
            print(f"{rel}: {len(a.read_text().splitlines())} rows, {'identical' if same else 'DIFFERENT'}")
            differing += not same
            continue
        x, y = flat(json.loads(a.read_text())), flat(json.loads(b.read_text()))
        diff = [k for k in sorted(set(x) | set(y)) if x.get(k) != y.get(k)]
        print(f"{rel}: {len(x)} values, {len(diff)} differ" + (f": {diff[:6]}" if diff else ""))
        differing += bool(diff)
    print(f"{len(files)} files compared, {differing} differ")
    return 1 if differing else 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]), Path(sys.argv[2])))
