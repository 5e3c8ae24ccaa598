"""Every experiment composes, and its datamodule, model and trainer build (nothing is run)."""

from __future__ import annotations

import lightning as L
import pytest
from hydra.utils import instantiate

from neuraldem.config.build import build_callbacks, build_trainer
from neuraldem.paths import config_dir
from neuraldem.train import model_kwargs

EXPERIMENTS = sorted(p.stem for p in (config_dir() / "experiment").glob("*.yaml"))


def test_there_are_experiments():
    assert {"hopper_quickstart", "hopper_micro", "hopper_macro", "fb", "fb_quick"} <= set(EXPERIMENTS)


@pytest.mark.solver
@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_experiment_builds(experiment: str, compose_train_cfg, request: pytest.FixtureRequest, tmp_path):
    # the tiny real dataset of the experiment's kind stands in for its own (built by the same pipeline)
    kind = compose_train_cfg(f"experiment={experiment}").data.kind
    if kind == "gns_export":  # trained from an export (`neuraldem export`): one of the tiny hopper stands in
        from neuraldem.export.__main__ import export_dataset

        export_dataset("gns", request.getfixturevalue("hopper_tiny_dataset"), tmp_path / "export", exits="hold")
        cfg = compose_train_cfg(f"experiment={experiment}", f"data.export_dir={tmp_path / 'export'}")
        module = instantiate(cfg.model, datamodule=instantiate(cfg.data.datamodule), _recursive_=False,
                             **model_kwargs(cfg))
        assert cfg.task_name == experiment and module.metadata["scene_kind"] == "hopper"
        assert module.net.n_scalars == len(module.metadata["conditioning"]) and module.net.n_extra_walls == 0
        return
    tiny = {"hopper": "hopper_tiny", "hopper_refill": "hopper_refill_tiny", "fluidized_bed": "fb_tiny"}[kind]
    dataset = request.getfixturevalue(f"{tiny}_dataset")
    overrides = [f"data.dataset_dir={dataset}", f"data.name={tiny}"]
    if kind == "hopper_refill":  # the tiny runs last 2 s, shorter than the production window
        overrides.append("data.reference.window=0.25")
    # fb_tiny's 6 x 1 x 15 cells need patches that divide 15 (the GNS has no patches)
    if kind == "fluidized_bed" and not experiment.startswith("gns"):
        overrides.append("model.net.patch_size=[2,1,3]")
    cfg = compose_train_cfg(f"experiment={experiment}", *overrides)
    assert cfg.task_name == experiment
    dm = instantiate(cfg.data.datamodule)
    module = instantiate(cfg.model, datamodule=dm, _recursive_=False, **model_kwargs(cfg))  # as neuraldem.train
    assert isinstance(module, L.LightningModule)
    assert module.net.n_scalars == len(cfg.data.conditioning)
    # a GNS checkpoint is of kind "gns" (the field surrogates' tools refuse it) and names its scene apart
    assert module.metadata.get("scene_kind", module.metadata["kind"]) == kind == cfg.data.kind
    if experiment == "fb":  # the rollout group's options are what the model trains with and its checkpoint records
        recorded = module.hparams["stability"]
        assert (recorded["conserve_volume"], recorded["mixing"], recorded["advection_flux"]) == (
            True, "advect", "consistent")
    trainer = build_trainer(cfg.trainer, callbacks=build_callbacks(cfg.callbacks), loggers=[])
    assert trainer.max_steps == cfg.trainer.max_steps


@pytest.mark.parametrize("split", ["random", "band"])
def test_ablation_grid_composes(split: str, compose_train_cfg):
    for experiment in ("hopper_micro", "hopper_theta", "hopper_ffc", "hopper_macro", "hopper_all"):
        cfg = compose_train_cfg(f"experiment={experiment}", f"data.split={split}")
        assert cfg.data.datamodule.split == split and cfg.evaluate


@pytest.mark.parametrize("override", ["model.net.particle_branch=false", "model.residual=true"])
def test_fb_model_options_are_overridable(override: str, compose_train_cfg):
    cfg = compose_train_cfg("experiment=fb", override)
    key, value = override.split("=")
    node = cfg
    for part in key.split("."):
        node = node[part]
    assert node is (value == "true")


def test_the_bed_recipe_embeds_the_velocity_at_scale_10(compose_train_cfg):
    """experiment=fb conditions on the inlet velocity at sin-cos scale 10 (at the model config's 1000 one net in
    two collapsed at one velocity between training ones, results/fluidized_bed/options/); the old scale stays one
    override away."""
    assert compose_train_cfg("experiment=fb").model.net.scalar_coord_scale == 10.0
    assert compose_train_cfg("model=fb_tiny").model.net.scalar_coord_scale == 1000.0
    old = compose_train_cfg("experiment=fb", "model.net.scalar_coord_scale=1000")
    assert old.model.net.scalar_coord_scale == 1000.0


@pytest.mark.parametrize("override", ["model.optimizer.name=adamw", "model.net.scalar_coord_scale=10",
                                      "data.datamodule.fold=2", "data.datamodule.tail_share=0.3",
                                      "+callbacks.ema._target_=lightning.pytorch.callbacks.EMAWeightAveraging"])
def test_hopper_training_options_are_overridable(override: str, compose_train_cfg):
    """Every option of the hopper options study (scripts/hopper_options.sh) composes on the command line."""
    cfg = compose_train_cfg("experiment=hopper_micro", override)
    key, value = override.lstrip("+").split("=")
    node = cfg
    for part in key.split("."):
        node = node[part]
    assert str(node) == value


@pytest.mark.parametrize("trainer,gpus", [("ddp_cpu", None), ("ddp", 4)])
def test_slurm_ddp_launcher_asks_for_gpus_only_on_gpus(trainer: str, gpus: int | None):
    """hydra/launcher=slurm_ddp: one task per process on each node, and GPUs per node only for a GPU trainer
    (sbatch refuses a GPU request on a CPU partition: found on a one-node Slurm, scripts/local_slurm.sh)."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base=None):
        cfg = compose("train", overrides=["hydra/launcher=slurm_ddp", f"trainer={trainer}", "trainer.devices=4",
                                          "trainer.num_nodes=2", "experiment=hopper_quickstart"],
                      return_hydra_config=True)
    launcher = cfg.hydra.launcher
    assert (launcher.tasks_per_node, launcher.nodes, launcher.gpus_per_node) == (4, 2, gpus)


def test_fb_averages_the_weights_unless_told_not_to(compose_train_cfg):
    """experiment=fb trains with the EMA of the weights (chosen on validation rollouts,
    results/fluidized_bed/options/ema_mirror_val.md); null drops it."""
    from neuraldem.config.build import build_callbacks
    from neuraldem.lit.ema import Ema

    with_ema = build_callbacks(compose_train_cfg("experiment=fb").callbacks)
    assert isinstance(with_ema[-1], Ema)  # last: its validation swap wraps every other callback's
    without = build_callbacks(compose_train_cfg("experiment=fb", "callbacks.ema=null").callbacks)
    assert not any(isinstance(cb, Ema) for cb in without)
    with pytest.raises(Exception, match="callbacks.ema.decay"):
        build_callbacks(compose_train_cfg("experiment=fb", "callbacks.ema.decay=1.5").callbacks)


def test_fb_keeps_every_validated_checkpoint_beside_the_kept_one(compose_train_cfg, tmp_path):
    """experiment=fb writes a checkpoint at every validation to checkpoints/all/ (for `neuraldem report fb-select`)
    while checkpoints/ keeps the one the rollout validation chose, and last.ckpt with it."""
    from lightning.pytorch.callbacks import ModelCheckpoint
    from lightning.pytorch.demos.boring_classes import BoringModel

    cfg = compose_train_cfg("experiment=fb", f"paths.output_dir={tmp_path}")
    every = [cb for cb in build_callbacks(cfg.callbacks) if isinstance(cb, ModelCheckpoint)
             and str(cb.dirpath).endswith("checkpoints/all")]
    assert len(every) == 1
    kept = ModelCheckpoint(dirpath=tmp_path / "checkpoints", filename="step{step:06d}", monitor="val_loss",
                           save_top_k=1, auto_insert_metric_name=False)

    class Model(BoringModel):
        def validation_step(self, batch, batch_idx):
            self.log("val_loss", 1.0 / (1 + self.global_step))  # improves every time: one file kept
            return super().validation_step(batch, batch_idx)

    trainer = L.Trainer(max_steps=6, val_check_interval=2, limit_val_batches=1, accelerator="cpu", logger=False,
                        enable_progress_bar=False, enable_model_summary=False, num_sanity_val_steps=0,
                        callbacks=[kept, every[0]])
    trainer.fit(Model())
    assert sorted(p.name for p in (tmp_path / "checkpoints" / "all").glob("*.ckpt")) == [
        "step000002.ckpt", "step000004.ckpt", "step000006.ckpt"]
    assert sorted(p.name for p in (tmp_path / "checkpoints").glob("*.ckpt")) == ["step000006.ckpt"]
