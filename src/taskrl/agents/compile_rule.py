"""``--compile auto`` and ``--updates-per-call auto`` (the defaults): the library chooses the faster path.

Compiling an update costs seconds to tens of seconds before the first update and saves a share of every later one,
so it pays only after enough updates. For each path (eager; compiled, one update per call; compiled, four per
call) the run's time is estimated as ``compile seconds + planned updates x ms per update`` from `MEASURED`,
and the fastest path is taken, a compiled one only where it is estimated at most `COMPILE_MARGIN` of eager's time.
A run's planned updates are its ``offline_updates`` plus ``updates_per_step x (total_steps - learning_starts)``
(an offline run's ``total_steps`` are updates).

A compile is cheaper where an earlier run on this machine compiled the same shapes (the same algorithm, env
settings, widths, batch, updates per call, device and torch): torch's on-disk cache then serves most of the work, and
the estimate takes ``LATER_RUN_FACTOR`` of the first compile's seconds. A run that compiled leaves a marker of its
shapes in the compile cache (`remember_compiled`) for later runs to find (`cached_calls`). A machine's first compile
costs `MACHINE_FIRST_SECONDS` more.

Networks that read pictures (conv encoders) have no measured case: ``auto`` keeps them eager. Other cases not
measured take the times of the measured case of the same algorithm nearest in work (batch x the
network's weights, on a log scale); an algorithm with no case of its own takes SAC's (TD3 and QT-Opt: one
actor or CEM and twin critics, SAC's shape). The table was measured on CPU with one torch thread; on a GPU the
same rule is used, unmeasured there.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from pathlib import Path
from typing import Any

import torch

from taskrl.agents.compiled import compile_cache_dir

__all__ = [
    "MEASURED",
    "COMPILE_MARGIN",
    "CompileChoice",
    "MeasuredUpdate",
    "cached_calls",
    "choose_compile",
    "machine_compiled_before",
    "planned_updates",
    "remember_compiled",
]

MANY = 4  # updates per call of the compiled-many path
#: a compiled path is taken only where it is estimated at no more than this share of eager's seconds: near the
#: break-even the estimate's error decides, and there eager loses little (DQN (256, 256) / 256 over a 30 s slice,
#: estimated 21.5 s compiled against 22.4 s eager, ran 6% slower compiled, 29.7 against 28.0 s: the run at commit
#: 4303883, benchmarks/results/learner_equal_auto_30s_4303883.json; RESULTS.md, "... 30 s slices", says it)
COMPILE_MARGIN = 0.9
#: a machine's first compile also builds what every later one reuses, whatever its shapes (the C++ compiler's checks,
#: torch's precompiled header): DQN (64, 64) / 32 compiled in 9.2 s on a fresh cache and in 5.2 s where the other
#: DQN case had compiled before (AMD EPYC; the no-flag runs of benchmarks/RESULTS.md, "Learner speed with no flag
#: (--compile auto) against Stable-Baselines3, 120 s slices", their compile seconds in learner_equal_auto_120s.json)
MACHINE_FIRST_SECONDS = 4.0
#: a later run of the same shapes compiled in 0.26x a first run's seconds, with one update per call (5.8 against 22.0 s)
#: and with four (12.6 against 49.2 s): DQN (256, 256) / 256, benchmarks/RESULTS.md, "Compile seconds of a first and a
#: later run"
LATER_RUN_FACTOR = 0.26


@dataclasses.dataclass(frozen=True)
class MeasuredUpdate:
    """One measured update: its shape and the milliseconds of each path, and the seconds of a first compile.

    Attributes:
        algo: the algorithm.
        hidden_sizes: the networks' hidden widths.
        batch_size: transitions per update.
        eager_ms: one eager update.
        compiled_ms: one compiled update, one per call.
        compiled_many_ms: one compiled update, four per call.
        compile_seconds: compiling the one-per-call graph in a first run of these shapes (on a machine that compiled
            other shapes before: `MACHINE_FIRST_SECONDS` apart).
        compile_many_seconds: the same for the four-per-call graphs.
    """

    algo: str
    hidden_sizes: tuple[int, ...]
    batch_size: int
    eager_ms: float
    compiled_ms: float
    compiled_many_ms: float
    compile_seconds: float
    compile_many_seconds: float

    @property
    def work(self) -> float:
        return update_work(self.hidden_sizes, self.batch_size)


#: AMD EPYC, 2 cores, one torch thread, torch 2.13.0, a compile cache where a throwaway update had compiled: the first
#: three rows measured 2026-12-06 (`benchmarks/learner_speed.py bound --only "DQN (64, 64) / 32" "DQN (256, 256) / 256,
#: as" "SAC (256, 256)"`, benchmarks/results/learner_bound_auto_table.json); MT10's on Intel Xeon, 2026-12-03
#: (learner_bound_mt10_xeon.json), its four-per-call compile not measured: taken as 2.24x its one-per-call compile, the
#: ratio DQN (256, 256) / 256 had then (benchmarks/RESULTS.md, "Compile seconds of a first and a later run")
MEASURED: tuple[MeasuredUpdate, ...] = (
    MeasuredUpdate("dqn", (64, 64), 32, 0.39, 0.093, 0.058, 3.2, 17.7),
    MeasuredUpdate("dqn", (256, 256), 256, 2.07, 1.586, 1.541, 4.4, 19.2),
    MeasuredUpdate("sac", (256, 256), 256, 8.54, 6.734, 6.396, 18.8, 34.9),
    MeasuredUpdate("sac", (400, 400, 400), 1280, 199.20, 176.50, 174.44, 70.56, 158.1),
)


def update_work(hidden_sizes: tuple[int, ...], batch_size: int) -> float:
    """batch x weights of an MLP with these hidden widths (inputs and outputs counted as 32 wide): what an update's
    matrix products scale with, for finding the nearest measured case."""
    widths = (32, *hidden_sizes, 32)
    return float(batch_size) * sum(a * b for a, b in zip(widths, widths[1:]))


@dataclasses.dataclass(frozen=True)
class CompileChoice:
    """What a run compiles, and why (the run's first note).

    Attributes:
        mode: ``off`` or a ``torch.compile`` mode.
        updates_per_call: updates per call of the agent.
        reason: one line saying which path and why.
    """

    mode: str
    updates_per_call: int
    reason: str


def planned_updates(config: Any) -> int:
    """The gradient updates a run's settings plan."""
    if config.data.offline:
        return int(config.total_steps)
    collected = max(0, config.total_steps - config.learning_starts)
    return int(config.data.offline_updates + config.updates_per_step * collected)


def nearest_measured(algo: str, hidden_sizes: tuple[int, ...], batch_size: int) -> MeasuredUpdate:
    """The measured case of ``algo`` (SAC's where it has none) nearest in work."""
    own = [m for m in MEASURED if m.algo == algo] or [m for m in MEASURED if m.algo == "sac"]
    work = update_work(hidden_sizes, batch_size)
    return min(own, key=lambda m: abs(math.log(m.work / work)))


def _shapes_marker(config: Any, per_call: int) -> Path:
    """The file that says a run of these shapes compiled on this machine: a hash of the algorithm, the env family and
    its settings, the widths, the batch, the updates per call, the device and torch's version."""
    shapes = {
        "algo": config.algo,
        "env": config.env,
        "env_settings": dataclasses.asdict(config.env_settings),
        "hidden_sizes": list(config.algo_settings.hidden_sizes),
        "batch_size": config.batch_size,
        "per_call": per_call,
        "device": config.device,
        "torch": torch.__version__,
    }
    digest = hashlib.sha256(json.dumps(shapes, sort_keys=True, default=str).encode()).hexdigest()[:24]
    return Path(compile_cache_dir()) / "taskrl-compiled-shapes" / digest


def cached_calls(config: Any) -> set[int]:
    """The updates per call (1, `MANY`, and the run's own where set) whose graphs a run of ``config``'s shapes compiled
    before on this machine."""
    return {k for k in {1, MANY, max(config.updates_per_call, 1)} if _shapes_marker(config, k).exists()}


def remember_compiled(config: Any, per_call: int) -> None:
    """Leave the marker `cached_calls` finds: a run of ``config``'s shapes compiled ``per_call`` updates per call."""
    marker = _shapes_marker(config, per_call)
    try:
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.touch()
    except OSError:  # a read-only cache: later runs estimate a first compile, as without a marker
        pass


def machine_compiled_before() -> bool:
    """Whether a taskrl run compiled anything on this machine before (any marker of `remember_compiled`)."""
    folder = Path(compile_cache_dir()) / "taskrl-compiled-shapes"
    return folder.is_dir() and any(folder.iterdir())


def choose_compile(
    config: Any,
    compiles: bool,
    many_allowed: bool,
    pictures: bool = False,
    cached: set[int] = frozenset(),
    machine_compiled: bool = True,
) -> CompileChoice:
    """The path of a run whose ``compile`` and ``updates_per_call`` may be ``auto`` (``updates_per_call`` 0).

    Args:
        config: the run's settings.
        compiles: whether the algorithm has a compiled update.
        many_allowed: whether the run's loop takes several updates per call (off-policy, one process, online).
        pictures: whether its networks read camera pictures (conv encoders: no case measured, so ``auto`` stays eager).
        cached: the updates per call whose graphs an earlier run of the same shapes compiled (`cached_calls`): their
            compile is estimated at `LATER_RUN_FACTOR` of a first one.
        machine_compiled: whether anything compiled on this machine before (`machine_compiled_before`); if not, a
            compile also costs `MACHINE_FIRST_SECONDS`.
    """
    mode_auto, calls_auto = config.compile == "auto", config.updates_per_call == 0
    if config.compile == "off" or not (mode_auto or calls_auto):  # set by the user: nothing to choose or say
        return CompileChoice(config.compile, max(config.updates_per_call, 1), "")
    if not compiles:
        return CompileChoice("off", 1, f"compile: eager ({config.algo} has no compiled update)")
    if pictures and mode_auto:
        return CompileChoice("off", 1 if calls_auto else config.updates_per_call, "compile: eager (networks reading "
                             "pictures have no measured compiled update; --compile default tries one)")  # fmt: skip
    n = planned_updates(config)
    case = nearest_measured(config.algo, tuple(config.algo_settings.hidden_sizes), config.batch_size)

    def compiling(k: int) -> float:  # seconds of compiling k updates per call: a first run's, or a later run's
        measured = case.compile_many_seconds if k > 1 else case.compile_seconds
        if k in cached:
            return LATER_RUN_FACTOR * measured
        return measured + (0.0 if machine_compiled else MACHINE_FIRST_SECONDS)

    eager = n * case.eager_ms / 1e3
    one = compiling(1) + n * case.compiled_ms / 1e3
    many = compiling(MANY) + n * case.compiled_many_ms / 1e3
    seconds = {("off", 1): eager, ("off", MANY): eager, ("default", 1): one, ("default", MANY): many}
    if not calls_auto:  # the number of updates per call as set (eager updates cost the same either way)
        k = config.updates_per_call
        seconds = {("off", k): eager, ("default", k): compiling(k) + n * case.compiled_many_ms / 1e3 if k > 1 else one}
    elif not many_allowed:
        seconds = {p: t for p, t in seconds.items() if p[1] == 1}
    if not mode_auto:  # a compile mode as set (``off`` returned above): only its compiled paths
        seconds = {p: t for p, t in seconds.items() if p[0] != "off"}
    mode, k = min(seconds, key=lambda path: seconds[path] * (COMPILE_MARGIN if path[0] == "off" else 1.0))
    mode = mode if mode_auto else config.compile
    path = "eager" if mode == "off" else f"compiled ({mode}), {k} update{'s' if k > 1 else ''} per call"
    basis = (
        f"{n:,} planned updates, estimated {eager:.0f} s eager, {one:.0f} s compiled and {many:.0f} s compiled four per "
        f"call, from the measured {case.algo.upper()} {case.hidden_sizes} / {case.batch_size}"
    )
    if not machine_compiled and not cached:
        basis += f"; nothing compiled on this machine before: {MACHINE_FIRST_SECONDS} s more"
    if cached:
        calls = " and ".join(str(k) for k in sorted(cached))
        basis += (
            f"; graphs of {calls} per call compiled before on this machine, their compile at a later run's {LATER_RUN_FACTOR}x"
        )
    return CompileChoice(mode, k, f"compile: {path} ({basis})")
