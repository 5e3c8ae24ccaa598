"""`neuraldem bench serve_latency`: how fast the explorer answers a slider move, in a real browser.

    neuraldem bench serve_latency moves=20 time_steps=10

Starts `neuraldem serve` on a free port of this machine, opens the hopper page in headless Chromium (Debian's
chromium + chromium-driver, through Selenium) and moves the sliders with the keyboard as a person would:
moves= parameter moves, one slider step each, every one to a point not seen before (nothing cached), pause=
seconds apart (the whole discharge then runs in the background between moves, as it does for a person), then
time_steps= moves of the time slider. For each move, milliseconds in the browser's own clock from the key
event to
- numbers: the numbers table in the DOM showing the new point (a MutationObserver);
- fields: the particle view redrawn by Plotly with the new point (`plotly_afterplot`);
- painted: two animation frames after that (headless Chromium has no GPU: SwiftShader draws WebGL on the CPU).
The first warmup= moves (Plotly's first WebGL draws) are not counted. The server's own time for each frame
(the field model at one time) is read from the page. Writes results/explorer/serve_latency.json and .md, and the
page as a new visitor sees it as serve_latency.png (the screenshot docs/explorer.md shows).

    neuraldem bench serve_latency page=bed moves=20

The bed page (`page=bed`): waits until the server's lattice of background rollouts is ready (it starts at
server start; the time it took is recorded), then moves= steps of the inlet-velocity slider (0.01 m/s each, to
velocities not seen before), pause= seconds apart, timed as above to the numbers table and to the fields
figure redrawn for the new velocity. A rollout takes seconds, so what that figure shows within the time
measured is the nearest ready rollout (a lattice one), not the exact velocity's: each move records the
velocity shown and its distance from the slider's. Last, the time from the slider resting to the exact
rollout's numbers on the page. Writes results/explorer/serve_latency_fb.json, .md and .png.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path
from typing import Any

from neuraldem.bench.report import command_line, machine_at_start, resolve_out, write_report
from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.errors import ConfigError

TARGETS_MS = {"numbers_ms": 100.0, "fields_ms": 300.0}  # the targets: numbers <= 100 ms, fields <= 300 ms


def parse_point(text: str) -> dict[str, float]:
    return {k: float(v) for k, v in (item.split("=") for item in text.split())}


def point_text(values: dict[str, float]) -> str:
    return " ".join(f"{k}={v:g}" for k, v in values.items())


def summary(rows: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Median, 90th percentile and largest of each latency over the counted moves."""
    out = {}
    for key in ("numbers_ms", "fields_ms", "painted_ms", "server_frame_ms"):
        values = sorted(r[key] for r in rows if r.get(key) is not None)
        if values:
            out[key] = {"median": statistics.median(values), "p90": values[min(len(values) - 1,
                                                                                 int(0.9 * len(values)))],
                        "max": values[-1], "n": len(values)}
    return out


def parameter_moves(page: Any, steps: dict[str, float], n: int, pause: float) -> list[dict[str, Any]]:
    """`n` slider steps to the right, the sliders in turn: every point is new."""
    from neuraldem.serve.inputs import parameter_value

    rows = []
    values = parse_point(page.numbers()["point"])
    keys = [k for k in values if k in steps]
    for i in range(n):
        key = keys[i % len(keys)]
        values[key] = parameter_value(values[key] + steps[key])
        target = point_text(values)
        rows.append({"slider": key, "point": target, **page.timed_press(key, target),
                     "server_frame_ms": float(page.status("frame-ms"))})
        time.sleep(pause)
    return rows


def time_moves(page: Any, n: int, pause: float) -> list[dict[str, Any]]:
    """`n` steps of the time slider at the point shown (each a frame not drawn before)."""
    point, t, step = page.status("point"), float(page.status("time")), float(page.status("step"))
    rows = []
    for _ in range(n):
        t = round(t + step, 9)
        rows.append({"slider": "time", "point": point, "t": t, **page.timed_time_step(point, t),
                     "server_frame_ms": float(page.status("frame-ms"))})
        time.sleep(pause)
    return rows


def docs_screenshot(page: Any, url: str, path: Path) -> None:
    """The page as a new visitor sees it (the default point, t = 1 s), once the field model's numbers are in."""
    from neuraldem.scenes.hopper.explorer.browser import HopperBrowser

    fresh = HopperBrowser(page.driver, url, timeout=page.timeout)
    fresh.wait_field_numbers(timeout=120)
    time.sleep(1.0)  # the curve redrawn with the field model's
    fresh.screenshot(path)


def row(name: str, stats: dict[str, Any], key: str) -> str:
    """One table row: moves, median (against its target), p90 and max of `stats[key]`."""
    if key not in stats:
        return f"| {name} | - | - | - | - |"
    v = stats[key]
    target = TARGETS_MS.get(key)
    verdict = "" if target is None else (" (met)" if v["median"] <= target else f" (over {target:.0f})")
    return f"| {name} | {v['n']} | {v['median']:.0f}{verdict} | {v['p90']:.0f} | {v['max']:.0f} |"


def head(title: str, result: dict[str, Any]) -> list[str]:
    """A latency report's title, how it was measured (command, browser, load) and the table's header."""
    load = (result["machine"].get("load_average_1_5_15min") or [float("nan")])[0]
    return [f"# {title} (model {result['model']})", "",
            f"`{result['command']}`; headless {result['browser']}; 1-minute load average {load:.2f} on "
            f"{result['machine'].get('cpu_count')} CPUs when it began.", "",
            "| move -> update | moves | median [ms] | p90 [ms] | max [ms] |", "|---|---|---|---|---|"]


def targets() -> str:
    return (f"Targets: numbers <= {TARGETS_MS['numbers_ms']:.0f} ms, fields <= "
            f"{TARGETS_MS['fields_ms']:.0f} ms (medians).")


def markdown(result: dict[str, Any]) -> str:
    s, ts = result["summary"]["parameter_moves"], result["summary"]["time_moves"]
    lines = [*head("Explorer latency: slider move to updated page", result),
             row("parameter slider -> numbers (DOM)", s, "numbers_ms"),
             row("parameter slider -> particles redrawn (plotly_afterplot)", s, "fields_ms"),
             row("parameter slider -> particles painted", s, "painted_ms"),
             row("(server: the frame's field model, in the above)", s, "server_frame_ms"),
             row("time slider -> particles redrawn", ts, "fields_ms"),
             row("time slider -> particles painted", ts, "painted_ms"), "",
             f"{targets()} Each parameter move is one slider step to a point not "
             f"seen before (no cache hit), {result['pause_s']:g} s apart; {result['warmup']} warm-up moves not "
             "counted. 'Painted' adds the browser's WebGL draw: without a GPU, Chromium draws it with "
             "SwiftShader on the same CPUs as the server."]
    return "\n".join(lines) + "\n"


def bed_moves(page: Any, n: int, pause: float) -> list[dict[str, Any]]:
    """`n` steps of the bed's velocity slider to the right (each a velocity not seen before)."""
    from neuraldem.scenes.fluidized_bed.explorer.engine import STEP
    from neuraldem.serve.inputs import parameter_value

    rows = []
    v = page.numbers()["velocity"]
    for _ in range(n):
        v = parameter_value(v + STEP)
        timed = page.timed_press(v)
        shown = float(timed["fields_title"].split("rollout at ")[1].split(" m/s")[0])
        rows.append({"velocity": v, **timed, "shown_velocity": shown, "shown_off_m_s": round(abs(shown - v), 6),
                     "shown_exact": shown == v})
        time.sleep(pause)
    return rows


def bed_markdown(result: dict[str, Any]) -> str:
    s = result["summary"]

    moves = result["moves"]
    off = [m["shown_off_m_s"] for m in moves]
    return "\n".join([
        *head("Explorer latency, bed page: velocity slider move to updated page", result),
        row("velocity slider -> numbers (GP, DOM)", s, "numbers_ms"),
        row("velocity slider -> fields redrawn (nearest ready rollout, plotly_afterplot)", s, "fields_ms"),
        row("velocity slider -> fields painted", s, "painted_ms"), "",
        f"{targets()} What the fields figure shows within that time is the "
        f"nearest rollout already computed, labelled with its velocity, not a rollout at the new velocity: "
        f"over these moves it was {statistics.median(off):.3f} m/s (median; at most {max(off):.3f}) from the "
        f"slider's ({sum(m['shown_exact'] for m in moves)} of {len(moves)} exact). The lattice of "
        f"{result['lattice_size']} rollouts was ready {result['lattice_ready_s']:.0f} s after the page opened; "
        f"after the slider rested, the exact rollout's numbers were on the page in "
        f"{result['exact_after_rest_s']:.1f} s. Each move is one 0.01 m/s step to a velocity not seen before, "
        f"{result['pause_s']:g} s apart; {result['warmup']} warm-up moves not counted.", ""])


def bed_main(args: Any, argv: list[str]) -> int:
    from neuraldem.scenes.fluidized_bed.explorer.browser import BedBrowser, page_url
    from neuraldem.serve.browser import ServerProcess, start_chromium, wait_for

    out = resolve_out(args.out, "serve_latency_fb")
    machine = machine_at_start()
    with ServerProcess(["page=bed", *([f"model={args.model}"] if args.model else [])]) as server:
        driver = start_chromium()
        try:
            t0 = time.monotonic()
            page = BedBrowser(driver, page_url(server.url), timeout=120)
            lattice = int(page.status("lattice"))
            wait_for(lambda: page.status("ready") == str(lattice), 900, "the lattice of rollouts", poll=0.5)
            lattice_s = time.monotonic() - t0
            warm = bed_moves(page, args.warmup, args.pause)
            moves = bed_moves(page, args.moves, args.pause)
            rest = time.monotonic()
            page.wait_field_numbers(moves[-1]["velocity"], timeout=300)
            exact_s = time.monotonic() - rest
            page.wait_shown(moves[-1]["velocity"])
            time.sleep(1.0)
            page.screenshot(out.with_suffix(".png"))
            model = page.status("model")
            browser = driver.capabilities.get("browserName", "chrome") + " " + driver.capabilities.get(
                "browserVersion", "")
        finally:
            driver.quit()
    result = {"model": model, "page": "bed", "command": command_line("serve_latency", argv), "browser": browser,
              "pause_s": args.pause, "warmup": args.warmup, "targets_ms": TARGETS_MS, "lattice_size": lattice,
              "lattice_ready_s": lattice_s, "exact_after_rest_s": exact_s, "summary": summary(moves),
              "warmup_moves": warm, "moves": moves, "machine": machine}
    write_report("serve_latency_fb", result, bed_markdown(result), command=result["command"], path=out, machine=machine)
    return 0


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    from neuraldem.scenes.hopper.explorer.browser import HopperBrowser
    from neuraldem.scenes.hopper.explorer.page import STEPS
    from neuraldem.serve.browser import ServerProcess, chromium_paths, start_chromium

    argv = sys.argv[1:] if argv is None else argv
    p = doc_parser("neuraldem.bench serve_latency", __doc__)
    p.add_argument("--page", choices=["hopper", "bed"], default="hopper", help="the page measured")
    p.add_argument("--model", default=None, help="shipped model of the page (default: the shipped one)")
    p.add_argument("--moves", type=int, default=20, help="parameter slider moves counted")
    p.add_argument("--time-steps", type=int, default=10, help="time slider moves counted")
    p.add_argument("--warmup", type=int, default=3, help="moves before counting (first WebGL draws)")
    p.add_argument("--pause", type=float, default=1.0, help="seconds between moves")
    p.add_argument("--out", type=Path, default=None, help="results JSON (default results/explorer/serve_latency.json, "
                                                                "serve_latency_fb.json for page=bed)")
    args = p.parse_args(argv)
    if chromium_paths() is None:
        raise ConfigError("the benchmark drives a real browser: chromium and chromedriver are not installed",
                          "apt-get install chromium chromium-driver (scripts/setup.sh does)")
    if args.page == "bed":
        return bed_main(args, argv)
    out = resolve_out(args.out, "serve_latency")
    machine = machine_at_start()
    with ServerProcess(["page=hopper", *([f"model={args.model}"] if args.model else [])]) as server:
        driver = start_chromium()
        try:
            page = HopperBrowser(driver, server.url, timeout=120)
            warm = parameter_moves(page, STEPS, args.warmup, args.pause)
            moves = parameter_moves(page, STEPS, args.moves, args.pause)
            steps = time_moves(page, args.time_steps, args.pause)
            model = page.status("model")
            docs_screenshot(page, server.url, out.with_suffix(".png"))
            browser = driver.capabilities.get("browserName", "chrome") + " " + driver.capabilities.get(
                "browserVersion", "")
        finally:
            driver.quit()
    result = {"model": model, "command": command_line("serve_latency", argv), "browser": browser,
              "pause_s": args.pause, "warmup": args.warmup, "targets_ms": TARGETS_MS,
              "summary": {"parameter_moves": summary(moves), "time_moves": summary(steps)},
              "warmup_moves": warm, "parameter_moves": moves, "time_moves": steps, "machine": machine}
    write_report("serve_latency", result, markdown(result), command=result["command"], path=out, machine=machine)
    return 0


if __name__ == "__main__":
    sys.exit(main())
