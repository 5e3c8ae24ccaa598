"""The fluidized bed in OpenFOAM's DPMFoam, by role: the scene and its start packing (`scene`), the case
files (`case`), the trajectory read back from a case (`reader`), the CPU-time bookkeeping of a run's app
attempts (`attempts`), and running, resuming and classifying a run (`runner`)."""
