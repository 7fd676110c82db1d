"""What the subcommands share: a parser whose errors are one line (exit 2), and every setting of a run as a
``--kebab-case`` flag, from the preset, a ``--config`` file and the active env and algorithm sections."""

from __future__ import annotations

import argparse
import difflib
import re
import typing
from collections.abc import Sequence
from typing import Any

COMMANDS = ("train", "eval", "export", "plot", "presets", "solve", "demos")
POSITIONAL = ("preset", "run_dir", "source")
#: Errors about files rather than settings: named as they are, not as flags.
FILES = {"config": "config.json:", "config_file": "--config", "checkpoint": "checkpoint:", "policy": "policy:"}
NUMBER = re.compile(r"-(\d+\.?\d*|\.\d+)(e[-+]?\d+)?", re.IGNORECASE)


def numbers_as_values(argv: Sequence[str]) -> list[str]:
    """``--lr -1e-3`` -> ``--lr=-1e-3``: argparse would read a negative number in exponent form as a flag."""
    out: list[str] = []
    for token in argv:
        if out and out[-1].startswith("--") and "=" not in out[-1] and NUMBER.fullmatch(token):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


class UsageError(Exception):
    """Bad command-line input: printed as one line, exit code 2."""


class Parser(argparse.ArgumentParser):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__(allow_abbrev=False, **kwargs)

    def error(self, message: str) -> typing.NoReturn:
        raise UsageError(message)


#: whole-number settings whose 0 means "the library chooses", given as ``auto`` on the command line
AUTO_COUNTS = {"updates_per_call"}


def count_or_auto(text: str) -> int:
    if text == "auto":
        return 0
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number or auto, got {text!r}") from None


def as_flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def terminal_text(markup: str) -> str:
    """A docstring's markup as a terminal shows it: ````code```` and `` `code` `` as the code, cross-references
    ``[`name`][taskrl.path]`` as the name."""
    text = re.sub(r"\[`([^`]+)`\]\[[\w.]+\]", r"\1", markup)
    return re.sub(r"``?([^`]+)``?", r"\1", text)


def add_config_flags(
    parser: argparse.ArgumentParser, env: str, algo: str, base: Any = None, sharing: str = "none"
) -> dict[str, list[str]]:
    """One flag per setting, in sections (``--algo.lr``, ``--env.n-bits``, ``--algo.cem.samples``,
    ``--data-sharing.share-fraction``), each also under its short name (``--lr``) where no other setting
    has it; the ``dest`` is the dotted name [`taskrl.overrides.with_overrides`][taskrl.overrides.with_overrides] reads. Returns the
    ambiguous short names (``{short flag: [its dotted flags]}``) for the error that names them."""
    from taskrl.agents.registry import ALGORITHMS
    from taskrl.config import to_dict
    from taskrl.encoders import PICTURE_ENCODERS
    from taskrl.envs.registry import ENV_FAMILIES
    from taskrl.runmodes.registry import RUN_MODES
    from taskrl.setting_names import dotted_name, leaf_fields, setting_help, setting_names
    from taskrl.sharing.registry import SHARING_STRATEGIES

    docs = setting_help(env, algo, sharing)
    names = setting_names(env, algo, sharing)
    values = to_dict(base) if base is not None and base.env == env and base.algo == algo else {}
    docs[("env",)] += " Choices: " + "; ".join(f"{f.name} ({f.description})" for f in ENV_FAMILIES.values())
    docs[("algo",)] += " Choices: " + "; ".join(f"{a.name} ({a.description})" for a in ALGORITHMS.values())
    docs[("mode",)] += " Choices: auto; " + "; ".join(f"{m.name} ({m.summary})" for m in RUN_MODES.values())
    choices = {"env": tuple(ENV_FAMILIES), "algo": tuple(ALGORITHMS), "mode": ("auto", *RUN_MODES)}
    # settings whose values are registered pieces: every registered one is a choice, with its summary in the help
    registered = {("data_sharing", "sharing"): SHARING_STRATEGIES, (algo, "encoder"): PICTURE_ENCODERS}
    for path, registry in registered.items():
        if path in docs:
            docs[path] += " Choices: " + "; ".join(f"{e.name} ({e.summary})" for e in registry.values())
    family = ENV_FAMILIES[env]
    titles = {
        "replay": "the replay (what it keeps, how batches are drawn)",
        "evaluation": "evaluation (when, how many episodes)",
        "checkpoints": "checkpoints (when, with the replay or not)",
        "data": "where the data comes from (stored data, scripted episodes)",
        "conditioning": "task conditioning (multi-task networks)",
        "cluster": "where the roles run (--distributed)",
        "data_sharing": "data sharing between tasks",
        family.section: f"env family '{env}' (--env.* flags, {family.section} section)",
        algo: f"algorithm '{algo}' (--algo.* flags, {algo} section)",
    }
    groups: dict[str, Any] = {}
    for path, _field, tp in leaf_fields(env, algo, sharing):
        section = path[0] if len(path) > 1 else "run"
        if section not in groups:  # one block per section of config.json, so --help reads as the reference does
            groups[section] = parser.add_argument_group(f"settings: {titles.get(section, 'run')}")
        name, dotted = path[-1], dotted_name(path, env, algo)
        text = terminal_text(docs.get(path, "")).replace("%", "%%")
        node: Any = values
        for key in path:
            node = node.get(key, {}) if isinstance(node, dict) else {}
        if values and not isinstance(node, dict):  # this run's value (the preset's, or the resumed run's)
            shown = " ".join(map(str, node)) if isinstance(node, list) else node
            text += f" [here: {shown}]"
        kwargs: dict[str, Any] = {"dest": dotted, "default": argparse.SUPPRESS, "help": text}
        origin = typing.get_origin(tp)
        if name in choices and len(path) == 1:
            kwargs["choices"] = choices[name]
        elif path in registered:
            kwargs["choices"] = tuple(registered[path])
        elif tp is bool:
            kwargs["action"] = argparse.BooleanOptionalAction
        elif origin is typing.Literal:
            kwargs["choices"] = typing.get_args(tp)
        elif origin is tuple and typing.get_args(tp)[:1] == (float,):
            kwargs.update(type=float, nargs="*", metavar="X")  # none given: the empty default (e.g. cem.init_mean)
        elif origin is tuple:
            kwargs.update(type=int, nargs="+", metavar="N")
        elif name in AUTO_COUNTS:
            kwargs.update(type=count_or_auto, metavar="{N,auto}")
        else:
            kwargs["type"] = tp
        if "choices" not in kwargs and "action" not in kwargs and "metavar" not in kwargs:
            kwargs["metavar"] = name.upper()
        flags = [as_flag(dotted)] if "." in dotted else []
        if names.paths.get(name) == path:
            flags.append(as_flag(name))
        groups[section].add_argument(*flags, **kwargs)
    return {as_flag(short): [as_flag(d) for d in dotted] for short, dotted in names.ambiguous.items()}


def config_file(argv: Sequence[str]) -> tuple[dict[str, Any], Any]:
    """``(settings by name, full config or None)`` from ``--config FILE``: a full config (a run's
    config.json, or what --print-config printed) becomes the starting point; a mapping of settings
    by name (``lr: 0.001``) is applied like flags, before them."""
    peek = Parser(add_help=False)
    peek.add_argument("--config")
    known, _ = peek.parse_known_args(argv)
    if known.config is None:
        return {}, None
    from pathlib import Path

    from taskrl.config import from_dict
    from taskrl.errors import ConfigError
    from taskrl.files import read_data_file

    path = Path(known.config)
    try:
        data = read_data_file(path)
    except ValueError as error:
        raise ConfigError("config_file", str(error)) from None
    if not isinstance(data, dict):
        raise ConfigError("config_file", f"{path} must hold a mapping of settings")
    if any(isinstance(v, dict) for v in data.values()):  # sections: a full config
        return {}, from_dict(data)
    return {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}, None


def active_sections(argv: Sequence[str], file_base: Any = None, file_settings: dict | None = None) -> tuple[str, str, str, Any]:
    """``(env, algo, sharing, base)``: the env family, algorithm and sharing strategy whose settings the flags address
    (``--env`` / ``--algo`` / ``--sharing``; ``--env-id`` or ``--task-file`` alone select their family), else the
    preset's, else the resumed run's; and the config the flags start from."""
    from taskrl.agents.registry import ALGORITHMS
    from taskrl.config import TrainConfig
    from taskrl.envs.registry import ENV_FAMILIES
    from taskrl.presets import PRESETS, preset_config
    from taskrl.sharing.registry import SHARING_STRATEGIES

    peek = Parser(add_help=False)
    peek.add_argument("preset", nargs="?")
    peek.add_argument("--env")
    peek.add_argument("--algo")
    peek.add_argument("--sharing", "--data-sharing.sharing", dest="sharing")
    peek.add_argument("--resume")
    selectors = {f.selected_by: f.name for f in ENV_FAMILIES.values() if f.selected_by}
    for setting in selectors:
        peek.add_argument(as_flag(setting))
    peek.add_argument("--env-module")
    known, _ = peek.parse_known_args(argv)
    if known.env_module:  # it may register env families and algorithms the flags below name
        from taskrl.wiring.calls import import_env_module

        import_env_module(known.env_module)
    named = (
        ("--env", known.env, ENV_FAMILIES),
        ("--algo", known.algo, ALGORITHMS),
        ("--sharing", known.sharing, SHARING_STRATEGIES),
    )
    for flag, value, allowed in named:
        if value is not None and value not in allowed:
            hint = " (a gymnasium id goes to --env-id)" if flag == "--env" else ""
            raise UsageError(f"argument {flag}: invalid choice: {value!r} (choose from {', '.join(map(repr, allowed))}){hint}")
    base = TrainConfig()
    if file_base is not None:
        base = file_base
    elif known.preset in PRESETS:
        base = preset_config(known.preset)
    elif known.resume is not None:
        from pathlib import Path

        from taskrl.config import load
        from taskrl.errors import ConfigError

        saved = Path(known.resume) / "config.json"
        if saved.exists():
            try:
                base = load(saved)
            except ConfigError:
                pass  # train() reports a damaged config.json in one line
    env = known.env or (file_settings or {}).get("env")
    known.algo = known.algo or (file_settings or {}).get("algo")
    if env is None:
        given = [name for setting, name in selectors.items() if getattr(known, setting) is not None]
        env = given[0] if given and given[0] != base.env else base.env
    sharing = known.sharing or (file_settings or {}).get("sharing") or base.data_sharing.sharing
    return env, known.algo or base.algo, sharing, base


def parse(
    parser: argparse.ArgumentParser, argv: Sequence[str], ambiguous: dict[str, list[str]] | None = None
) -> argparse.Namespace:
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        flags = sorted(f for a in parser._actions for f in a.option_strings if f.startswith("--"))
        bad = unknown[0]
        spelled = bad.split("=")[0].replace("--no-", "--")
        if ambiguous and spelled in ambiguous:
            raise UsageError(f"{spelled} is a setting of several sections here: say {' or '.join(ambiguous[spelled])}")
        from taskrl.setting_names import strategy_owning

        owner = strategy_owning(spelled.lstrip("-"))
        if owner is not None:
            raise UsageError(f"{spelled} is a setting of the {owner} sharing strategy: choose it with --sharing {owner}")
        close = difflib.get_close_matches(bad.split("=")[0], flags, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise UsageError(f"unknown option {bad!r}{hint}; allowed: {', '.join(flags)}")
    return args
