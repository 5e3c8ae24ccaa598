"""Would one forward pass for several bed rollouts be faster than one pass each? The net's step call, batched.

    neuraldem bench fb_batch [model=fb_small] [batch=9] [repeats=7] [runtime=both|torch|onnx]

The explorer rolls out a lattice of inlet velocities in the background (`explorer.engine.LATTICE`, 9), and an
ensemble would roll out several seeds: each rollout steps the net with a batch of one. This benchmark measures
what stepping `batch=` rollouts together would give, on the first states of `batch=` velocities evenly over the
trained range, one thread, torch and ONNX Runtime (exported with a batch axis into a temporary folder):
- the net's call of a step (latents, the grid decoded at the cell centres), one call per member against one for
  all; each member reads the supernodes of its own call, and the table gives the largest difference of a member's
  outputs from its own call alone;
- the model step (`autoregressive.advance`: the net, the stability options, re-sampled particles and their decoded
  displacement), one per member against one for all;
- a rollout step as `predict` takes it (`ModelStepper`, STEPS steps), and the most a batch could make of it: the
  whole step batched as well as the model step batches (an upper bound: it assumes that the stepper's own numpy
  work around the model step batches as well).
Milliseconds per member, the median of `repeats=` rounds, side by side in one run.
Writes results/fluidized_bed/speed/fb_batch.json and .md.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem import pretrained
from neuraldem.bench.report import command_line, machine_at_start, resolve_out, write_report
from neuraldem.bench.timing import time_call, torch_threads
from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.config import checks

NAME = "fb_batch"
MAX_BATCH = 64
STEPS = 50  # rollout steps timed for the cost of a whole step


def member_inputs(module: Any, states: Any, velocities: list[float]) -> list[Any]:
    """The net's input of each velocity's first rollout step as its rollout reads it (`ModelStepper.net_inputs`, a
    batch of one each), all with the same particle count (the smallest: the shipped first states differ by a few
    particles) and each with the supernodes its own call reads."""
    from dataclasses import replace

    import torch

    from neuraldem.scenes.fluidized_bed.surrogate.rollout import ModelStepper

    picked = [states.nearest(v)[0] for v in velocities]
    n = min(len(s.positions) for s in picked)
    noise = torch.zeros(1, module.net.noise_dim) if module.net.noise_dim else None
    members = [ModelStepper(module, v, runtime="torch").net_inputs(
        replace(s, positions=s.positions[:n], displacement=s.displacement[:n]), noise=noise)
        for s, v in zip(picked, velocities, strict=True)]
    if module.net.particle_branch:
        encoder = module.net.encoders["particles"]
        members = [replace(x, supernode_idx=encoder.graph(x.particle_pos).supernode_idx) for x in members]
    return members


def stacked(members: list[Any]) -> Any:
    """The members as one batch (each keeps the supernodes of its own call)."""
    import torch

    from neuraldem.models.multi_branch_operator import OperatorInputs

    def cat(name: str) -> torch.Tensor | None:
        parts = [getattr(x, name) for x in members]
        return None if parts[0] is None else torch.cat(parts)

    return OperatorInputs(particle_pos=cat("particle_pos"), particle_features=cat("particle_features"),
                          grid=cat("grid"), mixing_grid=cat("mixing_grid"), scalars=cat("scalars"),
                          supernode_idx=cat("supernode_idx"), noise=cat("noise"))


def step_call(net: Any, off_branches: bool) -> Any:
    """What a rollout step asks of the net: latents, then the grid branches at the cell centres (B members)."""
    from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import grid_queries

    branches = ("fluid", "mixing") if off_branches else ("fluid",)

    def call(x: Any) -> list[Any]:
        tokens, cond = net.latents(x, off_branches=off_branches)  # ONNX: the grid decoded in the same run
        decoded = net.decode(tokens, cond, {b: grid_queries(x) for b in branches})
        return [*(tokens[b] for b in sorted(tokens)), *(decoded[b] for b in branches)]

    return call


def largest_difference(batch_out: list[Any], member_outs: list[list[Any]]) -> float:
    return max(float((b[i:i + 1] - m).abs().max()) for i, outs in enumerate(member_outs)
               for b, m in zip(batch_out, outs, strict=True))


def measure(module: Any, members: list[Any], state: Any, velocity: float, repeats: int, runtime: str,
            folder: Path) -> dict[str, Any]:
    """ms per member of one call per member and of one call for all, the largest difference, and ms per rollout
    step (from `state` at `velocity`)."""
    import torch

    from neuraldem.models.operator_onnx import OnnxOperator
    from neuraldem.scenes.fluidized_bed.surrogate.options import BedStability

    off_branches = (getattr(module, "stability", None) or BedStability()).mixing != "advect"
    net = module.net.eval()
    batch = stacked(members)
    if runtime == "onnx":
        grid_shape = tuple(int(n) for n in members[0].grid.shape[2:])
        single = OnnxOperator(net, folder, off_branches=off_branches, threads=1)
        single.prepare(grid_shape)
        batched = OnnxOperator(net, folder, off_branches=off_branches, threads=1, batch_axis=True)
        batched.prepare(grid_shape)
    else:
        single = batched = net
    one, together = step_call(single, off_branches), step_call(batched, off_branches)
    n = len(members)
    with torch.inference_mode():
        t_one, outs = time_call(lambda: [one(x) for x in members], repeats, warmup=2)
        t_all, out = time_call(lambda: together(batch), repeats, warmup=2)
        a_one, _ = time_call(lambda: [model_step(module, single, x) for x in members], repeats, warmup=1)
        a_all, _ = time_call(lambda: model_step(module, batched, batch), repeats, warmup=1)
    per = {"call_one_each": t_one, "call_for_all": t_all, "step_one_each": a_one, "step_for_all": a_all}
    out_ms = {f"{k}_ms_per_member": 1000 * t.median.wall_s / n for k, t in per.items()}
    rollout_ms = step_ms(module, state, velocity, repeats, runtime)
    # the most a batch could give: the whole rollout step (the stepper's numpy fields, mirroring and checks too)
    # batched as well as the model step batches
    bound_ms = rollout_ms * out_ms["step_for_all_ms_per_member"] / out_ms["step_one_each_ms_per_member"]
    return {**out_ms, "largest_difference": largest_difference(out, outs), "rollout_step_ms": rollout_ms,
            "batched_rollout_step_bound_ms": bound_ms}


def model_step(module: Any, net: Any, x: Any) -> Any:
    """One step of the model in model units (`autoregressive.advance`: the net, the stability options, the
    re-sampled particles and their decoded displacement), for every member of `x`."""
    from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import advance
    from neuraldem.scenes.fluidized_bed.surrogate.options import BedStability, RolloutOptions

    stability = RolloutOptions().apply(getattr(module, "stability", None) or BedStability())
    return advance(net, x, module.norm, n_particles=x.particle_pos.shape[1], chunk_size=module.chunk_size,
                   step_scales=module.step_scales, stability=stability)


def step_ms(module: Any, state: Any, velocity: float, repeats: int, runtime: str) -> float:
    """ms per step of a rollout as `predict` steps it (`ModelStepper`, this runtime): what a batch would save on."""
    from neuraldem.scenes.fluidized_bed.surrogate.rollout import ModelStepper, rollout

    t, _ = time_call(lambda: rollout(ModelStepper(module, velocity, runtime=runtime), state, STEPS, progress=False),
                     repeats, warmup=1)
    return 1000 * t.median.wall_s / STEPS


def markdown(result: dict[str, Any]) -> str:
    b = result["batch"]
    lines = [f"# One forward pass for {b} bed rollouts, or one each? (model {result['model']})", "",
             f"`{result['command']}`", "",
             f"The first states of {b} velocities over the trained range, one thread, median of {result['repeats']} "
             "rounds, milliseconds per member. The net's call: latents and the grid at the cell centres; the model "
             "step: the net, the stability options, re-sampled particles and their decoded displacement "
             "(`autoregressive.advance`).", "",
             "| runtime | net call, one each | net call, one for all | model step, one each | model step, one for all "
             "| largest difference |", "|---|---|---|---|---|---|"]
    for rt, r in result["runtimes"].items():
        lines.append(f"| {rt} | {r['call_one_each_ms_per_member']:.3g} | {r['call_for_all_ms_per_member']:.3g} | "
                     f"{r['step_one_each_ms_per_member']:.3g} | {r['step_for_all_ms_per_member']:.3g} | "
                     f"{r['largest_difference']:.2g} |")
    lines += ["", f"A rollout step as `predict` steps it ({STEPS} steps), and the most a batch could make of it: the "
              "whole step batched as well as the model step batches:", "",
              "| runtime | rollout step [ms] | batched, at best [ms per member] |", "|---|---|---|"]
    for rt, r in result["runtimes"].items():
        lines.append(f"| {rt} | {r['rollout_step_ms']:.3g} | {r['batched_rollout_step_bound_ms']:.3g} |")
    fastest = min(r["rollout_step_ms"] for r in result["runtimes"].values())
    best = min(r["batched_rollout_step_bound_ms"] for r in result["runtimes"].values())
    lines += ["", f"Fastest rollout step: {fastest:.3g} ms one rollout at a time, at best {best:.3g} ms per member "
              f"batched ({fastest / best:.2f}x). A batch's members match their own rollouts only to round-off "
              f"(largest difference above), which a bubbling bed's rollout grows into another history.", ""]
    return "\n".join(lines)


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = doc_parser(f"neuraldem.bench {NAME}", __doc__)
    p.add_argument("--model", default=None, help="shipped bed model (default: the shipped one)")
    p.add_argument("--batch", type=int, default=9, help=f"rollouts stepped together (2 .. {MAX_BATCH})")
    p.add_argument("--repeats", type=int, default=7, help="timed rounds (median)")
    p.add_argument("--runtime", default="both", help="torch, onnx or both")
    p.add_argument("--out", type=Path, default=None,
                   help=f"results JSON (default results/fluidized_bed/speed/{NAME}.json)")
    args = p.parse_args(argv)
    checks.positive_int("batch", args.batch)
    checks.number("batch", args.batch, lo=2, hi=MAX_BATCH)
    checks.positive_int("repeats", args.repeats)
    chosen = checks.one_of("runtime", args.runtime, ("torch", "onnx", "both"))
    runtimes = ("torch", "onnx") if chosen == "both" else (chosen,)
    if "onnx" in runtimes:
        from neuraldem.models.operator_onnx import resolve_runtime

        resolve_runtime("onnx")  # one line when ONNX Runtime is missing
    machine = machine_at_start()
    model = pretrained.load(args.model or pretrained.default_for("fluidized_bed"), "fluidized_bed")
    lo, hi = (float(x) for x in model.meta["trained_range"]["inlet_velocity"])
    velocities = [float(v) for v in np.linspace(lo, hi, args.batch)]
    from neuraldem.scenes.fluidized_bed.predict import fb_field_model

    module, states, _, _ = fb_field_model(model, "bench")
    members = member_inputs(module, states, velocities)
    middle = velocities[len(velocities) // 2]
    state = states.nearest(middle)[0]
    with torch_threads(1), tempfile.TemporaryDirectory(prefix="fb_batch_") as tmp:
        measured = {rt: measure(module, members, state, middle, args.repeats, rt, Path(tmp)) for rt in runtimes}
    result = {"model": model.name, "command": command_line(NAME, argv), "batch": args.batch,
              "velocities": velocities, "repeats": args.repeats, "runtimes": measured}
    write_report(NAME, result, markdown(result), command=result["command"], path=resolve_out(args.out, NAME),
                 machine=machine)
    return 0


if __name__ == "__main__":
    sys.exit(main())
