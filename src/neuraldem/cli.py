"""The one argument grammar of every command: `neuraldem VERB [OBJECT] key=value ...` (docs/cli.md).

Runs composed from the config tree (datagen, train, evaluate) are Hydra apps, and Hydra reads `key=value`;
every other command reads the same form, so a user learns one style: `ckpt=PATH`, `steps=60`, `verify=true`,
lists as `ckpt=[a.ckpt,b.ckpt]`. The tools keep argparse for types, defaults, choices and help (a well-kept
library); `CommandParser` only translates `key=value` into what argparse reads, where `key` is an option's
destination (`--n-velocities` is `n_velocities=`), and says its errors in that grammar:

- a key given twice is refused (it used to be that the last one silently won);
- an unknown key is refused with the command's options listed;
- the old spellings (`--ckpt X`, `--verify`, a bare positional) still work for one release and print the
  new form on stderr.
User errors end as one line `neuraldem: error: ...` with exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import functools
import os
import re
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from neuraldem.commands import command_or_module
from neuraldem.errors import ConfigError, NeuraldemError
from neuraldem.paths import config_dir

if TYPE_CHECKING:
    from omegaconf import DictConfig

TRUE, FALSE = ("true", "yes", "on", "1"), ("false", "no", "off", "0")
OUTPUT_KEYS = ("out", "out_dir")  # options naming where a command writes: created (or refused) when parsed


def quiet_environment() -> None:
    """Defaults that make runs offline-safe and CPU-friendly; a user's own setting always wins."""
    os.environ.setdefault("WANDB_MODE", "offline")
    os.environ.setdefault("WANDB_SILENT", "true")
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def fail(message: str) -> NoReturn:
    print(f"neuraldem: error: {message}", file=sys.stderr)
    sys.exit(2)


def report_user_errors(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Turn a NeuraldemError into `neuraldem: error: ...` on stderr and exit status 2."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except NeuraldemError as err:
            fail(str(err))

    return wrapper


def tool_prog(module: str) -> str:
    """A tool's name in its usage line and errors: the command typed when the `neuraldem` command runs it
    (which puts that name in argv[0], e.g. `neuraldem report fb-table`), else the command that runs the module
    (`neuraldem.bench fb_speed` is `neuraldem bench fb_speed`; `python -m <module>` where no verb runs it)."""
    return sys.argv[0] if sys.argv[0].startswith("neuraldem ") else command_or_module(module)


def key_of(action: argparse.Action) -> str:
    return action.dest


def as_bool(key: str, text: str) -> bool:
    if text.lower() in TRUE:
        return True
    if text.lower() in FALSE:
        return False
    raise ConfigError(f"{key}={text!r} is not a boolean", f"write {key}=true or {key}=false")


def list_value(text: str) -> list[str]:
    """`[a,b]` (or a single value) as a list of strings."""
    text = text.strip()
    if text.startswith("[") and text.endswith("]"):
        return [t.strip() for t in text[1:-1].split(",") if t.strip()]
    return [text]


def value_text(action: argparse.Action) -> str:
    if action.nargs == 0:
        return "true|false"
    if action.choices:
        return "|".join(map(str, action.choices))
    many = action.nargs in ("+", "*") or isinstance(action, argparse._AppendAction) or (
        isinstance(action.nargs, int) and action.nargs > 1)
    name = action.metavar or action.dest.upper()
    return f"[{name},...]" if many else str(name)


def is_object(action: argparse.Action) -> bool:
    """A positional with choices: the command's object, typed bare (`neuraldem export gns ...`)."""
    return not action.option_strings and bool(action.choices) and not isinstance(action, argparse._SubParsersAction)


class KeyValueFormatter(argparse.RawDescriptionHelpFormatter):
    """Help that shows every option as `key=VALUE` (the command's object as its bare choices)."""

    def _format_action_invocation(self, action: argparse.Action) -> str:
        if isinstance(action, argparse._HelpAction):
            return "-h, --help"
        if isinstance(action, argparse._SubParsersAction):
            return super()._format_action_invocation(action)
        if is_object(action):
            return value_text(action)
        return f"{key_of(action)}={value_text(action)}"

    def _format_usage(self, usage: str | None, actions: Iterable[argparse.Action], groups: Any,
                      prefix: str | None) -> str:
        parts = []
        for a in actions:
            if isinstance(a, argparse._HelpAction) or a.help == argparse.SUPPRESS:  # e.g. an old flag's alias
                continue
            if isinstance(a, argparse._SubParsersAction):
                parts.append("{" + ",".join(a.choices) + "} ...")
                continue
            item = value_text(a) if is_object(a) else f"{key_of(a)}={value_text(a)}"
            parts.append(item if a.required or not a.option_strings and a.nargs not in ("?", "*") else f"[{item}]")
        return f"{'usage: ' if prefix is None else prefix}{self._prog} {' '.join(parts)}".rstrip() + "\n\n"


class CommandParser(argparse.ArgumentParser):
    """argparse that reads `key=value` (see the module docstring)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", KeyValueFormatter)
        super().__init__(*args, **kwargs)

    def options(self) -> dict[str, argparse.Action]:
        """The keys and their actions; a hidden action (an old flag kept as an alias of a key) is no key."""
        return {key_of(a): a for a in self._actions if a.help != argparse.SUPPRESS
                and not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))}

    def option_list(self) -> str:
        return ", ".join(f"{k}=" for k in self.options())

    def error(self, message: str) -> NoReturn:
        """argparse's messages in the key=value grammar, one line, status 2."""
        message = re.sub(r"--([A-Za-z0-9][\w.-]*)", lambda m: m.group(1).replace("-", "_") + "=", message)
        message = message.replace("argument ", "option ")
        fail(f"{self.prog}: {message} ({self.prog} --help lists the options)")

    def parse_args(self, args: Any = None, namespace: Any = None) -> Any:  # type: ignore[override]
        argv = list(sys.argv[1:] if args is None else args)
        try:
            translated = self.to_argparse(argv)
        except NeuraldemError as err:
            fail(f"{self.prog}: {err}")
        args = super().parse_args(translated, namespace)
        for key in OUTPUT_KEYS:  # an output place that cannot be made is said now, not as a traceback later
            value = getattr(args, key, None)
            if isinstance(value, (str, Path)):
                try:
                    output_folder(Path(value) if not Path(value).suffix else Path(value).parent, key)
                except ConfigError as err:
                    fail(f"{self.prog}: {err}")
        return args

    def to_argparse(self, argv: list[str]) -> list[str]:
        """`key=value` tokens as argparse's own; old spellings pass through with a note naming the new form."""
        options = self.options()
        subparsers = next((a for a in self._actions if isinstance(a, argparse._SubParsersAction)), None)
        flags: list[str] = []
        positional: dict[str, list[str]] = {}
        seen: set[str] = set()
        old: list[str] = []
        i = 0
        while i < len(argv):
            token = argv[i]
            if token in ("-h", "--help"):
                return ["--help"]
            if subparsers is not None and token in subparsers.choices:
                sub = subparsers.choices[token]
                return [*self._ordered(positional), *flags, token, *sub.to_argparse(argv[i + 1:])]
            if token.startswith("-"):  # the old flag spelling: kept one release, values passed on as they are
                old.append(token)
                taken = self._old_values(token, argv[i + 1:], options)
                flags += [token, *taken]
                i += 1 + len(taken)
                continue
            obj = self._object(token, positional)
            if obj is not None:  # `export gns dataset=...`: a bare choice of a positional is the command's object
                positional[key_of(obj)] = [token]
                seen.add(key_of(obj))
                i += 1
                continue
            key, sep, value = token.partition("=")
            if not sep or not re.fullmatch(r"[A-Za-z_][\w.]*", key):  # a key may be dotted: rollout.rollout_noise
                old.append(token)
                flags.append(token)  # a bare positional (old spelling), e.g. a dataset folder
                i += 1
                continue
            if key in seen:
                fail(f"{self.prog}: {key}= is given twice: give each option once")
            seen.add(key)
            action = options.get(key)
            if action is None:
                fail(f"{self.prog}: unknown option {key}=: the options are {self.option_list()}")
            flags_for, positional_values = self._translate(action, key, value)
            if positional_values is not None:
                positional[key] = positional_values
            flags += flags_for
            i += 1
        if old:
            self._note_old_spelling(argv)
        return [*self._ordered(positional), *flags]

    def _object(self, token: str, given: dict[str, list[str]]) -> argparse.Action | None:
        """The positional whose choices hold `token` (a bare word naming what the command acts on), if not given."""
        for a in self._actions:
            if (not a.option_strings and a.choices and not isinstance(a, argparse._SubParsersAction)
                    and token in a.choices and key_of(a) not in given):
                return a
        return None

    def _old_values(self, flag: str, rest: list[str], options: dict[str, argparse.Action]) -> list[str]:
        """The tokens an old `--flag` takes (`--param alpha=30`: the value looks like key=value, and is not)."""
        action = next((a for a in self._actions if flag.split("=")[0] in a.option_strings), None)
        if action is None or action.nargs == 0 or "=" in flag:
            return []
        if action.nargs in ("+", "*"):
            taken = []
            for token in rest:
                if token.startswith("-") or token.partition("=")[0] in options:
                    break
                taken.append(token)
            return taken
        return rest[:action.nargs if isinstance(action.nargs, int) else 1]

    def _ordered(self, positional: dict[str, list[str]]) -> list[str]:
        out: list[str] = []
        for a in self._actions:
            if not a.option_strings and key_of(a) in positional:
                out += positional[key_of(a)]
        return out

    @staticmethod
    def _translate(action: argparse.Action, key: str, value: str) -> tuple[list[str], list[str] | None]:
        """(argparse tokens of an option, or the values of a positional)."""
        if not action.option_strings:
            many = action.nargs in ("+", "*") or (isinstance(action.nargs, int) and action.nargs > 1)
            return [], list_value(value) if many else [value]
        flag = action.option_strings[-1]
        if action.nargs == 0:  # store_true / store_false / store_const
            wanted = as_bool(key, value)
            if isinstance(action, argparse._StoreFalseAction):
                return ([] if wanted else [flag]), None
            return ([flag] if wanted else []), None
        if isinstance(action, argparse._AppendAction):
            return [t for v in list_value(value) for t in (flag, v)], None
        if action.nargs in ("+", "*") or (isinstance(action.nargs, int) and action.nargs > 1):
            return [flag, *list_value(value)], None
        return [flag, value], None

    def _note_old_spelling(self, argv: list[str]) -> None:
        print(f"neuraldem: note: flags and bare values are the old spelling (kept for one release): "
              f"{self.prog} {' '.join(new_spelling(self, argv))}", file=sys.stderr)


def new_spelling(parser: CommandParser, argv: list[str]) -> list[str]:
    """The `key=value` form of an old command line (best effort, for the note)."""
    options = {s: a for a in parser._actions for s in a.option_strings}
    positionals = [a for a in parser._actions if not a.option_strings
                   and not isinstance(a, argparse._SubParsersAction)]
    out, i = [], 0
    while i < len(argv):
        token = argv[i]
        action = options.get(token.split("=")[0])
        if action is not None:
            key = key_of(action)
            if action.nargs == 0:
                out.append(f"{key}={'false' if isinstance(action, argparse._StoreFalseAction) else 'true'}")
                i += 1
                continue
            values = []
            i += 1
            while i < len(argv) and not argv[i].startswith("-") and "=" not in argv[i]:
                values.append(argv[i])
                i += 1
                if action.nargs not in ("+", "*"):
                    break
            out.append(f"{key}={values[0]}" if len(values) == 1 else f"{key}=[{','.join(values)}]")
        elif not token.startswith("-") and "=" not in token and positionals:
            first = positionals.pop(0)
            out.append(token if first.choices and token in first.choices else f"{key_of(first)}={token}")
            i += 1
        else:
            out.append(token)
            i += 1
    return out


def command_parser(module: str, doc: str | None, summary: bool = False) -> CommandParser:
    """A tool's parser: its usage names the `neuraldem` command that runs it; --help shows the module docstring
    (its first line only with `summary`)."""
    description = doc.split("\n")[0] if (summary and doc) else doc
    return CommandParser(prog=tool_prog(module), description=description)


doc_parser = command_parser


def add_trajectory_options(p: argparse.ArgumentParser, ckpt_help: str, sim_help: str) -> None:
    """`ckpt=`, `dataset=`, `sim=`: one trajectory of a checkpoint's dataset, found from the checkpoint by default,
    as every tool that times one checkpoint asks for it."""
    p.add_argument("--ckpt", type=Path, required=True, help=ckpt_help)
    p.add_argument("--dataset", type=Path, default=None,
                   help="dataset dir of the checkpoint's scene (default: <data dir>/datasets/<its data name>)")
    p.add_argument("--sim", default=None, help=sim_help)


def output_folder(path: Path, key: str = "out") -> Path:
    """`path` created (with its parents); one line naming the key and the reason when it cannot be."""
    try:
        Path(path).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ConfigError(f"{key}={path}: the folder cannot be created ({err.strerror})",
                          f"give a folder you can write, e.g. {key}=./out") from None
    return Path(path)


def split_kind_factor(text: str) -> tuple[str, float]:
    """A `KIND:FACTOR` command-line value as (kind, factor); the factor is NaN when it is not a number, so a
    caller rejects it with its own range check and message."""
    kind, _, value = text.partition(":")
    try:
        factor = float(value)
    except ValueError:
        factor = float("nan")
    return kind, factor


def parse_assignments(items: list[str], key: str, example: str) -> dict[str, float]:
    """`NAME=NUMBER` values (e.g. `param=[alpha=30,mu_s=0.4]`) as a dict."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        try:
            out[key] = float(value)
        except ValueError:
            sep = ""
        if not sep or not key:
            raise ConfigError(f"{key}= {item!r}: expected NAME=NUMBER, e.g. {key}=[{example}]")
    return out


def check_overrides(config_name: str, overrides: list[str]) -> None:
    """Hydra overrides checked before composing: each key once, a first segment the config knows (its keys, its
    groups, `hydra`), and a group option that exists in one config folder (`data=nope` names the folders searched,
    your own included: `neuraldem.config.user`), so a typo names the options instead of Hydra's stack of messages."""
    from omegaconf import OmegaConf

    from neuraldem.config.user import check_group_choice

    seen: set[str] = set()
    primary = OmegaConf.to_container(OmegaConf.load(config_dir() / f"{config_name}.yaml"))
    known = {k for k in primary if k != "defaults"}  # type: ignore[union-attr]
    for entry in primary.get("defaults", []):  # type: ignore[union-attr]
        if isinstance(entry, dict):
            known |= {k.split("@")[0].removeprefix("override ") for k in entry}
    known |= {p.name for p in config_dir().iterdir() if p.is_dir()} | {"hydra"}
    for token in overrides:
        if token.startswith("-"):
            continue  # Hydra's own flags (-m, --cfg job, --help)
        key, sep, _ = token.partition("=")
        if not sep:
            continue
        bare = key.lstrip("+~")
        if bare in seen:
            fail(f"neuraldem {config_name}: {bare}= is given twice: give each option once")
        seen.add(bare)
        if token.startswith(("+", "~")) or bare.split(".")[0].split("/")[0] in known:
            if "." not in bare and "/" not in bare and not token.startswith("~"):
                try:
                    check_group_choice(bare, token.partition("=")[2])
                except ConfigError as err:
                    fail(f"neuraldem {config_name}: {err}")
            continue
        fail(f"neuraldem {config_name}: unknown option {bare}=: the options are "
             f"{', '.join(sorted(k + '=' for k in known if k != 'hydra'))} (and their sub-keys, e.g. data.name=)")


def renamed_overrides(config_name: str, overrides: list[str]) -> list[str]:
    """Hydra overrides with the keys a scene renamed (`Scene.renamed_keys`, read one release) in their new
    spelling, a note on stderr for each."""
    from neuraldem.scenes import registry

    renamed = {old: new for s in registry().values() for old, new in s.renamed_keys.get(config_name, {}).items()}
    out = []
    for token in overrides:
        key, sep, value = token.partition("=")
        bare = key.lstrip("+")
        if sep and bare in renamed:
            token = f"{renamed[bare]}={value}"
            print(f"neuraldem: note: {bare}= is the old spelling (kept for one release): {token}", file=sys.stderr)
        out.append(token)
    return out


def named_scene_file(task: Callable[[DictConfig], Any]) -> Callable[[DictConfig], Any]:
    """A config error about a `data.` key names the scene file it came from (`neuraldem.config.user`)."""

    @functools.wraps(task)
    def run(cfg: DictConfig) -> Any:
        try:
            return task(cfg)
        except ConfigError as err:
            from hydra.core.hydra_config import HydraConfig

            from neuraldem.config.user import with_scene_file

            choices = dict(HydraConfig.get().runtime.choices) if HydraConfig.initialized() else {}
            raise with_scene_file(err, choices) from None

    return run


def hydra_app(config_name: str) -> Callable[[Callable[[DictConfig], Any]], Callable[[], Any]]:
    """Decorator for `main(cfg)` functions: our config tree, our error reporting, offline defaults."""

    def decorate(task: Callable[[DictConfig], Any]) -> Callable[[], Any]:
        # Hydra and the config resolvers are imported here, not with this module: the tools that only take
        # key=value options (predict, scan, report, ...) start about 0.4 s faster without them
        import hydra

        import neuraldem.config  # noqa: F401  (registers resolvers before Hydra composes)

        quiet_environment()
        wrapped = report_user_errors(named_scene_file(task))
        app = hydra.main(version_base="1.3", config_path=str(config_dir()), config_name=config_name)(wrapped)

        @functools.wraps(app)
        def checked() -> Any:
            sys.argv[1:] = renamed_overrides(config_name, sys.argv[1:])
            check_overrides(config_name, sys.argv[1:])
            return app()

        return checked

    return decorate
