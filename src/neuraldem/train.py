"""`neuraldem train experiment=NAME`: compose the config, build data + model, fit with Lightning.

Outputs (checkpoints, logs, the composed config) go to the run folder under the data dir.
`--cfg job` prints the composed config, `--help` lists the config groups, `-m` runs a Hydra sweep.
Data-parallel training (trainer=ddp_cpu, trainer=ddp; docs/cluster_training.md): every process runs `train`,
rank 0 alone writes checkpoints and logs and runs the evaluation after training.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import lightning as L
import torch
from hydra.errors import InstantiationException
from hydra.utils import get_class, instantiate
from omegaconf import DictConfig, OmegaConf

from neuraldem.cli import hydra_app
from neuraldem.config import checks
from neuraldem.config.build import build_callbacks, build_loggers, build_trainer, check_trainer
from neuraldem.data.manifest import require_dataset
from neuraldem.errors import ConfigError, DataError, NeuraldemError
from neuraldem.eval.checkpoints import differing_keys, read_checkpoint
from neuraldem.lit import distributed
from neuraldem.models.schemas import validate_net
from neuraldem.scenes import scene

log = logging.getLogger(__name__)


def train(cfg: DictConfig) -> dict[str, float]:
    """Fit the model of `cfg` on its dataset; return the final logged metrics (for sweeps and tests)."""
    distributed.quiet_other_ranks()
    seed = checks.positive_int("seed", cfg.seed, allow_zero=True)
    L.seed_everything(seed, workers=True)
    for key in ("data", "model"):
        if cfg.get(key) is None:
            raise ConfigError(f"no {key} config selected: pick one with {key}=NAME or experiment=NAME")
    check_trainer(cfg.trainer)
    if cfg.model.get("net") is not None:  # the net's typed schema, before minutes go into loading data
        validate_net(cfg.model.net)
    check_resume_checkpoint(cfg)
    if OmegaConf.is_missing(cfg.data, "export_dir"):
        raise ConfigError("data.export_dir is required: neuraldem train experiment=gns_export_tiny "
                          "data.export_dir=DIR (a folder written by `neuraldem export gns`)")
    if cfg.data.get("export_dir") is None:  # else trained from an export, which its datamodule reads
        require_dataset(Path(cfg.data.dataset_dir), str(cfg.data.name))

    datamodule = instantiate_checked("data.datamodule", cfg.data.datamodule)
    module = instantiate_checked("model", cfg.model, datamodule=datamodule, _recursive_=False, **model_kwargs(cfg))
    loggers = build_loggers(cfg.get("logger"))
    trainer = build_trainer(cfg.trainer, callbacks=build_callbacks(cfg.get("callbacks"), with_logger=bool(loggers)),
                            loggers=loggers, strategies=distributed.STRATEGIES)
    distributed.prepare(trainer, cfg)
    for lg in trainer.loggers:
        lg.log_hyperparams(OmegaConf.to_container(cfg, resolve=True))  # type: ignore[arg-type]

    log.info("training %s on %s, run folder %s", type(module).__name__, cfg.data.name, cfg.paths.output_dir)
    trainer.fit(module, datamodule=datamodule, ckpt_path=cfg.get("ckpt_path"))
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items() if torch.is_tensor(v) and v.numel() == 1}
    if cfg.get("test"):
        trainer.test(module, datamodule=datamodule, ckpt_path="best" if trainer.checkpoint_callback else None)
        metrics.update({k: float(v) for k, v in trainer.callback_metrics.items() if v.numel() == 1})
    distributed.finish(trainer)
    bad = [k for k, v in metrics.items() if not math.isfinite(v)]
    if bad:
        log.warning("non-finite metrics at the end of training: %s", bad)
    if cfg.get("evaluate") and trainer.is_global_zero:  # one process writes the evaluation
        metrics.update(evaluate_after_training(cfg, trainer))
    return metrics


def evaluate_after_training(cfg: DictConfig, trainer: L.Trainer) -> dict[str, float]:
    """Score the best (else the last) checkpoint on the test split, into <run>/evaluation."""
    cb = trainer.checkpoint_callback
    ckpt = (cb.best_model_path or cb.last_model_path) if cb is not None else ""
    if not ckpt:
        raise ConfigError("evaluate=true needs checkpoints: keep callbacks.checkpoint enabled")
    out = Path(cfg.paths.output_dir) / "evaluation"
    result = scene(cfg.data.get("kind")).evaluate_run(cfg, Path(ckpt))
    log.info("evaluation of %s written to %s", ckpt, out)
    return {f"test/{k}": float(v) for k, v in result["aggregate"].items()}


RESUME_FIX = "resume with the killed run's <run>/checkpoints/latest.ckpt, or leave ckpt_path out to start afresh"


def model_class(model_cfg: DictConfig) -> Any:
    """The class `model._target_` names (None when it names none: a bad _target_ is reported where it is built)."""
    try:
        return get_class(str(model_cfg.get("_target_")))
    except Exception:
        return None


def model_kwargs(cfg: DictConfig) -> dict[str, Any]:
    """Constructor arguments the model's class derives from the whole config, not `model` alone, as the class
    declares them (`config_kwargs(cfg)`, e.g. the bed's stability options with the `rollout` group's in place)."""
    hook = getattr(model_class(cfg.model), "config_kwargs", None)
    return hook(cfg) if hook is not None else {}


def data_derived_net_keys(model_cfg: DictConfig) -> frozenset[str]:
    """Net keys the model's class sets from its dataset rather than from model.net, as the class declares them
    (`DATA_DERIVED_NET_KEYS`, e.g. the bed's grid channel count): a resumed run gets them from the same data."""
    return frozenset(getattr(model_class(model_cfg), "DATA_DERIVED_NET_KEYS", ()))


def check_resume_checkpoint(cfg: DictConfig) -> None:
    """A checkpoint to resume from that is missing, damaged or of another net fails here, in one line and
    before any data is read (Lightning would fail later, with a traceback)."""
    path = cfg.get("ckpt_path")
    if not path:
        return
    try:
        ckpt = read_checkpoint(Path(path))
    except DataError as err:
        raise ConfigError(f"config value ckpt_path={path} is invalid: {err.problem}", RESUME_FIX) from None
    net = cfg.model.get("net")
    trained = ckpt.hyper_parameters.get("net")
    if net is not None and trained is not None:
        diff = differing_keys(trained, OmegaConf.to_container(net, resolve=True))  # type: ignore[arg-type]
        derived = data_derived_net_keys(cfg.model)
        diff = [k for k in diff if k not in derived]
        if diff:
            raise ConfigError(f"config value ckpt_path={path} is invalid: its net differs from model.net in "
                              f"{', '.join(diff[:5])}",
                              "resume with the model overrides the run was started with, or leave ckpt_path out "
                              "to start afresh")


def instantiate_checked(key: str, node: DictConfig, **kwargs: Any) -> Any:
    """`hydra.utils.instantiate`, but a wrong `_target_` or argument becomes a ConfigError naming `key`;
    our own errors raised inside a constructor (bad value, missing dataset) pass through unchanged."""
    try:
        return instantiate(node, **kwargs)
    except InstantiationException as err:
        cause = err.__cause__
        if isinstance(cause, NeuraldemError):
            raise cause from None
        if cause is not None and not isinstance(cause, TypeError):  # a reader failed: say what, not Hydra's wrap
            raise DataError(f"cannot build {key}: {type(cause).__name__}: {cause}".splitlines()[0],
                            "if it names a dataset file, delete that file and rerun datagen (or re-import it)"
                            ) from None
        msg = str(err).strip().splitlines()[0]
        raise ConfigError(f"cannot build {key}: {msg}") from None


@hydra_app("train")
def main(cfg: DictConfig) -> float | None:
    metrics = train(cfg)
    return metrics.get("val/loss")  # what a Hydra sweeper optimises


if __name__ == "__main__":
    main()
