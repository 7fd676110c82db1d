"""Pieces every agent shares, so each agent's file holds only its own algorithm.

- `ObservationInput`: the network input (chosen observation keys -> float -> running
  normalisation; pictures beside that vector as stored, a `PictureState`), one module for the online and target
  networks alike;
- `ActionBox`: between an action box ``[low, high]`` and the ``[-1, 1]^A`` networks see;
- `td_target`: ``y = r + gamma (1 - terminated) v'``, optionally clipped;
- `polyak_update`: ``theta_target <- tau theta + (1 - tau) theta_target`` over parameter lists;
- `gradient_step`: zero the gradients, backpropagate, clip the norm, step (functionally
  inside a compiled update: `functional_adam_step`);
- `set_requires_grad`: gradients of some parameters off and on again (eager updates);
- `explore_in_box`: the hindsight paper's exploration for deterministic policies;
- `linear_schedule`: an exploration level decaying linearly with env steps;
- `check_learning_settings`: the checks every algorithm's section shares.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from torch import nn

from taskrl.agents.cem import action_bounds, sample_in_box
from taskrl.encoders import PICTURE_KEYS
from taskrl.errors import require
from taskrl.nets import ObsConcat
from taskrl.normalization import RunningNorm
from taskrl.types import Obs, PictureState


class ObservationInput(nn.Module):
    """``obs -> [vector keys concatenated, as float] -> (x - mean) / std`` (clipped), or no normalisation; where
    the keys hold pictures (`taskrl.encoders.PICTURE_KEYS`), a `PictureState`: that vector beside the pictures as
    they are (uint8 ``[B, H, W, C]`` each, stacked), never flattened into it.

    Args:
        keys: observation keys the networks read, e.g. ``("observation", "desired_goal")`` or ``("observation",
            "image")``.
        dim: the numbers one observation holds under those keys (pictures included).
        normalize: standardise the vector with running statistics from the training batches.
        picture_dim: how many of ``dim`` are pictures' values (so the vector's width is ``dim - picture_dim``).
        raw_columns: columns of the vector handed on as the env gives them, not normalised (a gripper's pose that
            a network reads as a place in the picture).
    """

    def __init__(
        self, keys: Sequence[str], dim: int, normalize: bool, picture_dim: int = 0, raw_columns: tuple[int, ...] = ()
    ) -> None:
        super().__init__()
        self.keys, self.dim = tuple(keys), int(dim)
        self.picture_keys = tuple(k for k in PICTURE_KEYS if k in self.keys)
        self.vector_keys = tuple(k for k in self.keys if k not in self.picture_keys)
        self.vector_dim = self.dim - int(picture_dim)
        self.encode = ObsConcat(self.vector_keys)
        # pixels only: nothing to scale
        self.normalize = (
            RunningNorm(self.vector_dim, raw_columns=tuple(raw_columns)) if normalize and self.vector_dim > 0 else nn.Identity()
        )

    def forward(self, obs: Obs) -> torch.Tensor | PictureState:
        if not self.picture_keys:
            return self.normalize(self.encode(obs))
        pictures = torch.stack([obs[k] for k in self.picture_keys], dim=1)
        if self.vector_keys:
            vector = self.normalize(self.encode(obs))
        else:
            vector = torch.zeros(pictures.shape[0], 0, device=pictures.device)
        return PictureState(vector, pictures)

    def update_statistics(self, obs: Obs) -> None:
        """Merge a training batch into the running statistics (no-op without normalisation)."""
        if isinstance(self.normalize, RunningNorm):
            self.normalize.update(self.encode(obs))


class ActionBox:
    """An action box ``[low, high]`` and its affine map to and from ``[-1, 1]^A``.

    Args:
        action_space: a gymnasium ``Box`` or a ``(low, high)`` pair.
        device: where the bounds live.
    """

    def __init__(self, action_space: Any, device: str | torch.device) -> None:
        self.low, self.high = action_bounds(action_space, device)
        self.dim = self.low.numel()
        self.center, self.half = (self.high + self.low) / 2, (self.high - self.low) / 2

    def to_unit(self, action: torch.Tensor) -> torch.Tensor:
        """Box -> [-1, 1] (what the networks see)."""
        return (action.float() - self.center) / self.half

    def from_unit(self, unit: torch.Tensor) -> torch.Tensor:
        """[-1, 1] -> box."""
        return self.center + self.half * unit


def negative_return_bounds(gamma: float) -> tuple[float, float]:
    """``[-1 / (1 - gamma), 0]``: where every discounted return lies when rewards are in {-1, 0}."""
    return -1.0 / (1.0 - gamma), 0.0


def td_target(
    reward: torch.Tensor,
    terminated: torch.Tensor,
    next_value: torch.Tensor,
    gamma: float,
    clip: tuple[float, float] | None = None,
) -> torch.Tensor:
    """``y = r + gamma * (1 - terminated) * v'``, clamped to ``clip`` when given.

    Only ``terminated`` stops bootstrapping: a time-limit truncation still bootstraps from ``v'``.
    """
    target = reward.float() + gamma * (~terminated).float() * next_value
    return target if clip is None else target.clamp(*clip)


@torch.no_grad()
def polyak_update(target: list[torch.Tensor], online: list[torch.Tensor], tau: float) -> None:
    """``theta_target <- tau * theta + (1 - tau) * theta_target`` for every pair (``tau = 1``: copy).

    One fused call over all parameters where torch has it (its ``_foreach`` kernels), else a loop.
    """
    if tau >= 1.0:
        if hasattr(torch, "_foreach_copy_"):
            torch._foreach_copy_(target, online)
        else:  # pragma: no cover - older torch
            for t, p in zip(target, online):
                t.copy_(p)
    elif hasattr(torch, "_foreach_lerp_"):
        torch._foreach_lerp_(target, online, tau)
    else:  # pragma: no cover - older torch
        for t, p in zip(target, online):
            t.lerp_(p, tau)


def gradient_step(optimizer: torch.optim.Optimizer, loss: torch.Tensor, params: list[torch.Tensor], max_grad_norm: float) -> None:
    """``zero_grad -> backward -> clip_grad_norm (if max_grad_norm > 0) -> step``.

    Inside a compiled update (`taskrl.agents.compiled`) the same step is taken without touching
    ``.grad``, which a compiled graph cannot: `functional_adam_step`.
    """
    if torch.compiler.is_compiling():
        functional_adam_step(optimizer, loss, params, max_grad_norm)
        return
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if max_grad_norm > 0:
        nn.utils.clip_grad_norm_(params, max_grad_norm, foreach=True)
    optimizer.step()


def set_requires_grad(params: list[torch.Tensor], enabled: bool) -> None:
    """Switch gradients of ``params`` on or off, e.g. to keep an actor's backward out of the critics. Eager
    only: a compiled step differentiates the named parameters (``torch.autograd.grad``) and needs no switch."""
    if torch.compiler.is_compiling():
        return
    for p in params:
        p.requires_grad_(enabled)


def gradient_norms(grads: list[torch.Tensor]) -> list[torch.Tensor]:
    """``||g||_2`` of each gradient, one ``vector_norm`` each: in a compiled step each is a reduction Inductor
    generates (``torch._foreach_norm`` has no lowering and runs as a call out of the graph; side by side, the
    compiled DQN (64, 64) / 32 update took 0.90x the time with these, (256, 256) / 256 0.96-0.98x,
    ``benchmarks/per_call_costs.py``)."""
    return [torch.linalg.vector_norm(g) for g in grads]


def functional_adam_step(
    optimizer: torch.optim.Optimizer, loss: torch.Tensor, clipped: list[torch.Tensor], max_grad_norm: float
) -> None:
    """The step of `gradient_step` as pure tensor operations (what ``torch.compile`` fuses into one graph):

        g = d loss / d theta                                        (torch.autograd.grad)
        g <- g * min(1, max_grad_norm / (||g_clipped||_2 + 1e-6))   (over ``clipped``' gradients only, as clip_grad_norm_)
        g <- g + weight_decay * theta                               (Adam's own L2 term, after the clip as in Adam.step)
        t <- t + 1,  m <- m + (1 - beta1) (g - m),  v <- beta2 v + (1 - beta2) g^2
        theta <- theta - lr / (1 - beta1^t) * m / (sqrt(v) / sqrt(1 - beta2^t) + eps)

    Adam as ``torch.optim.Adam`` takes it, on the optimiser's own state. Parameters the loss does not
    reach are left alone, as ``optimizer.step`` leaves a parameter without a gradient. The optimiser's
    state must exist first (`init_adam_state`).
    """
    group = optimizer.param_groups[0]
    grads = torch.autograd.grad(loss, group["params"], allow_unused=True)
    reached = [(p, g) for p, g in zip(group["params"], grads) if g is not None]
    params, grads = [p for p, _ in reached], [g for _, g in reached]
    beta1, beta2 = group["betas"]
    n = len(params)
    if not n:
        return
    with torch.no_grad():
        state = [optimizer.state[p] for p in params]
        steps = [s["step"] for s in state]
        torch._foreach_add_(steps, 1.0)
        t = torch.stack(steps)
        scalars = [group["lr"] / (1 - beta1**t), (1 - beta2**t).rsqrt()]
        is_clipped = [any(p is c for c in clipped) for p in params] if max_grad_norm > 0 else [False] * n
        clip = any(is_clipped)
        if clip:
            norm = torch.linalg.vector_norm(torch.stack(gradient_norms([g for g, c in zip(grads, is_clipped) if c])))
            scalars.append((max_grad_norm / (norm + 1e-6)).clamp(max=1.0).view(1))
        # the update's scalars in one buffer (a compiled step's cat is a buffer of its own on CPU): computed once,
        # then read by every parameter's loop; written into those loops (torch's functional Adam), the generated
        # code recomputed them (powers, roots, divisions) for every 8 elements. Side by side the whole compiled
        # DQN (256, 256) / 256 update took 0.87x the time (benchmarks/per_call_costs.py)
        scalars = torch.cat(scalars)
        step_size, inv_sqrt_bias2 = scalars[:n], scalars[n : 2 * n]
        if clip:
            grads = [g * scalars[2 * n] if c else g for g, c in zip(grads, is_clipped)]
        if group["weight_decay"]:
            grads = torch._foreach_add(grads, params, alpha=group["weight_decay"])
        exp_avgs, exp_avg_sqs = [s["exp_avg"] for s in state], [s["exp_avg_sq"] for s in state]
        torch._foreach_lerp_(exp_avgs, grads, 1 - beta1)
        torch._foreach_mul_(exp_avg_sqs, beta2)
        torch._foreach_addcmul_(exp_avg_sqs, grads, grads, value=1 - beta2)
        for i, (p, m, v) in enumerate(zip(params, exp_avgs, exp_avg_sqs)):
            p.sub_(step_size[i] * m / (v.sqrt() * inv_sqrt_bias2[i] + group["eps"]))


def init_adam_state(optimizer: torch.optim.Optimizer) -> None:
    """Create the Adam state of every parameter that has none yet, as ``Adam.step`` would on its first
    call (zero moments, step 0 on the parameter's device): a compiled step reads it and cannot create it."""
    require(
        type(optimizer) is torch.optim.Adam and len(optimizer.param_groups) == 1,
        "compile",
        "compiles updates of agents with one Adam optimiser per loss",
    )
    group = optimizer.param_groups[0]
    require(not (group["amsgrad"] or group["maximize"]), "compile", "does not support Adam's amsgrad or maximize")
    for p in optimizer.param_groups[0]["params"]:
        if not optimizer.state[p]:
            optimizer.state[p] = {
                "step": torch.zeros((), dtype=torch.float32, device=p.device),
                "exp_avg": torch.zeros_like(p, memory_format=torch.preserve_format),
                "exp_avg_sq": torch.zeros_like(p, memory_format=torch.preserve_format),
            }


def explore_in_box(
    unit: torch.Tensor,
    noise_std: float,
    random_prob: float,
    generator: torch.Generator | None = None,
    truncated: bool = False,
) -> torch.Tensor:
    """Exploration around deterministic actions in ``[-1, 1]^A`` (the hindsight paper's, for Fetch):

    a = clip(a* + N(0, noise_std^2), -1, 1)     Gaussian noise, in half-widths of the box
    a = U(-1, 1)^A  with probability random_prob per row   (the paper: 0.2 noise, 30% random)

    ``truncated``: the noise is drawn from the normal truncated to the box instead of clipped to it, so no mass
    piles up on a bound (a clipped draw puts every sample beyond a bound on it).
    """
    n, dim = unit.shape
    if noise_std > 0 and truncated:
        std = torch.full_like(unit, noise_std)
        unit = sample_in_box(unit, std, 1, -torch.ones_like(unit[0]), torch.ones_like(unit[0]), "truncated", generator)[:, 0]
    elif noise_std > 0:
        unit = (unit + noise_std * torch.randn(unit.shape, generator=generator, device=unit.device)).clamp(-1.0, 1.0)
    if random_prob > 0:
        pick = torch.rand(n, 1, generator=generator, device=unit.device) < random_prob
        uniform = torch.rand(n, dim, generator=generator, device=unit.device) * 2 - 1
        unit = torch.where(pick, uniform, unit)
    return unit


def share_on_bound(unit: torch.Tensor) -> torch.Tensor:
    """The share of ``unit`` action components (in ``[-1, 1]``) that sit on a bound of the box: the metric
    ``action_on_bound`` of the algorithms that log it."""
    return (unit.abs() >= 1.0 - 1e-6).float().mean()


def linear_schedule(start: float, end: float, decay_steps: int, env_steps: int) -> float:
    """``start`` decaying linearly to ``end`` over ``decay_steps`` env steps (0: ``end`` from the start)."""
    if decay_steps <= 0:
        return end
    frac = min(env_steps / decay_steps, 1.0)
    return start + frac * (end - start)


def check_learning_settings(config: Any, gamma_may_be_one: bool = False) -> None:
    """The checks every algorithm's section shares: lr, network widths, gradient clip and, where the
    section has them, gamma, the Polyak factor and target clipping's precondition."""
    c = config
    if hasattr(c, "gamma"):  # a learner without returns (behaviour cloning) has none
        top = "1]" if gamma_may_be_one else "1)"
        require(0.0 <= c.gamma <= 1.0 and (gamma_may_be_one or c.gamma < 1.0), "gamma", f"must be in [0, {top} (got {c.gamma})")
    require(c.lr > 0, "lr", f"must be > 0 (got {c.lr})")
    require(
        len(c.hidden_sizes) >= 1 and all(int(h) >= 1 for h in c.hidden_sizes),
        "hidden_sizes",
        f"must be one or more positive widths (got {list(c.hidden_sizes)})",
    )
    require(c.max_grad_norm >= 0, "max_grad_norm", f"must be >= 0 (got {c.max_grad_norm})")
    if hasattr(c, "tau"):
        require(0.0 < c.tau <= 1.0, "tau", f"must be in (0, 1] (got {c.tau})")


def check_probability(config: Any, *names: str) -> None:
    """Each named setting must lie in [0, 1]."""
    for name in names:
        value = getattr(config, name)
        require(0.0 <= value <= 1.0, name, f"must be in [0, 1] (got {value})")


def check_non_negative(config: Any, *names: str) -> None:
    """Each named setting must be >= 0."""
    for name in names:
        value = getattr(config, name)
        require(value >= 0, name, f"must be >= 0 (got {value})")
