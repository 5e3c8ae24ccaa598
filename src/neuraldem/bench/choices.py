"""What a benchmark runs on when it is not told: the folder for its solver runs, the trajectory it times, the
names of its series. Shared by the scenes' benchmarks."""

from __future__ import annotations

from pathlib import Path

from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.paths import data_dir


def default_workdir(benchmark: str) -> Path:
    """Solver run folders of benchmarks: under the data dir, never in the git checkout."""
    return data_dir() / "bench" / benchmark


def pick_record(m: Manifest, split: str, sim_id: str | None) -> SimRecord:
    """`sim_id`, else the first test simulation of `split`, else the first usable one."""
    if sim_id is not None:
        return m.record(sim_id)
    ids = m.splits.get(split, {}).get("test", [])
    return m.record(ids[0]) if ids else m.usable()[0]


def default_labels(ckpts: list[Path]) -> list[str]:
    """A series name per checkpoint: its run folder (`<run>/checkpoints/x.ckpt`), else its file name;
    repeated names get a number."""
    out: list[str] = []
    for c in ckpts:
        c = Path(c)
        name = c.parent.parent.name if c.parent.name == "checkpoints" and c.parent.parent.name else c.stem
        out.append(name if name not in out else f"{name} ({len(out) + 1})")
    return out
