"""What every agent shares: acting on any form of observation, and one save / load of its parts.

An agent subclasses `Agent` and implements

- ``policy(obs, explore, generator, env_steps) -> actions``: actions for a batch of observation
  tensors, greedy when ``explore`` is False, with the algorithm's own exploration when True (DQN's
  epsilon, QT-Opt's random actions, TD3's noise, SAC's and PPO's sampling), decayed by
  ``env_steps`` where its schedule says so;
- ``update(batch) -> dict of scalars``: counters and schedules, around ``self.step(...)``, the
  update itself (``learn``), run eagerly or compiled (`Agent.compile`);
- ``checkpointed``: checkpoint name -> attribute path of each module, optimiser or tensor to save.

and gets `Agent.act`, `Agent.exploration`, `Agent.state_dict` and
`Agent.load_state_dict`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import numpy as np
import torch

from taskrl.agents.compiled import COMPILE_MODES, CompiledStep
from taskrl.agents.parts import ObservationInput
from taskrl.errors import one_of
from taskrl.types import Obs

__all__ = ["Agent", "ObservationForm", "batch_observations"]


@dataclasses.dataclass(frozen=True)
class ObservationForm:
    """How an observation came in, so actions go back out the same way.

    Attributes:
        single: one observation (no batch dimension): the action has none either.
        numpy: numpy (or plain Python) data: actions come back as numpy (an ``int`` for one discrete action).
    """

    single: bool
    numpy: bool

    def restore(self, action: torch.Tensor) -> Any:
        """Actions ``[B, ...]`` in this form."""
        if not self.numpy:
            return action[0] if self.single else action
        out = action.detach().cpu().numpy()
        if not self.single:
            return out
        first = out[0]
        return int(first) if first.ndim == 0 and np.issubdtype(first.dtype, np.integer) else first


def batch_observations(obs: Any, inputs: ObservationInput, device: torch.device) -> tuple[Obs, ObservationForm]:
    """``(batched tensors on device, form)`` of any of:

    - a batch of tensors (``{key: [B, ...]}``, what native envs and the loops give);
    - one observation as numpy (``gymnasium.make(...)``: ``{key: array}``);
    - a batch of numpy observations (``gymnasium.make_vec(...)``: ``{key: [B, ...] array}``);
    - a bare array or tensor (an env without a dict space, e.g. Meta-World's own ``gymnasium.make``),
      read as the ``observation`` key.

    An observation is one (not a batch) when the keys the networks read hold exactly one input's
    worth of numbers, unless every one of them has a leading dimension of 1 (a batch of one).
    """
    if not isinstance(obs, Mapping):
        obs = {"observation": obs}
    tensors, numpy = {}, False
    for key, value in obs.items():  # tensors on the device pass through untouched (the loops' path)
        if isinstance(value, torch.Tensor):
            tensors[key] = value if value.device == device else value.to(device)
        else:
            numpy = True
            tensors[key] = torch.as_tensor(np.asarray(value), device=device)
    try:
        read = [tensors[k] for k in inputs.keys]
    except KeyError:
        missing = [k for k in inputs.keys if k not in tensors]
        raise ValueError(f"observation lacks {missing}: the agent reads {list(inputs.keys)}, got {list(tensors)}") from None
    total = sum(t.numel() for t in read)
    if total % inputs.dim:
        raise ValueError(
            f"observation holds {total} numbers under {list(inputs.keys)}: not a multiple of the agent's input size {inputs.dim}"
        )
    single = total == inputs.dim and not all(t.ndim >= 2 and t.shape[0] == 1 for t in read)
    if single:
        tensors = {k: t.unsqueeze(0) for k, t in tensors.items()}
    return tensors, _FORMS[single, numpy]


_FORMS = {(s, n): ObservationForm(single=s, numpy=n) for s in (False, True) for n in (False, True)}


class Agent:
    """Base of every agent (see the module docstring).

    Attributes:
        device: where the networks live.
        inputs: the observation input module (keys read, normalisation).
        updates: gradient updates made.
        checkpointed: checkpoint name -> dotted attribute path (``"normalize": "inputs.normalize"``);
            ``None``-valued attributes (an absent task encoder) are skipped.
        acting: the names of ``checkpointed`` that acting needs (a policy export keeps only these).
    """

    device: torch.device
    inputs: ObservationInput
    updates: int = 0
    checkpointed: ClassVar[dict[str, str]] = {}
    #: the checkpointed parts acting needs (what a policy export keeps)
    acting: ClassVar[tuple[str, ...]] = ()

    def setup(
        self,
        config: Any,
        device: str | torch.device,
        keys: tuple[str, ...],
        input_dim: int,
        conditioning: Any = None,
        picture_dim: int = 0,
        raw_columns: tuple[int, ...] = (),
    ) -> None:
        """The start every agent's constructor shares: its validated settings, its device, the (normalised, but for
        ``raw_columns``) input of the observation keys its networks read and, on multi-task runs, the task encoder
        (else None)."""
        config.validate()
        self.config, self.device = config, torch.device(device)
        self.inputs = ObservationInput(keys, input_dim, config.normalize_inputs, picture_dim, raw_columns).to(self.device)
        self.conditioning = conditioning
        self.task_encoder = conditioning.encoder.to(self.device) if conditioning is not None else None

    # ---------------------------------------------------------------- acting
    @torch.no_grad()
    def act(self, obs: Any, explore: bool = False, generator: torch.Generator | None = None, env_steps: int = 0) -> Any:
        """Actions for ``obs``: one observation or a batch, numpy or tensors (see `batch_observations`).

        Args:
            obs: observations as an env gives them; actions come back in the same form (numpy in,
                numpy out; one observation in, one action out; tensors in, tensors out).
            explore: use the algorithm's exploration (collection) instead of its greedy action (evaluation).
            generator: random generator for exploration.
            env_steps: training progress, for exploration that decays with env steps.
        """
        batch, form = batch_observations(obs, self.inputs, self.device)
        return form.restore(self.policy(batch, explore, generator, env_steps))

    def policy(self, obs: Obs, explore: bool, generator: torch.Generator | None, env_steps: int) -> torch.Tensor:
        """Actions ``[B, ...]`` for a batch of observation tensors (implemented by each agent)."""
        raise NotImplementedError

    def exploration(self, env_steps: int) -> dict[str, float]:
        """The exploration levels in force at ``env_steps`` (logged with each metrics row)."""
        return {}

    # ---------------------------------------------------------------- learning
    def learn(self, *args: Any) -> dict[str, torch.Tensor]:
        """One update's tensor work (implemented by each agent that compiles; see `compile`)."""
        raise NotImplementedError

    def schedule(self, update: int) -> tuple:
        """What `learn` takes after the batch at update number ``update`` (1-based): the flags of
        its schedules (whether a target network refreshes, an actor steps), fixed by the count alone."""
        return ()

    def step(self, *args: Any) -> dict[str, torch.Tensor]:
        """The update step as this agent runs it: `learn` eagerly, or compiled after `compile`."""
        return self.learn(*args)

    def counted_step(self, batch: Any, *args: Any, flags: tuple | None = None) -> dict[str, torch.Tensor]:
        """One update: count it, then `step` on ``batch`` with its `schedule` flags (or ``flags``) and ``args``."""
        if self.updates == 0:
            self.check_batch(batch)
        self.updates += 1
        return self.step(batch, *(self.schedule(self.updates) if flags is None else flags), *args)

    def check_batch(self, batch: Any) -> None:
        """Called with the first update's batch: raise ``ConfigError`` (one line naming the setting) for data
        these settings cannot learn from, e.g. rewards outside the range a bounded Q assumes. Default: accept."""

    def update_many(self, batch: Any, k: int) -> list[dict[str, torch.Tensor]]:
        """``k`` updates in one call, one on each of the ``k`` batches ``batch.split(k)`` makes, in order (after
        `compile`: one graph for all of them, the split included, which saves the per-call overhead
        ``k - 1`` times and the split's own small operations); the metrics of each."""
        if self.updates == 0:
            self.check_batch(batch)
        flags = tuple(self.schedule(self.updates + i + 1) for i in range(k))
        self.updates += k
        return self.step_many(batch, flags)

    def learn_many(self, batch: Any, flags: tuple[tuple, ...]) -> list[dict[str, torch.Tensor]]:
        """`learn` on each of the ``len(flags)`` batches ``batch.split(len(flags))`` makes, with its flags."""
        return [self.learn(part, *part_flags) for part, part_flags in zip(batch.split(len(flags)), flags)]

    def step_many(self, batch: Any, flags: tuple[tuple, ...]) -> list[dict[str, torch.Tensor]]:
        """`learn_many` eagerly, or compiled after `compile`."""
        return self.learn_many(batch, flags)

    def compile(self, mode: str, say: Callable[[str], None] | None = None) -> None:
        """Run `learn` as one ``torch.compile`` graph (``mode``: see `taskrl.agents.compiled`),
        or eagerly again with ``"off"``. ``say`` gets the one-line notice if compilation turns out unavailable."""
        one_of(mode, COMPILE_MODES, "compile", "mode")
        if mode == "off":
            self.__dict__.pop("step", None)
            self.__dict__.pop("step_many", None)
            return
        optimizers = [obj for obj in self._parts().values() if isinstance(obj, torch.optim.Optimizer)]
        kwargs = {"device": self.device} | ({} if say is None else {"say": say})
        self.step = CompiledStep(self.learn, mode, optimizers, **kwargs)
        self.step_many = CompiledStep(self.learn_many, mode, optimizers, what="updates", **kwargs)

    # ---------------------------------------------------------------- checkpointing
    def _parts(self) -> dict[str, Any]:
        parts = {}
        for name, path in self.checkpointed.items():
            obj: Any = self
            for attr in path.split("."):
                obj = getattr(obj, attr)
            if obj is not None:
                parts[name] = obj
        return parts

    def state_dict(self, parts: tuple[str, ...] | None = None) -> dict[str, Any]:
        """Every checkpointed module, optimiser and tensor, and the update count; or only the named
        ``parts`` (e.g. ``self.acting``, what a policy export keeps), without it."""
        chosen = self._parts()
        if parts is not None:
            chosen = {name: obj for name, obj in chosen.items() if name in parts}
        state: dict[str, Any] = {
            name: obj.detach().clone() if isinstance(obj, torch.Tensor) else obj.state_dict() for name, obj in chosen.items()
        }
        if parts is None:
            state["updates"] = self.updates
        return state

    def load_parts(self, state: dict[str, Any]) -> None:
        """Restore the parts ``state`` holds (tensors in place, so optimisers keep their references)."""
        for name, obj in self._parts().items():
            if name not in state:
                continue
            if isinstance(obj, torch.Tensor):
                with torch.no_grad():
                    obj.copy_(torch.as_tensor(state[name]).reshape(obj.shape))
            else:
                obj.load_state_dict(state[name])

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what `state_dict` saved: every part, and the update count."""
        missing = [name for name in (*self._parts(), "updates") if name not in state]
        if missing:
            raise KeyError(f"the saved agent lacks {missing}")
        self.load_parts(state)
        self.updates = int(state["updates"])
