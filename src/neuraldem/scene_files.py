"""`neuraldem scene new|list|show`: scene files of your own, outside the checkout, without knowing Hydra.

    neuraldem scene new my_hopper from=hopper_small   # writes ~/.config/neuraldem/data/my_hopper.yaml
    neuraldem scene list                              # every scene: packaged, plug-ins', yours
    neuraldem scene show my_hopper                    # the scene a command composes from it, and its file

A scene file is a `data` config: `neuraldem datagen data=my_hopper`, `neuraldem train experiment=hopper_micro
data=my_hopper`. `scene new` copies every scene key of the scene it starts from, each with its unit, meaning and
cost as a comment (the table of docs/your-own-scene.md); what it does not list (splits, metrics, the training
datamodule) comes from that scene through `defaults:`. Your folder is `$NEURALDEM_CONFIG` (default
`~/.config/neuraldem`); every Hydra command searches it after the packaged configs, and a name taken by a
packaged scene is refused rather than shadowed (`neuraldem.config.user`).
"""

from __future__ import annotations

import re
import sys
import textwrap
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import yaml

from neuraldem.cli import CommandParser, command_parser, report_user_errors
from neuraldem.config.user import SCENE_GROUP, group_options
from neuraldem.errors import ConfigError
from neuraldem.paths import user_config_dir
from neuraldem.scenes import import_class, registry

ACTIONS = ("new", "list", "show")
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")


def base_chain(name: str) -> list[str]:
    """`name` and the data configs it inherits from through `defaults:` (first entry of each), nearest first."""
    chain, options = [name], group_options(SCENE_GROUP)
    while True:
        text = yaml.safe_load(options[chain[-1]][1].read_text()) or {}
        bases = [d for d in text.get("defaults", []) if isinstance(d, str) and d != "_self_"]
        if not bases or bases[0] in chain or bases[0] not in options:
            return chain
        chain.append(bases[0])


def scene_kind(name: str) -> str | None:
    """The `kind:` a data config states or inherits."""
    options = group_options(SCENE_GROUP)
    for link in base_chain(name):
        kind = (yaml.safe_load(options[link][1].read_text()) or {}).get("kind")
        if kind:
            return str(kind)
    return None


def composed(name: str) -> Any:
    """The `data` config `name` as every Hydra command composes it (defaults, interpolations resolved)."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from omegaconf import OmegaConf

    import neuraldem.config  # noqa: F401  (resolvers)
    from neuraldem.paths import config_dir

    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
            cfg = compose(config_name="datagen", overrides=[f"{SCENE_GROUP}={name}"])
    finally:
        GlobalHydra.instance().clear()
    return OmegaConf.to_container(cfg[SCENE_GROUP], resolve=True)


def known_scene(name: str) -> tuple[str, Path]:
    options = group_options(SCENE_GROUP)
    if name not in options:
        raise ConfigError(f"no scene {name!r}", f"the scenes are {', '.join(options)} (neuraldem scene list)")
    return options[name]


def dotted(cfg: dict[str, Any], key: str) -> Any:
    node: Any = cfg
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def flow(value: Any) -> str:
    """A value as one line of YAML (`0.01`, `[0.0, 60.0]`, `epsd2`)."""
    text = yaml.safe_dump(value, default_flow_style=True, width=10**6).strip()
    return text.removesuffix("...").strip()


def scene_text(name: str, source: str, kind: str, cfg: dict[str, Any]) -> str:
    """The commented scene file: every key of the scene's table (`Scene.scene_keys`) with the source's value."""
    date = datetime.now(UTC).date().isoformat()
    lines = [f"# {name}: your own {kind} scene, written by `neuraldem scene new {name} from={source}` ({date}).",
             "# Change the values below; docs/your-own-scene.md explains every key (unit, meaning, cost).",
             f"# What is not listed here (splits, metrics, training settings) comes from {source}.",
             f"# Next: neuraldem datagen data={name} workers=2   (neuraldem scene show {name}: the composed scene)",
             "defaults:", f"  - {source}", "  - _self_", "", f"name: {name}"]
    ref = registry().get(kind)
    keys = import_class(ref.scene_keys) if ref is not None and ref.scene_keys else ()
    if not keys:  # a plug-in without a key table: its sections as they are
        lines.append(yaml.safe_dump({k: cfg[k] for k in ("scene", "parameters") if k in cfg}, sort_keys=False))
        return "\n".join(lines) + "\n"
    written: list[str] = []  # the sections already open, as dotted prefixes
    for k in keys:
        value = dotted(cfg, k.key)
        if value is None and k.key.rsplit(".", 1)[-1] not in (dotted(cfg, k.key.rsplit(".", 1)[0]) or {}):
            continue  # a key the source scene does not have
        parts = k.key.split(".")
        for depth in range(len(parts) - 1):
            prefix = ".".join(parts[:depth + 1])
            if prefix not in written:
                if depth == 0:
                    lines.append("")
                lines.append(f"{'  ' * depth}{parts[depth]}:")
                written.append(prefix)
        indent = "  " * (len(parts) - 1)
        unit = "" if k.unit == "-" else f"[{k.unit}] "
        cost = "" if k.cost in ("none", "") else f" Cost: {k.cost}."
        lines += textwrap.wrap(f"{unit}{k.meaning}.{cost}", width=116 - len(indent), initial_indent=f"{indent}# ",
                               subsequent_indent=f"{indent}#   ")
        lines.append(f"{indent}{parts[-1]}: {flow(value)}")
    return "\n".join(lines) + "\n"


def new_scene(name: str, source: str, force: bool = False) -> Path:
    if not NAME.fullmatch(name):
        raise ConfigError(f"scene name {name!r} is invalid", "use letters, digits, _ and -, e.g. my_hopper")
    where, path = group_options(SCENE_GROUP).get(name, ("", None))  # type: ignore[arg-type]
    if path is not None and where != "yours":
        raise ConfigError(f"{name} is a {where} scene ({path})", "choose another name for yours, e.g. my_" + name)
    target = user_config_dir() / SCENE_GROUP / f"{name}.yaml"
    if target.exists() and not force:
        raise ConfigError(f"{target} exists", "edit it, or write it again with force=true")
    known_scene(source)
    kind = scene_kind(source)
    if kind is None:
        raise ConfigError(f"from={source}: that data config states no kind:", "start from a scene, e.g. hopper_small")
    text = scene_text(name, source, kind, composed(source))
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(text)
    return target


def list_scenes() -> str:
    rows = ["| scene | kind | where | file |", "|---|---|---|---|"]
    kinds = registry()
    for name, (where, path) in group_options(SCENE_GROUP).items():
        kind = scene_kind(name)
        if kind in kinds:
            rows.append(f"| {name} | {kind} | {where} | {path} |")
    return "\n".join(rows) + (f"\n\nyour folder: {user_config_dir() / SCENE_GROUP} "
                              "(neuraldem scene new NAME from=SCENE writes one there)")


def show_scene(name: str) -> str:
    import yaml as _yaml

    where, path = known_scene(name)
    cfg = composed(name)
    shown = {k: cfg[k] for k in ("name", "kind", "dataset_dir", "scene", "parameters", "characterization", "fields",
                                 "storage") if k in cfg}
    return (f"# {name}: {where}, {path} (inherits {' <- '.join(base_chain(name)[1:]) or 'nothing'})\n"
            + _yaml.safe_dump(shown, sort_keys=False, default_flow_style=None, width=110))


def parser(action: str) -> CommandParser:
    p = command_parser("neuraldem.scene_files", __doc__)
    p.prog = f"neuraldem scene {action}"
    if action in ("new", "show"):
        p.add_argument("--name", required=True, help="the scene's name (also the first word after the action)")
    if action == "new":
        p.add_argument("--from", dest="from", required=True, metavar="SCENE",
                       help="the scene to start from (neuraldem scene list), e.g. hopper_small or fb_small")
        p.add_argument("--force", action="store_true", help="write over a scene file of yours")
    return p


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0
    action, rest = argv[0], argv[1:]
    if action not in ACTIONS:
        raise ConfigError(f"neuraldem scene: unknown action {action!r}", f"choose one of {', '.join(ACTIONS)}")
    if action in ("new", "show") and rest and "=" not in rest[0] and not rest[0].startswith("-"):
        rest = [f"name={rest[0]}", *rest[1:]]  # `scene new my_hopper ...`: the name typed bare
    args = parser(action).parse_args(rest)
    if action == "list":
        print(list_scenes())
    elif action == "show":
        print(show_scene(args.name))
    else:
        path = new_scene(args.name, getattr(args, "from"), args.force)
        print(f"wrote {path}: edit it, then: neuraldem datagen data={args.name} workers=2")
    return 0


if __name__ == "__main__":
    sys.exit(main())
