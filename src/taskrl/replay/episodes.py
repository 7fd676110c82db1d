"""Whole episodes laid flat, and the staging where running episodes wait until they end.

`Episodes` is how episodes travel (from a collector to the trainer's replay, from a dataset into
the replay, into a checkpoint): the observations of every episode one after another, ``length + 1``
each (observation ``t + 1`` is the next observation of step ``t``, so next states are never stored
twice), and the steps one after another, ``length`` each. No padding, no declared horizon.

`EpisodeStaging` holds the running episode of every env copy. Its rows grow on demand
(doubling), so an env that ends its own episodes needs no declared ``max_episode_steps``; a bound
(``max_length``, the replay's capacity) turns an episode that could never be stored into one error
naming ``buffer_size``.
"""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import torch

from taskrl.errors import ConfigError
from taskrl.types import Obs

__all__ = ["STEP_KEYS", "EpisodeRecorder", "EpisodeStaging", "Episodes", "space_dtype"]

#: the per-step tables (observations are per key, under ``obs``)
STEP_KEYS = ("action", "reward", "terminated", "truncated")
#: the length a staging row starts with when the env declares no horizon (it doubles when reached)
INITIAL_STAGING_LENGTH = 64


def space_dtype(space: gym.spaces.Space) -> torch.dtype:
    """The torch dtype of a gymnasium space's values (bits stay int8, images uint8)."""
    return torch.from_numpy(np.zeros((), dtype=space.dtype)).dtype


def step_dtypes(action_space: gym.spaces.Space) -> dict[str, torch.dtype]:
    return {"action": space_dtype(action_space), "reward": torch.float32, "terminated": torch.bool, "truncated": torch.bool}


@dataclasses.dataclass
class Episodes:
    """Complete episodes, flat: episode ``i`` has ``lengths[i]`` steps and ``lengths[i] + 1`` observations.

    Attributes:
        obs: per observation key, ``[sum(lengths + 1), ...]``: each episode's observations in order, its
            final observation last (a truncated episode keeps the one it was cut at).
        action, reward, terminated, truncated: ``[sum(lengths), ...]``.
        lengths: ``[n]`` steps of each episode (each at least 1).
    """

    obs: Obs
    action: torch.Tensor
    reward: torch.Tensor
    terminated: torch.Tensor
    truncated: torch.Tensor
    lengths: torch.Tensor

    @property
    def num_episodes(self) -> int:
        return int(self.lengths.numel())

    @property
    def num_transitions(self) -> int:
        return int(self.reward.shape[0])

    def newest(self, count: int) -> Episodes:
        """The last ``count`` episodes."""
        count = max(0, min(count, self.num_episodes))
        if count == self.num_episodes:
            return self
        steps = int(self.lengths[self.num_episodes - count :].sum())
        obs_rows = steps + count
        return Episodes(
            obs={k: v[v.shape[0] - obs_rows :] for k, v in self.obs.items()},
            **{k: getattr(self, k)[self.num_transitions - steps :] for k in STEP_KEYS},
            lengths=self.lengths[self.num_episodes - count :],
        )

    def to(self, device: str | torch.device) -> Episodes:
        return Episodes(
            obs={k: v.to(device) for k, v in self.obs.items()},
            **{k: getattr(self, k).to(device) for k in STEP_KEYS},
            lengths=self.lengths.to(device),
        )

    @classmethod
    def cat(cls, parts: list[Episodes]) -> Episodes:
        """One `Episodes` of ``parts`` in order (at least one part)."""
        if len(parts) == 1:
            return parts[0]
        return cls(
            obs={k: torch.cat([p.obs[k] for p in parts]) for k in parts[0].obs},
            **{k: torch.cat([getattr(p, k) for p in parts]) for k in STEP_KEYS},
            lengths=torch.cat([p.lengths for p in parts]),
        )

    @classmethod
    def empty(
        cls, observation_space: gym.spaces.Dict, action_space: gym.spaces.Space, device: str | torch.device = "cpu"
    ) -> Episodes:
        """No episode, with the tables of these spaces."""
        return cls(
            obs={k: torch.zeros((0, *s.shape), dtype=space_dtype(s), device=device) for k, s in observation_space.spaces.items()},
            **{
                k: torch.zeros((0, *(action_space.shape if k == "action" else ())), dtype=d, device=device)
                for k, d in step_dtypes(action_space).items()
            },
            lengths=torch.zeros(0, dtype=torch.long, device=device),
        )


class EpisodeStaging:
    """The running episode of each of ``num_envs`` env copies, handed out whole when it ends.

    Args:
        observation_space: the single-env gymnasium ``Dict`` observation space.
        action_space: the single-env action space.
        num_envs: env copies stepped together.
        device: where the rows live.
        initial_length: steps a row holds at first (the env's horizon where it declares one); rows
            double when an episode reaches it.
        max_length: the longest episode accepted (the replay's capacity: a longer one could never be
            stored); None for no bound.
    """

    def __init__(
        self,
        observation_space: gym.spaces.Dict,
        action_space: gym.spaces.Space,
        num_envs: int,
        device: str | torch.device = "cpu",
        initial_length: int | None = None,
        max_length: int | None = None,
    ) -> None:
        self.observation_space, self.action_space = observation_space, action_space
        self.num_envs, self.device, self.max_length = num_envs, torch.device(device), max_length
        length = initial_length if initial_length else INITIAL_STAGING_LENGTH
        self.rows_length = max(1, min(length, max_length) if max_length else length)
        self.obs_keys = list(observation_space.spaces)
        self.obs = {k: self._alloc(self.rows_length + 1, s.shape, space_dtype(s)) for k, s in observation_space.spaces.items()}
        self.steps = {
            k: self._alloc(self.rows_length, action_space.shape if k == "action" else (), d)
            for k, d in step_dtypes(action_space).items()
        }
        self.t = np.zeros(num_envs, dtype=np.int64)  # steps so far of each running episode (host copy)
        self._t = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        self._envs = torch.arange(num_envs, device=self.device)

    def _alloc(self, steps: int, shape: tuple, dtype: torch.dtype) -> torch.Tensor:
        return torch.zeros((self.num_envs, steps, *shape), dtype=dtype, device=self.device)

    def _grow(self) -> None:
        """Double the rows (up to ``max_length``): a running episode reached their end."""
        longest = int(self.t.max()) + 1
        if self.max_length is not None and longest > self.max_length:
            raise ConfigError(
                "buffer_size",
                f"an episode ran past {self.max_length:,} steps, more than the replay holds; "
                f"raise --buffer-size above the longest episode (or give the env a time limit)",
            )
        new_length = max(2 * self.rows_length, longest)
        if self.max_length is not None:
            new_length = min(new_length, self.max_length)
        grow = new_length - self.rows_length

        def padded(table: torch.Tensor) -> torch.Tensor:
            pad = torch.zeros((self.num_envs, grow, *table.shape[2:]), dtype=table.dtype, device=self.device)
            return torch.cat([table, pad], 1)

        self.obs = {k: padded(v) for k, v in self.obs.items()}
        self.steps = {k: padded(v) for k, v in self.steps.items()}
        self.rows_length = new_length

    def start(self, obs: Obs) -> None:
        """Begin an episode in every env copy from its first observation."""
        for k in self.obs_keys:
            self.obs[k][:, 0] = obs[k]
        self.t[:] = 0
        self._t.zero_()

    def add(
        self,
        action: torch.Tensor,
        reward: torch.Tensor,
        terminated: torch.Tensor,
        truncated: torch.Tensor,
        next_obs: Obs,
        reset_obs: Obs,
    ) -> Episodes | None:
        """Append one step of every env copy; the episodes that ended with it (None if none did).

        ``next_obs`` is the observation the step led to (the final observation where an episode
        ended); ``reset_obs`` is what the environment returned, whose rows start the next episode
        where one ended.
        """
        if self.t.max() >= self.rows_length:
            self._grow()
        envs, t = self._envs, self._t
        self.steps["action"][envs, t] = action.to(self.steps["action"].dtype)
        self.steps["reward"][envs, t] = reward.to(torch.float32)
        self.steps["terminated"][envs, t] = terminated
        self.steps["truncated"][envs, t] = truncated
        for k in self.obs_keys:
            self.obs[k][envs, t + 1] = next_obs[k]
        self._t += 1
        self.t += 1
        done = (terminated | truncated).cpu().numpy()
        if not done.any():
            return None
        ids = np.flatnonzero(done)
        episodes = self._take(ids)
        index = torch.as_tensor(ids, device=self.device)
        for k in self.obs_keys:
            self.obs[k][index, 0] = reset_obs[k][index]
        self.t[ids] = 0
        self._t[index] = 0
        return episodes

    def cut_running(self) -> Episodes | None:
        """The episodes still running, ended at their last step and ``truncated`` there (their future is
        unknown, so values bootstrap, as at a time limit); None if none has a step. Their rows restart
        empty from their last observation."""
        ids = np.flatnonzero(self.t > 0)
        if ids.size == 0:
            return None
        index = torch.as_tensor(ids, device=self.device)
        self.steps["truncated"][index, torch.as_tensor(self.t[ids] - 1, device=self.device)] = True
        episodes = self._take(ids)
        last = torch.as_tensor(self.t[ids], device=self.device)
        for k in self.obs_keys:
            self.obs[k][index, 0] = self.obs[k][index, last]
        self.t[ids] = 0
        self._t[index] = 0
        return episodes

    def _take(self, ids: np.ndarray) -> Episodes:
        """The staged episodes of env copies ``ids``, flat."""
        index = torch.as_tensor(ids, device=self.device)
        lengths = torch.as_tensor(self.t[ids], device=self.device)
        columns = torch.arange(self.rows_length + 1, device=self.device)
        obs_mask = columns[None] <= lengths[:, None]  # [n, rows + 1]: observations 0..length
        step_mask = columns[None, :-1] < lengths[:, None]  # [n, rows]: steps 0..length - 1
        return Episodes(
            obs={k: v[index][obs_mask] for k, v in self.obs.items()},
            **{k: v[index][step_mask] for k, v in self.steps.items()},
            lengths=lengths,
        )


class EpisodeRecorder:
    """Records the episodes of ``num_envs`` env copies and hands the finished ones out together
    (`drain`): what a collector sends to the replay of a trainer, or a dataset is made of.

    Args:
        observation_space, action_space, num_envs, device: as `EpisodeStaging`'s.
        horizon: the env's longest episode where it declares one (the staging rows' first length).
    """

    def __init__(
        self,
        observation_space: gym.spaces.Dict,
        action_space: gym.spaces.Space,
        num_envs: int,
        device: str | torch.device = "cpu",
        horizon: int | None = None,
    ) -> None:
        self.staging = EpisodeStaging(observation_space, action_space, num_envs, device, initial_length=horizon)
        self._finished: list[Episodes] = []
        self.episodes_added = 0

    def start(self, obs: Obs) -> None:
        self.staging.start(obs)

    def add(self, *step) -> None:
        """One step of every env copy (`EpisodeStaging.add`'s arguments)."""
        self._keep(self.staging.add(*step))

    @property
    def running_steps(self) -> int:
        """Steps of the episodes still running (not yet finished, so not yet drained)."""
        return int(self.staging.t.sum())

    def cut_running(self) -> int:
        """Record the running episodes as cut at their last step; how many there were."""
        episodes = self.staging.cut_running()
        self._keep(episodes)
        return 0 if episodes is None else episodes.num_episodes

    def _keep(self, episodes: Episodes | None) -> None:
        if episodes is not None:
            self._finished.append(episodes)
            self.episodes_added += episodes.num_episodes

    def drain(self) -> Episodes:
        """The episodes finished since the last drain (possibly none)."""
        st = self.staging
        if not self._finished:
            return Episodes.empty(st.observation_space, st.action_space, st.device)
        episodes, self._finished = Episodes.cat(self._finished), []
        return episodes
