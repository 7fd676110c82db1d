"""Hindsight relabelling (Andrychowicz et al., 2017).

A transition sampled for goal g is, with probability ``k / (k + 1)``, replayed as if the goal had
been a goal the agent actually achieved: with ``future`` a state reached later in the same
episode, ``final`` the episode's last state, ``episode`` any state of the episode, ``random`` any
stored state. The reward (and termination, where success ends an episode) is recomputed for the
new goal through the environment's own functions. Where the goal is also shown as a picture
(``goal_image``), the picture is replaced by the env's picture of the new goal (``goal_picture(goal)``, where the
env draws its goals so) or else by the ``image`` of the same state, so the two goals agree.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal

import torch

from taskrl.replay.batch import Batch
from taskrl.replay.storage import EpisodeReplay

GOAL_PICTURE, ACHIEVED_PICTURE = "goal_image", "image"
GoalFn = Callable[[torch.Tensor, torch.Tensor, Any], torch.Tensor]
STRATEGIES = ("future", "final", "episode", "random")
Strategy = Literal["future", "final", "episode", "random"]


class HindsightRelabeler:
    """Relabels a sampled batch with achieved goals; a ``relabel(batch, replay, generator)`` step.

    Args:
        reward_fn: ``compute_reward(achieved_goal, desired_goal, info)`` of the environment,
            vectorised over a batch.
        strategy: where replacement goals come from: ``future``, ``final``, ``episode`` or ``random``.
        k: relabelled transitions per original one; the relabelled fraction is ``k / (k + 1)``.
        terminated_fn: ``compute_terminated(achieved_goal, desired_goal, info)``; when given,
            termination of relabelled transitions is recomputed for the new goal (needed when
            success ends an episode), otherwise the stored flag is kept.
        achieved_key: observation key of the achieved goal.
        desired_key: observation key of the desired goal.
        task_key: on envs whose tasks are reward functions of the goal (``r_j(achieved, goal)``), the
            observation key of the task index: the reward functions then get ``info={task_key: task}``,
            so hindsight goals compose with data sharing's task relabelling (which comes first).
        goal_picture_fn: ``goal_picture(goal) -> [B, H, W, C]`` of the env, which draws its own goal pictures so:
            relabelled goal pictures are drawn by it (one distribution with the env's); None: the reached
            state's ``image``.
    """

    def __init__(
        self,
        reward_fn: GoalFn,
        strategy: Strategy = "future",
        k: int = 4,
        terminated_fn: GoalFn | None = None,
        achieved_key: str = "achieved_goal",
        desired_key: str = "desired_goal",
        task_key: str | None = None,
        goal_picture_fn: Callable[[torch.Tensor], torch.Tensor] | None = None,
    ) -> None:
        if strategy not in STRATEGIES:
            raise ValueError(f"her strategy must be one of {', '.join(STRATEGIES)}; got {strategy!r}")
        if k < 0:
            raise ValueError(f"her k must be >= 0, got {k}")
        self.reward_fn = reward_fn
        self.terminated_fn = terminated_fn
        self.strategy = strategy
        self.k = k
        self.relabel_fraction = k / (k + 1)
        self.achieved_key = achieved_key
        self.desired_key = desired_key
        self.task_key = task_key
        self.goal_picture_fn = goal_picture_fn

    def goal_indices(
        self, batch: Batch, replay: EpisodeReplay, generator: torch.Generator | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(episode, observation index)`` of each replacement goal.

        Observation index ``i`` is the state reached after step ``i - 1``; the transition at step
        ``t`` ends in observation ``t + 1``, so ``future`` draws from ``[t + 1, length]``.
        """
        episode, t = batch.episode, batch.step
        length = replay.length.index_select(0, episode)
        u = torch.rand(len(batch), generator=generator, device=t.device)
        if self.strategy == "future":
            index = t + 1 + (u * (length - t)).long().minimum(length - t - 1)
        elif self.strategy == "final":
            index = length
        elif self.strategy == "episode":
            index = 1 + (u * length).long().minimum(length - 1)
        else:  # random: the next state of any stored transition
            episode, step = replay.sample_indices(len(batch), generator)
            index = step + 1
        return episode, index

    def __call__(self, batch: Batch, replay: EpisodeReplay, generator: torch.Generator | None = None) -> Batch:
        relabel = torch.rand(len(batch), generator=generator, device=batch.reward.device) < self.relabel_fraction
        goal_episode, goal_index = self.goal_indices(batch, replay, generator)
        achieved = replay.observation_at(self.achieved_key, goal_episode, goal_index)
        old_goal = batch.obs[self.desired_key]
        goal = torch.where(relabel.view(-1, *[1] * (old_goal.dim() - 1)), achieved, old_goal)

        next_achieved = batch.next_obs[self.achieved_key]
        info = None if self.task_key is None else {self.task_key: batch.next_obs[self.task_key]}
        reward = torch.where(relabel, self.reward_fn(next_achieved, goal, info).to(batch.reward.dtype), batch.reward)
        terminated = batch.terminated
        if self.terminated_fn is not None:
            terminated = torch.where(relabel, self.terminated_fn(next_achieved, goal, info), terminated)
        goals = {self.desired_key: goal}
        if GOAL_PICTURE in batch.obs:  # the goal's picture: the picture of the state whose goal replaced it
            if self.goal_picture_fn is not None:
                picture = self.goal_picture_fn(achieved)
            else:
                picture = replay.observation_at(ACHIEVED_PICTURE, goal_episode, goal_index)
            old = batch.obs[GOAL_PICTURE]
            goals[GOAL_PICTURE] = torch.where(relabel.view(-1, *[1] * (old.dim() - 1)), picture, old)
        return batch.replace(
            obs={**batch.obs, **goals},
            next_obs={**batch.next_obs, **goals},
            reward=reward,
            terminated=terminated,
            truncated=batch.truncated & ~terminated,
        )
