"""Soft actor-critic (Haarnoja et al., 2018), with twin critics and a learned temperature.

Policy: a tanh-squashed Gaussian. For a state s the actor outputs mu(s) and log sigma(s), and

    u ~ N(mu, sigma^2),   a = tanh(u) in [-1, 1]^A,   action in the box = centre + half-width * a
    log pi(a|s) = sum_j [ log N(u_j; mu_j, sigma_j^2) - log(1 - tanh(u_j)^2) ]      (change of variables)

with log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)), which stays finite where tanh(u) = +-1
in float32. Log-probabilities and entropies are those of the [-1, 1] action (the constant
-sum log half-width of the box is left out), so the default target entropy -|A| means the
same thing whatever the bounds.

Losses, for a batch (s, a, r, s', terminated) and alpha = exp(log_alpha):

    y          = r + gamma (1 - terminated) (min_i Q_target_i(s', a') - alpha log pi(a'|s')),  a' ~ pi(.|s')
    J_Q        = sum_i 1/2 (Q_i(s, a) - y)^2
    J_pi       = alpha log pi(a~|s) - min_i Q_i(s, a~),  a~ ~ pi(.|s) (reparameterised)
    J_alpha    = -log_alpha (log pi(a~|s) + target_entropy)

Conservative Q-learning (Kumar et al., 2020; CQL(H)), for learning from a fixed dataset: with
``cql_alpha > 0`` the critic loss adds, per critic,

    cql_alpha * E_s [ log (1/2N) sum_k exp(Q_i(s, a_k) - log mu(a_k)) - Q_i(s, a_data) ]

over N uniform actions (mu = 2^-A) and N actions of the current policy (mu = pi(a|s)): an importance-
sampled logsumexp over all actions, so Q-values of actions the data did not take are pushed down.

Q_target_i follow Q_i by Polyak averaging. ``terminated`` stops bootstrapping; time-limit
truncation still bootstraps. With rewards in {-1, 0}, targets may be clipped to [-1/(1-gamma), 0].

From pixels (DrQ, Kostrikov et al., 2021): on an env with a camera, one conv encoder f (``--encoder``) turns
the picture into features shared by the actor and both critics; the critic loss trains it, the actor reads
f(s) as a constant; the target critics read a Polyak-averaged copy of it; every update shifts every picture
of s and s' at random (the camera's ``--shift``, DrQ's 4 pixels by default).

Multi-task SAC (Yu et al., 2019; Sodhani et al., 2021): given a
[`TaskConditioning`][taskrl.conditioning.networks.TaskConditioning], the actor and both critics take the task
context c = encoder(task) as well (``concat``, ``film`` or ``care``; optionally one output head per
task), every row of a batch with its own task, all tasks in one forward pass. The temperature is
per task, alpha_k = exp(log_alpha[k]), so a task that is already solved does not set the
exploration of one still being learnt; each row uses its own task's alpha in the three losses above,
and J_alpha averages over rows (a task-balanced batch gives every task's alpha equal weight). The
task encoder's parameters (a learned embedding, a language projection) are trained by the critic
loss; the actor sees the context as a constant, as in CARE's reference implementation.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from taskrl.agents.base import Agent
from taskrl.agents.parts import (
    ActionBox,
    check_learning_settings,
    gradient_step,
    negative_return_bounds,
    polyak_update,
    set_requires_grad,
    share_on_bound,
    td_target,
)
from taskrl.agents.spec import AlgorithmSpec
from taskrl.conditioning.networks import TaskConditioning, network_for
from taskrl.encoders import DRQ_SHIFT, ImageStateInput, PictureCoordinate, picture_encoder, picture_values, shift_pictures
from taskrl.errors import require
from taskrl.replay.batch import Batch, Obs

_LOG_2PI = math.log(2 * math.pi)
_LOG_2 = math.log(2.0)


@dataclasses.dataclass
class SACConfig:
    """SAC hyperparameters.

    Attributes:
        lr: Adam learning rate of the actor, the critics and the temperature.
        gamma: discount factor.
        hidden_sizes: widths of the hidden layers of the actor and of each critic.
        tau: Polyak factor of the target critics at every update.
        init_alpha: initial entropy temperature.
        learn_alpha: adapt the temperature towards the target entropy.
        target_entropy_per_dim: target entropy per action dimension (-1 gives the usual -|A|).
        clip_target: clip targets to [-1/(1-gamma), 0] (for rewards in {-1, 0}).
        max_grad_norm: gradient-norm clip of the actor and critics (0 disables).
        normalize_inputs: standardise observation inputs with running mean/std (clipped to +-5).
        log_std_min, log_std_max: range of the policy's log standard deviation.
        per_task_alpha: multi-task runs: one learned temperature per task (else one shared).
        cql_alpha: weight of the conservative (CQL) penalty on the critics; 0 disables it.
        cql_samples: CQL: uniform and policy actions per state (N of each) in its logsumexp.
        encoder: on envs with a camera, the registered picture encoder (`taskrl.encoders`) shared by the actor and
            the critics.
        image_features: the encoded picture's size (a linear layer, LayerNorm and tanh after the encoder).
    """

    lr: float = 3e-4
    gamma: float = 0.99
    hidden_sizes: tuple[int, ...] = (256, 256)
    tau: float = 0.005
    init_alpha: float = 1.0
    learn_alpha: bool = True
    target_entropy_per_dim: float = -1.0
    clip_target: bool = False
    max_grad_norm: float = 0.0
    normalize_inputs: bool = True
    log_std_min: float = -5.0
    log_std_max: float = 2.0
    per_task_alpha: bool = True
    cql_alpha: float = 0.0
    cql_samples: int = 10
    encoder: str = "conv"
    image_features: int = 50

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting."""
        check_learning_settings(self)
        picture_encoder(self.encoder)
        require(self.image_features >= 1, "image_features", f"must be >= 1 (got {self.image_features})")
        require(self.init_alpha > 0, "init_alpha", f"must be > 0 (got {self.init_alpha})")
        require(self.cql_alpha >= 0, "cql_alpha", f"must be >= 0 (got {self.cql_alpha})")
        require(self.cql_samples >= 1, "cql_samples", f"must be >= 1 (got {self.cql_samples})")
        require(
            self.log_std_min < self.log_std_max,
            "log_std_min",
            f"must be below log_std_max={self.log_std_max} (got {self.log_std_min})",
        )


def squashed_gaussian_log_prob(u: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """log density of a = tanh(u), u ~ N(mean, exp(log_std)^2), summed over the last dimension."""
    gaussian = -0.5 * ((u - mean) * torch.exp(-log_std)).square() - log_std - 0.5 * _LOG_2PI
    log_det = 2.0 * (_LOG_2 - u - F.softplus(-2.0 * u))  # log(1 - tanh(u)^2), stable
    return (gaussian - log_det).sum(-1)


class SquashedGaussianActor(nn.Module):
    """pi(a|s, c): a network giving the mean and log std of u, and a = tanh(u) in [-1, 1]^A.

    ``conditioning`` (multi-task) makes the network take the task context and index as well.
    """

    def __init__(
        self,
        in_dim: int,
        action_dim: int,
        hidden_sizes: tuple[int, ...],
        log_std_min: float,
        log_std_max: float,
        conditioning: TaskConditioning | None = None,
    ) -> None:
        super().__init__()
        self.body = network_for(in_dim, 2 * action_dim, hidden_sizes, conditioning)
        self.log_std_min, self.log_std_max = log_std_min, log_std_max

    def forward(
        self, x: torch.Tensor, context: torch.Tensor | None = None, task: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean, log_std) of u; log_std squashed smoothly into [log_std_min, log_std_max]."""
        mean, raw = self.body(x, context, task).chunk(2, dim=-1)
        log_std = self.log_std_min + 0.5 * (self.log_std_max - self.log_std_min) * (torch.tanh(raw) + 1.0)
        return mean, log_std

    def sample(
        self,
        x: torch.Tensor,
        generator: torch.Generator | None = None,
        context: torch.Tensor | None = None,
        task: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparameterised sample ``a = tanh(mean + std * eps)`` in [-1, 1] and ``log pi(a|s)``."""
        mean, log_std = self(x, context, task)
        eps = torch.randn(mean.shape, generator=generator, device=mean.device, dtype=mean.dtype)
        u = mean + log_std.exp() * eps
        return torch.tanh(u), squashed_gaussian_log_prob(u, mean, log_std)

    def mode(self, x: torch.Tensor, context: torch.Tensor | None = None, task: torch.Tensor | None = None) -> torch.Tensor:
        """The deterministic action tanh(mean)."""
        return torch.tanh(self(x, context, task)[0])


class Critic(nn.Module):
    """Q(s, a, c) -> [B]: the action joins the state after the task conditioning (if any)."""

    def __init__(
        self, in_dim: int, action_dim: int, hidden_sizes: tuple[int, ...], conditioning: TaskConditioning | None = None
    ) -> None:
        super().__init__()
        self.body = network_for(in_dim, 1, hidden_sizes, conditioning, extra_dim=action_dim)

    def forward(
        self, x: torch.Tensor, action: torch.Tensor, context: torch.Tensor | None = None, task: torch.Tensor | None = None
    ) -> torch.Tensor:
        return self.body(x, context, task, extra=action).squeeze(-1)


class SACAgent(Agent):
    """Soft actor-critic agent.

    Args:
        input_keys: observation keys the networks read (e.g. ``("observation", "desired_goal")``).
        input_dim: total flattened size of those keys.
        action_space: a gymnasium ``Box`` or a ``(low, high)`` pair of tensors / arrays.
        config: hyperparameters, see `SACConfig`.
        device: torch device of the networks.
        conditioning: multi-task runs: the task encoder and architecture the actor and critics
            use; observations then carry the task index under ``conditioning.task_key``.
        image_shape: ``(H, W, C)`` of an ``image`` observation (the last of ``input_keys``), or None.
        picture_shift: pixels of DrQ's random shift of the pictures in every update (0: none; None: DrQ's 4).
        picture_coordinates: vector entries that are positions in the picture's frame, moved with the shift
            (`taskrl.encoders.PictureCoordinate`).
    """

    acting = ("actor", "normalize", "task_encoder", "encoder")
    checkpointed = {
        "encoder": "encoder",
        "encoder_target": "encoder_target",
        "actor": "actor",
        "critics": "critics",
        "critics_target": "critics_target",
        "log_alpha": "log_alpha",
        "normalize": "inputs.normalize",
        "task_encoder": "task_encoder",
        "actor_optimizer": "actor_optimizer",
        "critic_optimizer": "critic_optimizer",
        "alpha_optimizer": "alpha_optimizer",
    }

    def __init__(
        self,
        input_keys: tuple[str, ...],
        input_dim: int,
        action_space: Any,
        config: SACConfig,
        device: str | torch.device = "cpu",
        conditioning: TaskConditioning | None = None,
        image_shape: tuple[int, ...] | None = None,
        picture_shift: int | None = None,
        picture_coordinates: tuple[PictureCoordinate, ...] = (),
    ) -> None:
        self.image_shape = tuple(image_shape) if image_shape is not None else None
        self.picture_shift = DRQ_SHIFT if picture_shift is None else int(picture_shift)
        self.picture_coordinates = tuple(picture_coordinates)
        raw = picture_values(self.image_shape) if self.image_shape is not None else 0
        self.setup(config, device, input_keys, input_dim, conditioning, picture_dim=raw)
        self.box = ActionBox(action_space, self.device)
        self.action_dim = self.box.dim
        self.target_entropy = config.target_entropy_per_dim * self.action_dim
        self.num_tasks = conditioning.num_tasks if conditioning is not None else 1
        # DrQ: one picture encoder for the actor and the critics (trained by the critic loss), a lagged copy for the targets
        self.encoder = self.encoder_target = None
        if self.image_shape is not None:
            self.encoder = ImageStateInput(input_dim - raw, self.image_shape, config.encoder, config.image_features).to(
                self.device
            )
            self.encoder_target = ImageStateInput(input_dim - raw, self.image_shape, config.encoder, config.image_features)
            self.encoder_target = self.encoder_target.to(self.device).requires_grad_(False)
            self.encoder_target.load_state_dict(self.encoder.state_dict())
            input_dim = self.encoder.out_dim
        self.actor = SquashedGaussianActor(
            input_dim, self.action_dim, config.hidden_sizes, config.log_std_min, config.log_std_max, conditioning
        ).to(self.device)
        self.critics = nn.ModuleList(Critic(input_dim, self.action_dim, config.hidden_sizes, conditioning) for _ in range(2)).to(
            self.device
        )
        self.critics_target = nn.ModuleList(
            Critic(input_dim, self.action_dim, config.hidden_sizes, conditioning) for _ in range(2)
        ).to(self.device)
        self.critics_target.load_state_dict(self.critics.state_dict())
        self.critics_target.requires_grad_(False)
        alphas = self.num_tasks if config.per_task_alpha else 1
        self.log_alpha = torch.full((alphas,), math.log(config.init_alpha), device=self.device, requires_grad=True)
        self._actor_params, self._critic_params = list(self.actor.parameters()), list(self.critics.parameters())
        self._target_params = list(self.critics_target.parameters())
        if self.encoder is not None:  # the picture encoder follows the critics: trained by their loss, Polyak-averaged
            self._critic_params += list(self.encoder.parameters())
            self._target_params += list(self.encoder_target.parameters())
        # The task encoder's own parameters (learned embedding, language projection) learn from the critics' loss.
        encoder_params = list(self.task_encoder.parameters()) if self.task_encoder is not None else []
        self.actor_optimizer = torch.optim.Adam(self._actor_params, lr=config.lr, fused=True)
        self.critic_optimizer = torch.optim.Adam(self._critic_params + encoder_params, lr=config.lr, fused=True)
        self.alpha_optimizer = torch.optim.Adam([self.log_alpha], lr=config.lr, fused=True)
        self.updates = 0

    # ---------------------------------------------------------------- helpers
    @property
    def alpha(self) -> torch.Tensor:
        """The temperature of every task, ``[T]`` (``[1]`` when shared)."""
        return self.log_alpha.detach().exp()

    def task_inputs(self, obs: Obs) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """``(context, task index)`` of a batch of observations; ``(None, None)`` for single-task agents."""
        return (None, None) if self.conditioning is None else self.conditioning.task_inputs(obs)

    def features(self, obs: Obs) -> torch.Tensor:
        """The networks' input for ``obs``: the normalised vector, and the encoded picture on envs with a camera."""
        x = self.inputs(obs)
        return x if self.encoder is None else self.encoder(x)

    def _row_alpha(self, task: torch.Tensor | None, log_alpha: torch.Tensor) -> torch.Tensor:
        """Each row's entry of ``log_alpha`` (or of its exp): its task's when per task, else the shared one."""
        return log_alpha[task] if task is not None and log_alpha.shape[0] > 1 else log_alpha[0]

    # ---------------------------------------------------------------- acting
    def policy(self, obs: Obs, explore: bool, generator: torch.Generator | None, env_steps: int) -> torch.Tensor:
        """Actions [B, A] in the action box: the deterministic tanh(mean) (evaluation), or a sample of
        the policy while exploring (SAC explores through its own entropy; there is no other setting)."""
        x = self.features(obs)
        context, task = self.task_inputs(obs)
        unit = self.actor.sample(x, generator, context, task)[0] if explore else self.actor.mode(x, context, task)
        return self.box.from_unit(unit)

    # ---------------------------------------------------------------- learning
    def bellman_target(self, batch: Batch, generator: torch.Generator | None = None) -> torch.Tensor:
        """y = r + gamma (1 - terminated) (min_i Q_target_i(s', a') - alpha log pi(a'|s')), a' ~ pi(.|s')."""
        cfg = self.config
        with torch.no_grad():
            flat = self.inputs(batch.next_obs)
            next_x, target_x = (flat, flat) if self.encoder is None else (self.encoder(flat), self.encoder_target(flat))
            context, task = self.task_inputs(batch.next_obs)
            next_action, next_log_prob = self.actor.sample(next_x, generator, context, task)
            next_q = torch.minimum(*(q(target_x, next_action, context, task) for q in self.critics_target))
            soft_value = next_q - self._row_alpha(task, self.alpha) * next_log_prob
            clip = negative_return_bounds(cfg.gamma) if cfg.clip_target else None
            return td_target(batch.reward, batch.terminated, soft_value, cfg.gamma, clip)

    def update(self, batch: Batch, generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
        """One critic, actor and temperature step; returns detached scalars
        (``critic_loss``, ``actor_loss``, ``alpha``, ``entropy``, ``q_mean``, ``action_on_bound``: the share of the
        batch's stored action components on a bound of the box)."""
        return self.counted_step(batch, generator)

    def learn(self, batch: Batch, generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
        """The update itself (what ``--compile`` compiles): critics, actor, temperature, target critics."""
        cfg = self.config
        if self.encoder is not None and self.picture_shift:  # DrQ: each state's pictures shifted at random
            shift = lambda obs: shift_pictures(obs, self.picture_shift, generator, self.picture_coordinates)  # noqa: E731
            batch = batch.replace(obs=shift(batch.obs), next_obs=shift(batch.next_obs))
        self.inputs.update_statistics(batch.obs)
        target = self.bellman_target(batch, generator)
        x, action = self.features(batch.obs), self.box.to_unit(batch.action)
        context, task = self.task_inputs(batch.obs)
        alpha = self._row_alpha(task, self.alpha)  # each row's task's temperature

        # critics: J_Q = sum_i 1/2 (Q_i(s, a) - y)^2
        q1, q2 = (q(x, action, context, task) for q in self.critics)
        critic_loss = 0.5 * (F.mse_loss(q1, target) + F.mse_loss(q2, target))
        extra = {}
        if cfg.cql_alpha > 0:
            gap = self.conservative_gap(x, context, task, (q1, q2), generator)
            critic_loss = critic_loss + cfg.cql_alpha * gap
            extra["cql_gap"] = gap.detach()
        gradient_step(self.critic_optimizer, critic_loss, self._critic_params, self.config.max_grad_norm)

        # actor: J_pi = alpha log pi(a~|s) - min_i Q_i(s, a~); the critics (and the context, and the picture's
        # features) are constants here
        set_requires_grad(self._critic_params, False)
        context = context.detach() if context is not None else None
        x = x.detach()
        new_action, log_prob = self.actor.sample(x, generator, context, task)
        q_new = torch.minimum(*(q(x, new_action, context, task) for q in self.critics))
        actor_loss = (alpha * log_prob - q_new).mean()
        gradient_step(self.actor_optimizer, actor_loss, self._actor_params, self.config.max_grad_norm)
        set_requires_grad(self._critic_params, True)

        # temperature: J_alpha = -log_alpha_k (log pi + target_entropy), k the row's task
        log_prob = log_prob.detach()
        if cfg.learn_alpha:
            alpha_loss = -(self._row_alpha(task, self.log_alpha) * (log_prob + self.target_entropy)).mean()
            gradient_step(self.alpha_optimizer, alpha_loss, [self.log_alpha], 0.0)

        self.update_target()
        return {
            "critic_loss": critic_loss.detach(),
            "actor_loss": actor_loss.detach(),
            "alpha": self.alpha.mean(),
            "entropy": -log_prob.mean(),
            "q_mean": q1.detach().mean(),
            "action_on_bound": share_on_bound(action),  # stored components on a bound (as QT-Opt's)
            **extra,
        }

    def conservative_gap(
        self,
        x: torch.Tensor,
        context: torch.Tensor | None,
        task: torch.Tensor | None,
        q_data: tuple[torch.Tensor, ...],
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        """CQL(H): sum_i E_s[log (1/2N) sum_k exp(Q_i(s, a_k) - log mu(a_k)) - Q_i(s, a_data)]."""
        n, rows = self.config.cql_samples, x.shape[0]

        def repeat(t: torch.Tensor | None) -> torch.Tensor | None:
            return None if t is None else t.repeat_interleave(n, 0)

        xr, cr, tr = repeat(x), repeat(context), repeat(task)
        uniform = torch.rand((rows * n, self.action_dim), generator=generator, device=x.device) * 2 - 1
        with torch.no_grad():
            policy_action, policy_log_prob = self.actor.sample(xr, generator, None if cr is None else cr.detach(), tr)
        log_uniform = -self.action_dim * _LOG_2  # density of the uniform on [-1, 1]^A
        gap = x.new_zeros(())
        for critic, q_taken in zip(self.critics, q_data):
            q_uniform = critic(xr, uniform, cr, tr).view(rows, n) - log_uniform
            q_policy = critic(xr, policy_action, cr, tr).view(rows, n) - policy_log_prob.view(rows, n)
            log_mean_exp = torch.logsumexp(torch.cat([q_uniform, q_policy], 1), 1) - math.log(2 * n)
            gap = gap + (log_mean_exp - q_taken).mean()
        return gap

    @torch.no_grad()
    def q_value(self, obs: Obs, action: torch.Tensor) -> torch.Tensor:
        """``min_i Q_i(s, a)`` of each row (no gradient): what conservative data sharing ranks rows by."""
        x, unit = self.features(obs), self.box.to_unit(action)
        context, task = self.task_inputs(obs)
        return torch.minimum(*(q(x, unit, context, task) for q in self.critics))

    def update_target(self) -> None:
        """theta_target_i <- tau * theta_i + (1 - tau) * theta_target_i."""
        polyak_update(self._target_params, self._critic_params, self.config.tau)


SPEC = AlgorithmSpec(
    name="sac",
    description="soft actor-critic: twin critics, learned temperature (per task on multi-task envs)",
    config=SACConfig,
    build=lambda inputs, config, device, conditioning: SACAgent(
        inputs.keys,
        inputs.dim,
        inputs.action_space,
        config,
        device,
        conditioning,
        inputs.image_shape,
        inputs.picture_shift,
        inputs.picture_coordinates,
    ),
    loop="off_policy",
    actions=("box",),
    multitask=True,
    compiles=True,
    q_values=True,
    images=True,
)
