"""Every key of a hopper scene file (`conf/data/hopper_small.yaml`), with its unit, meaning and what it costs.

`neuraldem scene new NAME from=hopper_small` writes these keys with a comment each; docs/your-own-scene.md shows
the same table (a test keeps the two equal). Costs quote results/ where a measurement exists.
"""

from __future__ import annotations

from neuraldem.scenes.parameters import SceneKey

SCENE_KEYS: tuple[SceneKey, ...] = (
    SceneKey("scene.material.diameter", "m", "particle diameter (monodisperse spheres)",
             "the stable timestep shrinks with it (Hertz contact time ~ diameter): halve it, halve material.dt"),
    SceneKey("scene.material.density", "kg/m^3", "particle density", "none"),
    SceneKey("scene.material.youngs_modulus", "Pa", "Young's modulus (softened: real glass is ~6e10)",
             "stiffer contacts need a smaller material.dt (contact time ~ E^-0.4)"),
    SceneKey("scene.material.poisson_ratio", "-", "Poisson ratio of the Hertz contact", "none"),
    SceneKey("scene.material.restitution", "-", "coefficient of restitution", "none"),
    SceneKey("scene.material.rolling_model", "-", "LIGGGHTS rolling-friction model (epsd2, cdt, epsd, epsd3)",
             "none"),
    SceneKey("scene.material.dt", "s", "DEM timestep",
             "~ 1/dt; must resolve a contact (about 1/10 of the Hertz contact time)"),
    SceneKey("scene.hopper_diameter", "m", "inner diameter of the cylinder",
             "sets the fill height of n_particles, hence the settle and drain time"),
    SceneKey("scene.outlet_diameter", "m", "outlet diameter at the bottom of the cone (at least 2 particle diameters)",
             "flow rate ~ (outlet - 1.4 d)^2.5 (Beverloo): a smaller outlet drains slower, below ~5 d it clogs"),
    SceneKey("scene.sink_depth", "m", "depth of the sink disk below the outlet plane: a particle crossing it has "
             "left (exit time recorded, particle deleted)", "none"),
    SceneKey("scene.n_segments", "-", "segments of the cylinder and cone meshes around the axis", "negligible"),
    SceneKey("scene.n_particles", "-", "particles filled in before the outlet opens",
             "~ linear: 18.8 CPU s per run at 2000, 48.6 at 5000 (results/hopper/speed/hopper_scaling.json)"),
    SceneKey("scene.insertion_fraction", "-", "solid fraction of the loose fill inserted above the cone "
             "(0.05 - 0.45; too high and not every particle fits in)",
             "lower: a taller box and a longer fall while settling"),
    SceneKey("scene.settle_time", "s", "fill and settle with the outlet closed; the outlet opens after it (t = 0)",
             "steps at the full particle count: 4.5 of the 18.8 CPU s of a run at 2000 particles "
             "(hopper_scaling.json)"),
    SceneKey("scene.snapshot_interval", "s", "particles stored every this long after opening (a multiple of dt)",
             "the model's time step: more snapshots, more disk and training samples"),
    SceneKey("scene.stall_time", "s", "a run stops when the particle count is unchanged this long (a multiple of "
             "snapshot_interval)", "shorter ends clogged runs sooner"),
    SceneKey("scene.max_time", "s", "horizon after opening: runs stop at it (or earlier, empty or stalled; a run "
             "that ended holds its final state up to it) and every run is scored over it",
             "only runs still flowing pay for it; the model answers over 0 .. max_time"),
    SceneKey("scene.timeout_s", "s", "wall-clock limit of one solver run (the run is recorded failed)", "none"),
    SceneKey("parameters.n_sims", "-", "runs of the dataset (a seeded Latin hypercube over the ranges; more can be "
             "added later, the first runs stay)", "~ linear; accuracy: see 'How many runs'"),
    SceneKey("parameters.seed", "-", "seed of the Latin hypercube", "none"),
    SceneKey("parameters.ranges.alpha", "deg", "cone angle to the horizontal, [low, high] (0 = flat bottom)",
             "flatter cones keep a residue (dead zones), steeper ones drain faster"),
    SceneKey("parameters.ranges.mu_s", "-", "sliding friction, [low, high]", "higher friction drains slower"),
    SceneKey("parameters.ranges.mu_r", "-", "rolling friction, [low, high]", "higher friction drains slower"),
    SceneKey("characterization.enabled", "-", "measure the shear angle theta and the angle of repose for every "
             "parameter set (needed only by models conditioned on them: experiment=hopper_macro)",
             "53 CPU s per parameter set at hopper_small (results/hopper/dataset/summary.json); false saves it"),
    SceneKey("storage.keep_raw", "-", "keep LIGGGHTS's text dumps (runs/<sim>/dump.txt) after conversion",
             "disk: tens of MB per run; needed to import a generated run again (neuraldem import liggghts)"),
)
