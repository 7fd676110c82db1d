"""What every training loop does between its own steps: clock, metric rows, evaluation, checkpoints.

The off-policy and on-policy loops differ in how they collect and learn; they share everything
else through `Bookkeeping`: the training stopwatch (evaluation and checkpoints do not
count), the sums that make a metrics row (the agent's update scalars kept as tensors, so the hot
loop never waits for the device; finished training episodes and their successes; env steps and
updates), and the schedule of evaluations, log rows, early stopping and checkpoints.
"""

from __future__ import annotations

import contextlib
import dataclasses
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import torch


class Stopwatch:
    """Training wall-clock that can be paused (evaluation and checkpoints do not count)."""

    def __init__(self, already: float = 0.0) -> None:
        self.total, self.started = already, time.perf_counter()

    def pause(self) -> float:
        self.total += time.perf_counter() - self.started
        return self.total

    def resume(self) -> None:
        self.started = time.perf_counter()

    def read(self) -> float:
        return self.total + time.perf_counter() - self.started


class StopRequest:
    """Ends a run early but cleanly: after a wall-clock limit, or on Ctrl-C / SIGTERM.

    The loops ask `due` after every step; when it says yes, the run evaluates, logs and
    checkpoints as at its natural end, so ``--resume`` continues it with nothing lost (stopping
    inside an optimiser step would checkpoint half an update), and ``stopped_by`` keeps the reason.
    The first signal prints what happens next; a second one interrupts at once, except while a
    checkpoint is being written (`critical`), where it takes effect right after the write.

    Args:
        max_hours: hours of wall-clock from now (this invocation, not the run's total) after which
            the run stops; 0 = no limit.
    """

    def __init__(self, max_hours: float = 0.0) -> None:
        self.deadline = time.monotonic() + max_hours * 3600 if max_hours > 0 else None
        self.signalled: str | None = None
        self.stopped_by: str | None = None  # "time limit", "SIGINT" or "SIGTERM" once due
        self._in_critical = False
        self._abort_after_critical = False

    def due(self) -> bool:
        if self.signalled:
            self.stopped_by = self.signalled
        elif self.deadline is not None and time.monotonic() >= self.deadline:
            self.stopped_by = "time limit"
        return self.stopped_by is not None

    @contextlib.contextmanager
    def on_signals(self) -> Iterator[StopRequest]:
        """Turn SIGINT / SIGTERM into a stop request while the block runs (main thread only)."""
        if threading.current_thread() is not threading.main_thread():
            yield self
            return

        def handle(signum: int, frame: Any) -> None:
            if self.signalled:  # asked twice: stop now (but never in the middle of a checkpoint)
                if self._in_critical:
                    self._abort_after_critical = True
                    _say("aborting once the checkpoint being written is complete")
                    return
                raise KeyboardInterrupt
            self.signalled = signal.Signals(signum).name
            _say(
                f"stopping ({self.signalled}): finishing this step, evaluating and saving a checkpoint; "
                f"press Ctrl-C again to abort (the last complete checkpoint stays)"
            )

        previous = {sig: signal.signal(sig, handle) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield self
        finally:
            for sig, old in previous.items():
                signal.signal(sig, old)

    @contextlib.contextmanager
    def critical(self) -> Iterator[None]:
        """A block a second signal must not cut (writing a checkpoint)."""
        self._in_critical = True
        try:
            yield
        finally:
            self._in_critical = False
        if self._abort_after_critical:
            raise KeyboardInterrupt


def _say(message: str) -> None:
    print(f"taskrl: {message}", file=sys.stderr, flush=True)


class TrainingDiverged(RuntimeError):
    """A loss or metric became NaN or infinite; the run stopped before checkpointing it."""


#: Success rates are fractions of episodes; compare them with this slack (e.g. a mean over tasks of 0.9s).
SUCCESS_SLACK = 1e-9


@dataclasses.dataclass
class LoopState:
    """Counters that survive a resume."""

    env_steps: int = 0
    updates: int = 0
    wall_seconds: float = 0.0
    update_credit: float = 0.0
    next_eval: int = 0
    next_checkpoint: int = 0
    best_success: float = 0.0
    last_success: float = 0.0

    def progress(self, axis: str = "env_steps") -> int:
        """The count a run's schedule follows: env steps, or gradient updates (``axis="updates"``)."""
        return self.updates if axis == "updates" else self.env_steps


class Bookkeeping:
    """Accumulates one metrics row and runs the evaluation / checkpoint schedule.

    Args:
        state: the loop's counters (advanced by the loop, read and updated here).
        evaluate: ``() -> metrics`` with ``success_rate``.
        on_log: receives each row.
        on_checkpoint: receives the state when a checkpoint is due (and at the end).
        total_steps: env steps after which the run is finished.
        eval_interval, checkpoint_interval: env steps between evaluations / checkpoints.
        stop_at_success: end the run once evaluation success reaches this (0: never).
        device: where the running sums live.
        stop: ends the run early (time limit, signals) with an evaluation and a checkpoint.
        checkpoint_seconds: also checkpoint once this much wall-clock has passed since the last one
            (0: by env steps only).
        axis: what ``total_steps`` and the intervals count: ``env_steps``, or ``updates`` for an
            offline loop (which never steps an env while it trains).

    Before each metrics row and each checkpoint the update scalars since the last row are checked:
    a NaN or infinite one raises `TrainingDiverged`, so no diverged weights are ever saved.
    """

    def __init__(
        self,
        state: LoopState,
        evaluate: Callable[[], dict[str, float]],
        on_log: Callable[[dict[str, Any]], None],
        on_checkpoint: Callable[[LoopState], None],
        total_steps: int,
        eval_interval: int,
        checkpoint_interval: int,
        stop_at_success: float,
        device: torch.device,
        stop: StopRequest | None = None,
        checkpoint_seconds: float = 0.0,
        axis: str = "env_steps",
    ) -> None:
        self.axis = axis
        self.state, self.evaluate, self.on_log, self.on_checkpoint = state, evaluate, on_log, on_checkpoint
        self.stop = stop
        self.checkpoint_seconds = checkpoint_seconds
        self.last_checkpoint = time.monotonic()
        #: called once when the run finishes, before its last checkpoint (the off-policy loop stores its
        #: running episodes there, so a stopped run keeps every transition it collected)
        self.on_finish: Callable[[], Any] | None = None
        #: called after every step with the env-step count (a console's heartbeat line)
        self.heartbeat: Callable[[int], Any] | None = None
        #: ``(env_steps, {scalar: mean since the last call})`` every ``train_log_interval`` env steps
        #: (TensorBoard's training curves between evaluations)
        self.on_train_log: Callable[[int, dict[str, float]], Any] | None = None
        self.train_log_interval = 0
        #: ``(seconds of the row) -> columns`` added to every metrics row (a distributed loop's per-role
        #: figures, data sharing's per-task shares)
        self.row_metrics: list[Callable[[float], dict[str, Any]]] = []
        self._train_base: dict[str, torch.Tensor] = {}
        self._train_calls = 0
        self._next_train_log = self.progress()
        self.total_steps = total_steps
        self.eval_interval, self.checkpoint_interval, self.stop_at_success = eval_interval, checkpoint_interval, stop_at_success
        self.clock = Stopwatch(state.wall_seconds)
        self.metric_sums: dict[str, torch.Tensor] = {}
        self.episodes_done = torch.zeros((), device=device)
        self.episodes_success = torch.zeros((), device=device)
        self.row_steps = self.row_updates = self.row_calls = 0
        self.row_start = self.clock.read()

    def progress(self) -> int:
        """The count the schedule follows: env steps, or gradient updates (``axis``)."""
        return self.state.progress(self.axis)

    def add_steps(self, n: int) -> None:
        self.state.env_steps += n
        self.row_steps += n

    def add_episodes(self, ended: torch.Tensor, succeeded: torch.Tensor) -> None:
        """Training episodes that finished and how many succeeded (counts or boolean masks)."""
        self.episodes_done += ended.sum()
        self.episodes_success += succeeded.sum()

    def add_update(self, metrics: dict[str, torch.Tensor], gradient_steps: int = 1) -> None:
        """The scalars one ``agent.update`` call returned, and how many gradient steps it took."""
        for name, value in metrics.items():
            self.metric_sums[name] = self.metric_sums[name] + value if name in self.metric_sums else value.clone()
        self.state.updates += gradient_steps
        self.row_updates += gradient_steps
        self.row_calls += 1

    def after_step(self, extra: dict[str, Any] | None = None) -> bool:
        """Evaluate, log and checkpoint when due; returns whether the run is finished."""
        state, at = self.state, self.progress()
        if self.heartbeat is not None:
            self.heartbeat(at)
        if self.on_train_log is not None and self.train_log_interval > 0 and at >= self._next_train_log:
            self._log_training()
        finished = at >= self.total_steps
        if not finished and self.stop is not None and self.stop.due():
            finished = True
        if at >= state.next_eval or finished:
            self.check_finite()
            state.wall_seconds = self.clock.pause()
            elapsed = max(state.wall_seconds - self.row_start, 1e-9)
            result = self.evaluate()
            row = {
                "env_steps": state.env_steps,
                "updates": state.updates,
                "wall_seconds": round(state.wall_seconds, 3),
                **result,
                "train_success": (self.episodes_success / self.episodes_done.clamp(min=1)).item(),
                **{name: (total / max(self.row_calls, 1)).item() for name, total in self.metric_sums.items()},
                **(extra or {}),
                **{name: value for columns in self.row_metrics for name, value in columns(elapsed).items()},
                "env_steps_per_s": self.row_steps / elapsed,
                "updates_per_s": self.row_updates / elapsed,
            }
            self.on_log(row)
            state.last_success = result["success_rate"]
            state.best_success = max(state.best_success, result["success_rate"])
            if at >= state.next_eval:  # an early stop's evaluation keeps the schedule as it was
                missed = (at - state.next_eval) // self.eval_interval + 1  # a big step may pass several
                state.next_eval += missed * self.eval_interval
            self.metric_sums.clear(), self.episodes_done.zero_(), self.episodes_success.zero_()
            self._train_base, self._train_calls = {}, 0
            self.row_steps = self.row_updates = self.row_calls = 0
            self.row_start = state.wall_seconds
            self.clock.resume()
            if self.stop_at_success > 0 and result["success_rate"] >= self.stop_at_success - SUCCESS_SLACK:
                finished = True
        overdue = self.checkpoint_seconds > 0 and time.monotonic() - self.last_checkpoint >= self.checkpoint_seconds
        if finished and self.on_finish is not None:
            self.on_finish()
        if at >= state.next_checkpoint or finished or overdue:
            self.check_finite()
            state.wall_seconds = self.clock.pause()
            state.next_checkpoint = at + self.checkpoint_interval
            with self.stop.critical() if self.stop is not None else contextlib.nullcontext():
                self.on_checkpoint(state)
            self.last_checkpoint = time.monotonic()
            self.clock.resume()
        return finished

    def _log_training(self) -> None:
        """The update scalars' means since the last training point: differences of the row's sums, so
        the updates themselves do no extra work; one device sync per point."""
        calls = self.row_calls - self._train_calls
        if calls > 0 and self.metric_sums:
            names = list(self.metric_sums)
            deltas = torch.stack([(self.metric_sums[k] - self._train_base.get(k, 0.0)).float().reshape(()) for k in names])
            values = (deltas / calls).cpu().tolist()
            self.on_train_log(self.progress(), dict(zip(names, values)))
            self._train_base = {k: v.clone() for k, v in self.metric_sums.items()}
            self._train_calls = self.row_calls
        missed = (self.progress() - self._next_train_log) // self.train_log_interval + 1
        self._next_train_log += missed * self.train_log_interval

    def check_finite(self) -> None:
        """Raise `TrainingDiverged` if an update scalar since the last row is NaN or infinite."""
        if not self.metric_sums:
            return
        values = torch.stack([v.detach().float().reshape(()) for v in self.metric_sums.values()]).cpu()
        bad = [name for name, ok in zip(self.metric_sums, torch.isfinite(values).tolist()) if not ok]
        if bad:
            raise TrainingDiverged(
                f"training diverged by {self.axis.replace('_', ' ')[:-1]} {self.progress():,}: {', '.join(bad)} "
                f"became {values[list(self.metric_sums).index(bad[0])].item()}; nothing after the "
                f"last checkpoint was saved (try a lower --lr or a --max-grad-norm)"
            )

    def close(self) -> LoopState:
        self.state.wall_seconds = self.clock.pause()
        return self.state
