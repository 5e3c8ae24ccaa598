"""`neuraldem report hopper-table folders=[RUNS_DIR,...] out=FILE.md`: the paper's Table 4 from runs.

Finds every `evaluation/metrics.json` under the given folders (e.g. the folder of the ablation sweep
`neuraldem train -m experiment=... data.split=random,band`), and writes one markdown table per
split with one row per conditioning, plus a JSON file with the same numbers next to it.
"""

from __future__ import annotations

import sys
from pathlib import Path

from neuraldem.cli import report_user_errors
from neuraldem.eval.run_results import find_results, table_main
from neuraldem.scenes.hopper.analysis.evaluation import TABLE_HEADER

ROW_ORDER = (["t", "alpha", "mu_s", "mu_r"], ["t", "alpha", "theta"], ["t", "alpha", "repose"],
             ["t", "alpha", "theta", "repose"], ["t", "alpha", "mu_s", "mu_r", "theta", "repose"])


def order_key(result: dict) -> tuple[int, str]:
    cond = result["conditioning"]
    return (ROW_ORDER.index(cond) if cond in ROW_ORDER else len(ROW_ORDER), result["path"])


def render(results: list[dict]) -> str:
    lines = []
    for split in sorted({r["split"] for r in results}):
        rows = sorted((r for r in results if r["split"] == split), key=order_key)
        n = sorted({r["aggregate"]["n_sims"] for r in rows})
        lines += [f"### split: {split} ({'/'.join(map(str, n))} test simulations)", "", TABLE_HEADER]
        lines += [row for r in rows for row in r.get("table_rows", [r["table_row"]])]
        lines.append("")
        lines.append("| conditioning | drainage t95 [% of mean] | flow-regime accuracy [%] | checkpoint |")
        lines.append("|---|---|---|---|")
        for r in rows:
            a = r["aggregate"]
            lines.append(f"| {', '.join(r['conditioning'])} | {a['drainage_t95_pct_of_mean']:.1f} | "
                         f"{100 * a['flow_regime_accuracy']:.0f} | {Path(r['checkpoint']).name} |")
        lines.append("")
    return "\n".join(lines)


def summary(r: dict) -> dict:
    return {k: r[k] for k in ("split", "conditioning", "aggregate", "checkpoint", "dataset", "machine", "command",
                              "date_utc", "path")}


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    return table_main(argv, "neuraldem.scenes.hopper.analysis.table", __doc__, find_results, render, summary)


if __name__ == "__main__":
    sys.exit(main())
