"""Episode storage and hindsight relabelling, including property tests over random episode data."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from taskrl.errors import ConfigError
from taskrl.replay import EpisodeReplay, HindsightRelabeler

# Synthetic goal data where every achieved goal says where it came from: (env, episode, step).
SPACE = gym.spaces.Dict(
    {
        "observation": gym.spaces.Box(-1e9, 1e9, (3,), np.float32),
        "achieved_goal": gym.spaces.Box(-1e9, 1e9, (3,), np.float32),
        "desired_goal": gym.spaces.Box(-1e9, 1e9, (3,), np.float32),
    }
)
ACTIONS = gym.spaces.Discrete(4)


def reward_fn(achieved, desired, info):
    return -(achieved != desired).any(dim=-1).float()


def terminated_fn(achieved, desired, info):
    return (achieved == desired).all(dim=-1)


def fill(replay: EpisodeReplay, num_envs: int, lengths_per_env: list[list[int]], horizon: int):
    """Drive ``replay`` like a batched env would, with episodes of the given lengths per env.

    Observation at step t of episode e of env i is (i, e, t); desired goal (i, e, -1).
    """
    episode_idx = [0] * num_envs
    t = [0] * num_envs

    def obs_of(i):
        v = torch.tensor([i, episode_idx[i], t[i]], dtype=torch.float32)
        return v

    def batch_obs(rows):
        o = torch.stack(rows)
        g = o.clone()
        g[:, 2] = -1
        return {"observation": o, "achieved_goal": o.clone(), "desired_goal": g}

    replay.start(batch_obs([obs_of(i) for i in range(num_envs)]))
    remaining = [list(x) for x in lengths_per_env]
    while any(remaining):
        next_rows, reset_rows, term, trunc = [], [], [], []
        for i in range(num_envs):
            length = remaining[i][0] if remaining[i] else horizon
            t[i] += 1
            next_rows.append(obs_of(i))
            done = t[i] >= length
            term.append(done and length < horizon)
            trunc.append(done and length == horizon)
            if done:
                if remaining[i]:
                    remaining[i].pop(0)
                episode_idx[i] += 1
                t[i] = 0
            reset_rows.append(obs_of(i))
        action = torch.zeros(num_envs, dtype=torch.long)
        nxt, rst = batch_obs(next_rows), batch_obs(reset_rows)
        reward = torch.full((num_envs,), -1.0)
        replay.add(action, reward, torch.tensor(term), torch.tensor(trunc), nxt, rst)
        if not any(remaining):
            break


def make_replay(num_envs=2, horizon=5, capacity=200):
    return EpisodeReplay(SPACE, ACTIONS, capacity=capacity, num_envs=num_envs, horizon=horizon)


def stored_ids(replay: EpisodeReplay) -> list[tuple[int, int]]:
    """(env, episode) of every stored episode, oldest first, read from its first observation."""
    first = replay.observation_at("observation", replay.stored_episodes(), 0)
    return [(int(e), int(k)) for e, k, _ in first.tolist()]


def test_only_finished_episodes_are_stored_and_transitions_are_exact():
    replay = make_replay(num_envs=2, horizon=5)
    fill(replay, 2, [[3], [5, 2]], horizon=5)
    assert replay.num_episodes >= 2
    assert replay.num_transitions == int(replay.length.sum())
    ep, step = replay.sample_indices(500, torch.Generator().manual_seed(0))
    b = replay.gather(ep, step)
    # The transition (s_t, s_{t+1}) comes from one env and one episode, consecutive steps.
    assert torch.equal(b.obs["observation"][:, :2], b.next_obs["observation"][:, :2])
    assert torch.equal(b.obs["observation"][:, 2] + 1, b.next_obs["observation"][:, 2])
    assert torch.equal(b.obs["observation"][:, 2], step.float())
    assert (step < replay.length[ep]).all()


def test_terminated_and_truncated_are_kept_apart():
    replay = make_replay(num_envs=1, horizon=4)
    fill(replay, 1, [[2, 4]], horizon=4)
    episodes = replay.episodes()
    assert episodes.lengths.tolist()[:2] == [2, 4]
    assert episodes.terminated[:6].tolist() == [False, True, False, False, False, False]
    assert episodes.truncated[:6].tolist() == [False, False, False, False, False, True]


def test_the_oldest_whole_episodes_make_room_and_are_counted():
    replay = make_replay(num_envs=1, horizon=4, capacity=8)
    fill(replay, 1, [[4, 3, 2]], horizon=4)  # 9 transitions: the first episode goes
    assert stored_ids(replay) == [(0, 1), (0, 2)]
    assert replay.num_transitions == 5 and replay.evicted_transitions == 4 and replay.evicted_episodes == 1
    assert replay.metrics() == {"replay_transitions": 5, "replay_episodes": 2, "replay_evicted": 4}


def test_short_episodes_fill_the_capacity_in_transitions():
    replay = make_replay(num_envs=1, horizon=50, capacity=100)  # the old layout held 2 episodes of 50 rows
    fill(replay, 1, [[2] * 50], horizon=50)
    assert replay.num_episodes == 50 and replay.num_transitions == 100 and replay.evicted_transitions == 0
    assert replay.episode_slots >= 50  # the episode slots grew past the horizon's guess


def test_sampling_is_uniform_over_transitions_not_episodes():
    replay = make_replay(num_envs=1, horizon=8, capacity=80)
    fill(replay, 1, [[1, 8]], horizon=8)  # 1 + 8 transitions
    ep, _ = replay.sample_indices(90_000, torch.Generator().manual_seed(1))
    short_share = (replay.length[ep] == 1).float().mean().item()
    assert abs(short_share - 1 / 9) < 0.01


def test_sampling_an_empty_replay_is_a_clear_error():
    with pytest.raises(RuntimeError, match="empty replay"):
        make_replay().sample(4)


def test_an_episode_longer_than_the_capacity_names_buffer_size():
    replay = make_replay(num_envs=1, horizon=None, capacity=6)
    with pytest.raises(ConfigError, match="buffer_size"):
        fill(replay, 1, [[10]], horizon=100)


def test_episodes_without_a_horizon_grow_their_staging():
    replay = make_replay(num_envs=2, horizon=None, capacity=1000)
    fill(replay, 2, [[150, 3], [2, 200]], horizon=10_000)  # past the staging's first 64 steps
    assert sorted(replay.length[replay.stored_episodes()].tolist()) == [2, 3, 150, 200]
    b = replay.gather(*replay.episode_steps(replay.stored_episodes()))
    assert torch.equal(b.obs["observation"][:, 2] + 1, b.next_obs["observation"][:, 2])


def reference_fifo(lengths_per_env: list[list[int]], capacity: int) -> tuple[list[tuple[int, int, int]], int, int]:
    """A plain-Python replay: episodes in the order they end (env order within a step), the oldest
    dropped while more than ``capacity`` transitions are kept. ``(env, episode, length)`` of those kept,
    and the episodes and transitions dropped."""
    ends = []
    for env, lengths in enumerate(lengths_per_env):
        t = 0
        for k, n in enumerate(lengths):
            t += n
            ends.append((t, env, k, n))
    kept, dropped_episodes, dropped = [], 0, 0
    for _, env, k, n in sorted(ends):
        kept.append((env, k, n))
        while sum(e[2] for e in kept) > capacity:
            dropped_episodes, dropped = dropped_episodes + 1, dropped + kept.pop(0)[2]
    return kept, dropped_episodes, dropped


@settings(max_examples=80, deadline=None)
@given(st.integers(1, 4), st.data(), st.booleans())
def test_stores_and_evicts_what_a_fifo_of_episodes_counted_in_transitions_does(num_envs, data, declared):
    lengths = [data.draw(st.lists(st.integers(1, 9), min_size=1, max_size=6)) for _ in range(num_envs)]
    total = max(sum(x) for x in lengths)
    lengths = [x + ([total - sum(x)] if sum(x) < total else []) for x in lengths]  # every env steps to the end
    longest = max(max(x) for x in lengths)
    capacity = data.draw(st.integers(longest, 3 * longest + 10))
    replay = make_replay(num_envs, horizon=data.draw(st.integers(1, 12)) if declared else None, capacity=capacity)
    fill(replay, num_envs, lengths, horizon=longest + 1)

    kept, dropped_episodes, dropped = reference_fifo(lengths, capacity)
    assert stored_ids(replay) == [(env, k) for env, k, _ in kept]
    assert replay.length[replay.stored_episodes()].tolist() == [n for _, _, n in kept]
    assert replay.num_transitions == sum(n for _, _, n in kept) <= capacity
    assert (replay.evicted_episodes, replay.evicted_transitions) == (dropped_episodes, dropped)
    assert replay.transitions_added == sum(map(sum, lengths)) == replay.num_transitions + dropped
    # every stored step, read back: its own episode, consecutive observations
    batch = replay.gather(*replay.episode_steps(replay.stored_episodes()))
    obs, nxt = batch.obs["observation"], batch.next_obs["observation"]
    assert torch.equal(obs[:, :2], nxt[:, :2]) and torch.equal(obs[:, 2], batch.step.float())
    assert torch.equal(nxt[:, 2], batch.step.float() + 1)


def test_sampling_is_uniform_over_stored_transitions_chi_square():
    from scipy.stats import chisquare

    replay = make_replay(num_envs=3, horizon=None, capacity=40)
    lengths = [[1, 2, 9, 3, 1, 1, 7, 2], [5, 5, 1, 1, 1, 1, 12], [2, 2, 2, 2, 2, 2, 2, 12]]
    fill(replay, 3, lengths, horizon=100)  # the ring wrapped, the episode slots grew
    assert replay.evicted_transitions > 0 and replay.layout > 0
    n = 60_000
    batch = replay.sample(n, torch.Generator().manual_seed(3))
    key = batch.obs["observation"] @ torch.tensor([10_000.0, 100.0, 1.0])  # (env, episode, step) as one number
    _, counts = torch.unique(key, return_counts=True)
    assert counts.numel() == replay.num_transitions  # every stored transition is drawn, nothing else
    assert chisquare(counts.numpy()).pvalue > 1e-3


episode_data = st.tuples(
    st.integers(1, 4),  # num_envs
    st.integers(2, 7),  # horizon
    st.data(),
)


@settings(max_examples=60, deadline=None)
@given(episode_data, st.sampled_from(["future", "final", "episode", "random"]), st.integers(1, 8), st.integers(0, 2**31))
def test_relabelled_goals_come_from_where_the_strategy_says(setup, strategy, k, seed):
    num_envs, horizon, data = setup
    lengths = [data.draw(st.lists(st.integers(1, horizon), min_size=1, max_size=4)) for _ in range(num_envs)]
    replay = make_replay(num_envs, horizon, capacity=horizon * 64)
    fill(replay, num_envs, lengths, horizon)
    g = torch.Generator().manual_seed(seed)
    batch = replay.sample(256, g)
    her = HindsightRelabeler(reward_fn, strategy, k, terminated_fn=terminated_fn)
    out = her(batch, replay, g)

    goal = out.obs["desired_goal"]
    relabelled = goal[:, 2] >= 0  # original goals carry step -1
    src = batch.obs["observation"]
    length = replay.length[batch.episode].float()
    if strategy in ("future", "final", "episode"):
        # Same env and same episode as the transition.
        assert torch.equal(goal[relabelled, :2], src[relabelled, :2])
    gstep = goal[relabelled, 2]
    if strategy == "future":  # an achieved goal of a later-or-equal transition: index in [t+1, L]
        assert (gstep >= src[relabelled, 2] + 1).all() and (gstep <= length[relabelled]).all()
    elif strategy == "final":
        assert torch.equal(gstep, length[relabelled])
    elif strategy == "episode":
        assert (gstep >= 1).all() and (gstep <= length[relabelled]).all()
    else:  # random: some stored next-state
        assert (gstep >= 1).all()
    # The goal is the same in s and s'; rewards and termination are those of compute_reward.
    assert torch.equal(out.next_obs["desired_goal"], goal)
    assert torch.equal(out.reward[relabelled], reward_fn(out.next_obs["achieved_goal"], goal, None)[relabelled])
    assert torch.equal(out.terminated[relabelled], terminated_fn(out.next_obs["achieved_goal"], goal, None)[relabelled])
    assert not (out.terminated & out.truncated).any()
    # Untouched transitions keep everything.
    keep = ~relabelled
    assert torch.equal(out.reward[keep], batch.reward[keep])
    assert torch.equal(out.terminated[keep], batch.terminated[keep])


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 8), st.integers(0, 2**31))
def test_relabelled_fraction_matches_k(k, seed):
    replay = make_replay(num_envs=2, horizon=5, capacity=500)
    fill(replay, 2, [[5, 5, 5], [5, 5]], horizon=5)
    g = torch.Generator().manual_seed(seed)
    batch = replay.sample(20_000, g)
    out = HindsightRelabeler(reward_fn, "future", k)(batch, replay, g)
    fraction = (out.obs["desired_goal"][:, 2] >= 0).float().mean().item()
    expected = k / (k + 1)
    # 5 binomial standard deviations.
    assert abs(fraction - expected) <= 5 * (expected * (1 - expected) / 20_000) ** 0.5 + 1e-9


def test_unknown_strategy_is_rejected_with_the_allowed_names():
    with pytest.raises(ValueError, match="future, final, episode, random"):
        HindsightRelabeler(reward_fn, "futur")


def test_state_round_trip_into_a_different_capacity_keeps_the_newest_episodes():
    replay = make_replay(num_envs=1, horizon=4, capacity=10)
    fill(replay, 1, [[4, 3, 2, 1, 4, 2]], horizon=4)  # 16 transitions: the ring wrapped
    assert stored_ids(replay) == [(0, 2), (0, 3), (0, 4), (0, 5)]

    smaller = make_replay(num_envs=1, horizon=4, capacity=6)
    smaller.load_state_dict(replay.state_dict())
    assert stored_ids(smaller) == [(0, 4), (0, 5)] and smaller.length[smaller.stored_episodes()].tolist() == [4, 2]
    assert smaller.episodes_added == 6 and smaller.evicted_transitions == replay.evicted_transitions + 3

    larger = make_replay(num_envs=1, horizon=4, capacity=40)
    larger.load_state_dict(replay.state_dict())
    assert stored_ids(larger) == [(0, 2), (0, 3), (0, 4), (0, 5)] and larger.num_transitions == replay.num_transitions
    for key in SPACE.spaces:
        assert torch.equal(larger.episodes().obs[key], replay.episodes().obs[key])


def test_a_replay_far_from_full_saves_its_written_rows_not_its_capacity(tmp_path):
    from taskrl.checkpoint import load_checkpoint, save_checkpoint

    replay = make_replay(num_envs=1, horizon=4, capacity=1_000)
    fill(replay, 1, [[4, 3, 2]], horizon=4)  # 9 transitions, 12 observations
    state = replay.state_dict()
    assert {state[f"obs/{k}"].shape[0] for k in SPACE.spaces} == {12}
    assert state["steps/reward"].shape[0] == 9
    save_checkpoint(tmp_path, {"replay": state}, 9)
    restored = make_replay(num_envs=1, horizon=4, capacity=1_000)
    restored.load_state_dict(load_checkpoint(tmp_path, ("replay",))["replay"])
    assert restored.num_transitions == 9 and restored.length[restored.stored_episodes()].tolist() == [4, 3, 2]
    for key in SPACE.spaces:
        assert torch.equal(restored.episodes().obs[key], replay.episodes().obs[key])

    wrapped = make_replay(num_envs=1, horizon=4, capacity=10)
    fill(wrapped, 1, [[4, 3, 2, 1, 4, 2]], horizon=4)
    assert wrapped.state_dict()["steps/reward"].shape[0] == 10  # wrapped: every row is in use


def test_checkpoints_of_the_horizon_row_layout_still_load():
    """A replay saved before capacity counted transitions: ``[episodes, horizon (+ 1)]`` rows."""
    lengths = torch.tensor([2, 3, 1])
    h = 3
    obs = torch.arange(3 * (h + 1) * 3, dtype=torch.float32).view(3, h + 1, 3)
    state = {f"storage/obs/{k}": obs for k in SPACE.spaces}
    state.update(
        {
            "storage/action": torch.zeros(3, h, dtype=torch.long),
            "storage/reward": torch.arange(9, dtype=torch.float32).view(3, h),
            "storage/terminated": torch.zeros(3, h, dtype=torch.bool),
            "storage/truncated": torch.zeros(3, h, dtype=torch.bool),
            "length": lengths,
            "counters": torch.tensor([1, 3, 7]),  # next slot 1: slot 1 is the oldest
        }
    )
    replay = make_replay(num_envs=1, horizon=None, capacity=20)
    replay.load_state_dict(state)
    assert replay.length[replay.stored_episodes()].tolist() == [3, 1, 2]
    assert replay.episodes().reward.tolist() == [3.0, 4.0, 5.0, 6.0, 0.0, 1.0]
    assert replay.episodes().obs["observation"][:, 0].tolist() == [12.0, 15.0, 18.0, 21.0, 24.0, 27.0, 0.0, 3.0, 6.0]


def test_the_memory_estimate_is_what_the_storage_allocates():
    from taskrl.envs import BitFlip, PointReach

    for env in (BitFlip(7, num_envs=4), PointReach(num_envs=3)):
        space, actions = env.single_observation_space, env.single_action_space
        replay = EpisodeReplay(space, actions, 5_000, num_envs=env.num_envs, horizon=env.horizon)
        replay.start(env.reset(seed=0))
        tables = [replay.obs, replay.steps, replay._staging.obs, replay._staging.steps]
        allocated = sum(t.nbytes for table in tables for t in table.values())
        allocated += sum(
            t.nbytes for t in (replay.step_episode, replay.episode_step_start, replay.episode_obs_start, replay.length)
        )
        assert EpisodeReplay.bytes_needed(space, actions, 5_000, num_envs=env.num_envs, horizon=env.horizon) == allocated


def test_interleaving_batches_is_what_splitting_undoes():
    from taskrl.replay.batch import Batch

    replay = make_replay()
    fill(replay, 2, [[3, 5, 4, 5]] * 2, 5)
    g = torch.Generator().manual_seed(0)
    batches = [replay.sample(6, g) for _ in range(3)]
    together = Batch.interleave(batches)
    assert len(together) == 18
    assert torch.equal(together.obs["observation"][1::3], batches[1].obs["observation"])  # batch i: rows i, i + 3, ...
    for part, batch in zip(together.split(3), batches):
        for name in ("action", "reward", "terminated", "truncated", "episode", "step"):
            assert torch.equal(getattr(part, name), getattr(batch, name))
        for key in batch.obs:
            assert torch.equal(part.obs[key], batch.obs[key]) and torch.equal(part.next_obs[key], batch.next_obs[key])
