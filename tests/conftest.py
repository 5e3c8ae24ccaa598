"""Shared test setup: quiet, CPU-friendly threading; a private data dir; the Hydra config, shrunk for CPU."""

from __future__ import annotations

import os

# Spinning OpenMP threads make small ops several times slower on a shared 2-core machine.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("WANDB_MODE", "offline")
os.environ.setdefault("WANDB_SILENT", "true")

from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(int(os.environ.get("NEURALDEM_TEST_THREADS", "1")))


@pytest.fixture(scope="session")
def data_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A data dir for the whole test session, so tests never touch the user's $NEURALDEM_DATA.

    Set NEURALDEM_TEST_DATA to reuse solver datasets between test sessions (they are resumable)."""
    keep = os.environ.get("NEURALDEM_TEST_DATA")
    root = Path(keep) if keep else tmp_path_factory.mktemp("neuraldem-data")
    root.mkdir(parents=True, exist_ok=True)
    return root


@pytest.fixture(autouse=True)
def _private_data_dir(data_root: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NEURALDEM_DATA", str(data_root))


@pytest.fixture
def compose_train_cfg(tmp_path: Path):
    """Compose `conf/train.yaml` with overrides, shrunk for a CPU test run (no logger, few steps)."""
    from tests.helpers import compose_cfg

    def _compose(*overrides: str, config_name: str = "train"):
        return compose_cfg(config_name, list(overrides), output_dir=tmp_path)

    return _compose
