"""Device-resident episode replay whose capacity counts transitions, whatever the episode lengths.

Layout (three rings, oldest episodes evicted whole, first in first out):

- **steps**: ``[capacity]`` rows of action, reward, ``terminated``, ``truncated`` and the id of the
  episode each step belongs to. ``capacity`` is exactly ``--buffer-size`` transitions.
- **observations**: ``[capacity + episode_slots]`` rows per key, in the space's dtype (bits int8,
  images uint8). An episode of ``L`` steps takes ``L + 1`` consecutive rows: row ``t + 1`` is the next
  observation of step ``t``, so next observations are not stored twice, and a truncated episode keeps
  its final observation.
- **episodes**: ``[episode_slots]`` records of where an episode's steps and observations start and its
  length; an episode's id is its slot here (``Batch.episode``).

Running episodes wait in an [`EpisodeStaging`][taskrl.replay.episodes.EpisodeStaging] and are stored only when
they end, so every sampleable transition belongs to a complete episode (hindsight goals need a real
future) and no horizon is declared. ``episode_slots`` starts from the horizon where the env declares one
(else a guess) and doubles when more, shorter episodes are stored: the episode and observation rings are
then laid out anew, oldest first, and ids change (`EpisodeReplay.layout` counts these). Storing
never drops a transition while fewer than ``capacity`` are stored; past it, whole oldest episodes go and
are counted (`EpisodeReplay.evicted_transitions`).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from taskrl.errors import ConfigError
from taskrl.replay.batch import Batch, Obs
from taskrl.replay.episodes import INITIAL_STAGING_LENGTH, STEP_KEYS, Episodes, EpisodeStaging, space_dtype, step_dtypes

__all__ = ["EpisodeReplay", "draw_transitions"]

#: the episode length assumed for the first episode slots when the env declares no horizon
GUESSED_EPISODE_LENGTH = 16


def draw_transitions(
    cumulative: torch.Tensor, lengths: torch.Tensor, n: int, generator: torch.Generator | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(position, step)`` of ``n`` transitions uniform over a run of episodes with these ``lengths`` and
    their ``cumulative`` sums (non-empty in total): the episode's position in the run, and the step in it."""
    total = cumulative[-1]
    u = (torch.rand(n, generator=generator, device=cumulative.device) * total).long().clamp_(max=total - 1)
    row = torch.searchsorted(cumulative, u, right=True)
    return row, u - (cumulative.index_select(0, row) - lengths.index_select(0, row))


def ring_rows(first: torch.Tensor, counts: torch.Tensor, ring: int) -> torch.Tensor:
    """The rows of runs of ``counts[i]`` consecutive rows from ``first[i]`` in a ring of ``ring`` rows, run after run."""
    offsets = torch.cumsum(counts, 0) - counts
    within = torch.arange(int(counts.sum()), device=counts.device) - offsets.repeat_interleave(counts)
    return (first.repeat_interleave(counts) + within) % ring


def _size(shape: tuple, dtype: torch.dtype) -> int:
    return int(np.prod(shape, dtype=np.int64)) * torch.empty((), dtype=dtype).element_size()


class EpisodeReplay:
    """Complete episodes, ``capacity`` transitions at most, sampled uniformly over stored transitions.

    Args:
        observation_space: the single-env gymnasium ``Dict`` observation space; each key is stored in
            the space's dtype (bits as int8, images as uint8).
        action_space: the single-env action space.
        capacity: transitions to hold (``--buffer-size``), whatever the episode lengths.
        num_envs: env copies writing at once through `add` (their running episodes wait in staging).
        device: where the storage lives (the device of the learner).
        horizon: the env's longest episode where it declares one, else None: only a first guess of the
            episode slots and staging rows, which grow on demand.
    """

    def __init__(
        self,
        observation_space: gym.spaces.Dict,
        action_space: gym.spaces.Space,
        capacity: int,
        *,
        num_envs: int = 1,
        device: str | torch.device = "cpu",
        horizon: int | None = None,
    ) -> None:
        if capacity < 1:
            raise ConfigError("buffer_size", f"the replay must hold at least 1 transition (got {capacity})")
        self.observation_space, self.action_space = observation_space, action_space
        self.device = torch.device(device)
        self.capacity, self.num_envs, self.horizon = int(capacity), int(num_envs), horizon
        self.obs_keys = list(observation_space.spaces)
        self.steps = {
            k: torch.zeros((self.capacity, *(action_space.shape if k == "action" else ())), dtype=d, device=self.device)
            for k, d in step_dtypes(action_space).items()
        }
        self.step_episode = torch.zeros(self.capacity, dtype=torch.long, device=self.device)
        self.episode_slots = 0
        self._allocate_episodes(self.first_episode_slots(self.capacity, num_envs, horizon))
        # ring positions (host integers: no device sync to sample or store)
        self._step_tail = self._step_count = 0
        self._obs_tail = self._obs_count = 0
        self._episode_tail = self.num_episodes = 0
        self.episodes_added = 0  # ever stored, evicted ones included
        self.transitions_added = 0
        self.evicted_episodes = 0
        self.evicted_transitions = 0
        self.version = 0  # changes whenever the stored episodes do (samplers cache per version)
        self.layout = 0  # changes whenever episode ids do (the episode slots grew)
        self._staging: EpisodeStaging | None = None

    # ---------------------------------------------------------------- sizes
    @staticmethod
    def first_episode_slots(capacity: int, num_envs: int, horizon: int | None) -> int:
        """Episode slots allocated at first: enough for episodes of ``horizon`` (or a guessed length)."""
        return max(1, min(capacity, capacity // (horizon or GUESSED_EPISODE_LENGTH) + num_envs + 1))

    @staticmethod
    def bytes_needed(
        observation_space: gym.spaces.Dict,
        action_space: gym.spaces.Space,
        capacity: int,
        *,
        num_envs: int = 1,
        horizon: int | None = None,
    ) -> int:
        """Memory the storage takes when allocated (its staging and episode slots grow with shorter or
        longer episodes than ``horizon``; each added episode slot costs one observation and 24 bytes)."""
        slots = EpisodeReplay.first_episode_slots(capacity, num_envs, horizon)
        obs = sum(_size(s.shape, space_dtype(s)) for s in observation_space.spaces.values())
        step = _size(action_space.shape, space_dtype(action_space)) + 4 + 1 + 1
        rows = min(horizon or INITIAL_STAGING_LENGTH, capacity)
        staging = num_envs * ((rows + 1) * obs + rows * step)
        return capacity * (step + 8 + obs) + slots * (obs + 24) + staging  # 8: each step's episode id

    def _allocate_episodes(self, slots: int) -> None:
        self.episode_slots = slots
        self.obs_rows = self.capacity + slots  # transitions + one final observation per episode
        self.obs = {
            k: torch.zeros((self.obs_rows, *s.shape), dtype=space_dtype(s), device=self.device)
            for k, s in self.observation_space.spaces.items()
        }
        self.episode_step_start = torch.zeros(slots, dtype=torch.long, device=self.device)
        self.episode_obs_start = torch.zeros(slots, dtype=torch.long, device=self.device)
        self.length = torch.zeros(slots, dtype=torch.long, device=self.device)  # 0: no episode in the slot
        self._host_length = np.zeros(slots, dtype=np.int64)

    @property
    def num_transitions(self) -> int:
        return self._step_count

    def stored_episodes(self) -> torch.Tensor:
        """Ids of the stored episodes, oldest first."""
        return (torch.arange(self.num_episodes, device=self.device) + self._episode_tail) % self.episode_slots

    def newest_episodes(self, count: int) -> torch.Tensor:
        """Ids of the ``count`` most recently stored episodes (fewer if fewer are stored), newest last."""
        count = min(count, self.num_episodes)
        head = self._episode_tail + self.num_episodes
        return (torch.arange(head - count, head, device=self.device)) % self.episode_slots

    # ---------------------------------------------------------------- writing
    def start(self, obs: Obs) -> None:
        """Begin an episode in every env copy from its first observation."""
        if self._staging is None:
            num_envs = next(iter(obs.values())).shape[0]
            self._staging = EpisodeStaging(
                self.observation_space, self.action_space, num_envs, self.device, self.horizon, self.capacity
            )
        self._staging.start(obs)

    def add(
        self,
        action: torch.Tensor,
        reward: torch.Tensor,
        terminated: torch.Tensor,
        truncated: torch.Tensor,
        next_obs: Obs,
        reset_obs: Obs,
    ) -> None:
        """Append one step of every env copy (as `EpisodeStaging.add`); the episodes it ended are stored."""
        episodes = self._staging.add(action, reward, terminated, truncated, next_obs, reset_obs)
        if episodes is not None:
            self.add_episodes(episodes)

    def cut_running(self) -> int:
        """Store the episodes still running as ended at their last step, ``truncated`` there: a run that
        stops keeps every transition it collected. Returns how many episodes were cut."""
        episodes = self._staging.cut_running() if self._staging is not None else None
        if episodes is None:
            return 0
        self.add_episodes(episodes)
        return episodes.num_episodes

    def add_episodes(self, episodes: Episodes) -> None:
        """Store whole episodes (a collector's, a dataset's), oldest first, as if one by one: the oldest
        stored ones make room, and of a batch larger than the capacity only its newest that fit stay."""
        n = episodes.num_episodes
        if n == 0:
            return
        lengths = episodes.lengths.cpu().numpy()
        self.episodes_added += n
        self.transitions_added += int(lengths.sum())
        fits = np.cumsum(lengths[::-1]) <= self.capacity  # newest first: which fit with those after them
        keep = int(fits.sum())
        if keep < n:
            if keep == 0:
                raise ConfigError(
                    "buffer_size",
                    f"an episode of {int(lengths[-1]):,} steps is longer than the replay holds ({self.capacity:,}); "
                    "raise --buffer-size",
                )
            self._evict(self._step_count)  # everything stored is older than the batch
            self.evicted_episodes += n - keep
            self.evicted_transitions += int(lengths[: n - keep].sum())
            episodes, lengths, n = episodes.newest(keep), lengths[n - keep :], keep
        steps = int(lengths.sum())
        self._evict(self._step_count + steps - self.capacity)
        if self.num_episodes + n > self.episode_slots:
            self._grow_episode_slots(self.num_episodes + n)

        if lengths.min() < 1:
            raise ValueError("every stored episode needs at least one step")
        dev = self.device
        ids_host = (np.arange(n) + self._episode_tail + self.num_episodes) % self.episode_slots
        ids = torch.as_tensor(ids_host, device=dev)
        lengths_dev = torch.as_tensor(lengths, device=dev)
        step_offsets = torch.cumsum(lengths_dev, 0) - lengths_dev
        step_head = (self._step_tail + self._step_count) % self.capacity
        obs_head = (self._obs_tail + self._obs_count) % self.obs_rows
        step_rows = (torch.arange(steps, device=dev) + step_head) % self.capacity
        obs_rows = (torch.arange(steps + n, device=dev) + obs_head) % self.obs_rows
        for key in STEP_KEYS:
            self.steps[key].index_copy_(0, step_rows, getattr(episodes, key).to(dev, self.steps[key].dtype))
        self.step_episode.index_copy_(0, step_rows, ids.repeat_interleave(lengths_dev))
        for key in self.obs_keys:
            self.obs[key].index_copy_(0, obs_rows, episodes.obs[key].to(dev, self.obs[key].dtype))
        self.episode_step_start[ids] = (step_offsets + step_head) % self.capacity
        self.episode_obs_start[ids] = (step_offsets + torch.arange(n, device=dev) + obs_head) % self.obs_rows
        self.length[ids] = lengths_dev
        self._host_length[ids_host] = lengths
        self._step_count += steps
        self._obs_count += steps + n
        self.num_episodes += n
        self.version += 1

    def _evict(self, transitions: int) -> None:
        """Drop the fewest oldest episodes that free ``transitions`` steps (nothing if <= 0)."""
        if transitions <= 0:
            return
        # each episode has at least one step: no more than `transitions` of them are needed
        look = min(self.num_episodes, transitions)
        oldest = (np.arange(look) + self._episode_tail) % self.episode_slots
        freed = np.cumsum(self._host_length[oldest])
        count = int(np.searchsorted(freed, transitions)) + 1  # the first prefix freeing enough
        steps = int(freed[count - 1])
        gone = torch.as_tensor(oldest[:count], device=self.device)
        self.length[gone] = 0
        self._host_length[oldest[:count]] = 0
        self._episode_tail = (self._episode_tail + count) % self.episode_slots
        self.num_episodes -= count
        self._step_tail = (self._step_tail + steps) % self.capacity
        self._step_count -= steps
        self._obs_tail = (self._obs_tail + steps + count) % self.obs_rows
        self._obs_count -= steps + count
        self.evicted_episodes += count
        self.evicted_transitions += steps
        self.version += 1

    def _grow_episode_slots(self, needed: int) -> None:
        """More episode slots (and observation rows with them), the stored episodes laid out anew, oldest
        first from slot 0."""
        slots = min(self.capacity, max(2 * self.episode_slots, needed))
        order = self.stored_episodes()
        count = self.num_episodes
        obs_rows = (torch.arange(self._obs_count, device=self.device) + self._obs_tail) % self.obs_rows
        old_obs, old_rows, old_tail = self.obs, self.obs_rows, self._obs_tail
        step_start, obs_start, length = self.episode_step_start[order], self.episode_obs_start[order], self.length[order]
        renumber = torch.zeros(self.episode_slots, dtype=torch.long, device=self.device)
        renumber[order] = torch.arange(count, device=self.device)
        self._allocate_episodes(slots)
        for key, table in old_obs.items():
            self.obs[key][: self._obs_count] = table.index_select(0, obs_rows)
        self.episode_step_start[:count] = step_start
        self.episode_obs_start[:count] = (obs_start - old_tail) % old_rows
        self.length[:count] = length
        self._host_length[:count] = length.cpu().numpy()
        self.step_episode = renumber[self.step_episode]
        self._episode_tail = self._obs_tail = 0
        self.layout += 1
        self.version += 1

    # ---------------------------------------------------------------- reading
    def sample_indices(self, batch_size: int, generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Uniform over stored transitions: ``(episode, step)`` index tensors."""
        if self.num_episodes == 0:  # a count on the host: no device sync per batch
            raise RuntimeError("cannot sample from an empty replay: no episode has finished yet")
        u = (torch.rand(batch_size, generator=generator, device=self.device) * self._step_count).long()
        row = (u.clamp_(max=self._step_count - 1) + self._step_tail) % self.capacity
        episode = self.step_episode.index_select(0, row)
        return episode, (row - self.episode_step_start.index_select(0, episode)) % self.capacity

    def episode_steps(self, episodes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(episode, step)`` of every step of these stored ``episodes``, episode by episode."""
        lengths = self.length.index_select(0, episodes)
        episode = episodes.repeat_interleave(lengths)
        first = torch.cumsum(lengths, 0) - lengths
        step = torch.arange(episode.numel(), device=self.device) - first.repeat_interleave(lengths)
        return episode, step

    def gather(self, episode: torch.Tensor, step: torch.Tensor) -> Batch:
        """The transitions at ``(episode, step)``."""
        at_step = (self.episode_step_start.index_select(0, episode) + step) % self.capacity
        at_obs = (self.episode_obs_start.index_select(0, episode) + step) % self.obs_rows
        at_next = (at_obs + 1) % self.obs_rows
        return Batch(
            obs={k: self.obs[k].index_select(0, at_obs) for k in self.obs_keys},
            action=self.steps["action"].index_select(0, at_step),
            reward=self.steps["reward"].index_select(0, at_step),
            next_obs={k: self.obs[k].index_select(0, at_next) for k in self.obs_keys},
            terminated=self.steps["terminated"].index_select(0, at_step),
            truncated=self.steps["truncated"].index_select(0, at_step),
            episode=episode,
            step=step,
        )

    def observation_at(self, key: str, episode: torch.Tensor, index: torch.Tensor | int) -> torch.Tensor:
        """Observation ``index`` (0: the first; ``length``: the last) of key ``key`` in each ``episode``."""
        return self.obs[key].index_select(0, (self.episode_obs_start.index_select(0, episode) + index) % self.obs_rows)

    def first_observations(self, key: str) -> torch.Tensor:
        """``[episode_slots]``: the first observation of key ``key`` of every episode slot (meaningless
        where no episode is stored: ``length`` is 0 there)."""
        return self.obs[key].index_select(0, self.episode_obs_start)

    def sample(self, batch_size: int, generator: torch.Generator | None = None) -> Batch:
        return self.gather(*self.sample_indices(batch_size, generator))

    def episodes(self) -> Episodes:
        """The stored episodes, oldest first, flat: a copy."""
        return saved_episodes(self.state_dict())[0]

    def metrics(self) -> dict[str, int]:
        """``replay_transitions`` (stored now), ``replay_episodes``, ``replay_evicted`` (transitions dropped so far)."""
        return {
            "replay_transitions": self._step_count,
            "replay_episodes": self.num_episodes,
            "replay_evicted": self.evicted_transitions,
        }

    # ---------------------------------------------------------------- checkpointing
    def state_dict(self) -> dict[str, torch.Tensor]:
        """Stored episodes, as the rings are (no copy; a run stores its running ones first, `cut_running`).

        A ring that has not wrapped yet is given up to its last written row only: a replay far from full
        saves what it holds, not its capacity (the rows past it were never written)."""
        obs_rows = max(min(self._obs_tail + self._obs_count, self.obs_rows), 1)  # past the ring's end: it wrapped
        step_rows = max(min(self._step_tail + self._step_count, self.capacity), 1)
        state = {f"obs/{k}": v[:obs_rows] for k, v in self.obs.items()}
        state.update({f"steps/{k}": v[:step_rows] for k, v in self.steps.items()})
        state["episode_step_start"] = self.episode_step_start
        state["episode_obs_start"] = self.episode_obs_start
        state["length"] = self.length
        state["rings"] = torch.tensor(
            [self.capacity, self._episode_tail, self.num_episodes, self.episodes_added, self.transitions_added]
            + [self.evicted_episodes, self.evicted_transitions]
        )
        return state

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Restore stored episodes (into an empty replay); a resumed run may have a different capacity, so
        the newest episodes that fit are kept. Checkpoints of the earlier horizon-row layout load too."""
        episodes, counters = saved_episodes(state)
        self.add_episodes(episodes.to(self.device))
        if counters is not None:  # the run's history, not this load's
            self.episodes_added, self.transitions_added, saved_evicted_episodes, saved_evicted = counters
            self.evicted_episodes += saved_evicted_episodes
            self.evicted_transitions += saved_evicted


def saved_episodes(state: dict[str, torch.Tensor]) -> tuple[Episodes, list[int] | None]:
    """The episodes of a replay's ``state_dict``, oldest first, and its counters (added episodes and
    transitions, evicted episodes and transitions; None for a checkpoint of the horizon-row layout)."""
    if "rings" not in state:
        return _horizon_row_episodes(state), None
    capacity, tail, count, *counters = (int(x) for x in state["rings"])
    length = state["length"]
    slots = length.shape[0]
    ids = (torch.arange(count, device=length.device) + tail) % slots
    obs_tables = {k[len("obs/") :]: v for k, v in state.items() if k.startswith("obs/")}
    obs_rows = next(iter(obs_tables.values())).shape[0]
    lengths = length[ids]
    at_step = ring_rows(state["episode_step_start"][ids], lengths, capacity)
    at_obs = ring_rows(state["episode_obs_start"][ids], lengths + 1, obs_rows)
    episodes = Episodes(
        obs={k: v[at_obs] for k, v in obs_tables.items()},
        **{k: state[f"steps/{k}"][at_step] for k in STEP_KEYS},
        lengths=lengths,
    )
    return episodes, counters


def _horizon_row_episodes(state: dict[str, torch.Tensor]) -> Episodes:
    """Episodes of a checkpoint written by the earlier layout (one row of ``horizon`` steps per episode)."""
    next_slot, num_episodes, *_ = (int(x) for x in state["counters"])
    length = state["length"]
    rows = length.shape[0]
    order = (torch.arange(num_episodes) + (next_slot - num_episodes)) % rows
    lengths = length[order]
    horizon = state["storage/reward"].shape[1]
    steps = torch.arange(horizon + 1)
    obs_mask = steps[None] <= lengths[:, None]
    step_mask = steps[None, :-1] < lengths[:, None]
    return Episodes(
        obs={k[len("storage/obs/") :]: v[order][obs_mask] for k, v in state.items() if k.startswith("storage/obs/")},
        **{k: state[f"storage/{k}"][order][step_mask] for k in STEP_KEYS},
        lengths=lengths,
    )
