"""`neuraldem doctor`: is this machine ready? One line per check, with the fix for each failure.

Required checks (torch, torch-cluster, the Python stack, LIGGGHTS, OpenFOAM, the data dir) make the exit
status non-zero when they fail; the GPU check only informs.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from neuraldem import paths
from neuraldem.cli import doc_parser
from neuraldem.errors import NeuraldemError
from neuraldem.sim import liggghts, openfoam

TORCH_PIN = "2.13.0"
SETUP_HINT = "run `bash scripts/setup.sh` from the checkout"


@dataclass
class Check:
    name: str
    ok: bool
    detail: str
    fix: str = ""
    required: bool = True

    def line(self) -> str:
        tag = "ok" if self.ok else ("FAIL" if self.required else "warn")
        text = f"[{tag:>4}] {self.name}: {self.detail}"
        return text if self.ok or not self.fix else f"{text} -> fix: {self.fix}"


def check_python() -> Check:
    v = sys.version_info
    ok = (v.major, v.minor) == (3, 11)
    return Check("python", ok, f"{v.major}.{v.minor}.{v.micro} at {sys.executable}",
                 "use Python 3.11 (the pinned torch and torch-cluster wheels are built for it)")


def check_torch() -> Check:
    try:
        import torch
    except Exception as err:  # noqa: BLE001 - any import failure is a failed check
        return Check("torch", False, f"import failed ({err})", SETUP_HINT)
    base = torch.__version__.split("+")[0]
    detail = f"{torch.__version__}, {torch.get_num_threads()} threads"
    if base != TORCH_PIN:
        return Check("torch", False, f"{detail} (expected {TORCH_PIN})",
                     f"pip install torch=={TORCH_PIN} (CPU build), then {SETUP_HINT}")
    return Check("torch", True, detail)


def check_torch_cluster() -> Check:
    """A radius query with a known answer: 3 points on a line, spacing 1, radius 1.5 -> 2 neighbours each
    for the middle point, 1 for the ends (self loops excluded)."""
    fix = (f"pip install torch-cluster==1.6.3 --find-links ../shared/wheels/cpu-py311-torch{TORCH_PIN} "
           "(or build from source: pip install --no-build-isolation torch-cluster==1.6.3)")
    try:
        import torch
        import torch_cluster
    except Exception as err:  # noqa: BLE001
        return Check("torch-cluster", False, f"import failed ({err})", fix)
    x = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    try:
        row, col = torch_cluster.radius(x, x, 1.5, max_num_neighbors=8)
    except Exception as err:  # noqa: BLE001
        return Check("torch-cluster", False, f"radius query failed ({err})", fix)
    pairs = sorted((int(a), int(b)) for a, b in zip(row, col, strict=False) if a != b)
    expected = [(0, 1), (1, 0), (1, 2), (2, 1)]
    ok = pairs == expected
    return Check("torch-cluster", ok,
                 f"{torch_cluster.__version__}, radius query {'correct' if ok else f'wrong: {pairs}'}", fix)


def check_python_stack() -> Check:
    # import name -> distribution name
    mods = {"lightning": "lightning", "hydra": "hydra-core", "omegaconf": "omegaconf", "h5py": "h5py",
            "wandb": "wandb", "lion_pytorch": "lion-pytorch", "matplotlib": "matplotlib", "scipy": "scipy",
            "tqdm": "tqdm", "rich": "rich", "torch_geometric": "torch-geometric", "numba": "numba"}
    missing, versions = [], []
    for mod, dist in mods.items():
        try:
            importlib.import_module(mod)
            versions.append(f"{dist} {importlib.metadata.version(dist)}")
        except Exception:  # noqa: BLE001
            missing.append(mod)
    if missing:
        return Check("python packages", False, f"missing {missing}", SETUP_HINT)
    return Check("python packages", True, ", ".join(versions))


def check_liggghts() -> Check:
    try:
        with tempfile.TemporaryDirectory(prefix="neuraldem-doctor-") as tmp:
            version, z = liggghts.free_fall_check(Path(tmp))
    except NeuraldemError as err:
        return Check("LIGGGHTS", False, err.problem, err.fix or liggghts.INSTALL_HINT)
    expected = liggghts.FREE_FALL_EXPECTED_Z
    ok = abs(z - expected) < 1e-6
    detail = f"{version or 'unknown version'} at {liggghts.find_liggghts()}, free-fall test z={z:.7f}"
    if not ok:
        detail += f" (expected {expected:.7f})"
    if ok and version and not version.startswith("LIGGGHTS-PUBLIC 3.8"):
        return Check("LIGGGHTS", False, detail + " (datasets are made with 3.8)", liggghts.INSTALL_HINT)
    return Check("LIGGGHTS", ok, detail, "reinstall LIGGGHTS 3.8: " + liggghts.INSTALL_HINT)


def check_openfoam() -> Check:
    try:
        apps = openfoam.find_apps()
        env = openfoam.foam_env()
    except NeuraldemError as err:
        return Check("OpenFOAM", False, err.problem, err.fix or openfoam.INSTALL_HINT)
    try:
        proc = subprocess.run([str(apps["DPMFoam"]), "-help"], env=env, capture_output=True, text=True,
                              timeout=60)
    except subprocess.TimeoutExpired:
        return Check("OpenFOAM", False, "`DPMFoam -help` hung for 60 s", openfoam.INSTALL_HINT)
    out = proc.stdout + proc.stderr
    if proc.returncode != 0 or "Usage: DPMFoam" not in out:
        tail = " | ".join(out.strip().splitlines()[-2:])
        return Check("OpenFOAM", False, f"`DPMFoam -help` failed: {tail}",
                     f"set WM_PROJECT_DIR (Debian: {openfoam.DEBIAN_PROJECT_DIR}) or " + openfoam.INSTALL_HINT)
    m = re.search(r"Using: OpenFOAM-\S* \((\w+)\)", out)
    version = f"v{m.group(1)}" if m else "unknown version"
    return Check("OpenFOAM", True, f"{version}, DPMFoam + blockMesh at {apps['DPMFoam'].parent}, "
                                   f"WM_PROJECT_DIR={env['WM_PROJECT_DIR']}")


def check_data_dir() -> Check:
    root = paths.data_dir()
    fix = f"set {paths.ENV_VAR} to a writable folder with a few GB free"
    try:
        root.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=root, prefix=".doctor-"):
            pass
    except OSError as err:
        return Check("data dir", False, f"{root} is not writable ({err.strerror})", fix)
    free_gb = shutil.disk_usage(root).free / 2**30
    source = f"${paths.ENV_VAR}" if os.environ.get(paths.ENV_VAR) else "default"
    ok = free_gb >= 1.0
    return Check("data dir", ok, f"{root} ({source}), {free_gb:.1f} GB free", fix)


def check_gpu() -> Check:
    try:
        import torch

        if torch.cuda.is_available():
            name = torch.cuda.get_device_name(0)
            return Check("GPU", True, f"{torch.cuda.device_count()} x {name}", required=False)
    except Exception:  # noqa: BLE001
        pass
    return Check("GPU", False, "none (training and inference run on the CPU; a GPU only makes them faster)",
                 required=False)


CHECKS: dict[str, Callable[[], Check]] = {
    "python": check_python,
    "torch": check_torch,
    "torch-cluster": check_torch_cluster,
    "packages": check_python_stack,
    "liggghts": check_liggghts,
    "openfoam": check_openfoam,
    "data-dir": check_data_dir,
    "gpu": check_gpu,
}


def run_checks(names: list[str] | None = None) -> list[Check]:
    return [CHECKS[name]() for name in (names or list(CHECKS))]


def main(argv: list[str] | None = None) -> int:
    parser = doc_parser("neuraldem.doctor", __doc__)
    parser.add_argument("--only", nargs="+", choices=list(CHECKS), help="run only these checks")
    args = parser.parse_args(argv)
    checks = run_checks(args.only)
    for check in checks:
        print(check.line(), flush=True)
    failed = [c.name for c in checks if c.required and not c.ok]
    print(f"doctor: {len(failed)} required check(s) failed: {', '.join(failed)}" if failed
          else "doctor: all required checks passed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
