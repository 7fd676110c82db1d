"""Episode storage and hindsight relabelling, including property tests over random episode data."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

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
    return EpisodeReplay(SPACE, ACTIONS, capacity=capacity, horizon=horizon, num_envs=num_envs)


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
    lengths = replay.length[: replay.num_episodes].tolist()
    assert lengths[:2] == [2, 4]
    assert replay.storage["terminated"][0, :2].tolist() == [False, True]
    assert replay.storage["truncated"][1, :4].tolist() == [False, False, False, True]
    assert not replay.storage["terminated"][1, :4].any()


def test_ring_overwrites_whole_episodes():
    replay = make_replay(num_envs=1, horizon=4, capacity=8)  # room for 2 episodes
    fill(replay, 1, [[4, 3, 2]], horizon=4)
    assert replay.num_episodes == 2
    stored = sorted(int(replay.storage["obs/observation"][e, 0, 1]) for e in range(2))
    assert stored == [1, 2]  # episode 0 was replaced whole by episode 2
    assert sorted(replay.length.tolist()) == [2, 3]


def test_sampling_is_uniform_over_transitions_not_episodes():
    replay = make_replay(num_envs=1, horizon=8, capacity=80)
    fill(replay, 1, [[1, 8]], horizon=8)  # 1 + 8 transitions
    ep, _ = replay.sample_indices(90_000, torch.Generator().manual_seed(1))
    short_share = (replay.length[ep] == 1).float().mean().item()
    assert abs(short_share - 1 / 9) < 0.01


def test_sampling_an_empty_replay_is_a_clear_error():
    with pytest.raises(RuntimeError, match="empty replay"):
        make_replay().sample(4)


def test_capacity_too_small_for_parallel_envs_is_rejected():
    with pytest.raises(ValueError, match="at least 2 \\* num_envs"):
        EpisodeReplay(SPACE, ACTIONS, capacity=10, horizon=5, num_envs=4)


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
    replay = make_replay(num_envs=1, horizon=4, capacity=16)  # 4 episodes
    fill(replay, 1, [[4, 3, 2, 1, 4, 2]], horizon=4)  # 6 episodes: the ring wrapped
    newest = [4, 5]  # episode ids by their stored observation

    smaller = make_replay(num_envs=1, horizon=4, capacity=8)  # 2 episodes
    smaller.load_state_dict(replay.state_dict())
    ids = [int(smaller.storage["obs/observation"][e, 0, 1]) for e in range(2)]
    assert ids == newest and smaller.length.tolist() == [4, 2]

    larger = make_replay(num_envs=1, horizon=4, capacity=40)
    larger.load_state_dict(replay.state_dict())
    assert larger.num_episodes == 4 and larger.num_transitions == replay.num_transitions
    assert [int(larger.storage["obs/observation"][e, 0, 1]) for e in range(4)] == [2, 3, 4, 5]


def test_the_memory_estimate_is_what_the_storage_allocates():
    from taskrl.envs import BitFlip, PointReach

    for env in (BitFlip(7, num_envs=4), PointReach(num_envs=3)):
        replay = EpisodeReplay(env.single_observation_space, env.single_action_space, 5_000, env.horizon, env.num_envs)
        allocated = sum(t.nbytes for table in (replay.storage, replay.staging) for t in table.values())
        assert (
            EpisodeReplay.bytes_needed(env.single_observation_space, env.single_action_space, 5_000, env.horizon, env.num_envs)
            == allocated
        )


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
