"""DQN as fitted Q-iteration (Mnih et al., 2015), with double-Q (van Hasselt et al., 2016).

Each update regresses Q(s, a) onto the Bellman target

    y = r + gamma * (1 - terminated) * Q_target(s', argmax_a' Q(s', a'))     (double-Q)
    y = r + gamma * (1 - terminated) * max_a' Q_target(s', a')               (plain)

Time-limit truncation still bootstraps: only ``terminated`` zeroes the next value. With rewards
in {-1, 0} every return lies in [-1 / (1 - gamma), 0], so targets can be clipped there.

Exploration is epsilon-greedy: while collecting, a uniformly random action with probability
epsilon, decayed linearly from ``epsilon_start`` to ``epsilon_end`` over ``epsilon_decay_steps``.

Conservative Q-learning (Kumar et al., 2020), for learning from a fixed dataset: with
``cql_alpha > 0`` the loss adds

    cql_alpha * E_s [ logsumexp_a Q(s, a) - Q(s, a_data) ]

which pushes down the Q-values of actions the data did not take. On multi-task envs the Q-network
takes the task context (the run's task encoder and architecture), as SAC's networks do.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import torch
import torch.nn.functional as F
from torch import nn

from taskrl.agents.base import Agent
from taskrl.agents.parts import (
    check_learning_settings,
    check_non_negative,
    check_probability,
    gradient_step,
    linear_schedule,
    negative_return_bounds,
    polyak_update,
    td_target,
)
from taskrl.agents.spec import AlgorithmSpec
from taskrl.conditioning.networks import TaskConditioning, network_for
from taskrl.errors import one_of, require
from taskrl.nets import mlp
from taskrl.replay.batch import Batch, Obs


@dataclasses.dataclass
class DQNConfig:
    """DQN hyperparameters.

    Attributes:
        lr: Adam learning rate.
        gamma: discount factor.
        hidden_sizes: widths of the Q-network's hidden layers.
        loss: ``huber`` (smooth L1) or ``mse`` regression loss.
        double_q: select the next action with the online network, evaluate it with the target.
        target_update_interval: updates between target refreshes.
        tau: Polyak factor at each refresh (1.0 = hard copy).
        clip_target: clip targets to [-1/(1-gamma), 0] (for rewards in {-1, 0}).
        max_grad_norm: gradient-norm clip (0 disables).
        normalize_inputs: standardise network inputs with running mean/std from the
            training batches (clipped to +-5), as the hindsight paper's implementation does.
        epsilon_start: probability of a uniformly random action when collecting starts.
        epsilon_end: that probability after ``epsilon_decay_steps``.
        epsilon_decay_steps: environment steps over which epsilon decays linearly (0: ``epsilon_end`` throughout).
        cql_alpha: weight of the conservative (CQL) penalty; 0 disables it.
    """

    lr: float = 1e-3
    gamma: float = 0.98
    hidden_sizes: tuple[int, ...] = (256,)
    loss: Literal["huber", "mse"] = "huber"
    double_q: bool = True
    target_update_interval: int = 1
    tau: float = 0.05
    clip_target: bool = True
    max_grad_norm: float = 10.0
    normalize_inputs: bool = True
    epsilon_start: float = 0.5
    epsilon_end: float = 0.05
    epsilon_decay_steps: int = 20_000
    cql_alpha: float = 0.0

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting."""
        check_learning_settings(self)
        one_of(self.loss, ("huber", "mse"), "loss", "loss")
        require(self.target_update_interval >= 1, "target_update_interval", f"must be >= 1 (got {self.target_update_interval})")
        check_probability(self, "epsilon_start", "epsilon_end")
        check_non_negative(self, "epsilon_decay_steps", "cql_alpha")


class QNetwork(nn.Module):
    """Q(s, .) for discrete actions: an input vector (and the task context on multi-task envs) ->
    MLP -> one value per action."""

    def __init__(
        self, in_dim: int, n_actions: int, hidden_sizes: tuple[int, ...], conditioning: TaskConditioning | None = None
    ) -> None:
        super().__init__()
        self.conditioned = conditioning is not None
        self.body = (
            network_for(in_dim, n_actions, hidden_sizes, conditioning)
            if self.conditioned
            else mlp(in_dim, hidden_sizes, n_actions)
        )

    def forward(self, x: torch.Tensor, context: torch.Tensor | None = None, task: torch.Tensor | None = None) -> torch.Tensor:
        return self.body(x, context, task) if self.conditioned else self.body(x)


class DQNAgent(Agent):
    """Deep Q-learning agent with a target network.

    Args:
        input_keys: observation keys the Q-network reads (e.g. ``("observation", "desired_goal")``).
        input_dim: total flattened size of those keys.
        n_actions: number of discrete actions.
        config: hyperparameters, see `DQNConfig`.
        device: torch device of the networks.
        conditioning: multi-task runs: the task encoder and architecture of the Q-network;
            observations then carry the task index under ``conditioning.task_key``.
    """

    acting = ("q", "normalize", "task_encoder")
    checkpointed = {
        "q": "q",
        "q_target": "q_target",
        "normalize": "inputs.normalize",
        "task_encoder": "task_encoder",
        "optimizer": "optimizer",
    }

    def __init__(
        self,
        input_keys: tuple[str, ...],
        input_dim: int,
        n_actions: int,
        config: DQNConfig,
        device: str | torch.device = "cpu",
        conditioning: TaskConditioning | None = None,
    ) -> None:
        self.setup(config, device, input_keys, input_dim, conditioning)  # online and target read the same input
        self.n_actions = n_actions
        self.q = QNetwork(input_dim, n_actions, config.hidden_sizes, conditioning).to(self.device)
        self.q_target = QNetwork(input_dim, n_actions, config.hidden_sizes, conditioning).to(self.device)
        self.q_target.load_state_dict(self.q.state_dict())
        self.q_target.requires_grad_(False)
        # Parameter lists cached once: walking the module tree every update costs more than the math.
        self._params, self._target_params = list(self.q.parameters()), list(self.q_target.parameters())
        # fused Adam: one kernel for all parameters (CPU and CUDA), ~15% faster updates on small nets.
        # the task encoder's own parameters (a learned embedding) learn from the TD loss
        encoder_params = list(self.task_encoder.parameters()) if self.task_encoder is not None else []
        self.optimizer = torch.optim.Adam(self._params + encoder_params, lr=config.lr, fused=True)
        self.updates = 0

    # ---------------------------------------------------------------- acting
    def epsilon(self, env_steps: int) -> float:
        """The exploration probability at ``env_steps`` (linear decay)."""
        c = self.config
        return linear_schedule(c.epsilon_start, c.epsilon_end, c.epsilon_decay_steps, env_steps)

    def exploration(self, env_steps: int) -> dict[str, float]:
        return {"epsilon": self.epsilon(env_steps)}

    def policy(self, obs: Obs, explore: bool, generator: torch.Generator | None, env_steps: int) -> torch.Tensor:
        """argmax_a Q(s, a); while exploring, a uniformly random action with probability epsilon."""
        greedy = self.q_values(obs).argmax(dim=1)
        epsilon = self.epsilon(env_steps) if explore else 0.0
        if epsilon > 0.0:
            n = greedy.shape[0]
            pick = torch.rand(n, generator=generator, device=self.device) < epsilon
            random_actions = torch.randint(0, self.n_actions, (n,), generator=generator, device=self.device)
            greedy = torch.where(pick, random_actions, greedy)
        return greedy

    def task_inputs(self, obs: Obs) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """``(context, task index)`` of a batch of observations; ``(None, None)`` for single-task agents."""
        return (None, None) if self.conditioning is None else self.conditioning.task_inputs(obs)

    def q_values(self, obs: Obs, network: nn.Module | None = None) -> torch.Tensor:
        """``Q(s, .)`` ``[B, n_actions]`` of the online network (or ``network``)."""
        return (network or self.q)(self.inputs(obs), *self.task_inputs(obs))

    @torch.no_grad()
    def q_value(self, obs: Obs, action: torch.Tensor) -> torch.Tensor:
        """``Q(s, a)`` of each row (no gradient): what conservative data sharing ranks rows by."""
        return self.q_values(obs).gather(1, action.long().view(-1, 1)).squeeze(1)

    # ---------------------------------------------------------------- learning
    def bellman_target(self, batch: Batch) -> torch.Tensor:
        """y = r + gamma * (1 - terminated) * Q_target(s', a*), a* from Q (double) or Q_target."""
        cfg = self.config
        with torch.no_grad():
            next_x, context, task = self.inputs(batch.next_obs), *self.task_inputs(batch.next_obs)  # read once, used twice
            next_q_target = self.q_target(next_x, context, task)
            if cfg.double_q:
                next_action = self.q(next_x, context, task).argmax(dim=1, keepdim=True)
                next_value = next_q_target.gather(1, next_action).squeeze(1)
            else:
                next_value = next_q_target.max(dim=1).values
            clip = negative_return_bounds(cfg.gamma) if cfg.clip_target else None
            return td_target(batch.reward, batch.terminated, next_value, cfg.gamma, clip)

    def update(self, batch: Batch) -> dict[str, torch.Tensor]:
        """One gradient step on the TD error, then the target refresh when due; returns detached scalars (``loss``,
        ``q_mean``). The refresh runs after the step, not inside it, so that a compiled update is one graph: a
        refresh inside would make a second graph, about half of DQN (64, 64) / 32's compile seconds (6.2 against 3.2
        s: benchmarks/RESULTS.md, "Compile seconds of a DQN update: the target refresh inside the graph and after
        it"). `update_many` keeps it inside."""
        metrics = self.counted_step(batch, flags=(False,))
        if self.schedule(self.updates)[0]:
            self.update_target()
        return metrics

    def schedule(self, update: int) -> tuple[bool]:
        """``(refresh_target,)``: every ``target_update_interval`` updates."""
        return (update % self.config.target_update_interval == 0,)

    def learn(self, batch: Batch, refresh_target: bool) -> dict[str, torch.Tensor]:
        """The update itself (what ``--compile`` compiles): the TD step, then the target average if due."""
        cfg = self.config
        self.inputs.update_statistics(batch.obs)
        target = self.bellman_target(batch)
        q_all = self.q_values(batch.obs)
        q_taken = q_all.gather(1, batch.action.long().view(-1, 1)).squeeze(1)
        loss = F.smooth_l1_loss(q_taken, target) if cfg.loss == "huber" else F.mse_loss(q_taken, target)
        metrics = {}
        if cfg.cql_alpha > 0:  # CQL: + alpha E[logsumexp_a Q(s, a) - Q(s, a_data)]
            gap = (torch.logsumexp(q_all, dim=1) - q_taken).mean()
            loss = loss + cfg.cql_alpha * gap
            metrics["cql_gap"] = gap.detach()

        gradient_step(self.optimizer, loss, self._params, cfg.max_grad_norm)
        if refresh_target:
            self.update_target()
        return {"loss": loss.detach(), "q_mean": q_taken.detach().mean(), **metrics}

    def update_target(self) -> None:
        """theta_target <- tau * theta + (1 - tau) * theta_target (tau = 1: hard copy)."""
        polyak_update(self._target_params, self._params, self.config.tau)


SPEC = AlgorithmSpec(
    name="dqn",
    description="deep Q-learning with a target network and double-Q (discrete actions)",
    config=DQNConfig,
    build=lambda inputs, config, device, conditioning: DQNAgent(
        inputs.keys, inputs.dim, int(inputs.action_space.n), config, device, conditioning
    ),
    loop="off_policy",
    actions=("discrete",),
    multitask=True,
    compiles=True,
    q_values=True,
)
