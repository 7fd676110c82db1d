"""DQN as fitted Q-iteration (Mnih et al., 2015), with double-Q (van Hasselt et al., 2016).

Each update regresses Q(s, a) onto the Bellman target

    y = r + gamma * (1 - terminated) * Q_target(s', argmax_a' Q(s', a'))     (double-Q)
    y = r + gamma * (1 - terminated) * max_a' Q_target(s', a')               (plain)

Time-limit truncation still bootstraps: only ``terminated`` zeroes the next value. With rewards
in {-1, 0} every return lies in [-1 / (1 - gamma), 0], so targets can be clipped there.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

import torch
import torch.nn.functional as F
from torch import nn

from taskrl.agents.parts import ObservationInput, as_batch, gradient_step
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


class QNetwork(nn.Module):
    """Q(s, .) for discrete actions: an input vector -> MLP -> one value per action."""

    def __init__(self, in_dim: int, n_actions: int, hidden_sizes: tuple[int, ...]) -> None:
        super().__init__()
        self.body = mlp(in_dim, hidden_sizes, n_actions)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.body(x)


class DQNAgent:
    """Deep Q-learning agent with a target network.

    Args:
        input_keys: observation keys the Q-network reads (e.g. ``("observation", "desired_goal")``).
        input_dim: total flattened size of those keys.
        n_actions: number of discrete actions.
        config: hyperparameters, see :class:`DQNConfig`.
        device: torch device of the networks.
    """

    def __init__(self, input_keys: tuple[str, ...], input_dim: int, n_actions: int, config: DQNConfig, device: str | torch.device = "cpu") -> None:
        self.config = config
        self.device = torch.device(device)
        self.n_actions = n_actions
        # The online and target networks read the same (normalised) input.
        self.inputs = ObservationInput(input_keys, input_dim, config.normalize_inputs).to(self.device)
        self.q = QNetwork(input_dim, n_actions, config.hidden_sizes).to(self.device)
        self.q_target = QNetwork(input_dim, n_actions, config.hidden_sizes).to(self.device)
        self.q_target.load_state_dict(self.q.state_dict())
        self.q_target.requires_grad_(False)
        # Parameter lists cached once: walking the module tree every update costs more than the math.
        self._params, self._target_params = list(self.q.parameters()), list(self.q_target.parameters())
        # fused Adam: one kernel for all parameters (CPU and CUDA), ~15% faster updates on small nets.
        self.optimizer = torch.optim.Adam(self._params, lr=config.lr, fused=True)
        self.updates = 0

    # ---------------------------------------------------------------- acting
    @torch.no_grad()
    def act(self, obs: Obs | dict[str, Any], epsilon: float = 0.0, generator: torch.Generator | None = None):
        """Epsilon-greedy actions for a batch of observations.

        Accepts the batched tensors of a native environment, or one numpy observation of a
        gymnasium environment (then returns a Python int).
        """
        obs, single = as_batch(obs, self.device)
        greedy = self.q(self.inputs(obs)).argmax(dim=1)
        if epsilon > 0.0:
            n = greedy.shape[0]
            explore = torch.rand(n, generator=generator, device=self.device) < epsilon
            random_actions = torch.randint(0, self.n_actions, (n,), generator=generator, device=self.device)
            greedy = torch.where(explore, random_actions, greedy)
        return int(greedy[0]) if single else greedy

    # ---------------------------------------------------------------- learning
    def bellman_target(self, batch: Batch) -> torch.Tensor:
        """y = r + gamma * (1 - terminated) * Q_target(s', a*), a* from Q (double) or Q_target."""
        cfg = self.config
        with torch.no_grad():
            next_x = self.inputs(batch.next_obs)
            next_q_target = self.q_target(next_x)
            if cfg.double_q:
                next_action = self.q(next_x).argmax(dim=1, keepdim=True)
                next_value = next_q_target.gather(1, next_action).squeeze(1)
            else:
                next_value = next_q_target.max(dim=1).values
            target = batch.reward + cfg.gamma * (~batch.terminated).float() * next_value
            if cfg.clip_target:
                target = target.clamp(-1.0 / (1.0 - cfg.gamma), 0.0)
        return target

    def update(self, batch: Batch) -> dict[str, torch.Tensor]:
        """One gradient step on the TD error; returns detached scalars (``loss``, ``q_mean``)."""
        cfg = self.config
        self.inputs.update_statistics(batch.obs)
        target = self.bellman_target(batch)
        q_taken = self.q(self.inputs(batch.obs)).gather(1, batch.action.long().view(-1, 1)).squeeze(1)
        loss = F.smooth_l1_loss(q_taken, target) if cfg.loss == "huber" else F.mse_loss(q_taken, target)

        gradient_step(self.optimizer, loss, self._params, cfg.max_grad_norm)

        self.updates += 1
        if self.updates % cfg.target_update_interval == 0:
            self.update_target()
        return {"loss": loss.detach(), "q_mean": q_taken.detach().mean()}

    @torch.no_grad()
    def update_target(self) -> None:
        """theta_target <- tau * theta + (1 - tau) * theta_target (tau = 1: hard copy)."""
        if self.config.tau >= 1.0:
            torch._foreach_copy_(self._target_params, self._params)
        else:
            torch._foreach_lerp_(self._target_params, self._params, self.config.tau)

    # ---------------------------------------------------------------- checkpointing
    def state_dict(self) -> dict[str, Any]:
        return {
            "q": self.q.state_dict(),
            "q_target": self.q_target.state_dict(),
            "normalize": self.inputs.normalize.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "updates": self.updates,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.q.load_state_dict(state["q"])
        self.q_target.load_state_dict(state["q_target"])
        self.inputs.normalize.load_state_dict(state["normalize"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.updates = int(state["updates"])
