"""docs/your-own-scene.md, walked: the commands of its marked blocks (`<!-- walk SCENE -->` before a fenced block),
read from the page so the page cannot drift, run in a fresh home folder outside the checkout, for a hopper and a
bed, from a scene file in the user config folder to a `predict` answer of the released model beside the shipped
one. The scene sizes and run counts are swapped for tiny ones (those of hopper_tiny / fb_tiny: `TINY`); the
commands, the page's edits of the scene file, its ranges and the order are the page's.

The default suite checks the page without solver runs: its key tables are the ones `neuraldem scene new` writes,
every key of the packaged scenes is in them, its scene files compose into valid pipelines, and every command
names a verb and keys that verb takes. The walk itself (a few CPU minutes per scene) is marked slow.
"""

from __future__ import annotations

import json
import math
import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml
from omegaconf import OmegaConf

from tests.helpers import REPO

PAGE = REPO / "docs" / "your-own-scene.md"
BLOCK = re.compile(r"<!-- walk (\w+)(?: edit (\w+))? -->\n```(\w+)\n(.*?)```", re.DOTALL)
KINDS = {"hopper": "hopper", "bed": "fluidized_bed"}
SHIPPED = {"hopper": "hopper_small", "bed": "fb_small"}

# what makes a walked scene tiny: scene-file values (dotted) set after the page's edit, and command values
TINY: dict[str, dict[str, object]] = {
    "hopper": {"scene.material.diameter": 0.01, "scene.material.dt": 1.0e-4, "scene.hopper_diameter": 0.14,
               "scene.outlet_diameter": 0.07, "scene.n_particles": 500, "scene.settle_time": 0.3,
               "scene.max_time": 5.0, "scene.timeout_s": 600.0, "parameters.n_sims": 8,
               "characterization.enabled": False, "storage.keep_raw": True, "datamodule.batch_size": 4,
               "datamodule.n_queries": 256, "datamodule.eval_time_stride": 2},
    "bed": {"scene.width": 0.024, "scene.height": 0.06, "scene.cells": [6, 1, 15], "scene.n_particles": 300,
            "scene.spinup_time": 0.05, "scene.timeout_per_simulated_s": 1200.0, "parameters.n_sims": 5,
            "parameters.n_velocities": 5, "parameters.packings_per_velocity": 1, "parameters.duration": 0.2,
            "metrics.lacey_block": [1, 1, 2], "storage.keep_raw": True, "datamodule.batch_size": 4,
            "datamodule.eval_time_stride": 2},
}
TINY_COMMAND_VALUES = {"hopper": {"trainer.max_steps": "300", "trainer.val_check_interval": "100", "port": "0"},
                       "bed": {"trainer.max_steps": "40", "lacey_time": "0.1", "port": "0"}}
TINY_EXTRA = {"bed": {"train": ["trainer.val_check_interval=20", "callbacks.rollout_validation.steps=10"]}}


@dataclass
class Step:
    scene: str
    edit: str | None  # the scene file an edit block changes
    text: str

    def commands(self) -> list[str]:
        lines = self.text.replace("\\\n", " ").splitlines()
        return [line.strip() for line in lines if line.strip() and not line.strip().startswith("#")]


def steps(scene: str) -> list[Step]:
    found = [Step(m.group(1), m.group(2), m.group(4)) for m in BLOCK.finditer(PAGE.read_text())]
    assert found, f"{PAGE} has no walked blocks"
    return [s for s in found if s.scene == scene]


def flat(tree: object, prefix: str = "") -> dict[str, object]:
    if not isinstance(tree, dict):
        return {prefix.rstrip("."): tree}
    out: dict[str, object] = {}
    for k, v in tree.items():
        out.update(flat(v, f"{prefix}{k}."))
    return out


def edit_scene_file(path: Path, text: str, tiny: dict[str, object] | None = None) -> None:
    """The page's edit merged into the scene file `neuraldem scene new` wrote (each key must be one it wrote),
    then the tiny values."""
    written = OmegaConf.load(path)
    edit = yaml.safe_load(text)
    unknown = sorted(set(flat(edit)) - set(flat(OmegaConf.to_container(written))))
    assert not unknown, f"the page edits keys {path.name} does not have: {unknown}"
    merged = OmegaConf.merge(written, edit)
    for key, value in (tiny or {}).items():
        OmegaConf.update(merged, key, value, force_add=True)
    OmegaConf.save(merged, path)


def user_env(home: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("NEURALDEM_CONFIG", "NEURALDEM_MODELS", "NEURALDEM_PRETRAINED_DIR", "XDG_CONFIG_HOME",
                        "XDG_DATA_HOME")}
    (home / "bin").mkdir(parents=True, exist_ok=True)
    shim = home / "bin" / "neuraldem"
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m neuraldem "$@"\n')
    shim.chmod(0o755)
    env.update(HOME=str(home), NEURALDEM_DATA=str(home / "data"), PATH=f"{home / 'bin'}{os.pathsep}{env['PATH']}",
               PYTHONPATH=os.pathsep.join([str(REPO / "src"), *filter(None, [env.get("PYTHONPATH")])]))
    return env


def tokens(command: str, home: Path) -> list[str]:
    return shlex.split(command.replace("$HOME", str(home)))


def key_values(command: str) -> dict[str, str]:
    return {t.partition("=")[0]: t.partition("=")[2] for t in shlex.split(command) if "=" in t}


# ---- the default suite: the page against the code, no solver run


@pytest.mark.parametrize("kind", ["hopper", "fluidized_bed"])
def test_the_key_tables_are_the_ones_scene_new_writes(kind: str):
    from neuraldem.scenes import import_class, scene
    from neuraldem.scenes.parameters import scene_key_markdown

    table = scene_key_markdown(import_class(scene(kind).scene_keys))
    assert f"<!-- keys {kind} -->\n{table}\n" in PAGE.read_text()


@pytest.mark.parametrize(("kind", "config", "sections"), [
    ("hopper", "hopper_small", ("scene", "parameters")),
    ("fluidized_bed", "fb_small", ("scene", "parameters", "fields")),
])
def test_every_key_of_the_packaged_scene_has_a_row(kind: str, config: str, sections: tuple[str, ...]):
    from neuraldem.scenes import import_class, scene

    keys = {k.key for k in import_class(scene(kind).scene_keys)}
    data = yaml.safe_load((REPO / "conf" / "data" / f"{config}.yaml").read_text())
    missing = sorted(k for k in flat({s: data[s] for s in sections}) if k not in keys)
    assert not missing, f"scene keys without a row in {kind}'s scene_keys: {missing}"


@pytest.mark.parametrize("walk", ["hopper", "bed"])
def test_the_pages_scene_files_compose_into_pipelines(walk: str, tmp_path: Path, monkeypatch, capsys):
    """`scene new` as the page runs it, the page's edit, then the scene every command composes, checked by the
    scene's datagen pipeline (every value, the ranges) and big enough for its split."""
    from neuraldem.scene_files import composed, main
    from neuraldem.scenes import scene

    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("NEURALDEM_CONFIG", raising=False)
    monkeypatch.delenv("XDG_CONFIG_HOME", raising=False)
    new, edit = steps(walk)[0], next(s for s in steps(walk) if s.edit)
    assert main(tokens(new.commands()[0], tmp_path)[2:]) == 0
    name = edit.edit
    path = tmp_path / ".config" / "neuraldem" / "data" / f"{name}.yaml"
    assert f"wrote {path}" in capsys.readouterr().out
    edit_scene_file(path, edit.text)
    cfg = composed(name)
    assert cfg["kind"] == KINDS[walk] and cfg["name"] == name
    pipe = scene(cfg["kind"]).pipeline(OmegaConf.create(cfg))
    assert pipe.split_warning(int(cfg["parameters"]["n_sims"])) is None
    for key, value in flat(yaml.safe_load(edit.text)).items():
        got = OmegaConf.select(OmegaConf.create(cfg), key)
        assert got == value, (key, got, value)


def help_text(capsys, argv: list[str]) -> str:
    from neuraldem.__main__ import main

    with pytest.raises(SystemExit) as done:
        main([*argv, "--help"])
    assert done.value.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("walk", ["hopper", "bed"])
def test_every_command_names_a_verb_and_keys_it_takes(walk: str, tmp_path: Path, monkeypatch, capsys):
    from neuraldem.__main__ import VERBS
    from neuraldem.cli import check_overrides

    monkeypatch.setattr(sys, "argv", list(sys.argv))  # the verbs' main() sets it
    monkeypatch.setenv("NEURALDEM_CONFIG", str(tmp_path))
    for name in ("my_hopper", "my_bed"):  # the page's scenes, as `scene new` leaves them
        (tmp_path / "data").mkdir(exist_ok=True)
        (tmp_path / "data" / f"{name}.yaml").write_text("defaults:\n  - hopper_tiny\n  - _self_\n")
    for step in steps(walk):
        for command in step.commands() if step.edit is None else []:
            words = tokens(command, tmp_path)
            assert words[0] == "neuraldem" and words[1] in VERBS, command
            verb, rest = words[1], words[2:]
            if verb in ("datagen", "train", "evaluate"):
                check_overrides(verb, rest)  # exits with the one-line error on an unknown key or scene
                continue
            if verb == "scene":
                continue  # run by the test above
            head = [verb] + [w for w in rest[:1] if "=" not in w]
            text = help_text(capsys, head)
            for key in key_values(" ".join(rest)):
                assert f"{key}=" in text, f"{command}: {key}= is not an option of neuraldem {' '.join(head)}"


# ---- the walk (slow): every command of the page, in order, at the tiny sizes


def run(command: str, env: dict[str, str], home: Path, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(["bash", "-c", command], cwd=home, env=env, capture_output=True, text=True,
                          timeout=timeout)
    assert proc.returncode == 0, f"{command}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc


def tiny_command(walk: str, command: str) -> str:
    """The page's command with the tiny values of its keys (and the tiny-only keys of its verb added)."""
    words = shlex.split(command)
    values = TINY_COMMAND_VALUES[walk]
    words = [f"{w.partition('=')[0]}={values[w.partition('=')[0]]}" if "=" in w and w.partition("=")[0] in values
             else w for w in words]
    words += TINY_EXTRA.get(walk, {}).get(words[1], [])
    return " ".join(shlex.quote(w) if "$HOME" not in w else w for w in words)


def serve_starts(command: str, env: dict[str, str], home: Path) -> None:
    """`neuraldem serve` as the page starts it: its page address is printed, then it is stopped."""
    pytest.importorskip("panel")
    proc = subprocess.Popen(["bash", "-c", f"exec {command}"], cwd=home, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        for line in proc.stdout:  # type: ignore[union-attr]
            if "page at http://" in line:
                return
        pytest.fail(f"{command} ended without serving a page (status {proc.wait()})")
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def stage_own_run(walk: str, command: str, home: Path) -> tuple[str, dict]:
    """A run 'of your own' where the page's import command reads it: a run the walk's datagen made (raw files
    kept), the test run of its split, and the command with that run's parameters."""
    data = home / "data" / "datasets" / ("my_hopper" if walk == "hopper" else "my_bed")
    m = json.loads((data / "manifest.json").read_text())
    part = m["splits"]["random" if walk == "hopper" else "velocity"]["test"][0]
    rec = next(r for r in m["simulations"] if r["sim_id"] == part)
    kv = key_values(command.replace("$HOME", str(home)))
    target = Path(kv["dump"]).parent if walk == "hopper" else Path(kv["case"])
    shutil.copytree(data / "runs" / part, target)
    if walk == "hopper":
        p = rec["params"]
        return re.sub(r"param=\[[^\]]*\]", f"param=[alpha={p['alpha']},mu_s={p['mu_s']},mu_r={p['mu_r']}]",
                      command), rec
    return re.sub(r"inlet_velocity=\S+", f"inlet_velocity={rec['params']['inlet_velocity']}", command), rec


def finite(metrics: dict) -> dict:
    return {k: v for k, v in metrics.items() if not (isinstance(v, float) and math.isnan(v))}


@pytest.mark.slow
@pytest.mark.solver
@pytest.mark.parametrize("walk", ["hopper", "bed"])
def test_the_page_walked_from_a_scene_file_to_predict(walk: str, tmp_path: Path):
    home = tmp_path / "home"
    env = user_env(home)
    for step in steps(walk):
        if step.edit is not None:
            edit_scene_file(home / ".config" / "neuraldem" / "data" / f"{step.edit}.yaml", step.text, TINY[walk])
            continue
        for command in step.commands():
            command = tiny_command(walk, command)
            if " serve " in f"{command} ":
                serve_starts(command, env, home)
                continue
            if " import " in command:
                command, rec = stage_own_run(walk, command, home)
                run(command, env, home)
                kv = key_values(command.replace("$HOME", str(home)))
                ours = json.loads((Path(kv["dataset"]) / "manifest.json").read_text())["simulations"][0]
                assert finite(ours["metrics"]) == finite(rec["metrics"]), "imported != generated"
                continue
            proc = run(command, env, home)
            if " predict " in command:
                model = Path(key_values(command)["model"]).name
                assert f"(model {model})" in proc.stdout, proc.stdout
    # the user's model answered beside the shipped one
    models = home / "my-models"
    assert (models / f"my_{walk}" / "meta.json").is_file()
    meta = json.loads((models / f"my_{walk}" / "meta.json").read_text())
    assert meta["asked_range"] and meta["trained_range"]
    shipped = run(f"neuraldem predict {KINDS[walk]} model={SHIPPED[walk]} "
                  + ("alpha=45 mu_s=0.5 mu_r=0.15 fields=false" if walk == "hopper" else "inlet_velocity=1.8 "
                     "fields=false"), env, home)
    assert f"(model {SHIPPED[walk]})" in shipped.stdout
