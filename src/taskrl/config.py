"""Typed run configuration: run-level settings, the run's own sections (replay, evaluation, checkpoints, data,
conditioning, cluster, data sharing), one section for the env family and one for the algorithm, each validated by
its own ``validate()``, saved with every run.

``config.json`` reads::

    {"env": "bitflip", "algo": "dqn", "total_steps": 60000, ..., "replay": {"buffer_size": 1000000, "her": "future",
     ...}, "evaluation": {"eval_interval": 5000, ...}, ..., "bitflip": {"n_bits": 15, ...}, "dqn": {"lr": 0.001, ...}}

The env and algorithm sections are those of the registries (``taskrl.envs.registry``, ``taskrl.agents.registry``):
a new family or algorithm brings its own. The CLI turns every setting of the run and of the active sections into a
``--kebab-case`` flag, in its section (``--algo.lr``, ``--evaluation.eval-interval``) and by its short name where no
other setting has it (``--lr`` is the active algorithm's learning rate, ``--eval-interval`` the evaluation's).
"""

from __future__ import annotations

import dataclasses
import json
import typing
from pathlib import Path
from typing import Any, Literal

from taskrl.agents.registry import algorithm
from taskrl.conditioning.settings import ConditioningConfig
from taskrl.config_migration import migrate
from taskrl.distributed.settings import DistributedConfig
from taskrl.envs.registry import env_family
from taskrl.errors import ConfigError, reason
from taskrl.run_sections import CheckpointSettings, DataSettings, EvaluationSettings, ReplaySettings
from taskrl.rundir import atomic_write_text
from taskrl.setting_values import checked_value
from taskrl.sharing.registry import sharing_strategy
from taskrl.sharing.settings import SharingConfig

__all__ = ["ConfigError", "TrainConfig", "field_docs", "from_dict", "load", "run_fields", "save", "to_dict"]

_SECTIONS = ("env_settings", "algo_settings")
#: settings fields that hold the section of a registered piece chosen by name (saved under that name)
_CHOSEN = (*_SECTIONS, "strategy_settings")


@dataclasses.dataclass
class TrainConfig:
    """Everything a training run needs; saved as ``config.json`` in the run directory.

    Attributes:
        env: environment family (``taskrl train --help`` lists them; ``gym`` is any gymnasium id
            given by ``--env-id``, ``tasks`` a task set given by ``--task-file``). Its settings are
            the section named after it (``bitflip.n_bits``, ``metaworld.task``, ...).
        algo: learning algorithm; its section (``dqn``, ``qtopt``, ``sac``, ``td3``, ``ppo``) holds its
            hyperparameters and its exploration. ``ppo`` (also REINFORCE, via its ``estimator``) learns
            on-policy: the replay, relabelling, batch and update-ratio settings do not apply to it.
        total_steps: environment steps to train for (summed over parallel environments).
        num_envs: environments stepped in parallel while collecting.
        seed: seed for network initialisation, environments and sampling.
        device: ``cpu``, ``cuda``, ``cuda:N`` or ``auto`` (CUDA when available).
        batch_size: transitions per gradient update.
        learning_starts: environment steps collected before the first update.
        updates_per_step: gradient updates per environment step (fractions accumulate).
        updates_per_call: gradient updates made in one call of the agent, each on its own batch
            (compiled, one graph for all of them: less overhead per update at high update
            ratios); updates wait until that many are due. 1 = one at a time; 0 (``auto`` on the command
            line) = 4 where that is estimated faster with ``compile``, else 1.
        tensorboard_interval: environment steps between TensorBoard points of the training scalars
            (losses, Q, temperature; ``train/...``) between evaluations (0: at evaluations only).
        mode: the run mode (how the run runs: ``off_policy``, ``on_policy``, ``dataset``, ``stored_data``,
            ``distributed``, or a registered one); ``auto`` derives it from the algorithm and the switches given
            (``--offline``, ``--distributed``). A mode named here must fit the run (one line says why not).
        max_hours: stop cleanly (evaluation, checkpoint) after this many hours of wall-clock in
            this invocation, to continue later with ``--resume``; 0 = no limit. Ctrl-C and
            SIGTERM stop the same way.
        compile: run each gradient update as one ``torch.compile`` graph: ``default``,
            ``reduce-overhead`` (CUDA graphs on GPU) or ``max-autotune``; ``off`` = eager; ``auto`` = compiled
            (``default``) where the run plans enough updates to pay for the compilation, else eager
            (`taskrl.agents.compile_rule`; the run's first note says which and why). Compiling costs seconds
            before the first update (less in a later run: the cache is kept in the user's cache directory); where
            it cannot compile, the run says so on one line and updates eagerly.
        threads: torch CPU threads. 1 by default: the networks here are small, one thread is as
            fast, and torch's multi-threaded kernels stall when another process holds a core
            (measured 100x slower on a busy 2-core machine). 0 = torch's default.
        env_module: a Python module to import before the envs are built (one that registers your
            gymnasium ids). Resuming, evaluating and loading never import it unless you pass it again.
        replay: what the replay keeps and how batches are drawn (`ReplaySettings`: size, hindsight, sampling).
        evaluation: when and how the greedy policy is scored (`EvaluationSettings`).
        checkpoints: when the run is saved, and what with (`CheckpointSettings`).
        data: where the data comes from besides the agent's acting (`DataSettings`: stored data, scripted episodes).
        conditioning: how multi-task networks are told the task (task encoder, architecture).
        cluster: where the roles run: one process, or collectors and Bellman updaters as Ray actors.
        data_sharing: how tasks share data (multi-task envs whose tasks are reward functions).
        env_settings: the env family's section (saved under the family's section name).
        algo_settings: the algorithm's section (saved under the algorithm's name).
    """

    env: str = "bitflip"
    algo: str = "dqn"
    total_steps: int = 100_000
    num_envs: int = 32
    seed: int = 0
    device: str = "cpu"
    batch_size: int = 256
    learning_starts: int = 1_000
    updates_per_step: float = 0.1
    updates_per_call: int = 0
    tensorboard_interval: int = 1_000
    mode: str = "auto"
    max_hours: float = 0.0
    compile: Literal["auto", "off", "default", "reduce-overhead", "max-autotune"] = "auto"
    threads: int = 1
    env_module: str = ""
    replay: ReplaySettings = dataclasses.field(default_factory=ReplaySettings)
    evaluation: EvaluationSettings = dataclasses.field(default_factory=EvaluationSettings)
    checkpoints: CheckpointSettings = dataclasses.field(default_factory=CheckpointSettings)
    data: DataSettings = dataclasses.field(default_factory=DataSettings)
    conditioning: ConditioningConfig = dataclasses.field(default_factory=ConditioningConfig)
    cluster: DistributedConfig = dataclasses.field(default_factory=DistributedConfig)
    data_sharing: SharingConfig = dataclasses.field(default_factory=SharingConfig)
    env_settings: Any = None
    algo_settings: Any = None

    def __post_init__(self) -> None:
        if self.env_settings is None:
            self.env_settings = env_family(self.env).settings()
        if self.algo_settings is None:
            self.algo_settings = algorithm(self.algo).config()

    @property
    def env_section(self) -> str:
        """The name the env settings are saved under (families may share one, e.g. ``metaworld``)."""
        return env_family(self.env).section


def run_fields() -> list[dataclasses.Field]:
    return [f for f in dataclasses.fields(TrainConfig) if f.name not in _SECTIONS]


def field_docs(cls: type) -> dict[str, str]:
    """``{field: description}`` from the ``Attributes:`` sections of a dataclass's docstring and of its bases'
    (a family's settings inherit the camera's, `CameraSettings`); the class's own description wins."""
    docs: dict[str, str] = {}
    for base in reversed(cls.__mro__):
        if base is not cls and dataclasses.is_dataclass(base):
            docs.update(_own_field_docs(base))
    return {**docs, **_own_field_docs(cls)}


def _own_field_docs(cls: type) -> dict[str, str]:
    docs: dict[str, str] = {}
    lines = (cls.__doc__ or "").split("Attributes:", 1)[-1].splitlines()
    current: list[str] = []
    for line in lines:
        text = line.strip()
        head, sep, rest = text.partition(":")
        names = [h.strip() for h in head.split(",")]
        if sep and head and all(name.isidentifier() for name in names):  # "lr:" or "a, b:", not "spatial softmax:"
            current = names
            for name in current:
                docs[name] = rest.strip()
        elif text and current:
            for name in current:
                docs[name] += " " + text
    return docs


# ---------------------------------------------------------------------- saving and loading
def to_dict(config: TrainConfig) -> dict[str, Any]:
    """``config.json``'s content: run-level fields, the run's sections (replay, evaluation, ..., conditioning), and the
    env's and the algorithm's sections by name."""
    data = {f.name: getattr(config, f.name) for f in run_fields()}
    data.update({name: dataclasses.asdict(value) for name, value in data.items() if dataclasses.is_dataclass(value)})
    sharing = data["data_sharing"]
    own = sharing.pop("strategy_settings")
    if own is not None:  # the chosen strategy's settings, under its name
        sharing[config.data_sharing.sharing] = own
    data[config.env_section] = dataclasses.asdict(config.env_settings)
    data[config.algo] = dataclasses.asdict(config.algo_settings)
    return data


def _build(cls: type, data: dict[str, Any], where: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(where.rsplit(".", 1)[-1], f"{where} must be a mapping of settings, got {data!r}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)} - set(_CHOSEN)
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(unknown[0], f"unknown setting in {where}; allowed: {', '.join(sorted(names))}")
    kwargs = {}
    for name, value in data.items():
        tp = hints[name]
        kwargs[name] = _build(tp, value, f"{where}.{name}") if dataclasses.is_dataclass(tp) else checked_value(name, value, tp)
    return cls(**kwargs)


def _strategy_section(data_sharing: Any) -> tuple[Any, Any, dict | None]:
    """``(data_sharing without the chosen strategy's settings, that strategy, its settings or None)``."""
    if not isinstance(data_sharing, dict):
        return data_sharing, None, None  # _build names the defect
    section = dict(data_sharing)
    strategy = sharing_strategy(checked_value("sharing", section.get("sharing", "none"), str))
    own = section.pop(strategy.name, {}) if strategy.settings is not None else None
    return section, strategy, own


def from_dict(data: dict[str, Any]) -> TrainConfig:
    """Rebuild a config from `to_dict` output (e.g. a run's ``config.json``)."""
    data = migrate(dict(data))
    env, algo = data.get("env", TrainConfig.env), data.get("algo", TrainConfig.algo)
    family, spec = env_family(env), algorithm(algo)
    sections = {family.section, algo}
    top = {k: v for k, v in data.items() if k not in sections}
    top["data_sharing"], strategy, own = _strategy_section(top.get("data_sharing", {}))
    config = _build(TrainConfig, top, "config")
    if own is not None:
        config.data_sharing.strategy_settings = _build(strategy.settings, own, f"config.data_sharing.{strategy.name}")
    config.env_settings = _build(family.settings, data.get(family.section, {}), f"config.{family.section}")
    config.algo_settings = _build(spec.config, data.get(algo, {}), f"config.{algo}")
    return config


def save(config: TrainConfig, path: Path) -> None:
    """Write ``config.json`` atomically (temp file, fsync, rename: a kill never leaves half a file)."""
    atomic_write_text(path, json.dumps(to_dict(config), indent=2) + "\n")


def load(path: Path) -> TrainConfig:
    """A saved ``config.json``; any defect (unreadable, not JSON, foreign, wrong types) is one
    `ConfigError` line naming the file or the setting."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as error:
        raise ConfigError("config", f"{path} cannot be read as a taskrl config ({reason(error)})") from None
    if not isinstance(data, dict):
        raise ConfigError("config", f"{path} holds {type(data).__name__}, not a taskrl config (a JSON object)")
    return from_dict(data)
