"""Multi-task behaviour cloning (BC-Z, Jang et al., 2021): one supervised objective summed over tasks.

    c      = e(task)                      one-hot, learned, or a sentence embedding   (task_input = task)
           | z(D) = DemoEncoder(D)        one demonstration D of the task             (task_input = demo)
    c~     = c + N(0, sigma^2)            embedding noise while training (BC-Z: sigma = 0.1)
    pi(s, c~) = FiLMMLP(s; c~)            every hidden layer FiLM-modulated (or concat / care), H actions out
    L_BC   = mean over rows, chunk steps h < H inside the episode of
               huber(pi_h(s, c~) - a_{t+h})                             (loss = huber)
             | -log N(a_{t+h}; mu_h, sigma_h^2)                           (loss = gaussian)
    L_lang = 1 - cos(z(D), e_lang(task))  BC-Z's language regression (demo input with sentence embeddings)
    L      = L_BC + language_weight * L_lang

From pixels (BC-Z's camera policy, at CPU scale): on an env with a camera the picture goes through a conv
encoder whose every block is FiLM-modulated by the same context c ([`FiLMPictureEncoder`][taskrl.encoders.FiLMPictureEncoder],
``--encoder conv|resnet``), each training picture randomly shifted (the camera's ``--shift``, 2 pixels by default:
BC-Z's random crop);
its features join the state vector (the robot's own pose) before the policy network.

With demo input and sentence embeddings, a fraction ``language_prompts`` of each batch is conditioned
on the sentence embedding instead of the demonstration's, so one policy follows either prompt.
Batches are stratified over tasks ([`DemoSampler`][taskrl.demos.sampling.DemoSampler]).

At run time the policy acts on its prompt table: the training tasks' contexts by default, or the
contexts of other tasks (`BCAgent.prompt_with_descriptions`, `BCAgent.prompt_with_demos`),
so held-out tasks are evaluated zero-shot from a sentence or one demonstration. With chunks (H > 1),
overlapping predictions for the same step are averaged, weighted ``exp(-ensemble_decay * h)`` by how
far ahead (h) each was made (temporal ensembling).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

import torch
import torch.nn.functional as F

from taskrl.agents.base import Agent
from taskrl.agents.parts import (
    ActionBox,
    check_learning_settings,
    check_non_negative,
    check_probability,
    gradient_step,
)
from taskrl.agents.spec import AlgorithmSpec
from taskrl.conditioning.demo_encoder import DemoEncoder
from taskrl.conditioning.networks import ConditionedMLP, ConditioningConfig
from taskrl.conditioning.task_encoders import LanguageTaskEncoder
from taskrl.encoders import BC_SHIFT, FiLMPictureEncoder, picture_encoder, picture_values, shift_pictures
from taskrl.errors import ConfigError, one_of, require
from taskrl.types import PictureState

__all__ = ["BCAgent", "BCConfig"]

LOG_STD_BOUNDS = (-5.0, 2.0)


@dataclasses.dataclass
class BCConfig:
    """Behaviour-cloning settings.

    Attributes:
        dataset: the demonstration dataset folder (``taskrl demos collect ... --out DIR``).
        lr: Adam learning rate.
        hidden_sizes: widths of the policy's hidden layers.
        max_grad_norm: gradient-norm clip (0 disables).
        normalize_inputs: standardise states with the dataset's mean and std.
        loss: ``huber`` (deterministic actions) or ``gaussian`` (log-likelihood of a diagonal Gaussian; acts with its mean).
        task_input: ``task`` (the run's task encoder: one-hot, embedding or language) or ``demo``
            (an encoder of one demonstration of the task).
        embedding_noise: std of Gaussian noise on the task context while training (BC-Z: 0.1).
        language_weight: weight of the language-regression loss (demo input with language task embeddings).
        language_prompts: demo input with language: fraction of each batch conditioned on the sentence instead.
        demo_frames: frames of a prompt demonstration the demo encoder reads.
        chunk: actions predicted per step (BC-Z predicts 10 waypoints; 1: the next action).
        ensemble_decay: temporal ensembling of chunks: weight ``exp(-decay * h)`` of a prediction made h steps ahead.
        weight_decay: AdamW weight decay.
        held_out_tasks: task names (comma-separated) left out of training and kept for zero-shot
            evaluation (``taskrl eval RUN --held-out``); their demonstrations still serve as prompts there.
        encoder: on envs with a camera, the registered picture encoder (`taskrl.encoders`), FiLM-modulated by the
            task in every block (an encoder that declares its blocks: ``conv``, ``resnet``).
        image_features: the encoded picture's size.
    """

    dataset: str = ""
    lr: float = 1e-3
    hidden_sizes: tuple[int, ...] = (256, 256, 256)
    max_grad_norm: float = 1.0
    normalize_inputs: bool = True
    loss: Literal["huber", "gaussian"] = "huber"
    task_input: Literal["task", "demo"] = "task"
    embedding_noise: float = 0.1
    language_weight: float = 1.0
    language_prompts: float = 0.5
    demo_frames: int = 16
    chunk: int = 1
    ensemble_decay: float = 0.5
    weight_decay: float = 1e-4
    held_out_tasks: str = ""
    encoder: str = "conv"
    image_features: int = 64

    def held_out(self) -> list[str]:
        """The held-out task names."""
        return [n.strip() for n in self.held_out_tasks.split(",") if n.strip()]

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting."""
        check_learning_settings(self)
        one_of(self.loss, ("huber", "gaussian"), "loss", "loss")
        one_of(self.task_input, ("task", "demo"), "task_input", "task input")
        check_non_negative(self, "embedding_noise", "language_weight", "ensemble_decay", "weight_decay")
        check_probability(self, "language_prompts")
        require(self.demo_frames >= 2, "demo_frames", f"must be >= 2 (got {self.demo_frames})")
        require(1 <= self.chunk <= 100, "chunk", f"must be in 1..100 (got {self.chunk})")
        picture_encoder(self.encoder, film=True)
        require(self.image_features >= 1, "image_features", f"must be >= 1 (got {self.image_features})")


class BCAgent(Agent):
    """A task-conditioned behaviour-cloning policy (see the module docstring).

    Args:
        inputs: observation keys and their width, and the action box.
        config: settings, see `BCConfig`.
        device: where the networks live.
        conditioning: the run's [`TaskConditioning`][taskrl.conditioning.networks.TaskConditioning] on multi-task
            envs (its encoder gives ``task`` input's context and, when it embeds sentences, the
            language targets of ``demo`` input), None on single-task envs.
    """

    acting = ("policy", "normalize", "task_encoder", "demo_encoder", "prompt_demos", "encoder")
    checkpointed = {
        "policy": "net",
        "encoder": "encoder",
        "normalize": "inputs.normalize",
        "task_encoder": "task_encoder",
        "demo_encoder": "demo_encoder",
        "prompt_demos": "prompt_demos",
        "optimizer": "optimizer",
    }

    def __init__(self, inputs: Any, config: BCConfig, device: str | torch.device = "cpu", conditioning: Any = None) -> None:
        self.image_shape = getattr(inputs, "image_shape", None)
        shift = getattr(inputs, "picture_shift", None)  # the camera's; None: BC-Z's crop at this scale
        self.picture_shift = BC_SHIFT if shift is None else int(shift)
        self.picture_coordinates = tuple(getattr(inputs, "picture_coordinates", ()))
        if self.image_shape is not None and len(self.image_shape) != 3:
            raise ConfigError("env", "behaviour cloning reads one camera picture per state; this env gives goal pictures too")
        raw = picture_values(self.image_shape) if self.image_shape is not None else 0
        self.setup(config, device, inputs.keys, inputs.dim, conditioning, picture_dim=raw)
        self.box = ActionBox(inputs.action_space, self.device)
        # state_dim: the state vector's width (the picture's columns excluded)
        self.action_dim, self.state_dim = self.box.dim, int(inputs.dim) - raw
        self.language = isinstance(self.task_encoder, LanguageTaskEncoder)
        self.demo_encoder: DemoEncoder | None = None
        num_tasks = conditioning.num_tasks if conditioning is not None else 1
        if config.task_input == "demo":
            if raw:
                raise ConfigError(
                    "task_input", "demo input encodes state vectors; from pictures use task input (one-hot or language)"
                )
            if conditioning is None:
                raise ConfigError("task_input", "demo input conditions on a task: it needs a multi-task env")
            width = self.task_encoder.embedding_dim if self.language else 64
            self.demo_encoder = DemoEncoder(self.state_dim, width).to(self.device)
            context_dim = width
        else:
            context_dim = self.task_encoder.context_dim if self.task_encoder is not None else 0
        #: ``[T, L, D]`` one demonstration of each training task: demo input's prompts (set from the dataset)
        self.prompt_demos = torch.zeros(num_tasks, config.demo_frames, self.state_dim, device=self.device)
        outputs = self.action_dim * config.chunk * (2 if config.loss == "gaussian" else 1)
        c = conditioning.config if conditioning is not None else ConditioningConfig()
        self.encoder: FiLMPictureEncoder | None = None
        if raw:  # BC-Z: the picture's encoder FiLM-modulated by the task's context in every block
            self.encoder = FiLMPictureEncoder(self.image_shape, config.encoder, config.image_features, context_dim).to(
                self.device
            )
        self.net = ConditionedMLP(
            self.state_dim + (self.encoder.out_dim if self.encoder is not None else 0),
            outputs,
            config.hidden_sizes,
            context_dim,
            c.architecture,
            care_encoders=c.care_encoders,
            care_encoder_dim=c.care_encoder_dim,
        ).to(self.device)
        modules = (self.net, self.task_encoder, self.demo_encoder, self.encoder)
        self._params = [p for m in modules if m is not None for p in m.parameters()]
        self.optimizer = torch.optim.AdamW(self._params, lr=config.lr, weight_decay=config.weight_decay)
        self.updates = 0
        self.prompts: torch.Tensor | None = None  # contexts of the tasks being acted on (None: the training tasks')
        self._contexts: torch.Tensor | None = None  # training_contexts() until the weights or prompts change
        self._ensemble: tuple[torch.Tensor, torch.Tensor] | None = None

    # ---------------------------------------------------------------- data
    def use_dataset(self, demos: Any) -> Any:
        """Keep one prompt demonstration per task (its first), fit the state normaliser to the training tasks'
        demonstrations (held-out tasks excluded), and return the sampler of the batches this agent learns from (stratified over tasks)."""
        from taskrl.demos.sampling import DemoSampler, prompt_frames

        if self.demo_encoder is not None:
            with torch.no_grad():
                self.prompt_demos.copy_(prompt_frames(demos, self.config.demo_frames))
        self._contexts = None
        frames_per_prompt = self.config.demo_frames if self.demo_encoder is not None else 0
        held_out = [n for n in self.config.held_out() if n in demos.task_names]
        if held_out:  # their demonstrations prompt, they are never imitated
            demos = demos.without_tasks(held_out)
            if demos.num_episodes == 0:
                raise ConfigError("held_out_tasks", "holds out every task of the dataset: nothing is left to train on")
        # the training tasks' states only: a held-out task's states are unseen until it is prompted
        if self.encoder is not None and demos.images is None:
            raise ConfigError("dataset", "the env has a camera but the dataset holds no pictures: collect it from this env")
        if self.encoder is not None and tuple(demos.images.shape[1:]) != tuple(self.image_shape):
            size = demos.images.shape[1]
            raise ConfigError(
                "image_size",
                f"the dataset's pictures are {size}x{size} but the run's are {self.image_shape[0]}x{self.image_shape[1]}: "
                f"train with --image-size {size}, or collect with --pictures {self.image_shape[0]}",
            )
        if hasattr(self.inputs.normalize, "update"):  # the state vector's statistics (pictures are scaled by the encoder)
            self.inputs.normalize.update(demos.observations.to(self.device).float())
        return DemoSampler(demos.to(self.device), chunk=self.config.chunk, frames=frames_per_prompt)

    # ---------------------------------------------------------------- contexts
    def _normalize_frames(self, frames: torch.Tensor) -> torch.Tensor:
        b, n, d = frames.shape
        return self.inputs.normalize(frames.reshape(b * n, d)).reshape(b, n, d)

    def demo_context(self, frames: torch.Tensor) -> torch.Tensor:
        """z(D) of demonstrations ``[B, L, D]`` (raw states)."""
        return self.demo_encoder(self._normalize_frames(frames.to(self.device).float()))

    @torch.no_grad()
    def training_contexts(self) -> torch.Tensor | None:
        """``[T, C]`` the context of every training task (from its prompt demonstration under demo input),
        computed once until the next update or load: acting reads it at every step."""
        if self.task_encoder is None:
            return None
        if self._contexts is None:
            if self.demo_encoder is not None:
                self._contexts = self.demo_context(self.prompt_demos)
            else:
                self._contexts = self.task_encoder(torch.arange(self.task_encoder.num_tasks, device=self.device))
        return self._contexts

    def load_parts(self, state: dict[str, Any]) -> None:
        super().load_parts(state)
        self._contexts = None

    @torch.no_grad()
    def prompt_with_descriptions(self, descriptions: list[str]) -> None:
        """Act on the tasks these sentences describe (task index i: ``descriptions[i]``); language embeddings only."""
        if not self.language:
            raise ConfigError(
                "task", "prompting with a sentence needs a policy trained with language embeddings (--task-encoder language)"
            )
        from taskrl.conditioning.language import sentence_embeddings

        table = sentence_embeddings(list(descriptions)).to(self.device)
        encoder = self.task_encoder
        self.prompts = encoder.projection(table) if (self.demo_encoder is None and encoder.projection is not None) else table
        self._ensemble = None

    @torch.no_grad()
    def prompt_with_demos(self, frames: torch.Tensor) -> None:
        """Act on the tasks these demonstrations show (``[T', L, D]``, task index i: ``frames[i]``); demo input only."""
        if self.demo_encoder is None:
            raise ConfigError("prompt", "prompting with a demonstration needs a policy trained with --task-input demo")
        self.prompts = self.demo_context(frames)
        self._ensemble = None

    @torch.no_grad()
    def prompt_with_nothing(self, tasks: int) -> None:
        """Act on ``tasks`` tasks told nothing of them: a zero context each (the null-prompt control)."""
        contexts = self.training_contexts()
        if contexts is None:
            raise ConfigError("prompt", "a null prompt needs a policy told its task by an embedding (language or demo input)")
        self.prompts = torch.zeros(tasks, contexts.shape[1], device=self.device)
        self._ensemble = None

    def reset_prompts(self) -> None:
        """Act on the training tasks again."""
        self.prompts, self._ensemble = None, None

    def _acting_context(self, task: torch.Tensor) -> torch.Tensor | None:
        table = self.prompts if self.prompts is not None else self.training_contexts()
        return None if table is None else table[task.long().view(-1)]

    # ---------------------------------------------------------------- acting
    def _heads(self, x: torch.Tensor | PictureState, context: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """``(mean [B, H, A], log_std [B, H, A] or None)`` in the unit box, from the input ``x`` (the state vector,
        or a `PictureState` where the env has a camera: the picture goes to the encoder as stored)."""
        if self.encoder is not None:
            x = torch.cat([x.vector, self.encoder(x.pictures[:, 0], context)], 1)
        out = self.net(x, context)
        b, h, a = out.shape[0], self.config.chunk, self.action_dim
        if self.config.loss == "gaussian":
            mean, log_std = out.view(b, h, 2, a).unbind(dim=2)
            return mean, log_std.clamp(*LOG_STD_BOUNDS)
        return out.view(b, h, a), None

    def policy(self, obs: Any, explore: bool, generator: torch.Generator | None, env_steps: int) -> torch.Tensor:
        """The predicted action (the Gaussian's mean), chunks temporally ensembled; ``explore`` samples the Gaussian."""
        context = self._acting_context(obs["task"]) if self.task_encoder is not None else None
        mean, log_std = self._heads(self.inputs(obs), context)
        if explore and log_std is not None:
            mean = mean + log_std.exp() * torch.randn(mean.shape, generator=generator, device=mean.device)
        unit = self._ensembled(mean) if self.config.chunk > 1 else mean[:, 0]
        return self.box.from_unit(unit.clamp(-1.0, 1.0))

    def _ensembled(self, chunk: torch.Tensor) -> torch.Tensor:
        """Temporal ensembling: add this step's chunk to the running sums of the steps it covers, act on step 0's."""
        b, h, _ = chunk.shape
        weights = torch.exp(-self.config.ensemble_decay * torch.arange(h, device=chunk.device, dtype=chunk.dtype))
        if self._ensemble is None or self._ensemble[0].shape[0] != b:
            self._ensemble = (torch.zeros_like(chunk), torch.zeros(b, h, 1, device=chunk.device, dtype=chunk.dtype))
        sums, total = self._ensemble
        sums += weights[None, :, None] * chunk
        total += weights[None, :, None]
        action = sums[:, 0] / total[:, 0]
        # shift one step: what was predicted for t + 1 is now for the next step
        self._ensemble = (
            torch.cat([sums[:, 1:], torch.zeros_like(sums[:, :1])], 1),
            torch.cat([total[:, 1:], torch.zeros_like(total[:, :1])], 1),
        )
        return action

    def episodes_ended(self, ended: torch.Tensor) -> None:
        """Forget the ensembled predictions of slots whose episode just ended."""
        if self._ensemble is not None:
            keep = (~ended.to(self.device).bool()).float().view(-1, 1, 1)
            if keep.shape[0] == self._ensemble[0].shape[0]:
                self._ensemble = (self._ensemble[0] * keep, self._ensemble[1] * keep)

    # ---------------------------------------------------------------- learning
    def update(self, batch: Any) -> dict[str, torch.Tensor]:
        """One gradient step on a [`DemoBatch`][taskrl.demos.sampling.DemoBatch]; returns ``bc_loss``,
        ``action_error`` (mean absolute error of the first action) and, with alignment, ``language_loss``."""
        cfg = self.config
        obs = batch.obs
        if self.encoder is not None and self.picture_shift:  # BC-Z's random crop: every picture shifted at random
            obs = shift_pictures(obs, self.picture_shift, coordinates=self.picture_coordinates)
        x = self.inputs(obs)
        task = batch.obs["task"].long().view(-1)
        context, language_loss = None, None
        if self.demo_encoder is not None:
            context = self.demo_context(batch.demo)
            if self.language:
                target = self.task_encoder.table[task]
                language_loss = (1.0 - F.cosine_similarity(context, target, dim=-1)).mean()
                if cfg.language_prompts > 0:
                    use = torch.rand(task.shape[0], 1, device=self.device) < cfg.language_prompts
                    context = torch.where(use, target, context)
        elif self.task_encoder is not None:
            context = self.task_encoder(task)
        if context is not None and cfg.embedding_noise > 0:
            context = context + cfg.embedding_noise * torch.randn_like(context)
        mean, log_std = self._heads(x, context)
        target_actions = self.box.to_unit(batch.actions)
        mask = batch.mask[..., None].expand_as(mean)
        if log_std is None:
            per = F.huber_loss(mean, target_actions, reduction="none", delta=1.0)
        else:
            per = 0.5 * ((target_actions - mean) / log_std.exp()) ** 2 + log_std
        bc_loss = (per * mask).sum() / mask.sum().clamp(min=1)
        loss = bc_loss if language_loss is None else bc_loss + cfg.language_weight * language_loss
        gradient_step(self.optimizer, loss, self._params, cfg.max_grad_norm)
        self._contexts = None
        self.updates += 1
        metrics = {"bc_loss": bc_loss.detach(), "action_error": (mean[:, 0] - target_actions[:, 0]).abs().mean().detach()}
        if language_loss is not None:
            metrics["language_loss"] = language_loss.detach()
        return metrics


SPEC = AlgorithmSpec(
    name="bc",
    description="multi-task behaviour cloning (BC-Z): task-conditioned policy from demonstrations, FiLM, one-hot / language / demo prompts",
    config=BCConfig,
    build=lambda inputs, config, device, conditioning: BCAgent(inputs, config, device, conditioning),
    loop="offline",
    actions=("box",),
    multitask=True,
    images=True,
)
