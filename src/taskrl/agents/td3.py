"""TD3 (Fujimoto et al., 2018): a deterministic actor with twin critics, target smoothing and
delayed actor updates.

    a'  = clip(mu_target(s') + clip(eps, -c, c), -1, 1),   eps ~ N(0, target_noise^2)   (target smoothing)
    y   = r + gamma (1 - terminated) min_i Q_target_i(s', a')
    J_Q = sum_i 1/2 (Q_i(s, a) - y)^2
    every policy_delay updates:
        J_mu = -Q_1(s, mu(s));   theta_target <- tau theta + (1 - tau) theta_target (actor and critics)

Actions are in [-1, 1] inside the agent (mu = tanh(MLP)) and rescaled to the box outside.
``terminated`` stops bootstrapping; time-limit truncation bootstraps.

Exploration while collecting: a = clip(mu(s) + N(0, noise_std^2), -1, 1) (the paper: 0.1), and
with probability ``random_action_prob`` a uniformly random action instead (the hindsight paper's
Fetch exploration: noise 0.2, 30% random).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from taskrl.agents.base import Agent
from taskrl.agents.parts import (
    ActionBox,
    check_learning_settings,
    check_non_negative,
    check_probability,
    explore_in_box,
    gradient_step,
    negative_return_bounds,
    polyak_update,
    set_requires_grad,
    td_target,
)
from taskrl.agents.spec import AlgorithmSpec
from taskrl.errors import require
from taskrl.nets import StateActionQ, mlp
from taskrl.replay.batch import Batch, Obs


@dataclasses.dataclass
class TD3Config:
    """TD3 hyperparameters (the paper's defaults, on actions rescaled to [-1, 1]).

    Attributes:
        lr: Adam learning rate of the actor and the critics.
        gamma: discount factor.
        hidden_sizes: widths of the hidden layers of the actor and of each critic.
        tau: Polyak factor of the target networks at each actor update.
        policy_delay: critic updates per actor (and target) update.
        target_noise: std of the Gaussian smoothing noise on target actions.
        target_noise_clip: bound on that noise.
        clip_target: clip targets to [-1/(1-gamma), 0] (for rewards in {-1, 0}).
        max_grad_norm: gradient-norm clip (0 disables).
        normalize_inputs: standardise observation inputs with running mean/std (clipped to +-5).
        noise_std: while collecting, std of the Gaussian noise added to mu(s), in half-widths of the box (the paper: 0.1).
        random_action_prob: while collecting, the fraction of actions drawn uniformly from the box
            instead (the hindsight paper's Fetch exploration: 0.3, with Gaussian noise 0.2).
    """

    lr: float = 3e-4
    gamma: float = 0.99
    hidden_sizes: tuple[int, ...] = (256, 256)
    tau: float = 0.005
    policy_delay: int = 2
    target_noise: float = 0.2
    target_noise_clip: float = 0.5
    clip_target: bool = False
    max_grad_norm: float = 0.0
    normalize_inputs: bool = True
    noise_std: float = 0.1
    random_action_prob: float = 0.0

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting."""
        check_learning_settings(self)
        require(self.policy_delay >= 1, "policy_delay", f"must be >= 1 (got {self.policy_delay})")
        check_non_negative(self, "target_noise", "target_noise_clip", "noise_std")
        check_probability(self, "random_action_prob")


class DeterministicActor(nn.Module):
    """mu(s) = tanh(MLP(s)) in [-1, 1]^A."""

    def __init__(self, in_dim: int, action_dim: int, hidden_sizes: tuple[int, ...]) -> None:
        super().__init__()
        self.body = mlp(in_dim, hidden_sizes, action_dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.body(x))


class TD3Agent(Agent):
    """TD3 agent.

    Args:
        input_keys: observation keys the networks read.
        input_dim: total flattened size of those keys.
        action_space: a gymnasium ``Box`` or a ``(low, high)`` pair of tensors / arrays.
        config: hyperparameters, see `TD3Config`.
        device: torch device of the networks.
    """

    acting = ("actor", "normalize")
    checkpointed = {
        "actor": "actor",
        "actor_target": "actor_target",
        "critics": "critics",
        "critics_target": "critics_target",
        "normalize": "inputs.normalize",
        "actor_optimizer": "actor_optimizer",
        "critic_optimizer": "critic_optimizer",
    }

    def __init__(
        self,
        input_keys: tuple[str, ...],
        input_dim: int,
        action_space: Any,
        config: TD3Config,
        device: str | torch.device = "cpu",
    ) -> None:
        self.setup(config, device, input_keys, input_dim)
        self.box = ActionBox(action_space, self.device)
        self.action_dim = self.box.dim
        self.actor = DeterministicActor(input_dim, self.action_dim, config.hidden_sizes).to(self.device)
        self.actor_target = DeterministicActor(input_dim, self.action_dim, config.hidden_sizes).to(self.device)
        self.critics = nn.ModuleList(StateActionQ(input_dim, self.action_dim, config.hidden_sizes) for _ in range(2)).to(
            self.device
        )
        self.critics_target = nn.ModuleList(StateActionQ(input_dim, self.action_dim, config.hidden_sizes) for _ in range(2)).to(
            self.device
        )
        self.actor_target.load_state_dict(self.actor.state_dict())
        self.critics_target.load_state_dict(self.critics.state_dict())
        self.actor_target.requires_grad_(False)
        self.critics_target.requires_grad_(False)
        self._actor_params, self._critic_params = list(self.actor.parameters()), list(self.critics.parameters())
        self._online_params = self._actor_params + self._critic_params
        self._target_params = list(self.actor_target.parameters()) + list(self.critics_target.parameters())
        self.actor_optimizer = torch.optim.Adam(self._actor_params, lr=config.lr, fused=True)
        self.critic_optimizer = torch.optim.Adam(self._critic_params, lr=config.lr, fused=True)
        self.updates = 0
        self._last_actor_loss = torch.zeros((), device=self.device)

    # ---------------------------------------------------------------- acting
    def policy(self, obs: Obs, explore: bool, generator: torch.Generator | None, env_steps: int) -> torch.Tensor:
        """mu(s) in the action box; while exploring, plus Gaussian noise of std ``noise_std`` x half-width,
        clipped to the box, and with probability ``random_action_prob`` a uniformly random action instead."""
        unit = self.actor(self.inputs(obs))
        if explore:
            unit = explore_in_box(unit, self.config.noise_std, self.config.random_action_prob, generator)
        return self.box.from_unit(unit)

    # ---------------------------------------------------------------- learning
    def bellman_target(self, batch: Batch, generator: torch.Generator | None = None) -> torch.Tensor:
        """y = r + gamma (1 - terminated) min_i Q_target_i(s', clip(mu_target(s') + clipped noise, -1, 1))."""
        cfg = self.config
        with torch.no_grad():
            next_x = self.inputs(batch.next_obs)
            next_action = self.actor_target(next_x)
            if cfg.target_noise > 0:
                eps = torch.randn(next_action.shape, generator=generator, device=self.device) * cfg.target_noise
                next_action = (next_action + eps.clamp(-cfg.target_noise_clip, cfg.target_noise_clip)).clamp(-1.0, 1.0)
            next_q = torch.minimum(*(q(next_x, next_action) for q in self.critics_target))
            clip = negative_return_bounds(cfg.gamma) if cfg.clip_target else None
            return td_target(batch.reward, batch.terminated, next_q, cfg.gamma, clip)

    def update(self, batch: Batch, generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
        """A critic step; every ``policy_delay`` updates also an actor step and the target update.
        Returns detached scalars ``critic_loss``, ``actor_loss`` (the latest), ``q_mean``."""
        return self.counted_step(batch, generator)

    def schedule(self, update: int) -> tuple[bool]:
        """``(actor_step,)``: every ``policy_delay`` updates."""
        return (update % self.config.policy_delay == 0,)

    def learn(self, batch: Batch, actor_step: bool, generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
        """The update itself (what ``--compile`` compiles): the critic step; with ``actor_step`` also the
        actor step and the target average."""
        self.inputs.update_statistics(batch.obs)
        target = self.bellman_target(batch, generator)
        x, action = self.inputs(batch.obs), self.box.to_unit(batch.action)
        q1, q2 = (q(x, action) for q in self.critics)
        critic_loss = 0.5 * (F.mse_loss(q1, target) + F.mse_loss(q2, target))
        gradient_step(self.critic_optimizer, critic_loss, self._critic_params, self.config.max_grad_norm)

        if actor_step:
            set_requires_grad(self._critic_params, False)
            actor_loss = -self.critics[0](x, self.actor(x)).mean()
            gradient_step(self.actor_optimizer, actor_loss, self._actor_params, self.config.max_grad_norm)
            set_requires_grad(self._critic_params, True)
            self._last_actor_loss.copy_(actor_loss.detach())
            self.update_target()
        return {"critic_loss": critic_loss.detach(), "actor_loss": self._last_actor_loss.clone(), "q_mean": q1.detach().mean()}

    def update_target(self) -> None:
        """theta_target <- tau * theta + (1 - tau) * theta_target, actor and critics."""
        polyak_update(self._target_params, self._online_params, self.config.tau)


SPEC = AlgorithmSpec(
    name="td3",
    description="TD3: a deterministic actor, twin critics, target smoothing and delayed actor updates",
    config=TD3Config,
    build=lambda inputs, config, device, conditioning: TD3Agent(inputs.keys, inputs.dim, inputs.action_space, config, device),
    loop="off_policy",
    actions=("box",),
    compiles=True,
)
