"""Device-resident episode storage.

Layout: one preallocated tensor per key, ``[max_episodes, horizon + 1, ...]`` for observations
(index ``t + 1`` is the next observation of step ``t``, so next states are never stored twice) and
``[max_episodes, horizon, ...]`` for actions, rewards and flags. Each parallel environment writes
its running episode into a staging row; the episode is committed to the ring of stored episodes
only when it ends. Hence every sampleable transition belongs to a complete episode: hindsight
goals never come from a future that does not exist yet, and an overwrite replaces whole episodes.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from taskrl.replay.batch import Batch, Obs


def _space_dtype(space: gym.spaces.Space) -> torch.dtype:
    return torch.from_numpy(np.zeros((), dtype=space.dtype)).dtype


def draw_transitions(
    cumulative: torch.Tensor, lengths: torch.Tensor, n: int, generator: torch.Generator | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(row, step)`` of ``n`` transitions uniform over a run of episodes with these ``lengths`` and their
    ``cumulative`` sums (non-empty in total)."""
    total = cumulative[-1]
    u = (torch.rand(n, generator=generator, device=cumulative.device) * total).long().clamp_(max=total - 1)
    row = torch.searchsorted(cumulative, u, right=True)
    return row, u - (cumulative.index_select(0, row) - lengths.index_select(0, row))


class EpisodeReplay:
    """Ring buffer of complete episodes with uniform sampling over stored transitions.

    Args:
        observation_space: the single-env gymnasium ``Dict`` observation space; each key is
            stored in the space's dtype (bits as int8, not float32).
        action_space: the single-env action space.
        capacity: number of transitions to hold (rounded down to whole episodes of ``horizon``).
        horizon: the longest episode the environment produces.
        num_envs: parallel environments writing at once.
        device: where the storage lives (the device of the learner).
    """

    @staticmethod
    def bytes_needed(
        observation_space: gym.spaces.Dict, action_space: gym.spaces.Space, capacity: int, horizon: int, num_envs: int
    ) -> int:
        """Memory the storage will take (episodes of ``horizon + 1`` observations and ``horizon`` steps)."""
        rows = capacity // horizon + num_envs  # stored episodes plus the staging rows

        def size(shape: tuple, dtype: torch.dtype) -> int:
            return int(np.prod(shape, dtype=np.int64)) * torch.empty((), dtype=dtype).element_size()

        per_row = sum((horizon + 1) * size(s.shape, _space_dtype(s)) for s in observation_space.spaces.values())
        per_row += horizon * (size(action_space.shape, _space_dtype(action_space)) + 4 + 1 + 1)  # reward, flags
        return rows * per_row

    def __init__(
        self,
        observation_space: gym.spaces.Dict,
        action_space: gym.spaces.Space,
        capacity: int,
        horizon: int,
        num_envs: int,
        device: str | torch.device = "cpu",
    ) -> None:
        self.device = torch.device(device)
        self.horizon = horizon
        self.num_envs = num_envs
        self.max_episodes = capacity // horizon
        if self.max_episodes < 2 * num_envs:
            raise ValueError(
                f"buffer_size={capacity} holds {self.max_episodes} episodes of horizon {horizon}; "
                f"it must hold at least 2 * num_envs = {2 * num_envs} episodes"
            )
        self.obs_keys = list(observation_space.spaces)
        h = horizon

        def alloc(rows: int, steps: int, shape: tuple, dtype: torch.dtype) -> torch.Tensor:
            return torch.zeros((rows, steps, *shape), dtype=dtype, device=self.device)

        def tables(rows: int) -> dict[str, torch.Tensor]:
            t = {f"obs/{k}": alloc(rows, h + 1, s.shape, _space_dtype(s)) for k, s in observation_space.spaces.items()}
            t["action"] = alloc(rows, h, action_space.shape, _space_dtype(action_space))
            t["reward"] = alloc(rows, h, (), torch.float32)
            t["terminated"] = alloc(rows, h, (), torch.bool)
            t["truncated"] = alloc(rows, h, (), torch.bool)
            return t

        self.storage = tables(self.max_episodes)
        self._flat = {k: v.view(-1, *v.shape[2:]) for k, v in self.storage.items()}  # the same memory, as rows
        self.staging = tables(num_envs)
        self.length = torch.zeros(self.max_episodes, dtype=torch.long, device=self.device)
        self.stage_t = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        self.next_slot = 0
        self.num_episodes = 0
        self.episodes_added = 0  # ever stored (never decreases; overwritten ones included)
        self._cumulative = torch.zeros(self.max_episodes, dtype=torch.long, device=self.device)
        self._env_ids = torch.arange(num_envs, device=self.device)

    # ---------------------------------------------------------------- writing
    def start(self, obs: Obs) -> None:
        """Begin an episode in every environment from its first observation."""
        for k in self.obs_keys:
            self.staging[f"obs/{k}"][:, 0] = obs[k]
        self.stage_t.zero_()

    def add(
        self,
        action: torch.Tensor,
        reward: torch.Tensor,
        terminated: torch.Tensor,
        truncated: torch.Tensor,
        next_obs: Obs,
        reset_obs: Obs,
    ) -> None:
        """Append one step of every environment.

        ``next_obs`` is the observation the step led to (the final observation where an episode
        ended); ``reset_obs`` is what the environment returned, whose rows start the next episode
        where one ended.
        """
        envs, t = self._env_ids, self.stage_t
        st = self.staging
        st["action"][envs, t] = action.to(st["action"].dtype)
        st["reward"][envs, t] = reward.float()
        st["terminated"][envs, t] = terminated
        st["truncated"][envs, t] = truncated
        for k in self.obs_keys:
            st[f"obs/{k}"][envs, t + 1] = next_obs[k]
        self.stage_t += 1
        done = terminated | truncated
        if bool((self.stage_t >= self.horizon).logical_and(~done).any()):
            raise RuntimeError(f"an episode ran past horizon={self.horizon} without being truncated")
        if bool(done.any()):
            ids = done.nonzero().squeeze(1)
            self._commit(ids)
            for k in self.obs_keys:
                st[f"obs/{k}"][ids, 0] = reset_obs[k][ids]
            self.stage_t[ids] = 0

    def cut_running(self) -> int:
        """Store the episodes still running as ended at their last step, ``truncated`` there (their
        future is unknown, so values bootstrap, as at a time limit): a run that stops keeps every
        transition it collected. Returns how many episodes were cut."""
        ids = (self.stage_t > 0).nonzero().squeeze(1)
        if ids.numel():
            self.staging["truncated"][ids, self.stage_t[ids] - 1] = True
            self._commit(ids)
            self.stage_t[ids] = 0
        return int(ids.numel())

    def _commit(self, env_ids: torch.Tensor) -> None:
        self.add_episodes({key: table[env_ids] for key, table in self.staging.items()}, self.stage_t[env_ids])

    def add_episodes(self, tables: dict[str, torch.Tensor], lengths: torch.Tensor) -> None:
        """Store whole episodes recorded elsewhere (a collector's :class:`EpisodeRecorder`): ``tables``
        has this replay's keys, ``[n, horizon + 1, ...]`` observations and ``[n, horizon, ...]`` steps."""
        n = int(lengths.numel())
        if n == 0:
            return
        if n > self.max_episodes:  # more than fit: the newest ones
            tables, lengths = {k: v[-self.max_episodes :] for k, v in tables.items()}, lengths[-self.max_episodes :]
            n = self.max_episodes
        slots = (self.next_slot + torch.arange(n, device=self.device)) % self.max_episodes
        for key, table in self.storage.items():
            table[slots] = tables[key].to(self.device, table.dtype)
        self.length[slots] = lengths.to(self.device)
        self.next_slot = (self.next_slot + n) % self.max_episodes
        self.num_episodes = min(self.num_episodes + n, self.max_episodes)
        self.episodes_added += n
        torch.cumsum(self.length, 0, out=self._cumulative)

    def recent_slots(self, count: int) -> torch.Tensor:
        """Slots of the ``count`` most recently stored episodes (fewer if fewer are stored), newest last."""
        count = min(count, self.num_episodes)
        return (torch.arange(-count, 0, device=self.device) + self.next_slot) % self.max_episodes

    # ---------------------------------------------------------------- reading
    @property
    def num_transitions(self) -> int:
        return int(self._cumulative[-1])

    def sample_indices(self, batch_size: int, generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Uniform over stored transitions: returns ``(episode, step)`` index tensors."""
        if self.num_episodes == 0:  # a count on the host: no device sync per batch
            raise RuntimeError("cannot sample from an empty replay: no episode has finished yet")
        return draw_transitions(self._cumulative, self.length, batch_size, generator)

    def gather(self, episode: torch.Tensor, step: torch.Tensor) -> Batch:
        """The transitions at ``(episode, step)``."""
        at_obs, at_step = episode * (self.horizon + 1) + step, episode * self.horizon + step
        rows = self._rows
        return Batch(
            obs={k: rows(f"obs/{k}", at_obs) for k in self.obs_keys},
            action=rows("action", at_step),
            reward=rows("reward", at_step),
            next_obs={k: rows(f"obs/{k}", at_obs + 1) for k in self.obs_keys},
            terminated=rows("terminated", at_step),
            truncated=rows("truncated", at_step),
            episode=episode,
            step=step,
        )

    def observation_at(self, key: str, episode: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
        """Observation ``index`` (0: the first; ``length``: the last) of key ``key`` in each ``episode``."""
        return self._rows(f"obs/{key}", episode * (self.horizon + 1) + index)

    def _rows(self, name: str, flat: torch.Tensor) -> torch.Tensor:
        """``storage[name][e, t]`` at flat positions ``e * steps + t``: one ``index_select`` on the table seen
        as rows: on CPU 0.62x the time of indexing it with two index tensors at a batch of 256, 0.89x at 32
        (``benchmarks/per_call_costs.py``)."""
        return self._flat[name].index_select(0, flat)

    def sample(self, batch_size: int, generator: torch.Generator | None = None) -> Batch:
        return self.gather(*self.sample_indices(batch_size, generator))

    # ---------------------------------------------------------------- checkpointing
    def state_dict(self) -> dict[str, torch.Tensor]:
        """Stored episodes only (a run stores its running ones first, :meth:`cut_running`)."""
        state = {f"storage/{k}": v for k, v in self.storage.items()}
        state["length"] = self.length
        state["counters"] = torch.tensor([self.next_slot, self.num_episodes, self.episodes_added])
        return state

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Restore stored episodes; a resumed run may have a different capacity, so the newest
        episodes that fit are kept, oldest first."""
        next_slot, num_episodes, *added = (int(x) for x in state["counters"])  # older checkpoints: no count added
        saved_max = state["length"].shape[0]
        order = (torch.arange(num_episodes) + (next_slot - num_episodes)) % saved_max  # oldest -> newest
        order = order[-self.max_episodes :].to(state["length"].device)
        keep = order.numel()
        for k, v in self.storage.items():
            v[:keep] = state[f"storage/{k}"][order].to(self.device)
        self.length.zero_()
        self.length[:keep] = state["length"][order].to(self.device)
        self.next_slot, self.num_episodes = keep % self.max_episodes, keep
        self.episodes_added = added[0] if added else num_episodes
        torch.cumsum(self.length, 0, out=self._cumulative)


class EpisodeRecorder(EpisodeReplay):
    """Records the episodes of ``num_envs`` environments and hands each finished one out whole
    (:meth:`drain`), instead of keeping them: what a collector sends to the replay of a trainer.

    Arguments as :class:`EpisodeReplay`'s, without a capacity (it stores nothing itself).
    """

    def __init__(
        self,
        observation_space: gym.spaces.Dict,
        action_space: gym.spaces.Space,
        horizon: int,
        num_envs: int,
        device: str | torch.device = "cpu",
    ) -> None:
        super().__init__(observation_space, action_space, 2 * num_envs * horizon, horizon, num_envs, device)
        self.storage, self._flat = {}, {}  # finished episodes go to _finished instead
        self._finished: list[tuple[dict[str, torch.Tensor], torch.Tensor]] = []

    def add_episodes(self, tables: dict[str, torch.Tensor], lengths: torch.Tensor) -> None:
        self._finished.append(({k: v.clone() for k, v in tables.items()}, lengths.clone()))
        self.episodes_added += int(lengths.numel())

    def drain(self) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        """``(tables, lengths)`` of the episodes finished since the last drain (``lengths`` may be empty)."""
        keys = list(self.staging)
        if not self._finished:
            return {k: self.staging[k][:0].clone() for k in keys}, self.stage_t[:0].clone()
        tables = {k: torch.cat([t[k] for t, _ in self._finished]) for k in keys}
        lengths = torch.cat([n for _, n in self._finished])
        self._finished = []
        return tables, lengths
