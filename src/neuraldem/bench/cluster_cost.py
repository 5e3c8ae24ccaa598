"""What a paper-scale dataset costs on a cluster, from measured solver rates (docs/cluster.md).

`neuraldem bench cluster_cost [hopper_scaling=results/hopper/speed/hopper_scaling.json]
[fb_speed=results/fluidized_bed/speed/fb_speed.json] [hopper_dataset=DIR] [particles=[5000,50000,250000]]
[hopper_runs=1000] [bed_trajectories=100] [out=results/cluster/cluster_cost.json]`

Nothing is re-run here: the figures come from two benchmarks' result files, each measured on one core.
- Hopper: `hopper_scaling` measured LIGGGHTS at 2k .. 50k particles (settle seconds, drain particle-steps per
  second, the dataset's stored window). A count it measured is read off; a count beyond it (250k) is a
  power-law fit of settle and drain seconds over the three largest measured counts, marked as extrapolated
  with the fit's exponent. `hopper_dataset=` adds the material characterization (shear + heap) per
  parameter set, the median its manifest recorded.
- Bed: `fb_speed` holds DPMFoam's CPU seconds per simulated second, the median over the dataset manifest's
  runs; a trajectory costs (spin-up + stored duration) times that, for the 3-s training and 30-s long ones.
CPU-hours are single-core solver hours; a Slurm array of K one-core tasks takes about CPU-hours / K of wall
time when the queue gives K cores at once.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.bench.report import command_line, default_path, read_results, resolve_out, write_report
from neuraldem.cli import doc_parser
from neuraldem.config import checks
from neuraldem.data.manifest import Manifest
from neuraldem.errors import DataError
from neuraldem.paths import results_dir

NAME = "cluster_cost"
DEFAULT_PARTICLES = (5000, 50000, 250000)
FIT_POINTS = 3  # the largest measured counts a power law is fitted to
HOUR = 3600.0


def power_law(n: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(exponent b, prefactor a) of y = a * n**b, least squares in log-log."""
    b, log_a = np.polyfit(np.log(n), np.log(y), 1)
    return float(b), float(math.exp(log_a))


def hopper_points(scaling: dict[str, Any]) -> list[dict[str, float]]:
    """Per measured particle count: settle seconds, drain seconds of the stored window, their sum, the drain
    rate, and the process CPU seconds of a full run where one was run in full."""
    try:
        points = scaling["solver"]["points"]
        rows = [{"n_particles": int(p["n_particles"]), "settle_s": float(p["measured"]["settle_s"]),
                 "drain_s": float(p["extrapolated"]["drain_s"]), "run_s": float(p["extrapolated"]["full_run_s"]),
                 "drain_particle_steps_per_s": float(p["measured"]["drain_particle_steps_per_s"]),
                 "full_run_cpu_s": float((p.get("full_run_measured") or {}).get("process_cpu_s", math.nan))}
                for p in points]
    except (KeyError, TypeError) as err:
        raise DataError(f"hopper_scaling results lack solver.points[...] field {err}: rerun "
                        "`neuraldem bench hopper_scaling`") from None
    if len(rows) < FIT_POINTS:
        raise DataError(f"hopper_scaling results hold {len(rows)} particle counts; the cost model fits "
                        f"{FIT_POINTS}: rerun it with particles=[2000,5000,10000,20000,50000]")
    return sorted(rows, key=lambda r: r["n_particles"])


def hopper_run_cost(points: list[dict[str, float]], n: int) -> dict[str, Any]:
    """One stored-window hopper run at `n` particles: measured when `n` was measured, else extrapolated."""
    for p in points:
        if p["n_particles"] == n:
            full = p["full_run_cpu_s"]
            source = "settle measured, drain at the measured rate" + (
                f"; a full run measured {full:.0f} CPU s" if math.isfinite(full) else "")
            return {"n_particles": n, "source": source, "settle_s": p["settle_s"], "drain_s": p["drain_s"],
                    "run_s": p["run_s"], "drain_particle_steps_per_s": p["drain_particle_steps_per_s"],
                    "full_run_cpu_s_measured": p["full_run_cpu_s"]}
    fit = points[-FIT_POINTS:]
    ns = np.array([p["n_particles"] for p in fit], dtype=float)
    out: dict[str, Any] = {"n_particles": n, "source": (f"power-law fit over {int(ns[0])} .. {int(ns[-1])} "
                                                        "particles" + (" (extrapolated)" if n > ns[-1] else ""))}
    for key in ("settle_s", "drain_s"):
        b, a = power_law(ns, np.array([p[key] for p in fit]))
        out[key], out[f"{key}_exponent"] = a * n ** b, b
    out["run_s"] = out["settle_s"] + out["drain_s"]
    out["source"] += f"; settle ~ N^{out['settle_s_exponent']:.2f}, drain ~ N^{out['drain_s_exponent']:.2f}"
    return out


def dataset_costs(dataset_dir: Path) -> dict[str, Any]:
    """What the dataset's manifest recorded: the material characterization per parameter set and the solver CPU
    seconds per stored run (a direct check of the read-off cost at the dataset's own particle count)."""
    m = Manifest.load(dataset_dir)

    def median(key: str) -> tuple[float, int]:
        values = [r.cost[key] for r in m.simulations if math.isfinite(r.cost.get(key, math.nan))]
        return (float(np.median(values)) if values else math.nan), len(values)

    char_s, n_char = median("characterization_cpu_s")
    run_s, n_run = median("cpu_s")
    sizes = [(dataset_dir / r.file).stat().st_size / 1e6 for r in m.usable() if r.file
             and (dataset_dir / r.file).is_file()]
    if not n_char:
        raise DataError(f"{dataset_dir}/manifest.json records no characterization_cpu_s: generate the dataset "
                        "with data.characterization.enabled=true, or leave hopper_dataset= out")
    return {"median_cpu_s": char_s, "n": n_char, "run_median_cpu_s": run_s, "runs": n_run,
            "run_median_mb": float(np.median(sizes)) if sizes else math.nan,
            "n_particles": int(m.scene.get("hopper", {}).get("n_particles", 0)),
            "dataset": str(dataset_dir)}


def bed_cost(fb_speed: dict[str, Any]) -> dict[str, Any]:
    try:
        manifest = fb_speed["solver"]["DPMFoam, dataset manifest"]
        per_sim = manifest["per_simulation"]
        simulated = float(np.median(per_sim["simulated_s"]))
        out = {"cpu_s_per_simulated_s": float(manifest["median_cpu_s"]), "repeats": int(manifest["repeats"]),
               "per_trajectory_cpu_s_measured": float(per_sim["median_cpu_s"]),
               "measured_simulated_s": simulated,
               "n_particles": int(fb_speed["n_particles"]), "cells": list(fb_speed["cells"]),
               "dt": float(fb_speed["dt"]), "dataset": manifest.get("dataset", "")}
    except (KeyError, TypeError) as err:
        raise DataError(f"fb_speed results lack the dataset-manifest solver timing (field {err}): rerun "
                        "`neuraldem bench fb_speed ckpt=CKPT`") from None
    return out


def bed_trajectories(bed: dict[str, Any], spinup_s: float, durations: dict[str, float]) -> list[dict[str, Any]]:
    return [{"trajectory": name, "simulated_s": spinup_s + d,
             "cpu_s": (spinup_s + d) * bed["cpu_s_per_simulated_s"]} for name, d in durations.items()]


def fb_durations() -> tuple[float, dict[str, float]]:
    """Spin-up and stored durations of the fb_small scene, read from its config."""
    from omegaconf import OmegaConf

    from neuraldem.paths import config_dir

    cfg = OmegaConf.load(Path(config_dir()) / "data" / "fb_small.yaml")
    return float(cfg.scene.spinup_time), {"training (3 s stored)": float(cfg.parameters.duration),
                                         "long test (30 s stored)": float(cfg.parameters.long.duration)}


def shown(path: Path) -> str:
    """A path as the results show it: relative to the results folder's checkout when inside it."""
    root = results_dir().parent
    try:
        return str(Path(path).resolve().relative_to(root.resolve()))
    except ValueError:
        return str(path)


def markdown(res: dict[str, Any]) -> str:
    n_runs, n_traj = res["hopper_runs"], res["bed_trajectories"]
    lines = [f"# Cluster cost model (`{res['command']}`)", "",
             "Single-core solver CPU time, from measured rates (see the module docstring). Inputs: "
             f"`{res['inputs']['hopper_scaling']}` ({res['inputs']['hopper_scaling_date']}), "
             f"`{res['inputs']['fb_speed']}` ({res['inputs']['fb_speed_date']}).", "",
             f"## Hopper (LIGGGHTS, the hopper_small shape scaled, {res['hopper_window_s']:.1f} s stored window)", "",
             f"| particles | settle s | drain s | one run, CPU min | {n_runs} runs, CPU-hours | source |",
             "|---|---|---|---|---|---|"]
    for r in res["hopper"]:
        lines.append(f"| {r['n_particles']:,} | {r['settle_s']:.0f} | {r['drain_s']:.0f} | {r['run_s'] / 60:.1f} | "
                     f"{r['cpu_hours_per_batch']:.0f} | {r['source']} |")
    ch = res.get("characterization")
    if ch:
        lines += ["", f"Material characterization (shear + heap, independent of the particle count): "
                      f"{ch['median_cpu_s']:.0f} CPU s per parameter set (median of {ch['n']}), "
                      f"{ch['cpu_hours_per_batch']:.0f} CPU-hours for {n_runs} parameter sets. The dataset's own "
                      f"stored runs ({ch['n_particles']:,} particles) took {ch['run_median_cpu_s']:.0f} CPU s each "
                      f"(median of {ch['runs']}, `{ch['dataset']}`)."]
        lines += ["", "Storage (the dataset's median file scaled with the particle count): " + ", ".join(
            f"{r['n_particles']:,}: {r['stored_gb_per_batch']:.0f} GB" for r in res["hopper"])
            + f" per {n_runs} runs."]
    rates = ", ".join(f"{p['n_particles']:,}: {p['drain_particle_steps_per_s'] / 1e6:.2f} M"
                      for p in res["hopper_measured"])
    lines += ["", f"Measured drain rate, particle-steps per CPU second: {rates}."]
    bed = res["bed"]
    lines += ["", f"## Fluidized bed (DPMFoam, {bed['n_particles']} particles, {bed['cells']} cells)", "",
              f"{bed['cpu_s_per_simulated_s']:.0f} CPU s per simulated second (median of {bed['repeats']} "
              "dataset runs).", "",
              f"| trajectory | simulated s (with spin-up) | one, CPU min | {n_traj}, CPU-hours |", "|---|---|---|---|"]
    for t in res["bed_trajectories_cost"]:
        lines.append(f"| {t['trajectory']} | {t['simulated_s']:.1f} | {t['cpu_s'] / 60:.1f} | "
                     f"{t['cpu_hours_per_batch']:.1f} |")
    return "\n".join(lines) + "\n"


def build(scaling_path: Path, fb_path: Path, particles: list[int], n_runs: int, n_traj: int,
          hopper_dataset: Path | None, command: str) -> dict[str, Any]:
    scaling, fb = read_results(scaling_path, "hopper_scaling"), read_results(fb_path, "fb_speed")
    points = hopper_points(scaling["results"])
    hopper = [hopper_run_cost(points, n) for n in particles]
    for r in hopper:
        r["cpu_hours_per_batch"] = r["run_s"] * n_runs / HOUR
    res: dict[str, Any] = {
        "command": command, "hopper_runs": n_runs, "bed_trajectories": n_traj,
        "inputs": {"hopper_scaling": shown(scaling_path), "hopper_scaling_date": scaling.get("date", ""),
                   "fb_speed": shown(fb_path), "fb_speed_date": fb.get("date", "")},
        "hopper_window_s": float(scaling["results"]["solver"]["drain_profile"]["drain_time_s"]),
        "hopper_measured": points, "hopper": hopper,
    }
    if hopper_dataset is not None:
        ch = dataset_costs(hopper_dataset)
        ch["cpu_hours_per_batch"] = ch["median_cpu_s"] * n_runs / HOUR
        res["characterization"] = ch
        for r in hopper:  # stored positions grow with the particle count
            r["stored_gb_per_batch"] = ch["run_median_mb"] * r["n_particles"] / ch["n_particles"] * n_runs / 1e3
    bed = bed_cost(fb["results"])
    spinup, durations = fb_durations()
    trajectories = bed_trajectories(bed, spinup, durations)
    for t in trajectories:
        t["cpu_hours_per_batch"] = t["cpu_s"] * n_traj / HOUR
    res["bed"], res["bed_trajectories_cost"] = bed, trajectories
    return res


def main(argv: list[str] | None = None) -> int:
    p = doc_parser("neuraldem.bench cluster_cost", __doc__)
    p.add_argument("--hopper-scaling", type=Path, default=default_path("hopper_scaling"))
    p.add_argument("--fb-speed", type=Path, default=default_path("fb_speed"))
    p.add_argument("--hopper-dataset", type=Path, default=None,
                   help="a hopper dataset whose manifest holds characterization costs")
    p.add_argument("--particles", type=int, nargs="+", default=list(DEFAULT_PARTICLES))
    p.add_argument("--hopper-runs", type=int, default=1000)
    p.add_argument("--bed-trajectories", type=int, default=100)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    for n in args.particles:
        checks.positive_int("particles", n)
    checks.positive_int("hopper_runs", args.hopper_runs)
    checks.positive_int("bed_trajectories", args.bed_trajectories)
    command = command_line(NAME, list(sys.argv[1:] if argv is None else argv))
    res = build(args.hopper_scaling, args.fb_speed, args.particles, args.hopper_runs, args.bed_trajectories,
                args.hopper_dataset, command)
    write_report(NAME, res, markdown(res), command=command, path=resolve_out(args.out, NAME))
    return 0
