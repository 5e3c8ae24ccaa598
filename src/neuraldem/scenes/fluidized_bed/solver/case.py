"""The files of a fluidized-bed DPMFoam case (mesh, boundary conditions, cloud, controls and flux monitors),
and a case directory prepared for a run: written fresh, or kept for a resume when its settings are the same."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.scenes.fluidized_bed.solver.attempts import record_killed_attempts
from neuraldem.scenes.fluidized_bed.solver.reader import latest_complete_time
from neuraldem.scenes.fluidized_bed.solver.scene import GRAVITY, BedScene, random_packing
from neuraldem.sim.foam_reader import FoamCase
from neuraldem.sim.openfoam import write_foam_file

STAMP = "neuraldem_case.json"


def write_case(scene: BedScene, case: Path, inlet_velocity: float, positions: np.ndarray,
               end_time: float) -> None:
    """All files of a DPMFoam case in `case` (created)."""
    W, T, H = scene.width, scene.thickness, scene.height
    nx, ny, nz = scene.cells
    write_foam_file(case / "system" / "blockMeshDict", "dictionary", "blockMeshDict", f"""scale 1;
vertices
(
    (0 0 0) ({W!r} 0 0) ({W!r} {T!r} 0) (0 {T!r} 0)
    (0 0 {H!r}) ({W!r} 0 {H!r}) ({W!r} {T!r} {H!r}) (0 {T!r} {H!r})
);
blocks (hex (0 1 2 3 4 5 6 7) ({nx} {ny} {nz}) simpleGrading (1 1 1));
edges ();
boundary
(
    bottom {{ type wall; faces ((0 3 2 1)); }}
    top {{ type wall; faces ((4 5 6 7)); }}
    walls {{ type wall; faces ((0 4 7 3) (1 2 6 5)); }}
    frontAndBack {{ type {'symmetry' if scene.front_back == 'symmetry' else 'wall'}; faces ((0 1 5 4) (3 7 6 2)); }}
);
""")
    sym = scene.front_back == "symmetry"
    fb_u = "type symmetry;" if sym else "type noSlip;"
    fb_p = "type symmetry;" if sym else "type fixedFluxPressure; value uniform 0;"
    u0 = f"(0 0 {float(inlet_velocity)!r})"
    write_foam_file(case / "0" / "U.air", "volVectorField", "U.air", f"""dimensions [0 1 -1 0 0 0 0];
internalField uniform (0 0 0);
boundaryField
{{
    bottom
    {{
        type interstitialInletVelocity;   // superficial inlet velocity / fluid fraction
        inletVelocity uniform {u0};
        value uniform {u0};
        phi phi.air;
        alpha alpha.air;
    }}
    top {{ type pressureInletOutletVelocity; phi phi.air; inletValue uniform (0 0 0); value uniform (0 0 0); }}
    walls {{ type noSlip; }}
    frontAndBack {{ {fb_u} }}
}}
""", location="0")
    write_foam_file(case / "0" / "p", "volScalarField", "p", f"""dimensions [0 2 -2 0 0 0 0];
internalField uniform 0;
boundaryField
{{
    bottom {{ type fixedFluxPressure; value uniform 0; }}
    top {{ type fixedValue; value uniform 0; }}
    walls {{ type fixedFluxPressure; value uniform 0; }}
    frontAndBack {{ {fb_p} }}
}}
""", location="0")
    write_foam_file(case / "constant" / "g", "uniformDimensionedVectorField", "g",
                    f"dimensions [0 1 -2 0 0 0 0];\nvalue (0 0 {-GRAVITY!r});\n", location="constant")
    write_foam_file(case / "constant" / "transportProperties", "dictionary", "transportProperties",
                    f"continuousPhase air;\nrho.air {scene.fluid_density!r};\ntransportModel Newtonian;\n"
                    f"nu {scene.fluid_viscosity!r};\n", location="constant")
    write_foam_file(case / "constant" / "turbulenceProperties.air", "dictionary", "turbulenceProperties.air",
                    "simulationType laminar;\n", location="constant")
    write_foam_file(case / "constant" / "kinematicCloudPositions", "vectorField", "kinematicCloudPositions",
                    f"{len(positions)}\n(\n" + "".join(f"({x!r} {y!r} {z!r})\n" for x, y, z in positions.tolist())
                    + ")\n", location="constant")
    _write_cloud_properties(scene, case)
    _write_system(scene, case, end_time)


def _write_cloud_properties(scene: BedScene, case: Path) -> None:
    rebound = "".join(f"        {p} {{ type rebound; e {scene.patch_restitution!r}; mu {scene.friction!r}; }}\n"
                      for p in ("bottom", "top", "walls", "frontAndBack"))
    contact = (f"alpha {scene.damping!r}; b 1.5; mu {scene.friction!r}; cohesionEnergyDensity 0; "
               f"collisionResolutionSteps {scene.collision_resolution_steps};")
    write_foam_file(case / "constant" / "kinematicCloudProperties", "dictionary", "kinematicCloudProperties", f"""
solution
{{
    active true;
    coupled true;
    transient yes;
    cellValueSourceCorrection off;
    interpolationSchemes {{ rho.air cell; U.air cellPoint; mu.air cell; }}
    integrationSchemes {{ U Euler; }}
    sourceTerms {{ schemes {{ U semiImplicit 1; }} }}
}}
constantProperties
{{
    parcelTypeId 1;
    rhoMin 1e-15;
    minParcelMass 1e-15;
    rho0 {scene.density!r};
    youngsModulus {scene.youngs_modulus!r};
    poissonsRatio {scene.poisson_ratio!r};
    constantVolume false;
    alphaMax {scene.alpha_max!r};
}}
subModels
{{
    particleForces
    {{
        {scene.drag}Drag {{ alphac alpha.air; }}
        gravity;
    }}
    injectionModels
    {{
        start
        {{
            type manualInjection;
            massTotal 0;
            parcelBasisType fixed;
            nParticle 1;
            SOI 0;
            positionsFile "kinematicCloudPositions";
            U0 (0 0 0);
            sizeDistribution {{ type fixedValue; fixedValueDistribution {{ value {scene.diameter!r}; }} }}
        }}
    }}
    dispersionModel none;
    patchInteractionModel localInteraction;
    localInteractionCoeffs
    {{
        patches
        (
{rebound}        );
    }}
    heatTransferModel none;
    surfaceFilmModel none;
    collisionModel pairCollision;
    pairCollisionCoeffs
    {{
        maxInteractionDistance {scene.diameter!r};
        writeReferredParticleCloud no;
        pairModel pairSpringSliderDashpot;
        pairSpringSliderDashpotCoeffs {{ useEquivalentSize no; {contact} }}
        wallModel wallSpringSliderDashpot;
        wallSpringSliderDashpotCoeffs
        {{
            useEquivalentSize no; youngsModulus {scene.youngs_modulus!r}; poissonsRatio {scene.poisson_ratio!r};
            {contact}
        }}
        U U.air;
    }}
    stochasticCollisionModel none;
    radiation off;
}}
cloudFunctions {{}}
""", location="constant")


def _write_system(scene: BedScene, case: Path, end_time: float) -> None:
    # Air volume flow through bottom and top in every step: sum over the patch faces of
    # alpha.air * phi.air (fluid fraction times the interstitial flux, both after the pressure correction).
    # The solver's own alphaPhi.air field is not used: it is set before the pressure correction.
    monitors = "".join(f"""
    flux_{patch}
    {{
        type surfaceFieldValue;
        libs ("libfieldFunctionObjects.so");
        writeControl timeStep;
        writeInterval 1;
        log false;
        writeFields false;
        regionType patch;
        name {patch};
        operation weightedSum;
        weightField alpha.air;
        fields (phi.air);
    }}""" for patch in ("bottom", "top"))
    write_foam_file(case / "system" / "controlDict", "dictionary", "controlDict", f"""application DPMFoam;
startFrom latestTime;
startTime 0;
stopAt endTime;
endTime {end_time!r};
deltaT {scene.dt!r};
writeControl timeStep;
writeInterval {round(scene.snapshot_interval / scene.dt)};
purgeWrite 0;
writeFormat ascii;
writePrecision {scene.write_precision};
writeCompression {'on' if scene.write_compression else 'off'};
timeFormat general;
timePrecision 8;
runTimeModifiable no;
functions
{{{monitors}
}}
""", location="system")
    write_foam_file(case / "system" / "fvSchemes", "dictionary", "fvSchemes", """
ddtSchemes { default Euler; }
gradSchemes { default Gauss linear; }
divSchemes
{
    default none;
    div(alphaPhi.air,U.air) Gauss linearUpwindV unlimited;
    div(((alpha.air*nuEff.air)*dev2(T(grad(U.air))))) Gauss linear;
    div(phiGByA,kinematicCloud:alpha) Gauss linear;
}
laplacianSchemes { default Gauss linear corrected; }
interpolationSchemes { default linear; }
snGradSchemes { default corrected; }
""", location="system")
    write_foam_file(case / "system" / "fvSolution", "dictionary", "fvSolution", """
solvers
{
    p { solver GAMG; tolerance 1e-7; relTol 0.01; smoother GaussSeidel; }
    pFinal { solver GAMG; tolerance 1e-7; relTol 0; smoother GaussSeidel; }
    "U.air.*" { solver smoothSolver; smoother symGaussSeidel; tolerance 1e-6; relTol 0; }
    kinematicCloud:alpha { solver smoothSolver; smoother symGaussSeidel; tolerance 1e-6; relTol 0; }
}
PIMPLE
{
    nOuterCorrectors 1;
    nCorrectors 2;
    momentumPredictor yes;
    nNonOrthogonalCorrectors 0;
    pRefCell 0;
    pRefValue 0;
}
relaxationFactors {}
""", location="system")


def case_stamp(scene: BedScene, inlet_velocity: float, duration: float, seed: int) -> dict[str, Any]:
    return {"scene": scene.as_dict(), "inlet_velocity": float(inlet_velocity), "duration": float(duration),
            "seed": int(seed)}


def prepare_case(scene: BedScene, workdir: Path, inlet_velocity: float, duration: float,
                 seed: int) -> tuple[bool, str | None]:
    """Write a fresh case, or keep a started one with the same settings. Returns (resumed, restart time)."""
    stamp = case_stamp(scene, inlet_velocity, duration, seed)
    stamp_path = workdir / STAMP
    if stamp_path.is_file():
        try:
            same = json.loads(stamp_path.read_text()) == json.loads(json.dumps(stamp))
        except json.JSONDecodeError:
            same = False
        if same and (workdir / "constant" / "polyMesh" / "owner").is_file() and (workdir / "0" / "C").is_file():
            restart = latest_complete_time(FoamCase(workdir))
            if restart is not None:
                record_killed_attempts(workdir)
                return True, restart
    if workdir.exists():
        shutil.rmtree(workdir)
    workdir.mkdir(parents=True)
    positions = random_packing(scene, np.random.default_rng(seed))
    write_case(scene, workdir, inlet_velocity, positions, end_time=round(scene.spinup_time + duration, 9))
    stamp_path.write_text(json.dumps(stamp, indent=1))
    return False, None
