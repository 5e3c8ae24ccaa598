"""`neuraldem report dataset dataset=DATASET_DIR out=results/hopper/dataset`: what a generated
dataset contains and what it cost: status counts, solver CPU seconds per simulation and per
characterization, particle-steps per CPU-second, the range of the ground-truth metrics, and figures of the
metrics over the parameter space (cf. the paper's dataset overview figure)."""

from __future__ import annotations

import sys
from collections import Counter
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from neuraldem.cli import command_parser, report_user_errors
from neuraldem.data.manifest import Manifest
from neuraldem.data.schema import atomic_write_json
from neuraldem.machine import machine_info
from neuraldem.paths import module_command

METRICS = {"drainage_time": "drainage time [s]", "residual_fraction": "residual fraction",
           "outflow_rate": "outflow rate [N0/s]", "mass_flow_index": "mass-flow index"}
REFILL_METRICS = {"outflow_rate": "outflow rate [N0/s]", "exit_residence_median": "exit residence, median [s]",
                  "exit_residence_p90": "exit residence, p90 [s]", "level_mean": "fill level [N/N0]"}


def metric_names(m: Manifest) -> dict[str, str]:
    """The ground-truth metrics of the dataset's kind (a refilling hopper never drains)."""
    return REFILL_METRICS if m.kind == "hopper_refill" else METRICS


def _stats(values: list[float]) -> dict[str, float]:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if v.size == 0:
        return {"n": 0}
    return {"n": int(v.size), "min": float(v.min()), "median": float(np.median(v)), "max": float(v.max()),
            "mean": float(v.mean())}


def summarise(m: Manifest) -> dict[str, Any]:
    ok = m.usable()
    out: dict[str, Any] = {
        "dataset": m.name, "solver": m.solver, "n_simulations": len(m.simulations),
        "status": dict(Counter(r.status for r in m.simulations)),
        "cpu_s_per_simulation": _stats([r.cost.get("cpu_s") for r in ok]),
        "cpu_s_per_characterization": _stats([r.cost.get("characterization_cpu_s") for r in ok]),
        "particle_steps_per_cpu_s": _stats([r.cost["particle_steps"] / r.cost["cpu_s"] for r in ok
                                            if r.cost.get("cpu_s")]),
        "metrics": {k: _stats([r.metrics.get(k) for r in ok]) for k in metric_names(m)},
        "macro": {k: _stats([r.macro.get(k) for r in ok]) for k in ("theta", "repose")},
        "flow_regimes": dict(Counter("mass" if r.metrics["mass_flow_index"] > 0.5 else "funnel"
                                     for r in ok if "mass_flow_index" in r.metrics)),
        "not_ok": [{"sim_id": r.sim_id, "status": r.status, "params": r.params, "reason": r.reason}
                   for r in m.simulations if r.status not in ("ok", "pending")],
    }
    return out


def plot_parameter_space(m: Manifest, path: Path) -> None:
    ok = m.usable()
    alpha = np.array([r.params["alpha"] for r in ok])
    theta = np.array([r.macro.get("theta", np.nan) for r in ok])
    mu_s = np.array([r.params["mu_s"] for r in ok])
    y, ylabel = (theta, "theta [deg]") if np.isfinite(theta).all() else (mu_s, "mu_s")
    names = metric_names(m)
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.8), sharey=True)
    for ax, (key, label) in zip(axes, names.items(), strict=False):
        c = np.array([r.metrics.get(key, np.nan) for r in ok])
        sc = ax.scatter(alpha, y, c=c, s=22, cmap="viridis")
        fig.colorbar(sc, ax=ax)
        ax.set(title=label, xlabel="alpha [deg]")
    axes[0].set_ylabel(ylabel)
    fig.suptitle(f"{m.name}: {len(ok)} LIGGGHTS simulations")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_macro(m: Manifest, path: Path) -> None:
    ok = [r for r in m.usable() if "theta" in r.macro]
    if not ok:
        return
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8))
    for ax, key in zip(axes, ("theta", "repose"), strict=False):
        sc = ax.scatter([r.params["mu_s"] for r in ok], [r.macro[key] for r in ok],
                        c=[r.params["mu_r"] for r in ok], s=20, cmap="plasma")
        test = "shear" if key == "theta" else "heap"
        ax.set(xlabel="mu_s", ylabel=f"{key} [deg]", title=f"{key} from the {test} test")
        fig.colorbar(sc, ax=ax, label="mu_r")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = command_parser("neuraldem.eval.dataset_report", __doc__)
    p.add_argument("dataset", type=Path)
    p.add_argument("--out", type=Path, required=True, help="output folder")
    a = p.parse_args(argv)
    m = Manifest.load(a.dataset)
    a.out.mkdir(parents=True, exist_ok=True)
    summary = summarise(m)
    command = module_command("neuraldem.eval.dataset_report")
    summary.update(machine=machine_info(), command=command,
                   date_utc=datetime.now(UTC).isoformat(timespec="seconds"))
    atomic_write_json(a.out / "summary.json", summary)
    plot_parameter_space(m, a.out / "metrics_over_parameters.png")
    plot_macro(m, a.out / "characterization.png")
    for key in ("cpu_s_per_simulation", "cpu_s_per_characterization", "particle_steps_per_cpu_s"):
        print(f"{key}: {summary[key]}")
    for key, s in summary["metrics"].items():
        print(f"{key}: {s}")
    print(f"status: {summary['status']}, flow regimes: {summary['flow_regimes']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
