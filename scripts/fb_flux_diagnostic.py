"""A bed model's predicted solids flux against CFD-DEM's, on held-out trajectories (a diagnostic of the mixing error).

    python scripts/fb_flux_diagnostic.py ckpt=CKPT dataset=DATASET_DIR sims=[sim_0003,sim_0081] [steps=200] \\
        [out=FILE.md]

Why: the advected mixing is only as good as the flux that carries it. Per trajectory, over a rollout of
`steps=` steps from snapshot 1 and the same CFD-DEM steps: the mean solids flux magnitude in the bed (cells
with solid fraction > 0.1), its autocorrelation in time at lags 1 and 5 steps (an oscillating bed has a
negative one), and how far the flux is from carrying the solid fraction's own change over the step: the norm
of the smallest gradient correction that makes it consistent (`consistent_faces`, as advection_flux=consistent
applies it) over the norm of the face fluxes. CFD-DEM's kernel flux is not exactly consistent either (the
kernel field of moving particles), which is the scale to compare with.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from neuraldem.cli import CommandParser
from neuraldem.models.modules.conservative_advection import consistent_faces, face_fluxes
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.rollout import ModelStepper, initial_state
from neuraldem.scenes.fluidized_bed.surrogate.rollout_run import load_fb_checkpoint

BED = 0.1  # solid fraction above which a cell counts as bed


def flux_stats(flux: np.ndarray, alpha: np.ndarray) -> tuple[float, float, float]:
    """Mean |j| in the bed [mm/s] and the lag-1 / lag-5 autocorrelation of j there; flux (T, ..., 3) of the
    steps ending at alpha (T, ...)."""
    bed = alpha > BED
    mag = float(np.linalg.norm(flux, axis=-1)[bed].mean()) * 1000.0

    def lag(k: int) -> float:
        return float(np.corrcoef(flux[k:][bed[k:]].ravel(), flux[:-k][bed[k:]].ravel())[0, 1])

    return mag, lag(1), lag(5)


def correction_ratio(alpha: np.ndarray, flux: np.ndarray, dt: float, spacing: list[float]) -> float:
    """||consistent - given|| / ||given|| over all face fluxes: alpha (T + 1, ...), flux (T, ..., 3) of step
    k -> k + 1."""
    num = den = 0.0
    for k in range(len(flux)):
        a0, a1 = (torch.from_numpy(np.asarray(alpha[i], dtype=np.float64))[None] for i in (k, k + 1))
        faces = face_fluxes(torch.from_numpy(np.moveaxis(np.asarray(flux[k], dtype=np.float64), -1, 0))[None])
        fixed = consistent_faces(a0, a1, faces, dt, spacing)
        for ax, jf in faces.items():
            num += float(((fixed[ax] - jf) ** 2).sum())
            den += float((jf ** 2).sum())
    return (num / den) ** 0.5


def main() -> None:
    p = CommandParser(prog="python scripts/fb_flux_diagnostic.py", description=__doc__)
    p.add_argument("ckpt", type=Path)
    p.add_argument("dataset", type=Path, help="the dataset dir (its sims/<id>.h5 are read)")
    p.add_argument("sims", nargs="+")
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args()
    module = load_fb_checkpoint(args.ckpt)
    lines = [f"`python scripts/fb_flux_diagnostic.py ckpt={args.ckpt} dataset={args.dataset} "
             f"sims=[{','.join(args.sims)}] steps={args.steps}`", "",
             "| trajectory | U0 [m/s] | mean abs. flux in bed [mm/s] model / CFD-DEM | lag-1 autocorr. model / "
             "CFD-DEM | lag-5 autocorr. model / CFD-DEM | correction / flux model / CFD-DEM |",
             "|---|---|---|---|---|---|"]
    for sim in args.sims:
        with BedFile(args.dataset / "sims" / f"{sim}.h5") as f:
            n, spacing = args.steps, [float(h) for h in f.grid.spacing]
            stepper, state = ModelStepper(module, f.inlet_velocity), initial_state(f, 1)
            alpha, flux = [state.solid_fraction], []
            for _ in range(n):
                state = stepper.step(state)
                alpha.append(state.solid_fraction)
                flux.append(state.solids_flux)
            alpha_m, flux_m = np.array(alpha), np.array(flux)
            alpha_t = f.solid_fraction(slice(1, n + 2))      # snapshots 1 .. n + 1
            flux_t = f.solids_flux()[2:n + 2]                  # the steps 1 -> 2 .. n -> n + 1
            m, t = flux_stats(flux_m, alpha_m[1:]), flux_stats(flux_t, alpha_t[1:])
            lines.append(f"| {sim} | {f.inlet_velocity:.3f} | {m[0]:.1f} / {t[0]:.1f} | {m[1]:.2f} / {t[1]:.2f} "
                         f"| {m[2]:.2f} / {t[2]:.2f} | {correction_ratio(alpha_m, flux_m, f.dt, spacing):.2f} / "
                         f"{correction_ratio(alpha_t, flux_t, f.dt, spacing):.2f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)


if __name__ == "__main__":
    main()
