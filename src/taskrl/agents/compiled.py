"""Opt-in compiled updates (``--compile MODE``): an agent's whole update as one ``torch.compile`` graph.

An update is many small tensor operations (gathers, three to nine matrix products, activations,
the loss, its backward, the optimiser, the target average); run one by one, each pays Python and
dispatch overhead, which at small networks costs more than the arithmetic. Compiled, the step
(forward, backward through ``torch.autograd.grad``, gradient clip, Adam, Polyak target) is traced once
into one graph whose elementwise work is fused into a few kernels around the matrix products.

- ``default``: TorchInductor kernels (CPU: generated C++; CUDA: Triton);
- ``reduce-overhead``: as ``default``, and on CUDA the graph is replayed as a CUDA graph (no launch
  overhead); on CPU the same as ``default``;
- ``max-autotune``: as ``reduce-overhead``, also timing kernel choices while compiling (slow to start).

What stays out of the graph: counters and schedules (the update count, when a target is refreshed),
so a step's graph does not change from one update to the next. Randomness inside a compiled step
(SAC's action samples) comes from the compiler's own generator: the same distributions, not the
same numbers as eager. Where compilation is unavailable (no C++ compiler, an unsupported op or
torch), the first update says so on one line and the run continues eagerly.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Callable
from typing import Any

import torch

from taskrl.agents.parts import init_adam_state
from taskrl.errors import one_of

#: ``--compile`` values: off, or a ``torch.compile`` mode
COMPILE_MODES = ("off", "default", "reduce-overhead", "max-autotune")


def _say(line: str) -> None:
    print(f"note: {line}", file=sys.stderr, flush=True)


def _keep_argument_guards(entries: list[Any]) -> list[bool]:
    """Which of the compiled step's guards to check at every call: the arguments' (a batch's shapes and
    dtypes, a schedule flag) and every tensor's that is not a parameter (buffers, optimiser state).

    Left out are the guards on the agent's own Python state (its config, its modules' structure),
    which the step never changes and which cost more to check than a small update takes (measured:
    180 us of a 2.9 ms DQN update at (256, 256), most of a 0.3 ms one at (64, 64)). An agent's config
    changed after :meth:`~taskrl.agents.base.Agent.compile` is therefore not seen by the step.
    """
    keep = []
    for entry in entries:
        root = re.match(r"\w*", entry.name).group()  # names are source paths: "batch.obs['observation']"
        is_argument = root != "self"
        is_state_tensor = entry.guard_type == "TENSOR_MATCH" and not isinstance(entry.value, torch.nn.Parameter)
        keep.append(is_argument or is_state_tensor)
    return keep


class CompiledStep:
    """``step(*args)``: ``fn`` compiled on its first call, or ``fn`` itself once compilation failed.

    Args:
        fn: the update step: tensors (and a batch of them) in, metrics out; no Python-side state
            that changes between calls.
        mode: a ``torch.compile`` mode (:data:`COMPILE_MODES` without ``off``).
        optimizers: the Adam optimisers ``fn`` steps; their state is created before tracing.
        say: where the one-line notice of a fallback goes (default: stderr).
    """

    def __init__(
        self,
        fn: Callable[..., Any],
        mode: str,
        optimizers: list[torch.optim.Optimizer],
        say: Callable[[str], None] = _say,
    ) -> None:
        one_of(mode, COMPILE_MODES[1:], "compile", "mode")
        self.fn, self.mode, self.say = fn, mode, say
        for optimizer in optimizers:
            init_adam_state(optimizer)
        # a mode is a set of compiler options; given as options, so the guard filter can join them
        options = {**torch._inductor.list_mode_options(mode), "guard_filter_fn": _keep_argument_guards}
        self.compiled: Callable[..., Any] | None = torch.compile(fn, fullgraph=True, options=options)
        self.calls = 0

    @property
    def active(self) -> bool:
        """Whether calls run compiled (False after a fallback)."""
        return self.compiled is not None

    def __call__(self, *args: Any) -> Any:
        if self.compiled is None:
            return self.fn(*args)
        try:
            # autograd.grad inside the graph: traced, not a graph break
            with torch._dynamo.config.patch(trace_autograd_ops=True):
                out = self.compiled(*args)
        except Exception as error:  # a compiler that is missing or refuses: the same step, eagerly
            self.compiled = None
            reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            self.say(f"--compile {self.mode} is unavailable here ({type(error).__name__}: {reason[:300]}); updating eagerly")
            return self.fn(*args)
        self.calls += 1
        return out
