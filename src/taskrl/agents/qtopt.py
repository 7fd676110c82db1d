"""QT-Opt (Kalashnikov et al., 2018): Q-learning over continuous actions, argmax by CEM.

There is no actor. A network Q(s, a) is regressed onto clipped double-Q targets whose max over
actions is found by the cross-entropy method (``agents/cem.py``):

    a* = CEM-argmax_a Q_target1(s', a)
    y  = r + gamma * (1 - terminated) * min(Q_target1(s', a*), Q_target2(s', a*))

Two target networks, one lagging the other, as in the paper: ``target1`` is a Polyak average of
the online network (the paper: averaging constant 0.9999, i.e. tau = 1e-4), ``target2`` is a
copy of ``target1`` taken every ``target2_interval`` updates (the paper: lagged by about 6000
gradient steps), so it trails ``target1`` by 0 to ``target2_interval`` - 1 updates.

In the paper the targets come from separate "Bellman updater" processes and the regression from
the "trainer": :meth:`QTOptAgent.bellman_target` reads only the batch, the target networks and
the shared input normaliser, and :meth:`QTOptAgent.regress` takes the batch with its targets.
:meth:`QTOptAgent.update` runs one after the other.

Loss: ``huber`` / ``mse`` on Q directly, or ``cross_entropy`` as in the paper for rewards in
[0, 1]: the network outputs a logit, Q = sigmoid(logit), targets are clipped to [0, 1] and the
loss is the log loss -(y log Q + (1 - y) log(1 - Q)).

Actions: the networks see actions rescaled from the box [low, high] to [-1, 1]; CEM searches in
that normalised box and acting maps the result back.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

import torch
import torch.nn.functional as F
from torch import nn

from taskrl.agents.cem import CEMConfig, CrossEntropyMethod
from taskrl.agents.parts import ActionBox, ObservationInput, as_batch, explore_in_box, gradient_step
from taskrl.nets import mlp
from taskrl.replay.batch import Batch, Obs


@dataclasses.dataclass
class QTOptConfig:
    """QT-Opt hyperparameters.

    Attributes:
        lr: Adam learning rate.
        gamma: discount factor.
        hidden_sizes: widths of the Q-network's hidden layers.
        loss: ``huber``, ``mse``, or ``cross_entropy`` (log loss on Q = sigmoid(logit), rewards
            in [0, 1], targets clipped to [0, 1], as in the paper).
        tau: Polyak factor of the first target network at every update.
        target2_interval: updates between copies of the first target network into the second.
        clip_target: clip targets to [-1/(1-gamma), 0] (for rewards in {-1, 0}; huber/mse only).
        max_grad_norm: gradient-norm clip (0 disables).
        normalize_inputs: standardise observation inputs with running mean/std (clipped to +-5).
        noise_std: while collecting, std of Gaussian noise added to the CEM action (half-widths of
            the box); the loop's exploration level is the probability of a uniformly random action.
        cem: cross-entropy-method settings, used both to act and in the Bellman target.
    """

    lr: float = 1e-3
    gamma: float = 0.98
    hidden_sizes: tuple[int, ...] = (256, 256)
    loss: Literal["huber", "mse", "cross_entropy"] = "huber"
    tau: float = 0.005
    target2_interval: int = 200
    clip_target: bool = False
    max_grad_norm: float = 10.0
    normalize_inputs: bool = True
    noise_std: float = 0.0
    cem: CEMConfig = dataclasses.field(default_factory=CEMConfig)


class StateActionQ(nn.Module):
    """Q(x, a) = MLP([x, a]) -> one value per (state, action) pair.

    ``score_actions(x, actions)`` evaluates N actions for each of B states in one call. It splits
    the first layer, W [x; a] + b = (W_x x + b) + W_a a, so the state's share is computed once
    per state instead of once per sample and no [B * N, in] copy of the states is built.
    """

    def __init__(self, in_dim: int, action_dim: int, hidden_sizes: tuple[int, ...]) -> None:
        super().__init__()
        self.in_dim = in_dim
        self.body = mlp(in_dim + action_dim, hidden_sizes, 1)

    def forward(self, x: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """x [B, D], action [B, A] -> [B]."""
        return self.body(torch.cat([x, action], dim=-1)).squeeze(-1)

    def score_actions(self, x: torch.Tensor, actions: torch.Tensor, chunk_rows: int | None = None) -> torch.Tensor:
        """x [B, D], actions [B, N, A] -> [B, N]: Q(x_b, a_bn) for all B * N pairs, for ``no_grad`` use (CEM).

        On CPU the rows go through the network in chunks of about ``chunk_rows`` (default 2048 per
        torch thread): a chunk's activations (2048 x 256 floats = 2 MiB) stay in cache between
        layers, which measured 2x faster (one thread) than one pass over all 16384 rows of a
        256-state, 64-sample CEM round. On GPU (or with ``chunk_rows=0``) it is one pass. Rows
        stay 2-D (a 3-D input makes ``Linear`` ~35% slower on CPU) and ReLUs run in place.
        """
        b, n, _ = actions.shape
        if chunk_rows is None:
            chunk_rows = 0 if x.is_cuda else 2048 * torch.get_num_threads()
        per_chunk = b if chunk_rows <= 0 else max(1, chunk_rows // n)
        if per_chunk >= b:
            return self._score(x, actions)
        return torch.cat([self._score(x[i : i + per_chunk], actions[i : i + per_chunk]) for i in range(0, b, per_chunk)])

    def _score(self, x: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        b, n, a = actions.shape
        first = self.body[0]
        state_part = F.linear(x, first.weight[:, : self.in_dim], first.bias)           # [b, H], once per state
        h = actions.reshape(b * n, a) @ first.weight[:, self.in_dim :].T                # [b * n, H]
        h.view(b, n, -1).add_(state_part.unsqueeze(1))
        for layer in self.body[1:]:
            h = h.relu_() if isinstance(layer, nn.ReLU) else layer(h)
        return h.view(b, n)


class QTOptAgent:
    """QT-Opt agent: a Q(s, a) network, two lagged target networks, CEM to act and to target.

    Args:
        input_keys: observation keys the Q-network reads (e.g. ``("observation", "desired_goal")``).
        input_dim: total flattened size of those keys.
        action_space: a gymnasium ``Box`` or a ``(low, high)`` pair of tensors / arrays.
        config: hyperparameters, see :class:`QTOptConfig`.
        device: torch device of the networks.
    """

    def __init__(self, input_keys: tuple[str, ...], input_dim: int, action_space: Any, config: QTOptConfig, device: str | torch.device = "cpu") -> None:
        if config.loss not in ("huber", "mse", "cross_entropy"):
            raise ValueError(f"loss: unknown loss {config.loss!r}; allowed: huber, mse, cross_entropy")
        if not 0.0 < config.tau <= 1.0:
            raise ValueError(f"tau: must be in (0, 1] (got {config.tau})")
        if config.target2_interval < 1:
            raise ValueError(f"target2_interval: must be >= 1 (got {config.target2_interval})")
        self.config = config
        self.device = torch.device(device)
        self.box = ActionBox(action_space, self.device)
        self.action_dim = self.box.dim
        self.unit_low, self.unit_high = -torch.ones_like(self.box.low), torch.ones_like(self.box.high)
        self.inputs = ObservationInput(input_keys, input_dim, config.normalize_inputs).to(self.device)
        self.q = StateActionQ(input_dim, self.action_dim, config.hidden_sizes).to(self.device)
        self.q_target1 = StateActionQ(input_dim, self.action_dim, config.hidden_sizes).to(self.device)
        self.q_target2 = StateActionQ(input_dim, self.action_dim, config.hidden_sizes).to(self.device)
        for target in (self.q_target1, self.q_target2):
            target.load_state_dict(self.q.state_dict())
            target.requires_grad_(False)
        self.cem = CrossEntropyMethod(config.cem)
        self._params = list(self.q.parameters())
        self._target1_params, self._target2_params = list(self.q_target1.parameters()), list(self.q_target2.parameters())
        self.optimizer = torch.optim.Adam(self._params, lr=config.lr, fused=True)
        self.updates = 0

    # ---------------------------------------------------------------- helpers
    def q_value(self, out: torch.Tensor) -> torch.Tensor:
        """Network output -> Q: a probability sigmoid(logit) for the cross-entropy loss."""
        return torch.sigmoid(out) if self.config.loss == "cross_entropy" else out

    def argmax(self, net: StateActionQ, x: torch.Tensor, generator: torch.Generator | None = None,
               warm_start: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """CEM over [-1, 1]^A: ``(a* [B, A] in [-1, 1], net output at a* [B])``, one forward pass per round.

        ``warm_start`` (``[B, A]`` in [-1, 1]) starts the search there (``cem.warm_std``, ``cem.warm_iterations``).
        """
        return self.cem.maximize(lambda a: net.score_actions(x, a), x.shape[0], self.unit_low, self.unit_high,
                                 init_mean=warm_start, generator=generator)

    # ---------------------------------------------------------------- acting
    @torch.no_grad()
    def act(self, obs: Obs | dict[str, Any], exploration: float = 0.0, generator: torch.Generator | None = None):
        """CEM-greedy actions [B, A] in the action box; while collecting (``exploration`` > 0),
        Gaussian noise of std ``noise_std`` around them and, with probability ``exploration`` per
        state, a uniformly random action in the box instead (epsilon-greedy over a continuous box).

        Accepts batched tensors, or one numpy observation of a gymnasium environment (then
        returns a numpy action of shape [A]).
        """
        obs, single = as_batch(obs, self.device)
        x = self.inputs(obs)
        unit, _ = self.argmax(self.q, x, generator)
        if exploration > 0.0:
            unit = explore_in_box(unit, self.config.noise_std, exploration, generator)
        action = self.box.from_unit(unit)
        return action[0].cpu().numpy() if single else action

    # ---------------------------------------------------------------- learning
    def bellman_target(self, batch: Batch, generator: torch.Generator | None = None,
                       warm_start: torch.Tensor | None = None, return_action: bool = False):
        """y = r + gamma (1 - terminated) min(Q_target1(s', a*), Q_target2(s', a*)), a* = CEM argmax of Q_target1.

        Reads only the batch, the two target networks and the input normaliser (a Bellman
        updater can run it on its own copy of those). A Bellman updater that recomputes targets
        for the same transitions can pass the previous ``a*`` (box units) as ``warm_start`` to
        search near it with fewer rounds, and gets ``(y, a*)`` back with ``return_action``.
        """
        cfg = self.config
        with torch.no_grad():
            next_x = self.inputs(batch.next_obs)
            warm = None if warm_start is None else self.box.to_unit(warm_start)
            next_action, out1 = self.argmax(self.q_target1, next_x, generator, warm)  # out1 = Q_target1(s', a*), from CEM
            out2 = self.q_target2(next_x, next_action)
            next_value = self.q_value(torch.minimum(out1, out2))                       # sigmoid is monotone
            target = batch.reward.float() + cfg.gamma * (~batch.terminated).float() * next_value
            if cfg.loss == "cross_entropy":
                target = target.clamp(0.0, 1.0)
            elif cfg.clip_target:
                target = target.clamp(-1.0 / (1.0 - cfg.gamma), 0.0)
        return (target, self.box.from_unit(next_action)) if return_action else target

    def regress(self, batch: Batch, target: torch.Tensor) -> dict[str, torch.Tensor]:
        """One gradient step of Q(s, a) towards ``target`` (the trainer's step); refreshes the targets.

        Returns detached scalars: ``loss``, ``q_mean`` (Q of the batch's actions), ``target_mean``.
        """
        cfg = self.config
        self.inputs.update_statistics(batch.obs)
        out = self.q(self.inputs(batch.obs), self.box.to_unit(batch.action))
        if cfg.loss == "cross_entropy":
            loss = F.binary_cross_entropy_with_logits(out, target)
        elif cfg.loss == "huber":
            loss = F.smooth_l1_loss(out, target)
        else:
            loss = F.mse_loss(out, target)

        gradient_step(self.optimizer, loss, self._params, cfg.max_grad_norm)

        self.updates += 1
        self.update_targets()
        return {"loss": loss.detach(), "q_mean": self.q_value(out.detach()).mean(), "target_mean": target.mean()}

    def update(self, batch: Batch, generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
        """Bellman target then regression: ``regress(batch, bellman_target(batch))``."""
        return self.regress(batch, self.bellman_target(batch, generator))

    @torch.no_grad()
    def update_targets(self) -> None:
        """target1 <- tau * online + (1 - tau) * target1; every target2_interval updates target2 <- target1."""
        torch._foreach_lerp_(self._target1_params, self._params, self.config.tau)
        if self.updates % self.config.target2_interval == 0:
            torch._foreach_copy_(self._target2_params, self._target1_params)

    # ---------------------------------------------------------------- checkpointing
    def state_dict(self) -> dict[str, Any]:
        return {
            "q": self.q.state_dict(),
            "q_target1": self.q_target1.state_dict(),
            "q_target2": self.q_target2.state_dict(),
            "normalize": self.inputs.normalize.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "updates": self.updates,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.q.load_state_dict(state["q"])
        self.q_target1.load_state_dict(state["q_target1"])
        self.q_target2.load_state_dict(state["q_target2"])
        self.inputs.normalize.load_state_dict(state["normalize"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.updates = int(state["updates"])
