"""Every key of a fluidized-bed scene file (`conf/data/fb_small.yaml`), with its unit, meaning and what it costs.

`neuraldem scene new NAME from=fb_small` writes these keys with a comment each; docs/your-own-scene.md shows the
same table (a test keeps the two equal). Costs quote results/ where a measurement exists: fb_small costs 109
CPU s per simulated second on a quiet 2-core AMD EPYC (results/fluidized_bed/speed/fb_speed.md).
"""

from pathlib import Path

from neuraldem.scenes.parameters import load_scene_keys

SCENE_KEYS = load_scene_keys(Path(__file__).with_suffix(".yaml"))  # the table: scene_keys.yaml beside
