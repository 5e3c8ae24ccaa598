"""Every key of a hopper scene file (`conf/data/hopper_small.yaml`), with its unit, meaning and what it costs.

`neuraldem scene new NAME from=hopper_small` writes these keys with a comment each; docs/your-own-scene.md shows
the same table (a test keeps the two equal). Costs quote results/ where a measurement exists.
"""

from pathlib import Path

from neuraldem.scenes.parameters import load_scene_keys

SCENE_KEYS = load_scene_keys(Path(__file__).with_suffix(".yaml"))  # the table: scene_keys.yaml beside
