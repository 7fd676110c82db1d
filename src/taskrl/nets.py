"""Small network building blocks shared by the agents."""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from taskrl.types import Obs

# Below this many multiply-adds a product is too small for its layout to matter: the plain path is cheaper.
_LAYOUT_MIN_MACS = 1 << 19


class Linear(nn.Linear):
    """``nn.Linear`` (the same parameters, initialisation and checkpoint keys) whose CPU matrix products
    take the layout MKL runs fastest, with the same results.

    MKL's single-precision product slows down when its output's rows are narrow or end in a ragged
    tail, and a layer's products can be laid out two ways (one core, batch 256;
    ``benchmarks/cpu_layouts.py``, ``docs/speed.md``):

    - forward ``y = x W^T + b`` with ``out_features % 16`` in 13..15 (15-bit flipping's 15 actions):
      ``W`` padded with zero rows to a multiple of 16, the extra columns dropped, is 2x faster;
    - the weight gradient ``dW = g^T x`` is ``in_features`` wide; where ``in_features < out_features``
      (a first layer from 30 inputs to 256 units) ``(x^T g)^T`` is 256 wide and about 2x faster. It
      needs its own backward (`_LaidOutLinear`), which only compiled updates take: eagerly an
      ``autograd.Function`` costs more than it saves. (Torch's cache of traced graphs refuses an
      ``autograd.Function``, so a later run of the same shapes traces the update again; the same layouts as
      plain tensor operations were cached but compiled slower on a first run: ``benchmarks/compile_cache.py``.)

    On this machine's MKL both gave the same bits as the plain products at these shapes;
    ``tests/test_nets.py`` checks outputs and gradients against ``nn.Linear``. On GPU, for other dtypes,
    without a bias, and for small products it is ``nn.Linear``.
    """

    @property
    def pad(self) -> int:
        """Zero rows the CPU forward pads ``W`` with (then its output is a view of the wider product)."""
        return -self.out_features % 16 if self.out_features % 16 >= 13 else 0

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        pad = self.pad
        transposed_grad = self.in_features < self.out_features
        if self.bias is None or x.device.type != "cpu" or x.dtype != torch.float32:
            return F.linear(x, self.weight, self.bias)
        needs_grad = torch.is_grad_enabled() and (x.requires_grad or self.weight.requires_grad or self.bias.requires_grad)
        rows = x.numel() // self.in_features
        if (
            not (pad or (transposed_grad and needs_grad))
            # eagerly a Python autograd.Function costs more than its layouts save
            or (needs_grad and not torch.compiler.is_compiling())
            or rows * self.in_features * self.out_features < _LAYOUT_MIN_MACS
        ):
            return F.linear(x, self.weight, self.bias)
        flat = x.reshape(-1, self.in_features)
        if needs_grad:
            y = _LaidOutLinear.apply(flat, self.weight, self.bias, pad, transposed_grad)
        else:
            y = _padded_linear(flat, self.weight, self.bias, pad)
        return y.view(*x.shape[:-1], self.out_features)


def _padded_linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, pad: int) -> torch.Tensor:
    """``x W^T + b`` with ``W`` padded by ``pad`` zero rows, the extra output columns dropped."""
    if not pad:
        return F.linear(x, weight, bias)
    return F.linear(x, F.pad(weight, (0, 0, 0, pad)), F.pad(bias, (0, pad)))[:, : weight.shape[0]]


class _LaidOutLinear(torch.autograd.Function):
    """``y = x W^T + b`` through `_padded_linear`; its backward takes the plain products of ``g``
    (not the padded ones: a wider sum adds in another order), ``dW`` as ``(x^T g)^T`` if asked."""

    @staticmethod
    def forward(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, pad: int, transposed_grad: bool) -> torch.Tensor:
        return _padded_linear(x, weight, bias, pad)

    @staticmethod
    def setup_context(ctx, inputs, output) -> None:
        x, weight, _, _, ctx.transposed_grad = inputs
        ctx.save_for_backward(x, weight)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        x, weight = ctx.saved_tensors
        grad_x = grad.mm(weight) if ctx.needs_input_grad[0] else None
        grad_weight = None
        if ctx.needs_input_grad[1]:
            grad_weight = x.t().mm(grad).t() if ctx.transposed_grad else grad.t().mm(x)
        grad_bias = grad.sum(0) if ctx.needs_input_grad[2] else None
        return grad_x, grad_weight, grad_bias, None, None


def activation_after(layer: nn.Module, activation: type[nn.Module]) -> nn.Module:
    """``activation()`` to follow ``layer``; a ReLU in place unless ``layer``'s output is a view (a padded
    ``Linear``). A product's backward does not need its output, so the in-place ReLU saves a buffer and a
    pass over memory with the same results (side by side, eager MT10 SAC updates: ``benchmarks/per_call_costs.py``,
    "ReLU in place")."""
    if activation is nn.ReLU and not getattr(layer, "pad", 0):
        return nn.ReLU(inplace=True)
    return activation()


def mlp(in_dim: int, hidden_sizes: Sequence[int], out_dim: int, activation: type[nn.Module] = nn.ReLU) -> nn.Sequential:
    """``Linear -> activation`` for each hidden size, then a final ``Linear`` to ``out_dim`` (``nets.Linear``:
    ``nn.Linear`` with faster CPU layouts). ReLUs run in place where the product before them is not a view
    (`activation_after`)."""
    layers: list[nn.Module] = []
    for size in hidden_sizes:
        layer = Linear(in_dim, size)
        layers += [layer, activation_after(layer, activation)]
        in_dim = size
    layers.append(Linear(in_dim, out_dim))
    return nn.Sequential(*layers)


class ObsConcat(nn.Module):
    """Flattens the chosen observation keys to float and concatenates them: ``[s, g]``.

    A goal-conditioned Q-function sees the state and the desired goal; the achieved goal is
    usually part of the state and left out.
    """

    def __init__(self, keys: Sequence[str]) -> None:
        super().__init__()
        self.keys = tuple(keys)

    def forward(self, obs: Obs) -> torch.Tensor:
        parts = [obs[k].flatten(1) for k in self.keys]
        if len({p.dtype for p in parts}) == 1 and not torch.compiler.is_compiling():
            return torch.cat(parts, dim=1).float()  # eager: one cast after the concat, fewer small ops
        # compiled: each cast feeds the concat, which Inductor then generates as one kernel (a concat of integer
        # tensors is a call out of the graph on CPU; side by side, ``benchmarks/per_call_costs.py``)
        return torch.cat([p.float() for p in parts], dim=1)


class StateActionQ(nn.Module):
    """Q(x, a) = MLP([x, a]) -> one value per (state, action) pair.

    ``score_actions(x, actions)`` evaluates N actions for each of B states in one call. It splits
    the first layer, W [x; a] + b = (W_x x + b) + W_a a, so the state's share is computed once
    per state instead of once per sample and no [B * N, in] copy of the states is built.

    ``state_input`` (e.g. [`ImageStateInput`][taskrl.encoders.ImageStateInput]) maps ``x`` first, once per state: an
    image is encoded once however many actions are scored, and the action joins after the encoder.
    """

    def __init__(self, in_dim: int, action_dim: int, hidden_sizes: tuple[int, ...], state_input: nn.Module | None = None) -> None:
        super().__init__()
        self.state_input = state_input
        self.in_dim = state_input.out_dim if state_input is not None else in_dim
        self.body = mlp(self.in_dim + action_dim, hidden_sizes, 1)

    def state(self, x: torch.Tensor) -> torch.Tensor:
        """The state's features: ``state_input(x)``, or ``x``."""
        return self.state_input(x) if self.state_input is not None else x

    def forward(self, x: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """x [B, D], action [B, A] -> [B]."""
        return self.body(torch.cat([self.state(x), action], dim=-1)).squeeze(-1)

    def score_actions(self, x: torch.Tensor, actions: torch.Tensor, chunk_rows: int | None = None) -> torch.Tensor:
        """x [B, D], actions [B, N, A] -> [B, N]: Q(x_b, a_bn) for all B * N pairs, for ``no_grad`` use (CEM).

        On CPU the rows go through the network in chunks of about ``chunk_rows`` (default 2048 per
        torch thread): a chunk's activations (2048 x 256 floats = 2 MiB) stay in cache between
        layers, which measured 2x faster (one thread) than one pass over all 16384 rows of a
        256-state, 64-sample CEM round. On GPU, in a compiled step (or with ``chunk_rows=0``) it is one pass. Rows
        stay 2-D (a 3-D input makes ``Linear`` ~35% slower on CPU) and ReLUs run in place.
        """
        b, n, _ = actions.shape
        x = self.state(x)
        if chunk_rows is None:
            chunk_rows = 0 if x.is_cuda or torch.compiler.is_compiling() else 2048 * torch.get_num_threads()
        per_chunk = b if chunk_rows <= 0 else max(1, chunk_rows // n)
        if per_chunk >= b:
            return self._score(x, actions)
        return torch.cat([self._score(x[i : i + per_chunk], actions[i : i + per_chunk]) for i in range(0, b, per_chunk)])

    def _score(self, x: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        b, n, a = actions.shape
        first = self.body[0]
        state_part = F.linear(x, first.weight[:, : self.in_dim], first.bias)  # [b, H], once per state
        h = actions.reshape(b * n, a) @ first.weight[:, self.in_dim :].T  # [b * n, H]
        h.view(b, n, -1).add_(state_part.unsqueeze(1))
        for layer in self.body[1:]:
            h = h.relu_() if isinstance(layer, nn.ReLU) else layer(h)
        return h.view(b, n)
