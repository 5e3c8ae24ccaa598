"""What `neuraldem import liggghts` knows about a run besides its dump: the scene (from the dataset it joins, a
scene file or name, a generated dataset, or the options), the run's own deck when it is one of ours (opening
step, sink plane, timestep), and whether the stated hopper fits the particles in the dump.

Precedence of each value: an option given on the command line, then the scene (scene=, else the dataset the
run joins), then the run's deck (in.hopper / log.liggghts / sink.stl written by neuraldem beside the dump).
The cone height comes from the scene and the run's cone angle (param alpha): (R - r_o) tan(alpha).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.data.manifest import MANIFEST_NAME, Manifest
from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings
from neuraldem.scenes.hopper.solver import HopperScene, HopperTrajectory

DECK_MARK = "# neuraldem "  # first line of every LIGGGHTS input neuraldem writes
WALL_TOLERANCE_D = 1.0  # the outermost particle centre lies within this many diameters of the stated wall
CONE_TOLERANCE_D = 0.1  # a centre this far below the stated cone lies inside the wall: refused
REST_TOLERANCE_D = 2.0  # the lowest particle at the wall rests within this many diameters above the stated cone


@dataclass
class StatedScene:
    """The scene of a run as stated: by the options, a scene, a dataset, or the run's own deck."""

    source: str  # where the scene came from (said in notes and errors)
    hopper: dict[str, Any]  # generated hopper keys (hopper_diameter, outlet_diameter, sink_depth, max_time, ...)
    metrics: HopperMetricSettings
    position_resolution: float | None


def deck_values(dump: Path) -> dict[str, float]:
    """Opening step, sink plane and timestep from a deck neuraldem wrote beside the dump (empty for another)."""
    folder = dump.parent
    deck = folder / "in.hopper"
    text = deck.read_text() if deck.is_file() else ""
    if not text.startswith(DECK_MARK):
        return {}
    out: dict[str, float] = {}
    opened = re.search(r'print "NEURALDEM_OPEN_STEP (\d+)"', text)
    if opened:
        out["open_step"] = int(opened.group(1))
    step = re.search(r"^timestep\s+(\S+)", text, re.MULTILINE)
    if step:
        out["dt"] = float(step.group(1))
    sink = folder / "sink.stl"
    if sink.is_file():
        z = {float(line.split()[3]) for line in sink.read_text().splitlines() if line.strip().startswith("vertex")}
        if len(z) == 1:
            out["sink_z"] = z.pop()
    return out


def stated_scene(scene: str | None, dataset: Path) -> StatedScene | None:
    """The scene a run is imported with: `scene=` (a scene file or name, or a dataset folder), else the dataset
    it joins when that exists; None when neither states one (the options must then)."""
    if scene is not None:
        path = Path(scene).expanduser()
        if (path / MANIFEST_NAME).is_file():
            return from_manifest(Manifest.load(path), f"dataset {path}")
        from neuraldem.config.user import scene_config

        file, cfg = scene_config(scene)
        if cfg.get("kind") not in (None, "hopper"):
            raise ConfigError(f"scene={scene}: {file} is a {cfg.get('kind')} scene", "give a hopper scene")
        hopper = HopperScene.from_config(cfg.get("scene", {}), f"scene file {file}: scene").as_dict()
        metrics = HopperMetricSettings.from_config(cfg.get("metrics") or {}, f"scene file {file}: metrics")
        storage = cfg.get("storage") or {}
        return StatedScene(f"scene {file}", hopper, metrics, storage.get("position_resolution"))
    if (dataset / MANIFEST_NAME).is_file():
        return from_manifest(Manifest.load(dataset), f"dataset {dataset}")
    return None


def from_manifest(m: Manifest, label: str) -> StatedScene:
    if m.kind != "hopper":
        raise ConfigError(f"{label} holds {m.kind} runs", "import hopper runs into a hopper dataset")
    metrics = HopperMetricSettings.from_config(m.metric_settings or {}, f"{label} metric_settings")
    return StatedScene(label, dict(m.scene.get("hopper", {})), metrics, m.scene.get("position_resolution"))


def resolve(a: Any, stated: StatedScene | None, deck: dict[str, float], params: dict[str, float]) -> dict[str, Any]:
    """Every value the import needs, each from the option, the scene or the deck (see the module docstring);
    one line naming the option when a value is known nowhere."""
    hop = stated.hopper if stated is not None else {}
    material = hop.get("material", {})
    out: dict[str, Any] = {
        "diameter": first(a.diameter, material.get("diameter")),
        "dt": first(a.dt, material.get("dt"), deck.get("dt")),
        "radius": first(a.radius, half(hop.get("hopper_diameter"))),
        "outlet_radius": first(a.outlet_radius, half(hop.get("outlet_diameter"))),
        "max_time": first(a.max_time, hop.get("max_time")),
        "open_step": first(a.open_step, deck.get("open_step")),
        "sink_z": first(a.sink_z, -hop["sink_depth"] if "sink_depth" in hop else None, deck.get("sink_z")),
        "resolution": first(a.resolution, stated.position_resolution if stated else None, 1e-5),
    }
    hints = {"diameter": "diameter= (particle diameter [m])", "dt": "dt= (the DEM timestep [s])",
             "radius": "radius= (hopper radius [m])", "outlet_radius": "outlet_radius= [m]",
             "max_time": "max_time= (the horizon every run is scored over [s], e.g. how long your runs were "
                         "simulated after opening)"}
    missing = [hint for key, hint in hints.items() if out[key] is None]
    if missing:
        raise ConfigError(f"the run's scene is not known: give {', '.join(missing)}",
                          "or scene=<your scene file or name> (neuraldem scene list) with param=[alpha=...]")
    for key in ("diameter", "dt", "radius", "outlet_radius", "max_time", "resolution"):
        if not out[key] > 0:
            raise ConfigError(f"{key}= must be positive, got {out[key]:g}")
    derived = None
    if "alpha" in params and out["outlet_radius"] < out["radius"]:
        derived = (out["radius"] - out["outlet_radius"]) * math.tan(math.radians(params["alpha"]))
    if a.cone_height is not None:
        if derived is not None and abs(a.cone_height - derived) > 0.01 * max(derived, out["diameter"]):
            raise ConfigError(f"cone_height={a.cone_height:g} differs from the cone of alpha={params['alpha']:g}: "
                              f"(R - r_o) tan(alpha) = {derived:.4g} m", "give one of them right (or leave out "
                              "cone_height=: it follows from alpha)")
        out["cone_height"] = float(a.cone_height)
    elif derived is not None:
        out["cone_height"] = derived
    else:
        raise ConfigError("cone_height= is needed: the height of the cone at the wall [m] (0 for a flat bottom)",
                          "or give the cone angle as param=[alpha=...]: the height follows from it")
    out["open_step"] = int(out["open_step"] or 0)
    out["sink_z"] = -math.inf if out["sink_z"] is None else float(out["sink_z"])
    return out


def first(*values: Any) -> Any:
    return next((v for v in values if v is not None), None)


def half(value: Any) -> float | None:
    return None if value is None else 0.5 * float(value)


def check_geometry(traj: HopperTrajectory, dump: Path, radius: float, outlet_radius: float, cone_height: float,
                   diameter: float) -> None:
    """The stated hopper must hold the particles of the dump (outlet centre at the origin, z up): no centre
    outside the wall or below the cone, the outermost within a diameter of the wall, and the material at the wall
    resting on the stated cone. Each refusal is one line naming the file, the largest distance and the fix."""
    start = traj.positions[0]
    alive = np.isfinite(start[:, 0])
    r0 = np.hypot(start[alive, 0], start[alive, 1])
    if not r0.size:
        raise DataError(f"{dump}: no particle at the opening step")
    r_max = float(r0.max())
    where = "(outlet centre at x = y = 0, z up, the outlet plane at z = 0)"
    if r_max > radius:
        raise DataError(f"{dump}: {int((r0 > radius).sum())} particle centres lie outside the stated hopper radius "
                        f"{radius:g} m, the farthest {r_max:.4g} m from the axis ({r_max - radius:.3g} m out)",
                        f"give the hopper's inner radius (radius= or the scene's hopper_diameter) and check the "
                        f"coordinates {where}")
    if r_max < radius - (0.5 + WALL_TOLERANCE_D) * diameter:
        raise DataError(f"{dump}: every particle centre lies within {r_max:.4g} m of the axis: the stated hopper "
                        f"radius {radius:g} m is {radius - r_max - 0.5 * diameter:.3g} m wider than the packing",
                        f"give the hopper's inner radius, about radius={r_max + 0.5 * diameter:.3g} "
                        f"(or check the coordinates {where})")
    pos = traj.positions.reshape(-1, 3)
    pos = pos[np.isfinite(pos[:, 0])]
    r = np.hypot(pos[:, 0], pos[:, 1])
    span = max(radius - outlet_radius, 1e-12)
    cone = np.clip(r - outlet_radius, 0.0, span) / span * cone_height
    inside = (pos[:, 2] > 0) & (r > outlet_radius)
    depth = (cone - pos[:, 2])[inside]
    if depth.size and float(depth.max()) > CONE_TOLERANCE_D * diameter:
        raise DataError(f"{dump}: particle centres lie below the stated cone (height {cone_height:g} m at the wall), "
                        f"the deepest {float(depth.max()):.3g} m below it",
                        f"give the cone's height at the wall (cone_height=, or param alpha with scene=) and check "
                        f"the coordinates {where}")
    wall = alive.copy()
    wall[alive] = r0 > radius - 1.5 * diameter
    if wall.any():
        rest = float(np.min(start[wall, 2]))
        if rest > cone_height + REST_TOLERANCE_D * diameter:
            raise DataError(f"{dump}: the particles at the wall rest at z >= {rest:.4g} m, "
                            f"{rest - cone_height:.3g} m above the stated cone (height {cone_height:g} m at the wall)",
                            "give the cone's height at the wall (cone_height=, or param alpha with scene=)")
