"""How far 2-process CPU DDP is from one process: the largest relative difference of every logged loss.

    python scripts/ddp_loss_difference.py [data_dir=DIR] [steps=4]

Trains the quick hopper and bed experiments (on DIR/datasets/hopper_tiny and fb_tiny, made by
`neuraldem datagen data=hopper_tiny` / `data=fb_tiny`; default DIR: the data dir) for a few steps with
`trainer=cpu` and with `trainer=ddp_cpu` (2 gloo processes, the same global batch), each through the
`neuraldem train` command, and compares what the CSV logger wrote. tests/test_ddp.py asserts the same runs
agree to 1e-5; this prints the measured difference.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

from neuraldem.cli import CommandParser
from neuraldem.eval.run_results import logged_losses
from neuraldem.paths import data_dir

LOSSES = {"loss", "occupancy", "transport", "residence", "occupancy_accuracy", "particles", "fluid", "mixing"}
SCENES = {"hopper": ("experiment=hopper_quickstart", "hopper_tiny"), "bed": ("experiment=fb_quick", "fb_tiny")}


def train(run: Path, trainer: str, overrides: list[str]) -> dict[tuple[int, str], float]:
    cmd = [sys.executable, "-m", "neuraldem.train", *overrides, f"trainer={trainer}", f"hydra.run.dir={run}"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    return logged_losses(run)


def main(argv: list[str] | None = None) -> int:
    p = CommandParser(prog="python scripts/ddp_loss_difference.py", description=__doc__)
    p.add_argument("--data-dir", type=Path, default=None)
    p.add_argument("--steps", type=int, default=4)
    args = p.parse_args(argv)
    root = args.data_dir or data_dir()
    for scene, (experiment, dataset) in SCENES.items():
        overrides = [experiment, f"data.dataset_dir={root / 'datasets' / dataset}", f"trainer.max_steps={args.steps}",
                     "trainer.log_every_n_steps=1", f"trainer.val_check_interval={args.steps}", "evaluate=false",
                     "logger=csv", "callbacks.progress=null", "trainer.enable_model_summary=false"]
        with tempfile.TemporaryDirectory() as tmp:
            one, two = train(Path(tmp) / "one", "cpu", overrides), train(Path(tmp) / "two", "ddp_cpu", overrides)
        rel = {key: abs(two[key] - v) / max(abs(v), 1e-12) for key, v in one.items()}
        losses = [r for key, r in rel.items() if key[1].split("/")[1] in LOSSES]
        others = [r for key, r in rel.items() if key[1].split("/")[1] not in LOSSES]
        print(f"{scene}: {len(losses)} logged losses, largest relative difference {max(losses):.2g}"
              + (f"; {len(others)} other logged values (scores), largest {max(others):.2g}" if others else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
