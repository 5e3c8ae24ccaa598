"""Building Lightning objects (trainer, loggers, callbacks) from their config groups, with checks."""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import lightning as L
from hydra.utils import instantiate
from lightning.pytorch.callbacks import LearningRateMonitor, ModelCheckpoint, ProgressBar, WeightAveraging
from lightning.pytorch.plugins.io import TorchCheckpointIO
from omegaconf import DictConfig

from neuraldem.config import checks
from neuraldem.errors import ConfigError

ACCELERATORS = ("auto", "cpu", "gpu", "cuda", "mps")
# logged by neuraldem.scenes.fluidized_bed.surrogate.rollout_validation.RolloutValidation
ROLLOUT_METRICS = "val/rollout_"


def check_trainer(cfg: DictConfig) -> None:
    """Validate the trainer values users commonly set; anything else is checked by Lightning itself."""
    checks.one_of("trainer.accelerator", cfg.get("accelerator", "auto"), ACCELERATORS)
    max_steps = cfg.get("max_steps", -1)
    if max_steps != -1:
        checks.positive_int("trainer.max_steps", max_steps)
    max_epochs = cfg.get("max_epochs", -1)
    if max_epochs not in (-1, None):
        checks.positive_int("trainer.max_epochs", max_epochs)
    checks.positive_int("trainer.log_every_n_steps", cfg.get("log_every_n_steps", 50))
    vci = cfg.get("val_check_interval")
    if vci is not None:
        if isinstance(vci, float) and not isinstance(vci, bool):
            checks.number("trainer.val_check_interval", vci, lo=0.0, hi=1.0, lo_open=True)
        else:
            checks.positive_int("trainer.val_check_interval", vci)
    clip = cfg.get("gradient_clip_val")
    if clip is not None:
        checks.positive("trainer.gradient_clip_val", clip)
    check_devices(cfg.get("devices", "auto"))
    checks.positive_int("trainer.num_nodes", cfg.get("num_nodes", 1))
    if cfg.get("use_distributed_sampler", False) is not False:
        raise ConfigError(f"config value trainer.use_distributed_sampler={cfg.get('use_distributed_sampler')!r} is "
                          "invalid: neuraldem's loaders split the data between processes themselves (Lightning's "
                          "sampler would split it again)", "leave it at false")


DEVICES_TEXT = re.compile(r"-1|\d+(,\d+)*,?")  # what Lightning reads from a string: a count, -1, GPU ids


def check_devices(devices: object) -> None:
    """trainer.devices: a number of processes (>= 1), -1 or auto (all GPUs / one CPU process), or GPU ids."""
    fix = ("must be a number of processes (>= 1), -1 (every GPU), auto, or a list of GPU ids "
           "(override it, e.g. trainer.devices=2)")
    if isinstance(devices, bool):
        ok = False
    elif isinstance(devices, int):
        ok = devices >= 1 or devices == -1
    elif isinstance(devices, str):
        ok = devices == "auto" or (DEVICES_TEXT.fullmatch(devices.strip()) is not None
                                   and devices.strip() not in ("0", ""))
    elif isinstance(devices, Sequence):
        ids = list(devices)
        ok = bool(ids) and all(isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in ids) \
            and len(set(ids)) == len(ids)
    else:
        ok = False
    if not ok:
        raise ConfigError(f"config value trainer.devices={devices!r} is invalid: {fix}")


class AtomicCheckpointIO(TorchCheckpointIO):
    """Checkpoints written under a temporary name, flushed, then renamed: a run killed while saving leaves the
    previous checkpoint (what `ckpt_path=<run>/checkpoints/latest.ckpt` resumes from) whole, never a
    half-written file under its name."""

    def save_checkpoint(self, checkpoint: dict[str, Any], path: str | Path, storage_options: Any = None) -> None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".partial")
        try:
            super().save_checkpoint(checkpoint, tmp, storage_options)
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)


def build_trainer(cfg: DictConfig, callbacks: list[Any], loggers: list[Any],
                  strategies: dict[str, Any] | None = None) -> L.Trainer:
    """The Trainer of `cfg`; `strategies` maps a strategy name to the object that replaces it (the caller's DDP
    that launches its own job, `lit.distributed.JobDDPStrategy`, for `trainer.strategy=ddp`)."""
    check_trainer(cfg)
    # the progress bar is the `callbacks.progress` entry; with it set to null there is none (Lightning would
    # otherwise add its default bar, which fills the logs of background runs)
    if not cfg.get("enable_progress_bar", True):  # switched off in the trainer config: no bar either way
        callbacks = [cb for cb in callbacks if not isinstance(cb, ProgressBar)]
    has_bar = any(isinstance(cb, ProgressBar) for cb in callbacks)
    try:
        extra: dict[str, Any] = {} if cfg.get("plugins") else {"plugins": [AtomicCheckpointIO()]}  # users' win
        strategy = cfg.get("strategy")
        if isinstance(strategy, str) and strategy in (strategies or {}):
            extra["strategy"] = (strategies or {})[strategy]()
        extra["use_distributed_sampler"] = False  # our loaders split the batches (data.part_loaders)
        return instantiate(cfg, callbacks=callbacks, logger=loggers or False, enable_progress_bar=has_bar, **extra)
    except Exception as err:  # Lightning's own validation (MisconfigurationException, ValueError, ...)
        msg = str(getattr(err, "__cause__", None) or err).strip().splitlines()[0]
        raise ConfigError(f"invalid trainer config: {msg}") from None


def _build_group(name: str, cfg: DictConfig | None) -> list[Any]:
    out = []
    for key, node in (cfg or {}).items():
        if node is None:  # disabled with e.g. callbacks.lr_monitor=null
            continue
        if not isinstance(node, DictConfig) or "_target_" not in node:
            raise ConfigError(f"{name}.{key} must be a config with a _target_ (or null to disable it)")
        try:
            out.append(instantiate(node))
        except Exception as err:  # noqa: BLE001
            msg = str(getattr(err, "__cause__", None) or err).strip().splitlines()[0]
            raise ConfigError(f"cannot build {name}.{key}: {msg}") from None
    return out


def build_loggers(cfg: DictConfig | None) -> list[Any]:
    return _build_group("logger", cfg)


def build_callbacks(cfg: DictConfig | None, with_logger: bool = True) -> list[Any]:
    """Callbacks of the config; without a logger, those that only feed a logger (LR monitor) are left out
    rather than letting Lightning refuse the run."""
    callbacks = _build_group("callbacks", cfg)
    if not with_logger:
        callbacks = [cb for cb in callbacks if not isinstance(cb, LearningRateMonitor)]
    # weight averaging (EMA) last: it swaps the averaged weights in at the start of a validation and back at its
    # end, so every other callback's validation hook (e.g. the practitioner validation) sees the averaged model
    callbacks.sort(key=lambda cb: isinstance(cb, WeightAveraging))
    check_monitored_metrics(callbacks)
    return callbacks


def check_monitored_metrics(callbacks: list[Any]) -> None:
    """A checkpoint that monitors the rollout validation's metrics needs that callback: without it Lightning
    would stop the run at its first validation, minutes or hours in; say so before training starts."""
    logs_rollouts = any(type(cb).__name__ == "RolloutValidation" for cb in callbacks)
    for cb in callbacks:
        monitor = getattr(cb, "monitor", None) if isinstance(cb, ModelCheckpoint) else None
        if monitor and str(monitor).startswith(ROLLOUT_METRICS) and not logs_rollouts:
            raise ConfigError(f"config value callbacks.checkpoint.monitor={monitor} is invalid: only "
                              "callbacks.rollout_validation logs it, and it is disabled (override it, e.g. "
                              "callbacks.checkpoint.monitor=val/loss)")
