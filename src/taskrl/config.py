"""Typed run configuration: one dataclass, validated in one place, saved with every run.

Agent hyperparameters live in each agent's own dataclass (``DQNConfig``, ``QTOptConfig``,
``SACConfig``) nested here, so every hyperparameter is declared once. The settings of a run are
the top-level fields plus the section of its ``algo``; the CLI turns each of them into a flat
``--kebab-case`` flag (``--lr`` means the active algorithm's learning rate).
"""

from __future__ import annotations

import dataclasses
import json
import typing
from pathlib import Path
from typing import Any, Literal

from taskrl.agents.cem import CEMConfig
from taskrl.agents.dqn import DQNConfig
from taskrl.agents.ppo import PPOConfig, check_ppo_config
from taskrl.agents.qtopt import QTOptConfig
from taskrl.agents.sac import SACConfig
from taskrl.agents.td3 import TD3Config
from taskrl.conditioning.networks import ARCHITECTURES, ConditioningConfig
from taskrl.conditioning.task_encoders import TASK_ENCODERS

ENVS = ("bitflip", "pointreach", "fetchreach", "fetchpush", "fetchpickandplace", "fetchslide",
        "pointreach-mt", "mt1", "mt10", "mt50")
#: Multi-task environments (observations carry the task index under ``task``).
MULTITASK_ENVS = ("pointreach-mt", "mt1", "mt10", "mt50")
#: Meta-World benchmarks by taskrl env name.
METAWORLD_BENCHMARKS = {"mt1": "MT1", "mt10": "MT10", "mt50": "MT50"}
#: Algorithms that run on multi-task environments (continuous actions, task-conditioned networks).
MULTITASK_ALGOS = ("sac", "ppo")
SAMPLINGS = ("uniform", "task_balanced")
#: Environments that come from gymnasium (through the vector-env adapter), by taskrl name.
GYMNASIUM_IDS = {
    "fetchreach": "FetchReach-v4",
    "fetchpush": "FetchPush-v4",
    "fetchpickandplace": "FetchPickAndPlace-v4",
    "fetchslide": "FetchSlide-v4",
}
#: Each algorithm's hyperparameters live in its own dataclass, a section of TrainConfig.
ALGO_CONFIGS: dict[str, type] = {"dqn": DQNConfig, "qtopt": QTOptConfig, "sac": SACConfig, "td3": TD3Config, "ppo": PPOConfig}
#: Algorithms trained on-policy (rollouts, no replay, no relabelling).
ON_POLICY_ALGOS = ("ppo",)
ALGOS = tuple(ALGO_CONFIGS)
HER_STRATEGIES = ("future", "final", "episode", "random", "none")


class ConfigError(ValueError):
    """A bad configuration value; ``field`` names the offending setting."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


@dataclasses.dataclass
class TrainConfig:
    """Everything a training run needs; saved as ``config.json`` in the run directory.

    Attributes:
        env: environment name (``fetch*`` need the ``robotics`` extra: gymnasium-robotics;
            ``mt1`` / ``mt10`` / ``mt50`` are Meta-World v3 and need the ``metaworld`` extra;
            ``pointreach-mt`` is the native multi-task point reaching with 5 named regions).
        n_bits: bit-string length for ``bitflip`` (also its horizon).
        terminate_on_success: end an episode when its goal is reached (bitflip, pointreach).
        reward: ``sparse`` (0 at the goal, else -1) or ``dense`` (-distance), for pointreach.
        vector_strategy: ``sync`` or ``async`` (one process per copy) for gymnasium environments.
        mt1_task: the Meta-World task of ``mt1`` (``reach``, ``push``, ... or with its ``-v3`` suffix).
        max_episode_steps: Meta-World episode length (Meta-World's own is 500).
        sampling: ``uniform`` over stored transitions, or ``task_balanced`` (multi-task envs: the
            same number of transitions of every task in each batch).
        algo: learning algorithm; its section (``dqn``, ``qtopt``, ``sac``, ``td3``, ``ppo``) holds its
            hyperparameters. ``ppo`` (also REINFORCE, via its ``estimator``) learns on-policy: the replay,
            relabelling, batch and update-ratio settings do not apply to it.
        total_steps: environment steps to train for (summed over parallel environments).
        num_envs: environments stepped in parallel while collecting.
        seed: seed for network initialisation, environments and sampling.
        device: ``cpu``, ``cuda``, ``cuda:N`` or ``auto`` (CUDA when available).
        buffer_size: replay capacity in transitions.
        her: hindsight strategy (``none`` disables relabelling).
        her_k: relabelled transitions per real one; the relabelled fraction is k/(k+1).
        batch_size: transitions per gradient update.
        learning_starts: environment steps collected before the first update.
        updates_per_step: gradient updates per environment step (fractions accumulate).
        epsilon_start: initial exploration level passed to the agent while collecting: DQN's
            epsilon, QT-Opt's probability of a uniformly random action, TD3's Gaussian noise std
            (fraction of the action half-width); SAC samples its policy whenever it is above 0.
        epsilon_end: final exploration level.
        epsilon_decay_steps: environment steps over which it decays linearly.
        eval_interval: environment steps between evaluations.
        eval_episodes: episodes per evaluation (greedy policy, fixed evaluation seeds); on
            multi-task envs, episodes per task (Meta-World: over distinct goal positions, at most 50).
        stop_at_success: stop once evaluation success reaches this (0 = train to total_steps).
        checkpoint_interval: environment steps between checkpoints (also one at the end).
        save_replay: include the replay buffer in checkpoints so a resumed run loses no data.
        max_hours: stop cleanly (evaluation, checkpoint) after this many hours of wall-clock in
            this invocation, to continue later with ``--resume``; 0 = no limit. Ctrl-C and
            SIGTERM stop the same way.
        threads: torch CPU threads. 1 by default: the networks here are small, one thread is as
            fast, and torch's multi-threaded kernels stall when another process holds a core
            (measured 100x slower on a busy 2-core machine). 0 = torch's default.
        dqn: DQN hyperparameters.
        qtopt: QT-Opt hyperparameters.
        sac: SAC hyperparameters.
        td3: TD3 hyperparameters.
        ppo: PPO / REINFORCE hyperparameters.
        conditioning: how multi-task networks are told the task (task encoder, architecture).
    """

    env: Literal["bitflip", "pointreach", "fetchreach", "fetchpush", "fetchpickandplace", "fetchslide",
                 "pointreach-mt", "mt1", "mt10", "mt50"] = "bitflip"
    n_bits: int = 15
    terminate_on_success: bool = True
    reward: Literal["sparse", "dense"] = "sparse"
    vector_strategy: Literal["sync", "async"] = "sync"
    mt1_task: str = "reach"
    max_episode_steps: int = 500
    sampling: Literal["uniform", "task_balanced"] = "uniform"
    algo: Literal["dqn", "qtopt", "sac", "td3", "ppo"] = "dqn"
    total_steps: int = 100_000
    num_envs: int = 32
    seed: int = 0
    device: str = "cpu"
    buffer_size: int = 1_000_000
    her: Literal["future", "final", "episode", "random", "none"] = "future"
    her_k: int = 4
    batch_size: int = 256
    learning_starts: int = 1_000
    updates_per_step: float = 0.1
    epsilon_start: float = 0.5
    epsilon_end: float = 0.05
    epsilon_decay_steps: int = 20_000
    eval_interval: int = 5_000
    eval_episodes: int = 100
    stop_at_success: float = 0.0
    checkpoint_interval: int = 50_000
    save_replay: bool = True
    max_hours: float = 0.0
    threads: int = 1
    dqn: DQNConfig = dataclasses.field(default_factory=DQNConfig)
    qtopt: QTOptConfig = dataclasses.field(default_factory=QTOptConfig)
    sac: SACConfig = dataclasses.field(default_factory=SACConfig)
    td3: TD3Config = dataclasses.field(default_factory=TD3Config)
    ppo: PPOConfig = dataclasses.field(default_factory=PPOConfig)
    conditioning: ConditioningConfig = dataclasses.field(default_factory=ConditioningConfig)


def field_docs(cls: type) -> dict[str, str]:
    """``{field: description}`` from the ``Attributes:`` section of a dataclass docstring."""
    docs: dict[str, str] = {}
    lines = (cls.__doc__ or "").split("Attributes:", 1)[-1].splitlines()
    current: list[str] = []
    for line in lines:
        text = line.strip()
        head, sep, rest = text.partition(":")
        if sep and head and all(part.isidentifier() for part in head.replace(" ", "").split(",")):
            current = [h.strip() for h in head.split(",")]
            for name in current:
                docs[name] = rest.strip()
        elif text and current:
            for name in current:
                docs[name] += " " + text
    return docs


def validate(config: TrainConfig) -> TrainConfig:
    """Raise :class:`ConfigError` naming the field and the allowed values; return the config."""

    def require(ok: bool, field: str, message: str) -> None:
        if not ok:
            raise ConfigError(field, message)

    c = config
    require(c.env in ENVS, "env", f"unknown env {c.env!r}; allowed: {', '.join(ENVS)}")
    require(c.algo in ALGOS, "algo", f"unknown algo {c.algo!r}; allowed: {', '.join(ALGOS)}")
    require(c.her in HER_STRATEGIES, "her", f"unknown strategy {c.her!r}; allowed: {', '.join(HER_STRATEGIES)}")
    require(c.reward in ("sparse", "dense"), "reward", f"unknown reward {c.reward!r}; allowed: sparse, dense")
    require(c.vector_strategy in ("sync", "async"), "vector_strategy",
            f"unknown strategy {c.vector_strategy!r}; allowed: sync, async")
    require(c.n_bits >= 1, "n_bits", f"must be >= 1 (got {c.n_bits})")
    require(c.sampling in SAMPLINGS, "sampling", f"unknown sampling {c.sampling!r}; allowed: {', '.join(SAMPLINGS)}")
    require(c.max_episode_steps >= 1, "max_episode_steps", f"must be >= 1 (got {c.max_episode_steps})")
    if c.env == "mt1":
        from taskrl.envs.metaworld_tasks import MT50_TASKS, version_free

        require(version_free(c.mt1_task) in MT50_TASKS, "mt1_task",
                f"unknown Meta-World task {c.mt1_task!r}; allowed: {', '.join(MT50_TASKS)}")
    if c.env in MULTITASK_ENVS:
        require(c.algo in MULTITASK_ALGOS, "algo",
                f"{c.algo!r} does not run on the multi-task env {c.env!r}; allowed: {', '.join(MULTITASK_ALGOS)}")
        require(c.her == "none", "her", f"{c.env!r} is not a goal env (no achieved/desired goal); use --her none")
        if c.env in ("mt10", "mt50"):
            from taskrl.envs.metaworld_tasks import MT10_TASKS, MT50_TASKS

            tasks = len(MT10_TASKS if c.env == "mt10" else MT50_TASKS)
            require(c.num_envs % tasks == 0, "num_envs",
                    f"must be a multiple of the {tasks} tasks of {c.env} (one or more copies per task; got {c.num_envs})")
        if c.env in METAWORLD_BENCHMARKS:
            require(c.eval_episodes <= 50, "eval_episodes",
                    f"Meta-World has 50 goal positions per task: at most 50 episodes per task (got {c.eval_episodes})")
    else:
        require(c.sampling == "uniform", "sampling", f"task_balanced needs a multi-task env ({', '.join(MULTITASK_ENVS)})")
    k = c.conditioning
    require(k.task_encoder in TASK_ENCODERS, "task_encoder",
            f"unknown task encoder {k.task_encoder!r}; allowed: {', '.join(TASK_ENCODERS)}")
    require(k.architecture in ARCHITECTURES, "architecture",
            f"unknown architecture {k.architecture!r}; allowed: {', '.join(ARCHITECTURES)}")
    for name in ("embedding_dim", "care_encoders", "care_encoder_dim"):
        require(getattr(k, name) >= 1, name, f"must be >= 1 (got {getattr(k, name)})")
    require(k.projection_dim >= 0, "projection_dim", f"must be >= 0 (got {k.projection_dim})")
    for name in ("total_steps", "num_envs", "batch_size", "eval_interval", "eval_episodes", "checkpoint_interval"):
        require(getattr(c, name) >= 1, name, f"must be >= 1 (got {getattr(c, name)})")
    require(c.her_k >= 0, "her_k", f"must be >= 0 (got {c.her_k})")
    require(c.learning_starts >= 0, "learning_starts", f"must be >= 0 (got {c.learning_starts})")
    require(c.updates_per_step >= 0, "updates_per_step", f"must be >= 0 (got {c.updates_per_step})")
    require(c.max_hours >= 0, "max_hours", f"must be >= 0 hours (0 = no limit; got {c.max_hours})")
    for name in ("epsilon_start", "epsilon_end", "stop_at_success"):
        require(0.0 <= getattr(c, name) <= 1.0, name, f"must be in [0, 1] (got {getattr(c, name)})")
    require(c.epsilon_decay_steps >= 0, "epsilon_decay_steps", f"must be >= 0 (got {c.epsilon_decay_steps})")
    require(c.threads >= 0, "threads", f"must be >= 0 (got {c.threads})")
    require(c.device == "auto" or c.device == "cpu" or c.device.startswith("cuda"), "device",
            f"unknown device {c.device!r}; allowed: cpu, cuda, cuda:N, auto")

    # The active algorithm's section: checks shared by every agent, then its own.
    a = getattr(c, c.algo)
    require(0.0 <= a.gamma < 1.0, "gamma", f"must be in [0, 1) (got {a.gamma})")
    require(a.lr > 0, "lr", f"must be > 0 (got {a.lr})")
    if hasattr(a, "tau"):  # target networks
        require(0.0 < a.tau <= 1.0, "tau", f"must be in (0, 1] (got {a.tau})")
    require(len(a.hidden_sizes) >= 1 and all(h >= 1 for h in a.hidden_sizes), "hidden_sizes",
            f"must be one or more positive widths (got {list(a.hidden_sizes)})")
    require(a.max_grad_norm >= 0, "max_grad_norm", f"must be >= 0 (got {a.max_grad_norm})")
    if c.algo == "dqn":
        require(a.loss in ("huber", "mse"), "loss", f"unknown loss {a.loss!r}; allowed: huber, mse")
        require(a.target_update_interval >= 1, "target_update_interval", f"must be >= 1 (got {a.target_update_interval})")
    if c.algo == "qtopt":
        require(a.loss in ("huber", "mse", "cross_entropy"), "loss",
                f"unknown loss {a.loss!r}; allowed: huber, mse, cross_entropy")
        require(a.target2_interval >= 1, "target2_interval", f"must be >= 1 (got {a.target2_interval})")
        require(a.noise_std >= 0, "noise_std", f"must be >= 0 (got {a.noise_std})")
        cem = a.cem
        require(cem.iterations >= 1, "iterations", f"must be >= 1 (got {cem.iterations})")
        require(1 <= cem.elites <= cem.samples, "elites", f"must be in [1, samples={cem.samples}] (got {cem.elites})")
        require(cem.first_samples == 0 or cem.first_samples >= cem.elites, "first_samples",
                f"must be 0 (same as samples) or >= elites={cem.elites} (got {cem.first_samples})")
        require(cem.warm_std > 0 and cem.warm_iterations >= 0, "warm_std",
                f"warm_std must be > 0 and warm_iterations >= 0 (got {cem.warm_std}, {cem.warm_iterations})")
    if c.algo == "sac":
        require(a.init_alpha > 0, "init_alpha", f"must be > 0 (got {a.init_alpha})")
    if c.algo == "ppo":
        require(c.her == "none", "her", "ppo learns on-policy from rollouts: there is no replay to relabel; use --her none")
        try:
            check_ppo_config(a)
        except ValueError as error:
            field, _, message = str(error).partition(": ")
            raise ConfigError(field, message) from None
    if c.algo == "td3":
        require(0.0 <= a.random_action_prob <= 1.0, "random_action_prob", f"must be in [0, 1] (got {a.random_action_prob})")
        require(a.policy_delay >= 1, "policy_delay", f"must be >= 1 (got {a.policy_delay})")
    return config


def _leaves(cls: type, prefix: tuple[str, ...]) -> list[tuple[tuple[str, ...], dataclasses.Field, type]]:
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        if dataclasses.is_dataclass(tp):
            out += _leaves(tp, prefix + (f.name,))
        else:
            out.append((prefix + (f.name,), f, tp))
    return out


def leaf_fields(algo: str = "dqn") -> list[tuple[tuple[str, ...], dataclasses.Field, type]]:
    """The settings of a run with ``algo``: ``(path, field, type)`` of every top-level field and of
    every field of that algorithm's section (nested sections flattened)."""
    top = [leaf for leaf in _leaves(TrainConfig, ()) if leaf[0][0] not in ALGO_CONFIGS]
    return top + _leaves(ALGO_CONFIGS[algo], (algo,))


def field_help(algo: str = "dqn") -> dict[str, str]:
    """``{setting: description}`` for the CLI, from the dataclasses' docstrings."""
    docs = field_docs(TrainConfig)
    for cls in (ConditioningConfig, ALGO_CONFIGS[algo], CEMConfig if algo == "qtopt" else None):
        if cls is not None:
            docs.update(field_docs(cls))
    return docs


def with_overrides(config: TrainConfig, overrides: dict[str, Any]) -> TrainConfig:
    """A copy of ``config`` with settings replaced by name (``{"n_bits": 30, "lr": 1e-3}``).

    Names are those of :func:`leaf_fields` for the resulting ``algo``: ``lr`` is the learning rate
    of whichever algorithm the run uses.
    """
    algo = overrides.get("algo", config.algo)
    if algo not in ALGO_CONFIGS:
        raise ConfigError("algo", f"unknown algo {algo!r}; allowed: {', '.join(ALGOS)}")
    paths = {path[-1]: path for path, _, _ in leaf_fields(algo)}
    unknown = sorted(set(overrides) - set(paths))
    if unknown:
        raise ConfigError(unknown[0], f"unknown setting for algo {algo!r}; allowed: {', '.join(sorted(paths))}")
    data = to_dict(config)
    for name, value in overrides.items():
        node = data
        *parents, leaf = paths[name]
        for p in parents:
            node = node[p]
        node[leaf] = list(value) if isinstance(value, tuple) else value
    return from_dict(data)


def to_dict(config: TrainConfig) -> dict[str, Any]:
    return dataclasses.asdict(config)


def _build(cls: type, data: dict[str, Any], where: str) -> Any:
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(unknown[0], f"unknown setting in {where}; allowed: {', '.join(sorted(names))}")
    kwargs = {}
    for name, value in data.items():
        tp = hints[name]
        if dataclasses.is_dataclass(tp):
            value = _build(tp, value, f"{where}.{name}")
        elif typing.get_origin(tp) is tuple:
            value = tuple(value)
        kwargs[name] = value
    return cls(**kwargs)


def from_dict(data: dict[str, Any]) -> TrainConfig:
    """Rebuild a config from :func:`to_dict` output (e.g. a run's ``config.json``)."""
    return _build(TrainConfig, data, "config")


def save(config: TrainConfig, path: Path) -> None:
    Path(path).write_text(json.dumps(to_dict(config), indent=2) + "\n")


def load(path: Path) -> TrainConfig:
    return from_dict(json.loads(Path(path).read_text()))
