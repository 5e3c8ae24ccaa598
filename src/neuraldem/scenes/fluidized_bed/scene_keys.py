"""Every key of a fluidized-bed scene file (`conf/data/fb_small.yaml`), with its unit, meaning and what it costs.

`neuraldem scene new NAME from=fb_small` writes these keys with a comment each; docs/your-own-scene.md shows the
same table (a test keeps the two equal). Costs quote results/ where a measurement exists: fb_small costs 76.9
CPU s per simulated second on a quiet 2-core Xeon (results/fluidized_bed/speed/fb_speed.md).
"""

from __future__ import annotations

from neuraldem.scenes.parameters import SceneKey

SCENE_KEYS: tuple[SceneKey, ...] = (
    SceneKey("scene.width", "m", "box width (x); the mixing groups split it at its mid-plane", "more cells and "
             "particles for the same bed"),
    SceneKey("scene.thickness", "m", "box thickness (y): a pseudo-2D bed is a few particle diameters thick",
             "as width"),
    SceneKey("scene.height", "m", "box height (z, gravity along -z); the start packing must fill at most 60 %",
             "more cells"),
    SceneKey("scene.cells", "-", "blockMesh cells [nx, ny, nz]; the model's grid (a cell of 2 particle diameters "
             "holds enough particles for a fluid fraction)", "CFD cost ~ cells; the model's cost ~ cells too"),
    SceneKey("scene.front_back", "-", "fluid condition on the y faces: symmetry (pseudo-2D) or wall (no-slip)",
             "none"),
    SceneKey("scene.n_particles", "-", "particles in the bed", "DEM part ~ linear"),
    SceneKey("scene.diameter", "m", "particle diameter", "smaller: more particles for the same bed, shorter "
             "contacts (more DEM substeps)"),
    SceneKey("scene.density", "kg/m^3", "particle density (glass 2526)", "none"),
    SceneKey("scene.youngs_modulus", "Pa", "Young's modulus (softened for the DEM substep)",
             "stiffer: more DEM substeps per CFD step"),
    SceneKey("scene.poisson_ratio", "-", "Poisson ratio", "none"),
    SceneKey("scene.damping", "-", "normal damping coefficient alpha of pairSpringSliderDashpot", "none"),
    SceneKey("scene.friction", "-", "sliding friction (particle-particle and particle-wall)", "none"),
    SceneKey("scene.collision_resolution_steps", "-", "DEM substeps that resolve one collision",
             "DEM part ~ linear"),
    SceneKey("scene.patch_restitution", "-", "rebound of a particle that still reaches an inlet or outlet face",
             "none"),
    SceneKey("scene.drag", "-", "drag model (ErgunWenYu, ...)", "none"),
    SceneKey("scene.fluid_density", "kg/m^3", "gas density (air 1.2)", "none"),
    SceneKey("scene.fluid_viscosity", "m^2/s", "kinematic gas viscosity (air 1.5e-5)", "none"),
    SceneKey("scene.alpha_max", "-", "DPMFoam alphaMax: the fluid fraction is kept above 1 - alpha_max", "none"),
    SceneKey("scene.dt", "s", "CFD timestep (the DEM substeps inside it)", "~ 1/dt"),
    SceneKey("scene.snapshot_interval", "s", "stored every this long: the model's step (a multiple of dt)",
             "fewer snapshots: less disk and data, a longer step to learn"),
    SceneKey("scene.spinup_time", "s", "simulated from the loose start packing but not stored: t = 0 is a "
             "fluidized bed", "paid by every trajectory"),
    SceneKey("scene.initial_packing_fraction", "-", "solid fraction of the loose random start packing", "none"),
    SceneKey("scene.write_precision", "-", "digits of the solver's ASCII output", "disk"),
    SceneKey("scene.write_compression", "-", "gzip the solver's time directories", "less disk, a little more CPU"),
    SceneKey("scene.max_lost_particles", "-", "more particles leaving the domain than this: the run failed", "none"),
    SceneKey("scene.max_fluid_speed", "m/s", "a fluid speed beyond this anywhere counts as divergence (the run "
             "failed)", "none"),
    SceneKey("scene.timeout_per_simulated_s", "s", "wall-clock limit per simulated second", "none"),
    SceneKey("parameters.n_sims", "-", "trajectories: n_velocities x packings_per_velocity, then the long ones",
             "~ linear"),
    SceneKey("parameters.seed", "-", "seed of the velocity table and the packings", "none"),
    SceneKey("parameters.inlet_velocity", "m/s", "superficial inlet velocity, [low, high] (a seeded 1-D Latin "
             "hypercube)", "faster beds bubble and slug: same cost per simulated second"),
    SceneKey("parameters.n_velocities", "-", "velocities of the table; the split holds out whole velocities",
             "~ linear"),
    SceneKey("parameters.packings_per_velocity", "-", "trajectories per velocity from other start packings "
             "(the solver's own spread)", "~ linear"),
    SceneKey("parameters.duration", "s", "stored seconds per trajectory (after spinup_time)",
             "76.9 CPU s per simulated second at fb_small (results/fluidized_bed/speed/fb_speed.md)"),
    SceneKey("parameters.long.inlet_velocities", "m/s", "long test trajectories at velocities the model never "
             "trained on ([] for none)", "each long.duration simulated seconds"),
    SceneKey("parameters.long.duration", "s", "stored seconds of each long trajectory (longer than duration)",
             "30 s is 2300 CPU s at fb_small"),
    SceneKey("parameters.long.part", "-", "where the long trajectories go: test, or val (a long validation set)",
             "none"),
    SceneKey("fields.kernel_sigma", "m", "Gaussian kernel (std) of the solid-fraction field from the particles",
             "none"),
    SceneKey("fields.mixing_sigma", "m", "Gaussian kernel (std) of the mixing concentration", "none"),
    SceneKey("fields.prior_solid_fraction", "-", "solid fraction where the kernel sees no particle", "none"),
    SceneKey("storage.keep_raw", "-", "keep DPMFoam's time directories after conversion",
             "disk: tens of MB per trajectory; needed to import a generated run again (neuraldem import foam)"),
)
