"""How well can advection alone mix the bed? The mixing concentration carried by CFD-DEM's own solid fraction and
solids flux (an oracle: no model in the loop), scored like a rollout against CFD-DEM's mixing field.

    neuraldem report advection-oracle dataset=DATASET_DIR [sims=[sim_0003,...]] [out=DIR]
    neuraldem report advection-oracle dataset=DATASET_DIR ckpt=CKPT part=train+val [steps=300]
    ... [flux=consistent]   # the flux corrected to carry the solid to the next solid fraction

For each trajectory and flux-correction weight (1 = flux-corrected transport, 0 = upwind) the concentration
starts from the stored one at snapshot 0 and is advected step by step with the stored solid fraction at t and
the solids flux of the step t -> t+1 (deposited at the particles' positions at t + 1, as the model's next state
carries it). Output: Lacey curves and their MAE against CFD-DEM's field Lacey index (the evaluation's
definition) and the largest swing of the tagged solid volume (0 when nothing is mixed in or lost from step to
step), JSON + a markdown table. It bounds what `rollout.mixing=advect` can reach: a model's flux
is at best this one.

With `ckpt=` the fields come from the model instead: one rollout per trajectory and correction weight
(`steps=` long, from snapshot 1, the model's own solid fraction and flux), scored the same way. Use it on the
training and validation parts only, to choose `rollout.advection_correction` for a trained model
without looking at the test velocities.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from neuraldem.cli import command_parser
from neuraldem.data.manifest import Manifest
from neuraldem.data.schema import atomic_write_json
from neuraldem.machine import machine_info
from neuraldem.models.modules.conservative_advection import advect_tagged, tagged_volume
from neuraldem.paths import module_command
from neuraldem.scenes.fluidized_bed.analysis.metrics import lacey_from_fields
from neuraldem.scenes.fluidized_bed.dataset.report import metric_settings
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.options import ADVECTION_FLUXES, RolloutOptions


def advected_mixing(f: BedFile, scheme: str, correction: float = 1.0, flux_mode: str = "predicted") -> np.ndarray:
    """(T, nx, ny, nz) concentration advected with the stored fields (module docstring); `flux_mode`
    "consistent": the flux corrected to carry the solid fraction at t to the stored one at t + 1."""
    spacing = [float(h) for h in f.grid.spacing]
    alpha, flux = f.solid_fraction(), f.solids_flux()
    conc = torch.tensor(f.mixing(0))[None]
    out = [f.mixing(0)]
    for t in range(f.n_snapshots - 1):
        j = torch.tensor(np.moveaxis(flux[t + 1], -1, 0))[None]
        target = torch.tensor(alpha[t + 1])[None] if flux_mode == "consistent" else None
        conc, _ = advect_tagged(torch.tensor(alpha[t])[None], conc, j, f.dt, spacing, scheme=scheme,
                                correction=correction, target=target)
        out.append(conc[0].numpy())
    return np.stack(out)


def tagged_swing(solid_fraction: np.ndarray, mixing: np.ndarray) -> float:
    """Largest relative change [%] of the tagged (group-B) solid volume over a (T, ...) series: 0 for a scheme
    that conserves it from step to step."""
    series = tagged_volume(torch.from_numpy(np.asarray(solid_fraction, dtype=np.float64)),
                           torch.from_numpy(np.asarray(mixing, dtype=np.float64))).numpy()
    return float(100 * np.max(np.abs(series / series[0] - 1.0)))


def oracle(path: Path, settings: dict[str, Any], corrections: list[float],
           flux_mode: str = "predicted") -> dict[str, Any]:
    block, min_count = tuple(settings["lacey_block"]), float(settings["lacey_min_count"])
    with BedFile(path) as f:
        alpha, vp = f.solid_fraction(), float(np.mean(f.particle_volumes))
        truth = lacey_from_fields(alpha, f.mixing(), f.grid.cell_volume, vp, block, min_count)
        row: dict[str, Any] = {"sim_id": f.sim_id, "inlet_velocity": f.inlet_velocity, "lacey_truth": truth.tolist()}
        for c in corrections:
            mixing = advected_mixing(f, "fct", c, flux_mode)
            lacey = lacey_from_fields(alpha, mixing, f.grid.cell_volume, vp, block, min_count)
            row[f"lacey_{c:g}"] = lacey.tolist()
            row[f"mae_{c:g}"] = float(np.nanmean(np.abs(lacey - truth)))
            row[f"tagged_swing_pct_{c:g}"] = tagged_swing(alpha, mixing)
    return row


def model_rows(ckpt: Path, paths: list[Path], settings: dict[str, Any], corrections: list[float],
               steps: int, flux_mode: str | None = None) -> list[dict[str, Any]]:
    from neuraldem.scenes.fluidized_bed.analysis.evaluation import FieldSeries
    from neuraldem.scenes.fluidized_bed.surrogate.rollout import (
        DEFAULT_INIT_SNAPSHOT,
        ModelStepper,
        initial_state,
        rollout,
    )
    from neuraldem.scenes.fluidized_bed.surrogate.rollout_run import load_fb_checkpoint

    module = load_fb_checkpoint(ckpt)
    block, min_count = tuple(settings["lacey_block"]), float(settings["lacey_min_count"])
    rows = []
    for path in paths:
        with BedFile(path) as f:
            truth = FieldSeries.from_dataset_file(f).since(DEFAULT_INIT_SNAPSHOT)
            n = min(steps, len(truth.times) - 1)
            vp = truth.particle_volume
            lacey_truth = lacey_from_fields(truth.solid_fraction[: n + 1], truth.mixing[: n + 1],
                                            f.grid.cell_volume, vp, block, min_count)
            row: dict[str, Any] = {"sim_id": f.sim_id, "inlet_velocity": f.inlet_velocity,
                                   "lacey_truth": lacey_truth.tolist()}
            state = initial_state(f)
            for c in corrections:
                options = RolloutOptions(mixing="advect", advection_correction=c, advection_flux=flux_mode)
                stepper = ModelStepper(module, f.inlet_velocity, 0, options=options)
                r = rollout(stepper, state, n, progress=False)
                if r.diverged_at is not None:  # a few steps say nothing about mixing: not scored
                    row[f"lacey_{c:g}"], row[f"mae_{c:g}"] = [], float("nan")
                    row[f"diverged_{c:g}"] = r.diverged_at
                    continue
                lacey = lacey_from_fields(r.solid_fraction.astype(np.float64), r.mixing.astype(np.float64),
                                          f.grid.cell_volume, vp, block, min_count)
                row[f"lacey_{c:g}"] = lacey.tolist()
                row[f"mae_{c:g}"] = float(np.nanmean(np.abs(lacey - lacey_truth[: len(lacey)])))
                row[f"tagged_swing_pct_{c:g}"] = tagged_swing(r.solid_fraction, r.mixing)
        rows.append(row)
    return rows


def markdown(rows: list[dict[str, Any]], corrections: list[float], command: str) -> str:
    head = " | ".join(f"correction {c:g}: 1 s / end | MAE | tagged swing [%]" for c in corrections)
    lines = ["# Mixing by advection (CFD-DEM's own solid fraction and solids flux, or with ckpt= a model's)", "",
             f"`{command}`", "", "correction 1 = flux-corrected transport, 0 = first-order upwind.", "",
             f"| trajectory | U0 [m/s] | Lacey CFD-DEM at 1 s / end | {head} |",
             "|---|---|---|" + "---|---|---|" * len(corrections)]
    for r in rows:
        k = min(100, len(r["lacey_truth"]) - 1)
        cells = [f"{r['lacey_truth'][k]:.2f} / {r['lacey_truth'][-1]:.2f}"]
        for c in corrections:
            curve = r[f"lacey_{c:g}"]
            if not curve:
                cells += [f"diverged at step {r.get(f'diverged_{c:g}')}", "n/a", "n/a"]
                continue
            cells += [f"{curve[min(k, len(curve) - 1)]:.2f} / {curve[-1]:.2f}", f"{r[f'mae_{c:g}']:.3f}",
                      f"{r[f'tagged_swing_pct_{c:g}']:.1f}"]
        lines.append(f"| {r['sim_id']} | {r['inlet_velocity']:.3f} | " + " | ".join(cells) + " |")
    means = [f"{np.nanmean([r[f'mae_{c:g}'] for r in rows]):.3f}" for c in corrections]
    swings = [f"{np.nanmax([r.get(f'tagged_swing_pct_{c:g}', np.nan) for r in rows]):.1f}" for c in corrections]
    lines.append("| mean MAE, largest swing | | | " + " | ".join(f"| {m} | {w}" for m, w in zip(means, swings,
                                                                                          strict=True)) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = command_parser("neuraldem.scenes.fluidized_bed.analysis.advection_oracle", __doc__, summary=True)
    p.add_argument("dataset", type=Path, help="a fluidized-bed dataset folder (with manifest.json)")
    p.add_argument("--sims", nargs="*", help="trajectories (default: the test part of the velocity split)")
    p.add_argument("--part", default="test", choices=["train", "val", "test", "train+val"],
                   help="the part of the velocity split scored when sims= is not given (calibrate on train+val)")
    p.add_argument("--corrections", nargs="*", type=float, default=[0.0, 1.0],
                   help="flux-correction weights to compare (1 = flux-corrected, 0 = upwind)")
    p.add_argument("--ckpt", type=Path, default=None,
                   help="score a model's rollouts (its own solid fraction and flux) instead of the oracle")
    p.add_argument("--steps", type=int, default=300, help="rollout steps with ckpt=")
    p.add_argument("--flux", choices=list(ADVECTION_FLUXES), default=None,
                   help="predicted: the stored (or the model's) flux as it is; consistent: corrected to carry the "
                        "solid to the next solid fraction (default: predicted for the oracle, the checkpoint's "
                        "option with ckpt=)")
    p.add_argument("--out", type=Path, default=None, help="folder for oracle.json and oracle.md")
    a = p.parse_args(argv)
    m = Manifest.load(a.dataset)
    sims = a.sims or [i for part in a.part.split("+") for i in m.split_ids("velocity", part)]
    bad = [c for c in a.corrections if not 0.0 <= c <= 1.0]
    if bad:
        p.error(f"corrections={bad}: each must be in [0, 1]")
    if not sims:
        p.error(f"{a.dataset} has no test trajectories; name some with sims=")
    unknown = [s for s in sims if s not in {r.sim_id for r in m.usable()}]
    if unknown:
        p.error(f"sims={unknown} are not finished trajectories of {a.dataset}")
    settings = metric_settings(m)
    paths = [a.dataset / str(m.record(s).file) for s in sims]
    if a.ckpt is not None:
        if a.steps < 1:
            p.error(f"steps={a.steps}: must be >= 1")
        rows = model_rows(a.ckpt, paths, settings, a.corrections, a.steps, a.flux)
    else:
        rows = [oracle(path, settings, a.corrections, a.flux or "predicted") for path in paths]
    command = module_command("neuraldem.scenes.fluidized_bed.analysis.advection_oracle", argv)
    text = markdown(rows, a.corrections, command)
    print(text)
    if a.out:
        a.out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(a.out / "oracle.json", {"rows": rows, "machine": machine_info(), "command": command})
        (a.out / "oracle.md").write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
