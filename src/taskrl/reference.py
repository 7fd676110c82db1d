"""The reference pages of the documentation, generated from the registries and the settings' docstrings.

Every env family, algorithm, preset and setting is listed with its default and meaning, read from the code
itself (``EnvFamily`` / ``AlgorithmSpec`` entries, the ``Attributes:`` sections of the settings dataclasses,
[`taskrl.presets.PRESETS`][taskrl.presets.PRESETS], each command's ``--help``), so the reference cannot drift from what runs.
``docs/hooks.py`` adds `pages` to the site at build time (``make docs``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import typing
from typing import Any

__all__ = ["pages", "settings_table", "undocumented_settings"]


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    return None


def _shown(value: Any) -> str:
    if isinstance(value, str):
        return f"`{value!r}`" if value == "" else f"`{value}`"
    if isinstance(value, (tuple, list)):
        return "`" + " ".join(map(str, value)) + "`" if value else "(none)"
    if isinstance(value, float) and value.is_integer() and abs(value) >= 1000:
        return f"`{int(value):_}`"
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10_000:
        return f"`{value:_}`"
    return f"`{value}`"


def _type_name(tp: Any) -> str:
    if typing.get_origin(tp) is typing.Literal:
        return " / ".join(str(a) for a in typing.get_args(tp))
    return getattr(tp, "__name__", str(tp)).replace("typing.", "")


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def settings_table(cls: type, skip: tuple[str, ...] = (), section: str = "") -> str:
    """A markdown table of a settings dataclass: flag, type, default, meaning (nested sections inlined).

    ``section`` is the flags' dotted prefix (``algo``, ``env``, ``data_sharing``); each row gives the
    dotted flag and the short one, which works where no other section of the run has the name."""
    from taskrl.config import field_docs

    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    rows = ["| flag | type | default | meaning |", "|---|---|---|---|"]
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        tp = hints[f.name]
        if dataclasses.is_dataclass(tp):
            nested = settings_table(tp, section=f"{section}.{f.name}" if section else f.name).splitlines()[2:]
            rows += nested
            continue
        short = "--" + f.name.replace("_", "-")
        flag = f"`--{section.replace('_', '-')}.{f.name.replace('_', '-')}` (`{short}`)" if section else f"`{short}`"
        rows.append(f"| {flag} | {_type_name(tp)} | {_shown(_default(f))} | {_cell(docs.get(f.name, ''))} |")
    return "\n".join(rows)


def undocumented_settings() -> list[str]:
    """``section.field`` of every setting whose dataclass docstring gives it no meaning (a test keeps this empty)."""
    from taskrl.agents.registry import ALGORITHMS
    from taskrl.config import TrainConfig, field_docs
    from taskrl.envs.registry import ENV_FAMILIES

    missing = []
    classes = {TrainConfig, *(f.settings for f in ENV_FAMILIES.values()), *(a.config for a in ALGORITHMS.values())}
    seen: set[type] = set()
    while classes:
        cls = classes.pop()
        if cls in seen:
            continue
        seen.add(cls)
        docs = field_docs(cls)
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            if dataclasses.is_dataclass(hints[f.name]):
                classes.add(hints[f.name])
            elif not docs.get(f.name, "").strip():
                missing.append(f"{cls.__name__}.{f.name}")
    return sorted(missing)


def _settings_page() -> str:
    from taskrl.conditioning.settings import ConditioningConfig
    from taskrl.config import TrainConfig
    from taskrl.distributed.settings import DistributedConfig
    from taskrl.run_sections import CheckpointSettings, DataSettings, EvaluationSettings, ReplaySettings
    from taskrl.sharing.registry import SHARING_STRATEGIES
    from taskrl.sharing.settings import SharingConfig

    sections = (
        ("Run", "Every run has these, whatever its env and algorithm.", TrainConfig),
        ("Replay (`replay`)", "What the replay keeps and how batches are drawn (off-policy runs).", ReplaySettings),
        ("Evaluation (`evaluation`)", "When and how the greedy policy is scored.", EvaluationSettings),
        ("Checkpoints (`checkpoints`)", "When the run is saved, and what with.", CheckpointSettings),
        (
            "Where the data comes from (`data`)",
            "Stored data and scripted episodes, besides the agent's own acting.",
            DataSettings,
        ),
        ("Task conditioning (`conditioning`)", "How multi-task networks are told the task.", ConditioningConfig),
        ("Where the roles run (`cluster`)", "One process, or collectors and Bellman updaters as Ray actors.", DistributedConfig),
        (
            "Data sharing (`data_sharing`)",
            "How tasks share data (multi-task envs whose tasks are reward functions).",
            SharingConfig,
        ),
    )
    out = [
        "# Settings",
        "",
        "Every setting is a `--kebab-case` flag of `taskrl train` and a keyword of `taskrl.train(...)`; `config.json` "
        "nests them by section. A section's setting has a dotted flag (`--algo.lr`, `--env.n-bits`, `--algo.cem.samples`, "
        "`--data-sharing.share-fraction`; in Python `taskrl.train(..., **{'algo.lr': 1e-3})`) and also answers to its short "
        "name (`--lr`, `lr=1e-3`) wherever no other section of the run has a setting of that name; a short name two "
        "sections share is refused with one line naming both dotted flags (a setting of the run's own sections, replay to "
        "data, keeps its short name as a run-level one does). The env family's and the algorithm's own settings are on the "
        "[env families](env_families.md) and [algorithms](algorithms.md) pages. `taskrl train PRESET --help` lists the "
        "ones that apply to a preset with its values.",
    ]
    for title, text, cls in sections:
        nested = ("replay", "evaluation", "checkpoints", "data", "conditioning", "cluster", "data_sharing")
        skip = (*nested, "env_settings", "algo_settings") if cls is TrainConfig else ("strategy_settings",)
        section = "" if cls is TrainConfig else title.split("`")[1]
        out += ["", f"## {title}", "", text, "", settings_table(cls, skip, section)]
    for strategy in SHARING_STRATEGIES.values():
        if strategy.settings is not None:
            section = f"data_sharing.{strategy.name}"
            text = f"Flags while the run shares with `--sharing {strategy.name}` ({strategy.summary})."
            table = settings_table(strategy.settings, (), section)
            out += ["", f"### `{strategy.name}` sharing (`{section}`)", "", text, "", table]
    return "\n".join(out) + "\n"


def _env_families_page() -> str:
    from taskrl.envs.registry import ENV_FAMILIES

    out = [
        "# Env families",
        "",
        "`--env NAME` picks a family; its settings are a section of `config.json` named after the family's section. "
        "Any gymnasium id trains through the `gym` family (`--env-id`); see the guide "
        "[Bring your own environment](../your_env.md).",
        "",
        "| family | kind | actions | section | what it is |",
        "|---|---|---|---|---|",
    ]
    for family in ENV_FAMILIES.values():
        out.append(
            f"| [`{family.name}`](#{family.name}) | {family.kind or 'from the env'} | {family.actions or 'from the env'} | "
            f"`{family.section}` | {_cell(family.description)} |"
        )
    done: set[str] = set()
    for family in ENV_FAMILIES.values():
        out += ["", f'<a id="{family.name}"></a>', "", f"## `{family.name}`", "", _cell(family.description), ""]
        if family.section in done:
            out.append(f"Settings: the `{family.section}` section, as above.")
            continue
        done.add(family.section)
        out.append(
            settings_table(family.settings, section="env") if dataclasses.fields(family.settings) else "No settings of its own."
        )
    return "\n".join(out) + "\n"


def _algorithms_page() -> str:
    from taskrl.agents.registry import ALGORITHMS

    out = [
        "# Algorithms",
        "",
        "`--algo NAME` picks one; its settings are the section of `config.json` named after it. The guide "
        "[Adding an algorithm](../guides/new_algorithm.md) shows what an entry needs.",
        "",
        "| algorithm | loop | actions | multi-task | compiled updates | Bellman updaters | what it is |",
        "|---|---|---|---|---|---|---|",
    ]
    yes = {True: "yes", False: "no"}
    for a in ALGORITHMS.values():
        out.append(
            f"| [`{a.name}`](#{a.name}) | {a.loop} | {', '.join(a.actions)} | {yes[a.multitask]} | {yes[a.compiles]} | "
            f"{yes[a.bellman_updaters]} | {_cell(a.description)} |"
        )
    for a in ALGORITHMS.values():
        out += [
            "",
            f'<a id="{a.name}"></a>',
            "",
            f"## `{a.name}`",
            "",
            _cell(a.description),
            "",
            settings_table(a.config, section="algo"),
        ]
    return "\n".join(out) + "\n"


def _presets_page() -> str:
    from taskrl.presets import PRESETS, preset_config

    out = [
        "# Presets",
        "",
        "`taskrl train PRESET` starts from one of these; every flag overrides it (`taskrl presets` prints this list).",
        "",
        "| preset | env | algo | what it trains | settings it sets |",
        "|---|---|---|---|---|",
    ]
    for name, preset in PRESETS.items():
        config = preset_config(name)
        changed = ", ".join(f"`{k}={v}`" for k, v in preset.overrides.items() if k not in ("env", "algo"))
        out.append(f"| `{name}` | `{config.env}` | `{config.algo}` | {_cell(preset.description)} | {_cell(changed)} |")
    return "\n".join(out) + "\n"


def _commands_page() -> str:
    from taskrl.cli import COMMANDS, main

    out = ["# Commands", "", "The `--help` of each `taskrl` command, as it prints it."]
    for command in COMMANDS:
        args = [command, "--help"] if command != "train" else ["train", "bitflip-her", "--help"]
        buffer = io.StringIO()
        with contextlib.redirect_stdout(buffer), contextlib.suppress(SystemExit):
            main(args)
        text = buffer.getvalue().strip()
        head = "`taskrl train PRESET --help`, here for `bitflip-her`" if command == "train" else f"`taskrl {command} --help`"
        out += ["", f"## taskrl {command}", "", head + ":", "", "```text", text, "```"]
    return "\n".join(out) + "\n"


def pages() -> dict[str, str]:
    """``{path inside the docs site: markdown}`` of the generated reference."""
    return {
        "reference/settings.md": _settings_page(),
        "reference/env_families.md": _env_families_page(),
        "reference/algorithms.md": _algorithms_page(),
        "reference/presets.md": _presets_page(),
        "reference/commands.md": _commands_page(),
    }
