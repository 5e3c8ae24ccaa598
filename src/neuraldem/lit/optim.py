"""The paper's optimisation (LION, linear warm-up then cosine decay) from `model.optimizer` / `model.scheduler`,
validated once here so every LightningModule checks the same keys the same way. `model.optimizer.name: adam`
takes Adam instead (the GNS baseline's optimizer), `adamw` AdamW (decoupled weight decay), with the same
schedule."""

from __future__ import annotations

from typing import Any

import torch
from lion_pytorch import Lion
from omegaconf import DictConfig, OmegaConf

from neuraldem.config import checks
from neuraldem.errors import ConfigError
from neuraldem.lit.schedules import warmup_cosine

DEFAULT_OPTIMIZER = {"name": "lion", "lr": 1e-4, "weight_decay": 0.05, "betas": [0.9, 0.99]}
OPTIMIZERS = ("lion", "adam", "adamw")
DEFAULT_SCHEDULER = {"warmup_steps": 100, "end_factor": 0.01}
FALLBACK_TOTAL_STEPS = 10_000  # cosine length when the trainer has no max_steps


def plain(cfg: DictConfig | dict | None) -> dict[str, Any]:
    """Plain Python containers: checkpoints must load without trusting omegaconf classes."""
    if cfg is None:
        return {}
    return OmegaConf.to_container(cfg) if isinstance(cfg, DictConfig) else dict(cfg)  # type: ignore[return-value]


def optimizer_settings(optimizer: DictConfig | dict | None,
                       scheduler: DictConfig | dict | None) -> tuple[dict[str, Any], dict[str, Any]]:
    """Defaults + the config's values, checked (keys named as the user writes them)."""
    opt = DEFAULT_OPTIMIZER | plain(optimizer)
    sched = DEFAULT_SCHEDULER | plain(scheduler)
    for key, values, known in (("model.optimizer", opt, DEFAULT_OPTIMIZER), ("model.scheduler", sched,
                                                                            DEFAULT_SCHEDULER)):
        checks.known_keys(key, values, known)
    checks.one_of("model.optimizer.name", opt["name"], OPTIMIZERS)
    checks.positive("model.optimizer.lr", opt["lr"])
    checks.number("model.optimizer.weight_decay", opt["weight_decay"], lo=0.0)
    betas = opt["betas"]
    if isinstance(betas, str) or not isinstance(betas, (list, tuple)) or len(betas) != 2:
        raise ConfigError(f"config value model.optimizer.betas={betas!r} is invalid: must be a pair "
                          "(override it, e.g. model.optimizer.betas=[0.9,0.99])")
    for i, b in enumerate(betas):
        checks.number(f"model.optimizer.betas[{i}]", b, lo=0.0, hi=1.0, hi_open=True)
    checks.positive_int("model.scheduler.warmup_steps", sched["warmup_steps"], allow_zero=True)
    checks.fraction("model.scheduler.end_factor", sched["end_factor"])
    return opt, sched


def lion_warmup_cosine(params: Any, opt: dict[str, Any], sched: dict[str, Any],
                       max_steps: int | None) -> dict[str, Any]:
    """What `configure_optimizers` returns: LION (or Adam, `opt["name"]`) with the schedule stepped every
    optimizer step."""
    kwargs = {"lr": opt["lr"], "betas": tuple(opt["betas"]), "weight_decay": opt["weight_decay"]}
    optimizer = {"adam": torch.optim.Adam, "adamw": torch.optim.AdamW}.get(opt.get("name"), Lion)(params, **kwargs)
    total = max_steps if max_steps and max_steps > 0 else FALLBACK_TOTAL_STEPS
    warm, end = sched["warmup_steps"], sched["end_factor"]
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda s: warmup_cosine(s, warm, total, end))
    return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}
