"""Batches of demonstrations for behaviour cloning: stratified over tasks, with action chunks and prompt demos.

    task   t ~ U{0..T-1}                     every task equally often, however many steps it has
    step   i ~ U(steps of task t)
    labels a_i, a_{i+1}, ..., a_{i+H-1}      an action chunk (H = 1: the action), masked past the episode's end
    prompt D = frames of one demonstration of task t (another episode where the task has several)

A prompt demonstration is ``frames`` states spaced evenly from its first to its last step: what a
demo encoder sees of a task.
"""

from __future__ import annotations

import dataclasses

import torch

from taskrl.demos.dataset import Demonstrations

__all__ = ["DemoBatch", "DemoSampler", "episode_frames", "prompt_frames"]


@dataclasses.dataclass
class DemoBatch:
    """One behaviour-cloning batch.

    Attributes:
        obs: ``{"observation": [B, D], "task": [B]}``, and ``"image"`` ``[B, H, W, 3]`` uint8 where the dataset has pictures.
        actions: ``[B, H, A]`` the expert's next H actions.
        mask: ``[B, H]`` 1 where that action exists (inside the episode).
        demo: ``[B, L, D]`` frames of a prompt demonstration of each row's task (None unless asked).
    """

    obs: dict[str, torch.Tensor]
    actions: torch.Tensor
    mask: torch.Tensor
    demo: torch.Tensor | None = None


def episode_frames(demos: Demonstrations, frames: int) -> torch.Tensor:
    """``[E, frames, D]``: each episode's states at ``frames`` evenly spaced steps, first to last."""
    fractions = torch.linspace(0.0, 1.0, frames, device=demos.observations.device)
    offsets = torch.round(fractions[None, :] * (demos.lengths[:, None] - 1).float()).long()
    return demos.observations[demos.starts[:, None] + offsets]


def prompt_frames(demos: Demonstrations, frames: int) -> torch.Tensor:
    """``[T, frames, D]``: each task's first demonstration as a prompt (zeros for a task without one)."""
    table = torch.zeros(len(demos.task_names), frames, demos.observations.shape[1], device=demos.observations.device)
    first = torch.full((len(demos.task_names),), demos.num_episodes, dtype=torch.long, device=demos.episode_tasks.device)
    first.scatter_reduce_(0, demos.episode_tasks, torch.arange(demos.num_episodes, device=first.device), "amin")
    has = first < demos.num_episodes
    table[has] = episode_frames(demos, frames)[first[has]]
    return table


class DemoSampler:
    """``sample(batch_size, generator) -> DemoBatch`` (stratified over tasks, see the module docstring).

    Args:
        demos: the dataset, on the device batches are made on.
        chunk: H, actions per label.
        frames: frames of each prompt demonstration (0: no prompts in the batch).
    """

    def __init__(self, demos: Demonstrations, chunk: int = 1, frames: int = 0) -> None:
        self.demos, self.chunk, self.frames = demos, int(chunk), int(frames)
        device = demos.tasks.device
        num_tasks = len(demos.task_names)
        self.step_order, self.step_counts, self.step_offsets = _grouped(demos.tasks, num_tasks)
        self.episode_order, self.episode_counts, self.episode_offsets = _grouped(demos.episode_tasks, num_tasks)
        self.present = torch.nonzero(self.step_counts > 0).flatten()  # tasks that have demonstrations
        self.step_episode = torch.repeat_interleave(torch.arange(demos.num_episodes, device=device), demos.lengths)
        self.step_end = (demos.starts + demos.lengths)[self.step_episode]  # one past each step's episode's last step
        self.prompt_frames = episode_frames(demos, frames) if frames > 0 else None

    def sample(self, batch_size: int, generator: torch.Generator | None = None) -> DemoBatch:
        d, device = self.demos, self.demos.tasks.device
        pick = torch.randint(len(self.present), (batch_size,), generator=generator, device=device)
        task = self.present[pick]
        u = torch.rand(batch_size, generator=generator, device=device)
        within = (u * self.step_counts[task]).long().clamp(max=self.step_counts[task] - 1)
        row = self.step_order[self.step_offsets[task] + within]
        ahead = row[:, None] + torch.arange(self.chunk, device=device)[None, :]
        mask = ahead < self.step_end[row][:, None]
        actions = d.actions[torch.where(mask, ahead, row[:, None])] * mask[..., None]
        demo = None
        if self.prompt_frames is not None:
            counts = self.episode_counts[task]
            v = torch.rand(batch_size, generator=generator, device=device)
            j = (v * counts).long().clamp(max=counts - 1)
            episode = self.episode_order[self.episode_offsets[task] + j]
            own = self.step_episode[row]
            # another demonstration of the task where it has one (the prompt is not the episode being imitated)
            again = (episode == own) & (counts > 1)
            j = torch.where(again, (j + 1) % counts, j)
            episode = self.episode_order[self.episode_offsets[task] + j]
            demo = self.prompt_frames[episode]
        obs = {"observation": d.observations[row], "task": task}
        if d.images is not None:
            obs["image"] = d.images[row]
        return DemoBatch(obs, actions, mask.float(), demo)


def _grouped(labels: torch.Tensor, num_groups: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(order, counts, offsets)``: indices sorted by label, how many per label, where each label's run starts."""
    order = torch.argsort(labels, stable=True)
    counts = torch.bincount(labels, minlength=num_groups)
    offsets = torch.cumsum(counts, 0) - counts
    return order, counts, offsets
