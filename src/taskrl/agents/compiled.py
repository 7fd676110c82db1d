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

import os
import sys
import time
from collections.abc import Callable
from typing import Any

import torch

from taskrl.agents.parts import init_adam_state
from taskrl.errors import one_of

#: ``--compile`` values: off, or a ``torch.compile`` mode
COMPILE_MODES = ("off", "default", "reduce-overhead", "max-autotune")
#: what a run may be given: those, or ``auto`` (`taskrl.agents.compile_rule`)
RUN_COMPILE_MODES = ("auto", *COMPILE_MODES)


def _say(line: str) -> None:
    print(f"note: {line}", file=sys.stderr, flush=True)


def _skip_parameter_guards(entries: list[Any]) -> list[bool]:
    """Which of the compiled step's guards to check at every call: all but those on the parameters.

    Parameters keep their shapes, dtypes and devices for an agent's life (loading a checkpoint copies
    into them), so checking them again at every call (measured: most of the guard time) buys nothing;
    every other guard stays: on the arguments (a batch's shapes, a schedule flag), the buffers and
    optimiser state, the agent's config and the identity of its modules and optimisers (so one agent's
    graph never runs another's).
    """
    return [not (entry.guard_type == "TENSOR_MATCH" and isinstance(entry.value, torch.nn.Parameter)) for entry in entries]


#: Dynamo's settings while compiling: autograd.grad inside the graph is traced, not a graph break; every agent
#: of a class compiles the same code with its own guards, so room for many in one process, and a notice (not
#: silent eager) past that
COMPILE_SETTINGS = {"trace_autograd_ops": True, "recompile_limit": 64, "fail_on_recompile_limit_hit": True}


def compile_options(mode: str, device: torch.device | str = "cpu") -> dict[str, Any]:
    """Inductor's options for ``mode`` on ``device``: the mode's own, the guard filter, no size asserts (the guards
    check every argument's shape and strides before a call, and a parameter keeps its own for the agent's life;
    side by side, a batch-32 DQN update took 0.94x the time without them), and on CPU the graph's wrapper (what
    calls its kernels and matrix products in order) generated as C++ instead of Python (side by side, 0.83x the
    time of a compiled DQN (64, 64) / 32 update; ``benchmarks/per_call_costs.py`` for both)."""
    on_cpu = torch.device(device).type == "cpu"
    return {
        **torch._inductor.list_mode_options(mode),
        "guard_filter_fn": _skip_parameter_guards,
        "size_asserts": False,
        "cpp_wrapper": on_cpu,
    }


def compile_cache_dir() -> str:
    """Where compiled graphs are kept across runs: ``TORCHINDUCTOR_CACHE_DIR`` when set, else the user's cache
    directory (``$XDG_CACHE_HOME`` or ``~/.cache``) under ``taskrl/torch-compile``, set for this process
    (torch's own default is under ``/tmp``, which does not survive a restart)."""
    chosen = os.environ.get("TORCHINDUCTOR_CACHE_DIR")
    if not chosen:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        chosen = os.environ["TORCHINDUCTOR_CACHE_DIR"] = os.path.join(base, "taskrl", "torch-compile")
    return chosen


def _graphs_compiled() -> int:
    """Graphs ``torch.compile`` has made in this process so far (its own statistics counter)."""
    return torch._dynamo.utils.counters["stats"]["unique_graphs"]


class CompiledStep:
    """``step(*args)``: ``fn`` compiled on its first call, or ``fn`` itself once compilation failed.

    Args:
        fn: the update step: tensors (and a batch of them) in, metrics out; no Python-side state
            that changes between calls.
        mode: a ``torch.compile`` mode (`COMPILE_MODES` without ``off``).
        optimizers: the Adam optimisers ``fn`` steps; their state is completed before the first trace.
        say: where the one-line notices go (the compile time; a fallback), default stderr.
        what: what it compiles, for those notices.
        device: where ``fn``'s tensors live (the compiler's options differ on CPU, `compile_options`).
    """

    def __init__(
        self,
        fn: Callable[..., Any],
        mode: str,
        optimizers: list[torch.optim.Optimizer],
        say: Callable[[str], None] = _say,
        what: str = "update",
        device: torch.device | str = "cpu",
    ) -> None:
        one_of(mode, COMPILE_MODES[1:], "compile", "mode")
        compile_cache_dir()
        self.fn, self.mode, self.say, self.optimizers, self.what = fn, mode, say, optimizers, what
        # a mode is a set of compiler options; given as options, so the guard filter can join them. Static
        # shapes: the batch size is fixed for a run, and another agent's shapes must not turn this one's dynamic
        self.compiled: Callable[..., Any] | None = torch.compile(
            fn, fullgraph=True, dynamic=False, options=compile_options(mode, device)
        )
        self.calls = 0
        #: seconds of the calls that compiled (tracing, compiling, one update each): the first, and the
        #: first of each further variant (a target refresh every N updates); the cost before compiling pays
        self.compile_seconds = 0.0

    @property
    def active(self) -> bool:
        """Whether calls run compiled (False after a fallback)."""
        return self.compiled is not None

    def __call__(self, *args: Any) -> Any:
        if self.compiled is None:
            return self.fn(*args)
        if self.calls == 0:  # the state a loaded checkpoint brought, or none yet: complete it before tracing
            for optimizer in self.optimizers:
                init_adam_state(optimizer)
        started, graphs = time.perf_counter(), _graphs_compiled()
        try:
            out = self._run(*args)
        except Exception as error:  # a compiler that is missing or refuses: the same step, eagerly
            self.compiled = None
            reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            self.say(
                f"--compile {self.mode} is unavailable for the {self.what} here ({type(error).__name__}: {reason[:300]}); updating eagerly"
            )
            return self.fn(*args)
        if _graphs_compiled() != graphs:  # this call compiled (the first, or a schedule's other variant)
            self.compile_seconds += time.perf_counter() - started
            if self.calls == 0:
                self.say(f"compiled the {self.what} ({self.mode}) in {self.compile_seconds:.1f} s")
        self.calls += 1
        return out

    def _run(self, *args: Any) -> Any:
        """The compiled call. Once a graph exists, a call first runs under the stance that refuses to
        compile, which is cheaper to enter than `COMPILE_SETTINGS` (side by side, a batch-32 DQN
        update took 0.87x the time, ``benchmarks/per_call_costs.py``); a call that needs a new graph (a
        schedule's other variant) is refused before anything runs and goes on to compile with them."""
        if self.calls:
            try:
                with torch.compiler.set_stance("fail_on_recompile"):
                    return self.compiled(*args)
            except RuntimeError as error:
                if "fail_on_recompile" not in str(error):
                    raise
        with torch._dynamo.config.patch(**COMPILE_SETTINGS):
            return self.compiled(*args)
