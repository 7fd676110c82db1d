"""Multi-task SAC: conditioned networks, per-task temperature, task encoder training, and runs."""

import json

import pytest
import torch
from torch import nn

import taskrl
from helpers import small_run
from taskrl.agents.sac import SACAgent, SACConfig
from taskrl.checkpoint import flatten_state, unflatten_state
from taskrl.conditioning.networks import ARCHITECTURES, ConditionedMLP, ConditioningConfig, make_conditioning
from taskrl.replay.batch import Batch

T = 3


def task_batch(task, n_state=4, seed=0):
    g = torch.Generator().manual_seed(seed)
    n = len(task)
    obs = {"observation": torch.randn(n, n_state, generator=g), "task": torch.tensor(task)}
    nxt = {"observation": torch.randn(n, n_state, generator=g), "task": torch.tensor(task)}
    return Batch(
        obs=obs,
        action=torch.rand(n, 2, generator=g) * 2 - 1,
        reward=torch.randn(n, generator=g),
        next_obs=nxt,
        terminated=torch.zeros(n, dtype=torch.bool),
        truncated=torch.zeros(n, dtype=torch.bool),
        episode=torch.zeros(n, dtype=torch.long),
        step=torch.zeros(n, dtype=torch.long),
    )


def make_agent(encoder="onehot", architecture="concat", multi_head=False, **cfg):
    torch.manual_seed(0)
    cond = make_conditioning(
        ConditioningConfig(
            task_encoder=encoder,
            architecture=architecture,
            multi_head=multi_head,
            embedding_dim=8,
            care_encoders=3,
            care_encoder_dim=8,
        ),
        T,
    )
    config = SACConfig(**{"hidden_sizes": (16, 16), "normalize_inputs": False, **cfg})
    return SACAgent(("observation",), 4, (-torch.ones(2), torch.ones(2)), config, "cpu", cond)


@pytest.mark.parametrize("architecture", ARCHITECTURES)
@pytest.mark.parametrize("heads", [1, T])
def test_conditioned_network_shapes_and_the_context_gets_gradient(architecture, heads):
    torch.manual_seed(0)
    net = ConditionedMLP(5, 2, (16, 16), context_dim=6, architecture=architecture, extra_dim=3, num_heads=heads)
    x, extra = torch.randn(7, 5), torch.randn(7, 3)
    context = torch.randn(7, 6, requires_grad=True)
    task = torch.tensor([0, 1, 2, 0, 1, 2, 0])
    y = net(x, context, task, extra)
    assert y.shape == (7, 2)
    if architecture == "film":  # FiLM starts as the identity: perturb it so the context matters
        for p in net.parameters():
            p.data.add_(0.1 * torch.randn_like(p))
        y = net(x, context, task, extra)
    y.square().sum().backward()
    assert context.grad.abs().sum() > 0
    assert all(p.grad is not None for p in net.parameters())


def test_multi_head_rows_read_their_own_tasks_head():
    torch.manual_seed(0)
    net = ConditionedMLP(4, 2, (8,), context_dim=3, num_heads=3)
    x, c = torch.randn(6, 4), torch.randn(6, 3)
    task = torch.tensor([2, 0, 1, 1, 0, 2])
    every_head = net.body(torch.cat([x, c], 1)).view(6, 3, 2)
    torch.testing.assert_close(net(x, c, task), every_head[torch.arange(6), task])
    with pytest.raises(ValueError, match="task index"):
        net(x, c)
    with pytest.raises(ValueError, match="context"):
        net(x)


def test_single_task_network_is_a_plain_mlp():
    net = ConditionedMLP(4, 1, (8,), extra_dim=2)
    x, a = torch.randn(5, 4), torch.randn(5, 2)
    torch.testing.assert_close(net(x, extra=a), net.body(torch.cat([x, a], 1)))


class ConstQ(nn.Module):
    def forward(self, x, action, context=None, task=None):
        return torch.full((x.shape[0],), 2.0)


class FixedActor:
    def sample(self, x, generator=None, context=None, task=None):
        return torch.zeros(x.shape[0], 2), torch.full((x.shape[0],), -3.0)


def test_bellman_target_uses_each_rows_own_task_temperature():
    agent = make_agent(gamma=0.5)
    with torch.no_grad():
        agent.log_alpha.copy_(torch.log(torch.tensor([0.1, 1.0, 2.0])))
    agent.critics_target = nn.ModuleList([ConstQ(), ConstQ()])
    agent.actor = FixedActor()
    batch = task_batch([0, 1, 2, 2])
    batch.terminated[3] = True
    # y = r + gamma (1 - term) (Q - alpha_k log pi) = r + 0.5 * (2 + 3 alpha_k)
    expected = batch.reward + 0.5 * torch.tensor([2.3, 5.0, 8.0, 0.0]) * torch.tensor([1.0, 1, 1, 0])
    torch.testing.assert_close(agent.bellman_target(batch), expected)


def test_temperature_loss_moves_only_the_tasks_in_the_batch():
    agent = make_agent()
    before = agent.log_alpha.detach().clone()
    agent.update(task_batch([1] * 32))
    after = agent.log_alpha.detach()
    assert after[1] != before[1] and after[0] == before[0] and after[2] == before[2]
    shared = make_agent(per_task_alpha=False)
    assert shared.log_alpha.shape == (1,)
    shared.update(task_batch([0, 1, 2] * 8))


def test_the_learned_task_embedding_is_trained_by_the_critic_loss():
    agent = make_agent("embedding")
    table = agent.task_encoder.embedding.weight.detach().clone()
    agent.update(task_batch([0, 1] * 16))
    changed = (agent.task_encoder.embedding.weight.detach() != table).any(1)
    assert changed.tolist() == [True, True, False]  # task 2 was not in the batch


@pytest.mark.parametrize("architecture,multi_head", [("concat", True), ("film", False), ("care", False)])
def test_checkpoint_round_trip_gives_the_same_actions(architecture, multi_head):
    agent = make_agent("embedding", architecture, multi_head)
    for seed in range(3):
        agent.update(task_batch([0, 1, 2] * 4, seed=seed))
    other = make_agent("embedding", architecture, multi_head)
    tensors, meta = flatten_state(agent.state_dict())
    other.load_state_dict(unflatten_state(tensors, meta))
    obs = task_batch([2, 1, 0]).obs
    torch.testing.assert_close(other.act(obs), agent.act(obs))
    assert not torch.equal(make_agent("embedding", architecture, multi_head).act(obs), agent.act(obs))


@pytest.mark.slow
def test_actions_depend_on_the_task_after_training():
    """A one-step multi-task bandit: the same state, and task t pays -|a - best_t|^2. Only an agent
    that learnt from the task reaches each task's own optimum; an untrained one reaches none."""
    best = torch.tensor([[-0.6, 0.6], [0.0, -0.6], [0.6, 0.0]])
    agent = make_agent(lr=3e-3, init_alpha=0.01, hidden_sizes=(64, 64))
    obs = {"observation": torch.zeros(3, 4), "task": torch.arange(3)}
    untrained = agent.act(obs)
    g = torch.Generator().manual_seed(0)
    for _ in range(600):
        task = torch.randint(0, T, (96,), generator=g)
        action = torch.rand(96, 2, generator=g) * 2 - 1
        state = {"observation": torch.zeros(96, 4), "task": task}
        done = torch.ones(96, dtype=torch.bool)
        agent.update(
            Batch(
                obs=state,
                action=action,
                reward=-(action - best[task]).square().sum(1),
                next_obs=state,
                terminated=done,
                truncated=~done,
                episode=task,
                step=task,
            ),
            generator=g,
        )
    trained = agent.act(obs)
    assert (trained - best).abs().max() < 0.2, trained  # every task at its own optimum
    assert (untrained - best).abs().max() > 0.3  # not by luck of the initialisation


@pytest.mark.slow
def test_multitask_run_with_one_hot_solves_every_region(tmp_path):
    run = small_run("pointreach-mt-sac-onehot", tmp_path / "run", total_steps=10_000)
    per_task = json.loads((tmp_path / "run" / "per_task_success.json").read_text())
    assert per_task["success"] == "at the final step" and set(per_task["tasks"]) == {
        "top-left",
        "top-right",
        "bottom-left",
        "bottom-right",
        "centre",
    }
    assert run.metrics["success_rate"] >= 0.9, per_task
    assert min(t["success_rate"] for t in per_task["tasks"].values()) >= 0.75
    assert run.metrics["success/centre"] == per_task["tasks"]["centre"]["success_rate"]
    again = taskrl.evaluate_run(tmp_path / "run", episodes=5)
    assert again["success_rate"] >= 0.8 and "success/top-left" in again


@pytest.mark.slow
def test_multitask_ppo_run_resumes_and_evaluates_per_task(tmp_path):
    out = tmp_path / "ppo"
    first = small_run("pointreach-mt-ppo-onehot", out, total_steps=20_000, eval_interval=10_000)
    assert first.metrics["env_steps"] >= 20_000 and "success/centre" in first.metrics
    assert {"policy_loss", "approx_kl", "explained_variance"} <= set(first.metrics)
    assert not (out / "checkpoints" / "latest").read_text().strip() == ""
    resumed = taskrl.train(resume=out, total_steps=40_000, tensorboard=False)
    assert resumed.metrics["env_steps"] >= 40_000 and resumed.metrics["updates"] > first.metrics["updates"]
    loaded = taskrl.load(out)
    obs = {"observation": torch.zeros(5, 2), "task": torch.arange(5)}
    torch.testing.assert_close(loaded.act(obs), resumed.agent.act(obs))
