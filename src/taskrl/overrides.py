"""A config with settings replaced by name, as the CLI and ``taskrl.train(**overrides)`` give them."""

from __future__ import annotations

import dataclasses
from typing import Any

from taskrl.agents.registry import algorithm
from taskrl.conditioning.settings import ConditioningConfig
from taskrl.config import TrainConfig, from_dict, to_dict
from taskrl.envs.registry import ENV_FAMILIES, env_family
from taskrl.setting_names import setting_names
from taskrl.setting_values import changed_fields
from taskrl.sharing.settings import SharingConfig

__all__ = ["SHARED_ALGO_SETTINGS", "with_overrides"]

#: Algorithm settings that carry over when ``algo`` changes (if the old section changed them).
SHARED_ALGO_SETTINGS = ("lr", "gamma", "hidden_sizes", "tau", "max_grad_norm", "normalize_inputs", "clip_target")


def _listed(settings: dict[str, Any]) -> str:
    """``lr=0.001, gamma=0.95``."""
    return ", ".join(f"{k}={v}" for k, v in settings.items())


def _lineage(name: str) -> set[str]:
    """The algorithm and the parents it declares (``AlgorithmSpec.parent``)."""
    seen: set[str] = set()
    while name and name not in seen:
        seen.add(name)
        name = algorithm(name).parent or ""
    return seen


def _switch_algorithm(old: Any, old_name: str, new_name: str, notes: list[str]) -> Any:
    """The new algorithm's section, keeping the shared settings the old section had changed."""
    new_cls = algorithm(new_name).config
    new_fields = {f.name for f in dataclasses.fields(new_cls)}
    changed = changed_fields(old)
    kin = _lineage(old_name) & _lineage(new_name)  # a variant and its parent, or two variants of one parent
    kept = {k: v for k, v in changed.items() if (kin or k in SHARED_ALGO_SETTINGS) and k in new_fields}
    dropped = sorted(set(changed) - set(kept))
    section = new_cls(**kept)
    if kept:
        notes.append(f"--algo {new_name}: kept {_listed(kept)} from {old_name}")
    if dropped:
        notes.append(
            f"--algo {new_name}: {old_name}'s {_listed({k: changed[k] for k in dropped})} "
            f"do{'es' if len(dropped) == 1 else ''} not carry over ({new_name} uses its own defaults)"
        )
    return section


def _selected_family(config: TrainConfig, overrides: dict[str, Any]) -> str:
    if "env" in overrides:
        return overrides["env"]
    for family in ENV_FAMILIES.values():  # --env-id X alone means the gym family, --task-file F the tasks one
        spellings = (family.selected_by, f"env.{family.selected_by}", f"{family.section}.{family.selected_by}")
        if family.selected_by and any(k in overrides for k in spellings) and family.name != config.env:
            current = dataclasses.fields(env_family(config.env).settings)
            if family.selected_by not in {f.name for f in current}:
                return family.name
    return config.env


def _selected_sharing(config: TrainConfig, overrides: dict[str, Any], notes: list[str]) -> SharingConfig:
    """The data-sharing section for the strategy the overrides name (its own settings from their defaults when the
    strategy changes)."""
    current = config.data_sharing
    name = next((overrides[k] for k in ("sharing", "data_sharing.sharing") if k in overrides), current.sharing)
    if name == current.sharing:
        return current
    changed = changed_fields(current.strategy_settings) if current.strategy_settings is not None else {}
    if changed:
        notes.append(f"--sharing {name}: {current.sharing}'s {_listed(changed)} do{'es' if len(changed) == 1 else ''} not apply")
    return SharingConfig(sharing=name, share_fraction=current.share_fraction)


def with_overrides(config: TrainConfig, overrides: dict[str, Any], notes: list[str] | None = None) -> TrainConfig:
    """A copy of ``config`` with settings replaced by name (``{"n_bits": 30, "lr": 1e-3}``).

    Names are those `setting_names` gives for the resulting ``env`` and ``algo``: in sections
    (``{"algo.lr": 1e-3, "env.n_bits": 30, "algo.cem.samples": 32}``) or short where unambiguous. Changing ``env``
    starts its family's section from defaults (families sharing a section keep it); changing
    ``algo`` keeps the `SHARED_ALGO_SETTINGS` the old section had changed (every setting both sections
    have, between a variant and its ``parent``). What was kept
    or dropped is appended to ``notes``.
    """
    notes = [] if notes is None else notes
    overrides = dict(overrides)
    env = _selected_family(config, overrides)
    algo = overrides.get("algo", config.algo)
    family, old_family = env_family(env), env_family(config.env)
    algorithm(algo)
    env_settings = config.env_settings
    if family.section != old_family.section:
        changed = changed_fields(config.env_settings)
        if changed:
            notes.append(f"--env {env}: {config.env}'s {_listed(changed)} do{'es' if len(changed) == 1 else ''} not apply")
        env_settings = family.settings()
    conditioning, conditioned = config.conditioning, changed_fields(config.conditioning)
    if family.kind in ("goal", "plain") and conditioned:  # the preset's task conditioning has no tasks here
        notes.append(f"--env {env}: has no tasks, so the preset's task conditioning ({_listed(conditioned)}) is off")
        conditioning = ConditioningConfig()
    algo_settings, her = config.algo_settings, config.replay.her
    if algo != config.algo:
        algo_settings = _switch_algorithm(config.algo_settings, config.algo, algo, notes)
        if algorithm(algo).loop != "off_policy" and her != "none" and "her" not in overrides:
            how = "offline" if algorithm(algo).loop == "offline" else "on-policy"
            notes.append(f"--algo {algo}: learns {how}, so the preset's hindsight relabelling (her={her}) is off")
            her = "none"
    data_sharing = _selected_sharing(config, overrides, notes)
    data = to_dict(
        dataclasses.replace(
            config,
            env=env,
            algo=algo,
            replay=dataclasses.replace(config.replay, her=her),
            data_sharing=data_sharing,
            env_settings=env_settings,
            algo_settings=algo_settings,
            conditioning=conditioning,
        )
    )
    names = setting_names(env, algo, data_sharing.sharing)
    overrides.pop("env", None), overrides.pop("algo", None)
    for name, value in overrides.items():
        node = data
        *parents, leaf = names.resolve(name, env, algo)
        for p in parents:
            node = node[p]
        node[leaf] = list(value) if isinstance(value, tuple) else value
    return from_dict(data)
