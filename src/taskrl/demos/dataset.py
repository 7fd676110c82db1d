"""Demonstration datasets in Minari's format, and the tensors behaviour cloning trains on.

A dataset folder ``DIR`` holds one Minari dataset in ``DIR/data`` (``metadata.json`` and
``main_data.hdf5``, what ``minari.MinariDataset(DIR/data)`` reads), written by
`write_dataset`:

- observations ``{"observation": Box, "task": Discrete(T)}`` (the task index into the dataset's
  own task list), and ``"image"`` (uint8 ``[H, W, 3]``) where the env has a camera; actions a ``Box``;
  each episode's metadata names its ``task``;
- the dataset's metadata adds ``tasks`` (``[{"name", "description"}, ...]``, in index order) and
  ``card`` (how it was made: source, episodes and expert success per task, seed, action noise).

`read_demonstrations` reads any Minari dataset whose episodes say their task (episode metadata
``task``, or a ``task`` observation key with the dataset's ``tasks`` list) into a
`Demonstrations`: flat tensors of every step, with episode boundaries and task indices.
Only HDF5 and JSON are read: loading a dataset never executes code.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from taskrl.errors import ConfigError

__all__ = [
    "DATA_FOLDER",
    "Demonstrations",
    "Episode",
    "check_new_dataset_folder",
    "dataset_card",
    "read_demonstrations",
    "write_dataset",
]

DATA_FOLDER = "data"  # DIR/data is the Minari dataset (its own layout: metadata.json, main_data.hdf5)
METADATA_FILE = "metadata.json"
DATASET_VERSION = 1


@dataclasses.dataclass
class Episode:
    """One recorded demonstration.

    Attributes:
        task: the task's name.
        observations: ``[T + 1, D]`` states, the last one after the final action.
        actions: ``[T, A]`` the expert's actions (the labels, also where noise was added to what ran).
        rewards: ``[T]`` the environment's rewards.
        success: ``[T]`` the environment's success flag after each step.
        terminated: whether the last step ended the episode (a success where collection stops there).
        images: ``[T + 1, H, W, 3]`` uint8 camera pictures of the same steps (None without a camera).
    """

    task: str
    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    success: np.ndarray
    terminated: bool
    images: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.actions.shape[0])


def _minari():
    try:
        from minari.data_collector.episode_buffer import EpisodeBuffer
        from minari.dataset.minari_storage import MinariStorage
    except ImportError as error:
        raise ConfigError(
            "dataset",
            f"demonstration datasets need the `imitation` extra (minari, h5py): pip install 'taskrl[imitation]' ({error})",
        ) from None
    return MinariStorage, EpisodeBuffer


def check_new_dataset_folder(out: str | Path) -> Path:
    """``out`` as a folder a new dataset can be written to: a `ConfigError` on ``out`` where it is a file or
    already holds a dataset."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError("out", f"{out} is a file, not a folder; choose another --out")
    if (out / DATA_FOLDER).exists():
        raise ConfigError("out", f"{out} already holds a dataset (see: taskrl demos info {out}); choose another --out")
    return out


def write_dataset(
    out: str | Path,
    episodes: Sequence[Episode],
    tasks: Sequence[tuple[str, str]],
    action_space: gym.spaces.Box,
    card: dict[str, Any],
    dataset_id: str = "taskrl/demos-v0",
) -> Path:
    """Write ``episodes`` as a Minari dataset in ``out/data`` (atomically: a reader sees no dataset or all of it).

    Args:
        out: the dataset folder.
        episodes: the demonstrations, any order.
        tasks: ``(name, description)`` of every task, in index order.
        action_space: the actions' box.
        card: what the dataset card says (saved in the metadata).
        dataset_id: Minari's id of the dataset.
    """
    MinariStorage, EpisodeBuffer = _minari()
    out = Path(out).resolve()  # Minari joins relative paths twice
    names = [name for name, _ in tasks]
    index = {name: i for i, name in enumerate(names)}
    dim = int(episodes[0].observations.shape[1]) if episodes else 0
    pictures = bool(episodes) and episodes[0].images is not None
    spaces = {
        "observation": gym.spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float32),
        "task": gym.spaces.Discrete(len(names)),
    }
    if pictures:
        spaces["image"] = gym.spaces.Box(0, 255, shape=episodes[0].images.shape[1:], dtype=np.uint8)
    observation_space = gym.spaces.Dict(spaces)
    out.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".data-", dir=out))
    umask = os.umask(0)
    os.umask(umask)
    staging.chmod(0o777 & ~umask)  # mkdtemp makes it private; a dataset is read like any folder the user makes
    try:
        # pictures stored exactly: Minari's default JPEG would smear the few pixels a small camera gives an object
        storage = MinariStorage.new(staging, observation_space, action_space, data_format="hdf5", jpeg_encoding=False)
        buffers = [
            EpisodeBuffer(
                id=i,
                observations={
                    "observation": e.observations.astype(np.float32),
                    "task": np.full(len(e) + 1, index[e.task], dtype=np.int64),
                    **({"image": e.images.astype(np.uint8)} if pictures else {}),
                },
                actions=e.actions.astype(np.float32),
                rewards=[float(r) for r in e.rewards],
                terminations=[False] * (len(e) - 1) + [bool(e.terminated)],
                truncations=[False] * (len(e) - 1) + [not e.terminated],
                infos={"success": e.success.astype(bool)},
            )
            for i, e in enumerate(episodes)
        ]
        storage.update_episodes(buffers)
        storage.update_episode_metadata([{"task": e.task} for e in episodes], list(range(len(episodes))))
        storage.update_metadata(
            {
                "dataset_id": dataset_id,
                "minari_version": _minari_version(),
                "tasks": [{"name": n, "description": d} for n, d in tasks],
                "card": card,
                "taskrl_dataset_version": DATASET_VERSION,
            }
        )
        for path in staging.iterdir():
            _fsync(path)
        final = out / DATA_FOLDER
        if final.exists():
            shutil.rmtree(final)
        os.replace(staging, final)
        _fsync(out)
        return final
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def _minari_version() -> str:
    import minari

    return str(minari.__version__)


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _data_path(path: str | Path) -> Path:
    """``DIR/data`` of a dataset folder, or the Minari data folder itself."""
    path = Path(path)
    if (path / DATA_FOLDER / METADATA_FILE).is_file():
        return path / DATA_FOLDER
    if (path / METADATA_FILE).is_file():
        return path
    raise ConfigError(
        "dataset", f"{path} holds no dataset (no {DATA_FOLDER}/{METADATA_FILE}); make one with: taskrl demos collect"
    )


def dataset_card(path: str | Path) -> dict[str, Any]:
    """The metadata of a dataset folder (its ``tasks``, ``card``, ``total_episodes``, ``total_steps``), read from JSON only."""
    data = _data_path(path)
    try:
        metadata = json.loads((data / METADATA_FILE).read_text())
    except (OSError, ValueError) as error:
        raise ConfigError("dataset", f"cannot read {data / METADATA_FILE}: {error}") from None
    if not isinstance(metadata, dict):
        raise ConfigError("dataset", f"{data / METADATA_FILE} is not a JSON object")
    return metadata


@dataclasses.dataclass
class Demonstrations:
    """Every step of a dataset as flat tensors, episode by episode.

    Attributes:
        observations: ``[N, D]`` the state at each step (the final states after each episode's last
            action are in ``final_observations``).
        actions: ``[N, A]`` the expert's actions.
        tasks: ``[N]`` task index of each step (into ``task_names``).
        starts: ``[E]`` row of each episode's first step.
        lengths: ``[E]`` steps of each episode.
        episode_tasks: ``[E]`` task index of each episode.
        task_names, descriptions: the tasks, in index order.
        card: the dataset card (``{}`` for a dataset not made by taskrl).
        images: ``[N, H, W, 3]`` uint8 camera pictures of the same steps (None: the dataset has none).
    """

    observations: torch.Tensor
    actions: torch.Tensor
    tasks: torch.Tensor
    starts: torch.Tensor
    lengths: torch.Tensor
    episode_tasks: torch.Tensor
    task_names: tuple[str, ...]
    descriptions: tuple[str, ...]
    card: dict[str, Any] = dataclasses.field(default_factory=dict)
    images: torch.Tensor | None = None

    @property
    def num_steps(self) -> int:
        return int(self.actions.shape[0])

    @property
    def num_episodes(self) -> int:
        return int(self.starts.shape[0])

    def to(self, device: str | torch.device) -> Demonstrations:
        moved = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for name, value in moved.items():
            if isinstance(value, torch.Tensor):
                moved[name] = value.to(device)
        return Demonstrations(**moved)

    def as_seen_under(self, env_settings: Any) -> Demonstrations:
        """The demonstrations as a policy sees them under ``env_settings``: their ``policy_observation``
        applied to every observation (the goal hidden by ML45's protocol, say); unchanged when the settings have none."""
        view = getattr(env_settings, "policy_observation", None)
        return self if view is None else dataclasses.replace(self, observations=view(self.observations))

    def episode(self, e: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``(observations [T, D], actions [T, A])`` of episode ``e``."""
        s, n = int(self.starts[e]), int(self.lengths[e])
        return self.observations[s : s + n], self.actions[s : s + n]

    def _keep_tasks(self, remap: torch.Tensor) -> Demonstrations:
        """The episodes of the tasks ``remap`` sends to an index >= 0, their tasks renumbered by it."""
        remap = remap.to(self.tasks.device)
        keep_episode, keep_step = remap[self.episode_tasks] >= 0, remap[self.tasks] >= 0
        lengths = self.lengths[keep_episode]
        return dataclasses.replace(
            self,
            observations=self.observations[keep_step],
            images=None if self.images is None else self.images[keep_step],
            actions=self.actions[keep_step],
            tasks=remap[self.tasks[keep_step]],
            starts=torch.cumsum(lengths, 0) - lengths,
            lengths=lengths,
            episode_tasks=remap[self.episode_tasks[keep_episode]],
        )

    def without_tasks(self, names: Sequence[str]) -> Demonstrations:
        """The episodes of every other task, task indices unchanged (held-out tasks left out of training)."""
        return self._keep_tasks(torch.tensor([-1 if n in names else i for i, n in enumerate(self.task_names)]))

    def select_tasks(self, names: Sequence[str], setting: str = "dataset") -> Demonstrations:
        """The episodes of ``names`` only, re-indexed so task ``i`` is ``names[i]`` (an env's task order).

        A `ConfigError` on ``setting`` names the tasks the dataset lacks.
        """
        missing = [n for n in names if n not in self.task_names]
        if missing:
            raise ConfigError(
                setting, f"the dataset has no demonstrations of {', '.join(missing)}; it holds {', '.join(self.task_names)}"
            )
        old = {n: i for i, n in enumerate(self.task_names)}
        remap = torch.full((len(self.task_names),), -1, dtype=torch.long)
        for i, n in enumerate(names):
            remap[old[n]] = i
        picked = self._keep_tasks(remap)
        return dataclasses.replace(picked, task_names=tuple(names), descriptions=tuple(self.descriptions[old[n]] for n in names))


def _read_episodes(path: str | Path) -> tuple[dict[str, Any], list[Episode], dict[str, str]]:
    """``(metadata, episodes, {task: description})`` of a Minari dataset, tasks in index order."""
    data = _data_path(path).resolve()
    metadata = dataset_card(data)
    MinariStorage, _ = _minari()
    try:
        storage = MinariStorage.read(data)
        total = storage.total_episodes
        raw = list(storage.get_episodes(range(total)))
        episode_meta = list(storage.get_episode_metadata(range(total)))
    except Exception as error:  # a damaged or foreign file is one line, not a traceback from h5py
        raise ConfigError("dataset", f"cannot read the dataset in {data}: {error}") from None
    if not raw:
        raise ConfigError("dataset", f"the dataset in {data} has no episodes")
    listed = metadata.get("tasks") or []
    names = [str(t["name"]) for t in listed if isinstance(t, dict) and "name" in t]
    descriptions = {str(t["name"]): str(t.get("description") or t["name"]) for t in listed if isinstance(t, dict) and "name" in t}
    episodes = []
    for ep, meta in zip(raw, episode_meta):
        obs = ep["observations"]
        states = obs["observation"] if isinstance(obs, dict) else obs
        task_name = meta.get("task")
        if task_name is None and isinstance(obs, dict) and "task" in obs and names:
            task_name = names[int(np.asarray(obs["task"])[0])]
        if task_name is None:
            raise ConfigError("dataset", f"episode {meta.get('id')} of {data} does not say its task (episode metadata 'task')")
        task_name = str(task_name)
        descriptions.setdefault(task_name, task_name)
        actions = np.asarray(ep["actions"], dtype=np.float32)
        n = actions.shape[0]
        images = obs.get("image") if isinstance(obs, dict) else None
        actions = actions.reshape(n, -1)
        success = (ep.get("infos") or {}).get("success")
        terminations = np.asarray(ep.get("terminations", np.zeros(n, bool)))
        episodes.append(
            Episode(
                task_name,
                np.asarray(states, dtype=np.float32).reshape(n + 1, -1),
                actions,
                np.asarray(ep.get("rewards", np.zeros(n)), dtype=np.float32).reshape(n),
                np.zeros(n, bool) if success is None else np.asarray(success, dtype=bool).reshape(n),
                bool(terminations[-1]) if n else False,
                None if images is None else np.asarray(images, dtype=np.uint8),
            )
        )
    return metadata, episodes, descriptions


def read_episodes(path: str | Path) -> list[Episode]:
    """Every episode of a Minari dataset as `Episode` records (final states included)."""
    return _read_episodes(path)[1]


def read_demonstrations(path: str | Path, device: str | torch.device = "cpu") -> Demonstrations:
    """Every episode of a Minari dataset (a folder written by ``taskrl demos collect``, or any Minari
    data folder whose episodes carry a ``task`` in their metadata or observations)."""
    metadata, episodes, descriptions = _read_episodes(path)
    names = list(descriptions)
    obs_rows, act_rows, task_rows, episode_tasks, lengths, image_rows = [], [], [], [], [], []
    for episode in episodes:
        n = len(episode)
        obs_rows.append(episode.observations[:n])
        if episode.images is not None:
            image_rows.append(episode.images[:n])
        act_rows.append(episode.actions)
        episode_tasks.append(names.index(episode.task))
        task_rows.append(np.full(n, episode_tasks[-1], dtype=np.int64))
        lengths.append(n)
    lengths_t = torch.tensor(lengths, dtype=torch.long)
    demos = Demonstrations(
        torch.from_numpy(np.concatenate(obs_rows)),
        torch.from_numpy(np.concatenate(act_rows)),
        torch.from_numpy(np.concatenate(task_rows)),
        torch.cumsum(lengths_t, 0) - lengths_t,
        lengths_t,
        torch.tensor(episode_tasks, dtype=torch.long),
        tuple(names),
        tuple(descriptions[n] for n in names),
        metadata.get("card") if isinstance(metadata.get("card"), dict) else {},
        torch.from_numpy(np.concatenate(image_rows)) if image_rows and len(image_rows) == len(episodes) else None,
    )
    return demos.to(device)
