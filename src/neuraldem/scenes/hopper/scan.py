"""`neuraldem scan hopper alpha=LO:HI:N mu_s=LO:HI:N mu_r=VALUE`: a hopper design chart in seconds.

    neuraldem scan hopper alpha=0:60:31 mu_s=0.05:1:20 mu_r=0.1
    neuraldem scan hopper alpha=0:60:31 mu_s=0.05:1:20 mu_r=0.1 verify=4   # + 4 points run with LIGGGHTS

Two parameters span a grid (LO:HI:N, N >= 2 values each), the others are fixed. The shipped scalar GP answers
every grid point at once: maps of the drainage time t95, the outflow and the mass-flow index, with the
mass/funnel-flow boundary (index = the regime threshold) and its uncertainty (where the 95 % interval of the
index straddles the threshold), a Jenike-style chart. `verify=K` runs LIGGGHTS at K grid points (seeded,
spread over the grid), marks them on the charts (filled: mass flow, open: funnel flow in LIGGGHTS) and lists
both answers and both times; finished solver runs are kept in <out>/liggghts and reused.
Outputs (out=, default <data dir>/scan/hopper/<parameters>/): design_chart.png, scan.json, scan.md.
"""


from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem import pretrained
from neuraldem.cli import output_folder
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import ConfigError
from neuraldem.paths import data_dir
from neuraldem.scenes.hopper.predict import hopper_gp
from neuraldem.scenes.parameters import ParameterTable, asked_note, named_values

MAX_POINTS = 250_000  # a grid larger than this is refused (the GP answers ~10k points per second)


def parse_axes(items: dict[str, str], names: list[str], scene: str,
               table: ParameterTable) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """(the two scanned axes {name: values}, the fixed values {name: value}) from name=LO:HI:N / name=VALUE."""
    axes: dict[str, np.ndarray] = {}
    fixed: dict[str, float] = {}
    for key, value in named_values(items, names, scene).items():
        parts = value.split(":")
        try:
            numbers = [float(p) for p in parts]
        except ValueError:
            raise ConfigError(f"parameter {key}={value!r}: expected numbers, LO:HI:N or VALUE") from None
        if len(parts) == 1:
            fixed[key] = numbers[0]
        elif len(parts) == 3 and numbers[2] == int(numbers[2]) and numbers[2] >= 2 and numbers[1] > numbers[0]:
            axes[key] = np.linspace(numbers[0], numbers[1], int(numbers[2]))
        else:
            raise ConfigError(f"parameter {key}={value!r} is invalid: a range is LO:HI:N with HI > LO and N >= 2 "
                              "points, e.g. 0:60:31")
        table.check(key, list(axes[key]) if key in axes else [fixed[key]])
    if len(axes) != 2:
        raise ConfigError(f"a scan needs exactly two ranges (LO:HI:N), got {len(axes)}",
                          f"e.g. {names[0]}=0:60:31 {names[1]}=0.05:1:20 and the rest as single values")
    if np.prod([len(v) for v in axes.values()]) > MAX_POINTS:
        raise ConfigError(f"the grid has {int(np.prod([len(v) for v in axes.values()]))} points, more than "
                          f"{MAX_POINTS}", "use fewer points per range")
    return axes, fixed


def grid_rows(axes: dict[str, np.ndarray], fixed: dict[str, float]) -> tuple[list[dict[str, float]], tuple[int, int]]:
    (a, av), (b, bv) = axes.items()
    A, B = np.meshgrid(av, bv, indexing="ij")
    rows = [{a: float(x), b: float(y), **fixed} for x, y in zip(A.ravel(), B.ravel(), strict=True)]
    return rows, (len(av), len(bv))


def pick_points(shape: tuple[int, int], k: int, seed: int) -> list[tuple[int, int]]:
    """K grid points spread over the grid: one seeded random point in each of K strata of the first axis."""
    rng = np.random.default_rng(seed)
    edges = np.linspace(0, shape[0], k + 1).astype(int)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        out.append((int(rng.integers(lo, max(hi, lo + 1))), int(rng.integers(0, shape[1]))))
    return out


def verify_hopper(model: pretrained.Pretrained, points: list[dict[str, float]], out: Path,
                  settings: Any) -> list[dict[str, Any]]:
    """LIGGGHTS at each point (a finished one is read back from <out>/<point>/liggghts.json)."""
    from neuraldem.scenes.hopper.solver import HopperScene
    from neuraldem.scenes.hopper.whatif import liggghts_answer

    scene = HopperScene.from_config(model.meta["scene"]["hopper"], "model scene")
    results = []
    for i, point in enumerate(points):
        folder = out / "_".join(f"{k}{v:.4g}" for k, v in point.items())
        done = folder / "liggghts.json"
        if done.is_file():
            results.append(json.loads(done.read_text()))
            continue
        print(f"LIGGGHTS {i + 1}/{len(points)} at {point} ...", file=sys.stderr)
        s = liggghts_answer(scene, point, folder / "run", settings)
        r = {"parameters": point, "status": s.status, "reason": s.reason, "metrics": s.metrics,
             "seconds": s.seconds}
        atomic_write_json(done, r)
        results.append(r)
    return results


def design_chart(axes: dict[str, np.ndarray], fixed: dict[str, float], answers: dict[str, np.ndarray],
                 threshold: float, checks: list[dict[str, Any]], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    (a, av), (b, bv) = axes.items()
    panels = [("drainage_t95", "drainage time t95 [s]", 1.0, "viridis"),
              ("outflow_rate", "outflow [% of the material per s]", 100.0, "magma"),
              ("mass_flow_index", "mass-flow index (1 = mass flow)", 1.0, "coolwarm")]
    fig, axs = plt.subplots(1, 3, figsize=(17, 5.2))
    for ax, (key, label, scale, cmap) in zip(axs, panels, strict=True):
        im = ax.pcolormesh(av, bv, scale * answers[f"{key}.mean"].T, shading="nearest", cmap=cmap)
        fig.colorbar(im, ax=ax, label=label)
        idx, lo, hi = (answers[f"mass_flow_index.{s}"].T for s in ("mean", "low", "high"))
        if idx.min() < threshold < idx.max():
            ax.contour(av, bv, idx, levels=[threshold], colors="k", linewidths=2)
        uncertain = (lo < threshold) & (hi > threshold)
        if uncertain.any():
            ax.contourf(av, bv, uncertain.astype(float), levels=[0.5, 1.5], colors="none", hatches=["//"])
        for c in checks:
            m = c.get("metrics") or {}
            mass = m.get("mass_flow_index", np.nan) > threshold
            ax.plot(c["parameters"][a], c["parameters"][b], "o", ms=9, mec="k", mew=1.5,
                    mfc="k" if mass else "white")
            if key == "drainage_t95" and np.isfinite(m.get("drainage_t95", np.nan)):
                ax.annotate(f"{m['drainage_t95']:.2f}", (c["parameters"][a], c["parameters"][b]),
                            textcoords="offset points", xytext=(6, 6), fontsize=8)
        ax.set(xlabel=a, ylabel=b, title=label)
    fixed_text = ", ".join(f"{k}={v:g}" for k, v in fixed.items())
    fig.suptitle(f"{title} ({fixed_text}): black line = mass/funnel boundary, hatched = its 95 % band"
                 + (", circles = LIGGGHTS (filled: mass flow; t95 in s)" if checks else ""), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def scan_table(checks: list[dict[str, Any]], answers_at: list[Any], regime_threshold: float) -> str:
    lines = ["| point | t95 GP [95 %] [s] | t95 LIGGGHTS [s] | outflow GP [%/s] | outflow LIGGGHTS [%/s] | "
             "regime GP | regime LIGGGHTS | LIGGGHTS time [s] |", "|---|---|---|---|---|---|---|---|"]
    for c, a in zip(checks, answers_at, strict=True):
        m = c.get("metrics") or {}

        def reg(v: float) -> str:
            return "-" if not np.isfinite(v) else ("mass" if v > regime_threshold else "funnel")

        lines.append(f"| {', '.join(f'{k}={v:.3g}' for k, v in c['parameters'].items())} | "
                     f"{a.mean['drainage_t95']:.2f} [{a.low['drainage_t95']:.2f}, {a.high['drainage_t95']:.2f}] | "
                     f"{m.get('drainage_t95', float('nan')):.2f} | {100 * a.mean['outflow_rate']:.1f} | "
                     f"{100 * m.get('outflow_rate', float('nan')):.1f} | {reg(a.mean['mass_flow_index'])} | "
                     f"{reg(m.get('mass_flow_index', float('nan'))) if m else c['status']} | {c['seconds']:.0f} |")
    return "\n".join(lines)


def add_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--verify", type=int, default=0, metavar="K", help="run LIGGGHTS at K grid points")
    p.add_argument("--seed", type=int, default=0, help="which grid points verify=K picks")


def scan(items: dict[str, str], model_name: str, out: Path | None, args: argparse.Namespace) -> int:
    """The design chart over the two ranges in `items` (name -> LO:HI:N or VALUE), printed and written."""
    from neuraldem.models.scalar_baselines import gp_answers
    from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings
    from neuraldem.scenes.hopper.parameters import PARAMETERS
    from neuraldem.scenes.hopper.whatif import QUANTITIES

    t0 = time.perf_counter()
    if args.verify < 0:
        raise ConfigError(f"verify={args.verify} is invalid: the number of LIGGGHTS checks must be >= 0")
    model = pretrained.load(model_name, "hopper")
    axes, fixed = parse_axes(items, list(model.meta["inputs"]), "hopper", PARAMETERS)
    settings = HopperMetricSettings.from_config(model.meta.get("metric_settings", {}), f"{model.name} metric_settings")
    rows, shape = grid_rows(axes, fixed)
    t_answer = time.perf_counter()
    answers = gp_answers(hopper_gp(model), rows)
    answer_s = time.perf_counter() - t_answer
    grids = {f"{q}.{s}": np.array([getattr(a, s)[q] for a in answers]).reshape(shape)
             for q in QUANTITIES for s in ("mean", "low", "high")}
    outside = sorted({k for a in answers for k in a.extrapolation})
    warnings = [f"warning: GP: the scanned {k} partly lies outside the trained range "
                f"{model.meta['trained_range'][k][0]:.4g} .. {model.meta['trained_range'][k][1]:.4g}"
                f"{asked_note(k, model.meta['trained_range'][k], model.meta.get('asked_range'))}: those points "
                "are extrapolations, trust them less" for k in outside]
    out = output_folder(out or data_dir() / "scan" / "hopper" / "_".join(
        f"{k}{v.min():g}-{v.max():g}x{len(v)}" for k, v in axes.items()))
    checks: list[dict[str, Any]] = []
    if args.verify:
        picked = pick_points(shape, args.verify, args.seed)
        checks = verify_hopper(model, [rows[i * shape[1] + j] for i, j in picked], out / "liggghts", settings)
    design_chart(axes, fixed, grids, settings.mass_flow_threshold, checks, out / "design_chart.png",
                 f"hopper design chart, model {model.name}")
    atomic_write_json(out / "scan.json", {
        "scene": "hopper", "model": model.name, "axes": {k: v.tolist() for k, v in axes.items()}, "fixed": fixed,
        "grids": {k: v.tolist() for k, v in grids.items()}, "answer_s": answer_s, "n_points": len(rows),
        "mass_flow_threshold": settings.mass_flow_threshold, "warnings": warnings, "liggghts": checks})
    text = [f"# hopper scan: {len(rows)} points in {answer_s:.3f} s (model {model.name})", ""]
    if checks:
        at = gp_answers(hopper_gp(model), [c["parameters"] for c in checks])
        text += [scan_table(checks, at, settings.mass_flow_threshold), ""]
    (out / "scan.md").write_text("\n".join(text))
    for w in warnings:
        print(w, file=sys.stderr)
    print("\n".join(text))
    print(f"design chart {out / 'design_chart.png'} ({time.perf_counter() - t0:.2f} s in this command)")
    return 0

