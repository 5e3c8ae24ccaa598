"""Every chart and table in one command, and redrawing them from their results files.

`neuraldem bench all runs=[DIR,...] ckpt=CKPT [dataset=DIR] [gns_hopper_ckpt=[CKPT,...]] [fb_ckpt=[CKPT,...]]
[gns_fb_ckpt=[CKPT,...]] [fb_runs=[DIR,...]] [fb_dataset=DIR] [no_solver=true] [out_dir=DIR]`
runs hopper_speed, hopper_scaling, speed_accuracy, right_sizing and hopper_stability in turn (with runs= and
ckpt=; gns_hopper_ckpt= adds the GNS to the chart and the map), then fb_speed (the first fb_ckpt= against
DPMFoam) and fb_stability (every fb_ckpt=, one series each) (with fb_ckpt=), gns_stability at the same
velocities and steps (with gns_fb_ckpt=; both maps then also go into one figure, stability_map.png), then
fb_speed_accuracy (with fb_runs=); each also runs on its own. With no_solver=true nothing runs LIGGGHTS or
DPMFoam: solver costs come from the dataset manifests and the solver parts of earlier results in out_dir=
(where there are none, the chart has no solver points). Without out_dir= each file goes to its own folder of
results/ (results/hopper/speed/, results/fluidized_bed/stability/, ...: `report.RESULT_FOLDERS`).

`neuraldem bench render [out_dir=DIR]` redraws every figure and table from the JSON files in out_dir=
(default: each benchmark's own folder of results/), measuring nothing (e.g. after a change of the plotting
code).
"""

from __future__ import annotations

from pathlib import Path

from neuraldem.bench import plots
from neuraldem.bench.report import default_path, read_results
from neuraldem.cli import command_parser
from neuraldem.errors import ConfigError, DataError
from neuraldem.paths import results_dir


def _json(out_dir: Path | None, name: str) -> Path:
    """Where benchmark `name` writes: `out_dir`/NAME.json, or without out_dir= its own folder of results/
    (`report.default_path`: results/hopper/speed/, results/fluidized_bed/stability/, ...)."""
    return out_dir / f"{name}.json" if out_dir is not None else default_path(name)


def kv(key: str, value: object) -> str:
    """One `key=value` of a benchmark's command line; a list as `key=[a,b]`."""
    if isinstance(value, (list, tuple)):
        return f"{key}=[{','.join(map(str, value))}]"
    return f"{key}={value}"


def plan(runs: list[Path] | None, ckpt: Path | None, dataset: Path | None, out_dir: Path | None, no_solver: bool,
         repeats: int, threads: int, skip_unevaluated: bool = False, fb_ckpts: list[Path] | None = None,
         fb_dataset: Path | None = None, fb_labels: list[str] | None = None,
         fb_runs: list[Path] | None = None, gns_fb_ckpts: list[Path] | None = None,
         gns_hopper_ckpts: list[Path] | None = None) -> list[tuple[str, list[str]]]:
    """The benchmark commands `all` runs, in order (name, argv): the hopper's with `runs` and `ckpt`, the
    fluidized bed's with `fb_ckpts`."""
    if bool(runs) != (ckpt is not None):
        raise ConfigError("runs= and ckpt= go together (the hopper benchmarks need both): give both, or "
                          "neither and fb_ckpt= for the fluidized-bed benchmarks alone")
    if not runs and not fb_ckpts and not fb_runs:
        raise ConfigError("nothing to run: give runs=DIR ckpt=CKPT (hopper) and/or fb_ckpt=CKPT / "
                          "fb_runs=DIR (fluidized bed)")
    if gns_hopper_ckpts and not runs:
        raise ConfigError("gns_hopper_ckpt= adds the GNS to the hopper's speed-accuracy chart: give runs= and "
                          "ckpt= too")
    steps = (_hopper_plan(runs, ckpt, dataset, out_dir, no_solver, repeats, threads, skip_unevaluated,
                          gns_hopper_ckpts or []) if runs else [])
    fb_data = [kv("dataset", fb_dataset)] if fb_dataset else []
    if fb_ckpts:
        # fb_speed times the surrogate on 1 thread and on every core by itself; threads= is the hopper's
        speed = [kv("ckpt", fb_ckpts[0]), *fb_data, kv("repeats", repeats), kv("out", _json(out_dir, "fb_speed"))]
        if no_solver:
            speed.append("reuse_dataset=true")
        if fb_labels and len(fb_labels) != len(fb_ckpts):
            raise ConfigError(f"fb_labels=: {len(fb_labels)} label(s) for {len(fb_ckpts)} fb_ckpt= checkpoint(s): "
                              "give one label per checkpoint, or none (the run folder names are used)")
        labels = [kv("labels", fb_labels)] if fb_labels else []
        stability = [kv("ckpt", fb_ckpts), *labels, *fb_data, kv("out", _json(out_dir, "fb_stability"))]
        steps += [("fb_speed", speed), ("fb_stability", stability)]
    if gns_fb_ckpts:
        if not fb_ckpts:
            raise ConfigError("gns_fb_ckpt= shares the velocities and steps of the field surrogates' stability map: "
                              "give fb_ckpt= too")
        steps.append(("gns_stability", [kv("ckpt", gns_fb_ckpts), *fb_data, kv("like", _json(out_dir, "fb_stability")),
                                        kv("out", _json(out_dir, "gns_stability"))]))
    if fb_runs:
        chart = [kv("runs", fb_runs), *fb_data, kv("repeats", repeats), kv("out", _json(out_dir, "fb_speed_accuracy"))]
        if no_solver:
            chart += _reuse_or_skip(_json(out_dir, "fb_speed_accuracy"))
        steps.append(("fb_speed_accuracy", chart))
    return steps


def _hopper_plan(runs: list[Path], ckpt: Path, dataset: Path | None, out_dir: Path | None, no_solver: bool,
                 repeats: int, threads: int, skip_unevaluated: bool,
                 gns_ckpts: list[Path]) -> list[tuple[str, list[str]]]:
    common = [kv("repeats", repeats), kv("threads", threads)]
    data = [kv("dataset", dataset)] if dataset else []
    speed = [kv("ckpt", ckpt), *data, *common, kv("out", _json(out_dir, "hopper_speed"))]
    scaling = [kv("ckpt", ckpt), *data, *common, kv("out", _json(out_dir, "hopper_scaling"))]
    accuracy = [kv("runs", runs), *data, *common, kv("out", _json(out_dir, "speed_accuracy"))]
    if skip_unevaluated:
        accuracy.append("skip_unevaluated=true")
    if gns_ckpts:
        accuracy.append(kv("gns_ckpt", gns_ckpts))
    if no_solver:
        speed.append("reuse_dataset=true")
        scaling += _reuse_or_skip(_json(out_dir, "hopper_scaling"))
        accuracy += _reuse_or_skip(_json(out_dir, "speed_accuracy"))
    sizing = [kv("from_file", _json(out_dir, "speed_accuracy")), "metric=all",
              kv("out", _json(out_dir, "right_sizing"))]
    stability = [kv("ckpt", ckpt), *data, kv("out", _json(out_dir, "hopper_stability"))]
    if gns_ckpts:
        stability.append(kv("gns_ckpt", gns_ckpts))
    return [("hopper_speed", speed), ("hopper_scaling", scaling), ("speed_accuracy", accuracy),
            ("right_sizing", sizing), ("hopper_stability", stability)]


def _reuse_or_skip(previous: Path) -> list[str]:
    return [kv("reuse_solver", previous)] if previous.is_file() else ["skip_solver=true"]


def run_all(argv: list[str]) -> int:
    from neuraldem.bench.__main__ import entry_point

    p = command_parser("neuraldem.bench all", __doc__, summary=True)
    p.add_argument("--runs", type=Path, nargs="+", default=None, help="folders holding evaluated hopper runs")
    p.add_argument("--ckpt", type=Path, default=None, help="the hopper checkpoint timed against LIGGGHTS")
    p.add_argument("--dataset", type=Path, default=None, help="dataset dir of the hopper checkpoint's scene")
    p.add_argument("--fb-ckpt", type=Path, nargs="+", default=None,
                   help="fluidized-bed checkpoints: the first is timed against DPMFoam, all go into the stability map")
    p.add_argument("--fb-labels", nargs="+", default=None, help="their names in the stability map (one per fb_ckpt=)")
    p.add_argument("--fb-dataset", type=Path, default=None, help="dataset dir of the fluidized-bed checkpoints' scene")
    p.add_argument("--gns-fb-ckpt", type=Path, nargs="+", default=None,
                   help="GNS checkpoints of the bed (experiment=gns_fb): their stability map beside those of fb_ckpt=")
    p.add_argument("--gns-hopper-ckpt", type=Path, nargs="+", default=None,
                   help="GNS checkpoints of the hopper (experiment=gns_hopper): points of its speed-accuracy chart")
    p.add_argument("--fb-runs", type=Path, nargs="+", default=None,
                   help="folders holding evaluated fluidized-bed runs: the bed's speed-accuracy chart and right-sizing")
    p.add_argument("--no-solver", action="store_true",
                   help="run no LIGGGHTS or DPMFoam (reuse recorded solver costs)")
    p.add_argument("--skip-unevaluated", action="store_true", help="leave out runs without evaluation/metrics.json")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out-dir", type=Path, default=None,
                   help="one folder for every file (default: each benchmark's own folder of results/)")
    a = p.parse_args(argv)
    out_dir = a.out_dir
    for name, args in plan(a.runs, a.ckpt, a.dataset, out_dir, a.no_solver, a.repeats, a.threads,
                           a.skip_unevaluated, a.fb_ckpt, a.fb_dataset, a.fb_labels, a.fb_runs, a.gns_fb_ckpt,
                           a.gns_hopper_ckpt):
        print(f"==> neuraldem bench {name} {' '.join(args)}", flush=True)
        rc = entry_point(name)(args)
        if rc != 0:
            return rc
    # only maps this call made: older results in out_dir (e.g. a GNS map of other velocities) are render's business
    combined = stability_map(out_dir) if a.gns_fb_ckpt else None
    if combined is not None:
        print(f"wrote {combined}")
    return 0


def stability_map(out_dir: Path | None) -> Path | None:
    """The field surrogates' and the GNS's stability maps in one figure (stability_map.png), where both exist."""
    from neuraldem.scenes.fluidized_bed.bench.stability_map import merge_maps

    fb, gns = _json(out_dir, "fb_stability"), _json(out_dir, "gns_stability")
    if not (fb.is_file() and gns.is_file()):
        return None
    merged = merge_maps(read_results(fb, "fb_stability")["results"], read_results(gns, "gns_stability")["results"])
    return plots.fb_stability_figure(merged, fb.parent / "stability_map.png")


def render(argv: list[str]) -> int:
    from neuraldem.bench import right_sizing, speed_accuracy
    from neuraldem.bench import stability_maps as hopper_stability
    from neuraldem.scenes.fluidized_bed.bench import speed as fb_speed
    from neuraldem.scenes.fluidized_bed.bench import speed_accuracy as fb_speed_accuracy
    from neuraldem.scenes.hopper.bench import speed as hopper_speed

    p = command_parser("neuraldem.bench render", "redraw from results")
    p.add_argument("--out-dir", type=Path, default=None,
                   help="one folder for every file (default: each benchmark's own folder of results/)")
    a = p.parse_args(argv)
    out_dir = a.out_dir
    written = []
    for name in ("hopper_speed", "hopper_scaling", "speed_accuracy", "right_sizing", "hopper_stability", "fb_speed",
                 "fb_stability", "gns_stability", "fb_speed_accuracy"):
        path = _json(out_dir, name)
        if not path.is_file():
            continue
        payload = read_results(path, name)
        results = payload["results"]
        if name == "hopper_speed":
            written.append(_write(path.with_suffix(".md"), hopper_speed.render_markdown(results, payload["machine"])))
        elif name == "hopper_scaling":
            written.append(plots.scaling_figure(results, path.with_suffix(".png")))
        elif name == "fb_speed":
            written.append(_write(path.with_suffix(".md"), fb_speed.render_markdown(results, payload["machine"])))
            written.append(plots.fb_speed_figure(results, path.with_suffix(".png")))
        elif name == "hopper_stability":
            written.append(plots.hopper_stability_figure(results, path.with_suffix(".png")))
            written.append(_write(path.with_suffix(".md"), hopper_stability.render_markdown(results)))
        elif name in ("fb_stability", "gns_stability"):
            written.append(plots.fb_stability_figure(results, path.with_suffix(".png")))
        elif name == "fb_speed_accuracy":
            written.append(plots.speed_accuracy_figure(results, path.with_suffix(".png")))
            written.append(_write(path.with_suffix(".md"), fb_speed_accuracy.render_markdown(results)))
        elif name == "speed_accuracy":
            written.append(plots.speed_accuracy_figure(results, path.with_suffix(".png")))
            written.append(_write(path.with_suffix(".md"), speed_accuracy.render_markdown(results)))
        else:
            written.append(_write(path.with_suffix(".md"), right_sizing.render_markdown(results["picks"])))
    combined = stability_map(out_dir)
    if combined is not None:
        written.append(combined)
    if not written:
        raise DataError(f"no benchmark results in {out_dir or results_dir()}: run `neuraldem bench all ...` first")
    for path in written:
        print(f"wrote {path}")
    return 0


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path
