"""Policy gradient: PPO (Schulman et al., 2017) and REINFORCE with reward-to-go, multi-task ready.

Both learn a stochastic policy pi(a|s, c) and a value V(s, c) from rollouts of T steps in each
of N environments (``Rollout``, tensors [T, N, ...]); c is the task context
``conditioning.encoder(obs[task_key])`` when the agent has a ``TaskConditioning``, nothing
otherwise. The policy is a Gaussian N(mu(s, c), diag(exp(2 log_std))) over the action box
rescaled to [-1, 1] (log_std a learned, state-independent vector; the sample u is clipped to the
box only when stepping the environment and log pi is that of the unclipped u), or a Categorical
softmax(logits(s, c)) over a ``Discrete`` space.

Bootstrapping. For step t let v'_t be the value of the state after it:

    v'_t = 0                 if terminated_t                     (a true end: nothing follows)
         = V(final_obs_t)    if truncated_t                      (a time limit: the episode goes on)
         = V(s_{t+1})        otherwise (V(s_T) = last_value after the rollout's last step)

Advantages, ``estimator="ppo"`` (GAE, Schulman et al., 2016), done_t = terminated_t | truncated_t:

    delta_t = r_t + gamma v'_t - V(s_t)
    A_t     = delta_t + gamma lambda (1 - done_t) A_{t+1},      A_T = 0
    R_t     = A_t + V(s_t)                                      (value target; lambda = 1: reward-to-go)

``estimator="reinforce"`` uses the discounted reward-to-go itself:

    G_t = r_t + gamma v'_t              if done_t or t = T-1
        = r_t + gamma G_{t+1}           otherwise
    A_t = G_t - b(s_t),   b = V (a learned baseline) when value_coef > 0, else b = 0 and v' = 0
                          (then bootstrap values are 0 too: plain REINFORCE on the returns)

Losses, averaged over a minibatch, with ratio rho = exp(log pi(a|s) - log pi_old(a|s)) and Â the
advantages (standardised per minibatch if ``normalize_advantages``):

    PPO        L_pi = -mean( min(rho Â, clip(rho, 1 - eps, 1 + eps) Â) )     (epochs x minibatches steps)
    REINFORCE  L_pi = -mean( log pi(a|s) Â )                                   (one step on the whole rollout)
    L_V = mean( (V(s) - R)^2 )        (R = G for REINFORCE)
    L   = L_pi + value_coef L_V - entropy_coef mean(H[pi(.|s)])

pi_old is the policy that collected the rollout: input statistics are merged *after* the
gradient steps, so rho = 1 exactly at the first step. Logged: policy_loss, value_loss, entropy,
approx_kl = mean((rho - 1) - log rho), clip_fraction = mean(|rho - 1| > eps) and
explained_variance = 1 - Var(R - V_old) / Var(R), all averaged over the update's gradient steps.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any, Literal

import gymnasium as gym
import torch
import torch.nn.functional as F
from torch import nn

from taskrl.agents.base import Agent
from taskrl.agents.parts import ActionBox, check_learning_settings, gradient_step
from taskrl.agents.spec import AlgorithmSpec
from taskrl.conditioning.networks import TaskConditioning, network_for
from taskrl.errors import one_of, require
from taskrl.types import Obs

if TYPE_CHECKING:
    from taskrl.training.onpolicy import Rollout

_LOG_2PI = math.log(2 * math.pi)
ESTIMATORS = ("ppo", "reinforce")


@dataclasses.dataclass
class PPOConfig:
    """PPO / REINFORCE hyperparameters.

    Attributes:
        estimator: ``ppo`` (GAE advantages, clipped surrogate, several epochs of minibatches) or ``reinforce`` (discounted reward-to-go, one gradient step per rollout on -log pi times the advantage; with value_coef 0 there is no baseline).
        lr: Adam learning rate of the policy, the value function and the task encoder.
        gamma: discount factor.
        gae_lambda: GAE's lambda (1 gives reward-to-go minus the value); ppo only.
        rollout_steps: environment steps per environment in each rollout (a rollout is rollout_steps x num_envs transitions).
        epochs: passes over each rollout; ppo only.
        minibatches: minibatches per pass (each of rollout_steps x num_envs / minibatches transitions); ppo only.
        clip_range: PPO's epsilon, the ratio is clipped to [1 - eps, 1 + eps]; ppo only.
        value_coef: weight of the value loss (0 with reinforce means no baseline).
        entropy_coef: weight of the entropy bonus.
        hidden_sizes: widths of the hidden layers of the policy and of the value network.
        init_log_std: initial log standard deviation of the Gaussian policy, in units of the action box's half-width.
        normalize_advantages: standardise the advantages of every minibatch.
        max_grad_norm: gradient-norm clip of all parameters together (0 disables).
        normalize_inputs: standardise observation inputs with running mean/std (clipped to +-5).
    """

    estimator: Literal["ppo", "reinforce"] = "ppo"
    lr: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    rollout_steps: int = 64
    epochs: int = 10
    minibatches: int = 4
    clip_range: float = 0.2
    value_coef: float = 0.5
    entropy_coef: float = 0.0
    hidden_sizes: tuple[int, ...] = (64, 64)
    init_log_std: float = 0.0
    normalize_advantages: bool = True
    max_grad_norm: float = 0.5
    normalize_inputs: bool = True

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting (gamma = 1 is allowed:
        rollouts are finite)."""
        one_of(self.estimator, ESTIMATORS, "estimator", "estimator")
        check_learning_settings(self, gamma_may_be_one=True)
        require(0.0 <= self.gae_lambda <= 1.0, "gae_lambda", f"must be in [0, 1] (got {self.gae_lambda})")
        for name in ("rollout_steps", "epochs", "minibatches"):
            require(getattr(self, name) >= 1, name, f"must be >= 1 (got {getattr(self, name)})")
        require(self.clip_range > 0, "clip_range", f"must be > 0 (got {self.clip_range})")
        require(
            self.value_coef > 0 or (self.value_coef == 0 and self.estimator == "reinforce"),
            "value_coef",
            f"must be > 0 for ppo (GAE needs a value function), >= 0 for reinforce (got {self.value_coef})",
        )
        require(self.entropy_coef >= 0, "entropy_coef", f"must be >= 0 (got {self.entropy_coef})")


# ---------------------------------------------------------------- returns and advantages
def next_values(
    value: torch.Tensor, final_value: torch.Tensor, last_value: torch.Tensor, terminated: torch.Tensor, truncated: torch.Tensor
) -> torch.Tensor:
    """v'_t [T, N]: 0 after a termination, V(final_obs) after a truncation, else V(s_{t+1})
    (``last_value`` [N] after the last step)."""
    following = torch.cat([value[1:], last_value.unsqueeze(0)], dim=0)
    following = torch.where(truncated, final_value, following)
    return following.masked_fill(terminated, 0.0)


def gae(
    reward: torch.Tensor,
    value: torch.Tensor,
    final_value: torch.Tensor,
    last_value: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
    gamma: float,
    lam: float,
) -> torch.Tensor:
    """Generalised advantage estimates A [T, N] (see the module docstring); returns are A + value."""
    delta = reward + gamma * next_values(value, final_value, last_value, terminated, truncated) - value
    carry = gamma * lam * (~(terminated | truncated)).to(value.dtype)
    advantages = torch.empty_like(value)
    running = torch.zeros_like(last_value)
    for t in range(reward.shape[0] - 1, -1, -1):
        running = delta[t] + carry[t] * running
        advantages[t] = running
    return advantages


def reward_to_go(
    reward: torch.Tensor,
    final_value: torch.Tensor,
    last_value: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
    gamma: float,
) -> torch.Tensor:
    """Discounted reward-to-go G [T, N]: r_t + gamma G_{t+1} within an episode; at an episode's
    end or the rollout's last step, r_t + gamma v'_t (0 after termination, V(final_obs) after
    truncation, ``last_value`` after the last step)."""
    done = terminated | truncated
    bootstrap = torch.where(truncated, final_value, torch.zeros_like(final_value)).masked_fill(terminated, 0.0)
    returns = torch.empty_like(reward)
    running = last_value.to(reward.dtype)
    for t in range(reward.shape[0] - 1, -1, -1):
        running = reward[t] + gamma * torch.where(done[t], bootstrap[t], running)
        returns[t] = running
    return returns


def clipped_surrogate(
    log_prob: torch.Tensor, old_log_prob: torch.Tensor, advantage: torch.Tensor, clip_range: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(L_pi, approx_kl, clip_fraction)``: L_pi = -mean(min(rho A, clip(rho, 1-eps, 1+eps) A))."""
    log_ratio = log_prob - old_log_prob
    ratio = log_ratio.exp()
    loss = -torch.minimum(ratio * advantage, ratio.clamp(1.0 - clip_range, 1.0 + clip_range) * advantage).mean()
    with torch.no_grad():
        approx_kl = ((ratio - 1.0) - log_ratio).mean()
        clip_fraction = ((ratio - 1.0).abs() > clip_range).float().mean()
    return loss, approx_kl, clip_fraction


def gaussian_log_prob(x: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """log N(x; mean, diag(exp(log_std)^2)), summed over the last dimension."""
    return (-0.5 * ((x - mean) * torch.exp(-log_std)).square() - log_std - 0.5 * _LOG_2PI).sum(-1)


def gaussian_entropy(log_std: torch.Tensor) -> torch.Tensor:
    """H[N(mean, diag(exp(log_std)^2))] = sum_j (log_std_j + (1 + log 2 pi) / 2)."""
    return (log_std + 0.5 * (1.0 + _LOG_2PI)).sum(-1)


def explained_variance(prediction: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """1 - Var(target - prediction) / Var(target) (NaN-free: 0 when the target is constant)."""
    var = target.var(unbiased=False)
    ev = 1.0 - (target - prediction).var(unbiased=False) / var
    return torch.where(var > 0, ev, torch.zeros_like(ev))


# ---------------------------------------------------------------- the agent
class PPOAgent(Agent):
    """PPO or REINFORCE (``config.estimator``) with an optional task conditioning.

    Args:
        input_keys: observation keys the networks read as the state (not the task key).
        input_dim: total flattened size of those keys.
        action_space: a gymnasium ``Box`` (or a ``(low, high)`` pair): Gaussian policy; or a
            gymnasium ``Discrete``: Categorical policy.
        config: hyperparameters, see `PPOConfig`.
        device: torch device of the networks.
        conditioning: the shared task encoder and architecture of a multi-task agent; the policy
            and the value read the context ``encoder(obs[task_key])``. ``None``: plain MLPs.
    """

    acting = ("policy", "log_std", "normalize", "task_encoder")
    checkpointed = {
        "policy": "policy_net",
        "value": "value_net",
        "log_std": "log_std",
        "normalize": "inputs.normalize",
        "optimizer": "optimizer",
        "task_encoder": "task_encoder",
    }

    def __init__(
        self,
        input_keys: tuple[str, ...],
        input_dim: int,
        action_space: Any,
        config: PPOConfig,
        device: str | torch.device = "cpu",
        conditioning: TaskConditioning | None = None,
    ) -> None:
        self.setup(config, device, input_keys, input_dim, conditioning)
        self.discrete = isinstance(action_space, gym.spaces.Discrete)
        if self.discrete:
            self.num_actions, self.action_start = int(action_space.n), int(action_space.start)
            out_dim = self.num_actions
        else:
            self.box = ActionBox(action_space, self.device)
            self.action_dim = out_dim = self.box.dim
        self.policy_net = network_for(input_dim, out_dim, config.hidden_sizes, conditioning).to(self.device)
        self.value_net = network_for(input_dim, 1, config.hidden_sizes, conditioning).to(self.device)
        _scale_output_layer(self.policy_net, 0.01)  # near-uniform / zero-mean initial policy
        self.log_std = nn.Parameter(
            torch.full((out_dim,), float(config.init_log_std), device=self.device), requires_grad=not self.discrete
        )
        self._params = [
            p
            for m in (self.policy_net, self.value_net, self.task_encoder)
            if m is not None
            for p in m.parameters()
            if p.requires_grad
        ]
        if not self.discrete:
            self._params.append(self.log_std)
        self.optimizer = torch.optim.Adam(self._params, lr=config.lr, eps=1e-5)
        self.updates = 0

    @property
    def rollout_steps(self) -> int:
        return self.config.rollout_steps

    @property
    def uses_value(self) -> bool:
        """False only for REINFORCE without a baseline (``value_coef == 0``)."""
        return self.config.value_coef > 0

    # ---------------------------------------------------------------- networks
    def _features(self, obs: Obs) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """(normalised state x, task context c, task index) of a batch."""
        x = self.inputs(obs)
        if self.conditioning is None:
            return x, None, None
        return x, *self.conditioning.task_inputs(obs)

    def _policy_output(self, feats) -> torch.Tensor:
        """Gaussian mean in [-1, 1] units, or Categorical logits."""
        return self.policy_net(*feats)

    def _value(self, feats) -> torch.Tensor:
        return self.value_net(*feats).squeeze(-1)

    def _log_prob_entropy(self, out: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if self.discrete:
            log_p = F.log_softmax(out, dim=-1)
            chosen = log_p.gather(-1, action.long().view(-1, 1)).squeeze(-1)
            return chosen, -(log_p.exp() * log_p).sum(-1)
        log_std = self.log_std.expand_as(out)
        return gaussian_log_prob(action, out, log_std), gaussian_entropy(log_std)

    def _sample(self, out: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
        if self.discrete:
            return torch.multinomial(F.softmax(out, dim=-1), 1, generator=generator).squeeze(-1)
        eps = torch.randn(out.shape, generator=generator, device=out.device, dtype=out.dtype)
        return out + self.log_std.exp() * eps

    def _to_env(self, action: torch.Tensor) -> torch.Tensor:
        """Policy action -> environment action: shift a Discrete index by ``start``; clip a
        Gaussian sample to [-1, 1] and map it into the box."""
        if self.discrete:
            return action + self.action_start
        return self.box.from_unit(action.clamp(-1.0, 1.0))

    # ---------------------------------------------------------------- acting
    def policy(self, obs: Obs, explore: bool, generator: torch.Generator | None, env_steps: int) -> torch.Tensor:
        """Environment actions: the mean (clipped to the box) or the argmax, or a sample of the policy
        while exploring."""
        out = self._policy_output(self._features(obs))
        if explore:
            action = self._sample(out, generator)
        else:
            action = out.argmax(-1) if self.discrete else out
        return self._to_env(action)

    @torch.no_grad()
    def rollout_step(
        self, obs: Obs, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """What collection stores: ``(env_action, action, log_prob, value)``; ``action`` is the
        policy's own sample (unclipped, in [-1, 1] units; or the 0-based index), ``env_action``
        what the environment is stepped with."""
        feats = self._features(obs)
        out = self._policy_output(feats)
        action = self._sample(out, generator)
        log_prob = self._log_prob_entropy(out, action)[0]
        value = self._value(feats) if self.uses_value else torch.zeros_like(log_prob)
        return self._to_env(action), action, log_prob, value

    @torch.no_grad()
    def value(self, obs: Obs) -> torch.Tensor:
        """V(s) [B] (zeros for REINFORCE without a baseline)."""
        feats = self._features(obs)
        if not self.uses_value:
            return torch.zeros(feats[0].shape[0], device=self.device)
        return self._value(feats)

    # ---------------------------------------------------------------- learning
    def advantages(self, rollout: Rollout) -> tuple[torch.Tensor, torch.Tensor]:
        """``(A, R)`` [T, N]: advantages and value targets of the configured estimator."""
        c, r = self.config, rollout
        if c.estimator == "ppo":
            adv = gae(r.reward, r.value, r.final_value, r.last_value, r.terminated, r.truncated, c.gamma, c.gae_lambda)
            return adv, adv + r.value
        returns = reward_to_go(r.reward, r.final_value, r.last_value, r.terminated, r.truncated, c.gamma)
        return returns - r.value, returns

    def update(self, rollout: Rollout, generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
        """Learn from one rollout: ``epochs x minibatches`` PPO steps, or one REINFORCE step.

        Returns detached scalars averaged over the steps: ``policy_loss``, ``value_loss``,
        ``entropy``, ``approx_kl``, ``clip_fraction``, ``explained_variance``.
        """
        c = self.config
        with torch.no_grad():
            adv, returns = self.advantages(rollout)
        obs = {k: v.flatten(0, 1) for k, v in rollout.obs.items()}
        action, old_log_prob = rollout.action.flatten(0, 1), rollout.log_prob.flatten(0, 1)
        adv, returns = adv.flatten(), returns.flatten()
        n = adv.shape[0]
        reinforce = c.estimator == "reinforce"
        epochs, minibatches = (1, 1) if reinforce else (c.epochs, c.minibatches)
        size = max(n // minibatches, 1)
        sums = torch.zeros(5, device=self.device)
        steps = 0
        for _ in range(epochs):
            order = torch.randperm(n, generator=generator, device="cpu").to(self.device) if not reinforce else None
            for start in range(0, n - size + 1, size):
                idx = order[start : start + size] if order is not None else slice(None)
                mb_obs = {k: v[idx] for k, v in obs.items()}
                mb_adv = adv[idx]
                if c.normalize_advantages and mb_adv.numel() > 1:
                    mb_adv = (mb_adv - mb_adv.mean()) / (mb_adv.std() + 1e-8)
                feats = self._features(mb_obs)
                log_prob, entropy = self._log_prob_entropy(self._policy_output(feats), action[idx])
                if reinforce:
                    policy_loss = -(log_prob * mb_adv).mean()
                    with torch.no_grad():  # the policy that acted: rho = 1 here
                        log_ratio = log_prob - old_log_prob[idx]
                        approx_kl = ((log_ratio.exp() - 1.0) - log_ratio).mean()
                        clip_fraction = torch.zeros((), device=self.device)
                else:
                    policy_loss, approx_kl, clip_fraction = clipped_surrogate(log_prob, old_log_prob[idx], mb_adv, c.clip_range)
                loss = policy_loss - c.entropy_coef * entropy.mean()
                if self.uses_value:
                    value_loss = F.mse_loss(self._value(feats), returns[idx])
                    loss = loss + c.value_coef * value_loss
                else:
                    value_loss = torch.zeros((), device=self.device)
                gradient_step(self.optimizer, loss, self._params, c.max_grad_norm)
                sums += torch.stack(
                    [policy_loss.detach(), value_loss.detach(), entropy.detach().mean(), approx_kl, clip_fraction]
                )
                steps += 1
        self.updates += steps
        self.inputs.update_statistics(obs)  # after the steps: the next rollout's pi_old is what acts
        means = sums / steps
        names = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction")
        metrics = {name: means[i] for i, name in enumerate(names)}
        metrics["explained_variance"] = explained_variance(rollout.value.flatten(), returns)
        if not self.discrete:
            metrics["policy_std"] = self.log_std.detach().exp().mean()
        return metrics


SPEC = AlgorithmSpec(
    name="ppo",
    description="PPO (GAE, clipped surrogate) or REINFORCE with reward-to-go, on-policy (Box or Discrete actions)",
    config=PPOConfig,
    build=lambda inputs, config, device, conditioning: PPOAgent(
        inputs.keys, inputs.dim, inputs.action_space, config, device, conditioning
    ),
    loop="on_policy",
    actions=("box", "discrete"),
    multitask=True,
)


def _scale_output_layer(net: nn.Module, gain: float) -> None:
    """Multiply the last ``nn.Linear`` of ``net`` (its output layer) by ``gain`` and zero its bias."""
    last = [m for m in net.modules() if isinstance(m, nn.Linear)][-1]
    with torch.no_grad():
        last.weight.mul_(gain)
        last.bias.zero_()
