"""``config.json`` files written before the registries, read in today's shape."""

from __future__ import annotations

import dataclasses
from typing import Any

from taskrl.envs.registry import env_family
from taskrl.run_sections import RUN_SECTIONS

__all__ = ["migrate"]

# Settings that sat flat on TrainConfig before the registries (and the section each now lives in).
_LEGACY_ENV_KEYS = ("n_bits", "terminate_on_success", "reward", "vector_strategy", "mt1_task", "max_episode_steps")
_LEGACY_EXPLORATION = ("epsilon_start", "epsilon_end", "epsilon_decay_steps")


def migrate(data: dict[str, Any]) -> dict[str, Any]:
    """A ``config.json`` of an earlier taskrl, in today's shape."""
    return _strategy_settings(_shift_with_the_camera(_run_sections(_sections_from_flat(data))))


#: the built-in strategies' settings, when ``data_sharing`` held them all
_SHARING_KNOBS = {"share_tasks": "random", "hipi_temperature": "hipi", "conservative_percentile": "conservative"}


def _strategy_settings(data: dict[str, Any]) -> dict[str, Any]:
    """``data_sharing`` held every built-in strategy's settings; it holds the chosen strategy's, under its name."""
    sharing = data.get("data_sharing")
    if not isinstance(sharing, dict) or not any(k in sharing for k in _SHARING_KNOBS):
        return data
    sharing = dict(sharing)
    knobs = {k: sharing.pop(k) for k in _SHARING_KNOBS if k in sharing}
    chosen = sharing.get("sharing", "none")
    own = {k: v for k, v in knobs.items() if _SHARING_KNOBS[k] == chosen}
    if own:
        sharing[chosen] = {**own, **sharing.get(chosen, {})}
    return {**data, "data_sharing": sharing}


def _run_sections(data: dict[str, Any]) -> dict[str, Any]:
    """The replay's, evaluation's, checkpoints' and data settings sat flat on the run; they are sections now."""
    flat = {name: {f.name for f in dataclasses.fields(cls)} for name, cls in RUN_SECTIONS.items()}
    if not any(key in fields for key in data for fields in flat.values()):
        return data
    data = dict(data)
    for name, fields in flat.items():
        section = dict(data.get(name, {}))
        for key in fields & set(data):
            section.setdefault(key, data.pop(key))
        if section:
            data[name] = section
    return data


def _shift_with_the_camera(data: dict[str, Any]) -> dict[str, Any]:
    """The picture shift was each algorithm's ``augment_pad``; it is the camera's ``shift`` now (`CameraSettings`)."""
    algo = data.get("algo", "dqn")
    if not isinstance(data.get(algo), dict) or "augment_pad" not in data[algo]:
        return data
    data = {**data, algo: dict(data[algo])}
    pad = data[algo].pop("augment_pad")
    family = env_family(data.get("env", "bitflip"))
    if "shift" in {f.name for f in dataclasses.fields(family.settings)}:
        section = dict(data.get(family.section, {}))
        section.setdefault("shift", pad)
        data[family.section] = section
    return data


def _sections_from_flat(data: dict[str, Any]) -> dict[str, Any]:
    """A ``config.json`` written before the registries, in today's shape (flat env settings and a
    loop-level exploration schedule become the sections' own settings; other algorithms' sections go)."""
    if not any(k in data for k in _LEGACY_ENV_KEYS + _LEGACY_EXPLORATION):
        return data
    data = dict(data)
    env, algo = data.get("env", "bitflip"), data.get("algo", "dqn")
    flat = {k: data.pop(k) for k in _LEGACY_ENV_KEYS + _LEGACY_EXPLORATION if k in data}
    family = env_family(env)
    if "mt1_task" in flat:
        flat["task"] = flat.pop("mt1_task")
    fields = {f.name for f in dataclasses.fields(family.settings)}
    data[family.section] = {k: v for k, v in flat.items() if k in fields}
    section = dict(data.get(algo, {}))
    start, end, steps = (flat.get(k) for k in _LEGACY_EXPLORATION)
    if start is not None:
        if algo == "dqn":
            section.update(epsilon_start=start, epsilon_end=end, epsilon_decay_steps=steps)
        elif algo == "qtopt":
            section.update(random_action_prob=start, random_action_prob_end=end, random_action_decay_steps=steps)
        elif algo == "td3":
            section.update(noise_std=end)  # the loop's level was TD3's noise std
    for name in [
        k
        for k in data
        if isinstance(data[k], dict) and k not in ("conditioning", "cluster", "data_sharing", family.section, *RUN_SECTIONS)
    ]:
        if name != algo:
            data.pop(name)  # every algorithm's section was saved; only the run's own is kept
    data[algo] = section
    return data
