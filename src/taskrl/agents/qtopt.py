"""QT-Opt (Kalashnikov et al., 2018): Q-learning over continuous actions, argmax by CEM.

There is no actor. A network Q(s, a) is regressed onto clipped double-Q targets whose max over
actions is found by the cross-entropy method (``agents/cem.py``):

    a* = CEM-argmax_a Q_target1(s', a)
    y  = r + gamma * (1 - terminated) * min(Q_target1(s', a*), Q_target2(s', a*))

Two target networks (``twin``):

- ``lagged`` (the paper's): one online network; ``target1`` is its Polyak average (the paper:
  averaging constant 0.9999, i.e. tau = 1e-4) and ``target2`` a copy of ``target1`` taken every
  ``target2_interval`` updates (the paper: lagged by about 6000 gradient steps), so it trails
  ``target1`` by 0 to ``target2_interval`` - 1 updates. The two differ only by that lag.
- ``independent`` (as TD3 and SAC twin their critics): two online networks with their own
  initialisations, both regressed onto the same target y; ``target1`` and ``target2`` are their
  Polyak averages, so the minimum is over two estimates that err independently.

In the paper the targets come from separate "Bellman updater" processes and the regression from
the "trainer": `QTOptAgent.bellman_target` reads only the batch, the target networks and
the shared input normaliser, and `QTOptAgent.regress` takes the batch with its targets.
`QTOptAgent.update` runs one after the other.

Bounded Q. Loss ``cross_entropy`` is the paper's for rewards in [0, 1]: the network outputs a logit,
Q = sigmoid(logit), targets are clipped to [0, 1] and the loss is the log loss
-(y log Q + (1 - y) log(1 - Q)). For rewards in {-1, 0} (the goal envs' sparse reward) ``huber`` /
``mse`` regress Q directly and ``clip_target`` clips targets to [-1/(1-gamma), 0], as the hindsight
paper does; the presets on goal envs with that reward (pointreach, fetchreach, fetchpush) turn it on with
``mse`` (``huber`` weighs every error above 1 by its sign alone, and Q spans [-50, 0] there), and
``grasp-qtopt-pixels`` bounds Q by ``cross_entropy`` instead (its reward is 0/1). The first update checks that the batch's rewards lie
in the range the chosen bound assumes and otherwise stops with one line naming the setting.

Actions: the networks see actions rescaled from the box [low, high] to [-1, 1]; CEM searches in
that normalised box and acting maps the result back.

The Bellman maximum. The target's argmax runs its own, smaller CEM (``target_samples`` candidates per row,
``target_iterations`` rounds, ``target_elites``): by default one round of 32, as TF-Agents' QtOpt samples 32 and
the QT-Opt team's simulated grasping benchmark (Quillen et al. 2018) took the maximum over 16 random samples; the
paper's 2 x 64 moved to separate Bellman-updater processes, which a two-core machine does not have. Acting keeps
the richer ``cem``. The target's search starts from the whole box (the centre, ``init_std`` 1) whatever prior the
acting search has (``cem.init_mean``, a narrower ``cem.init_std``), so a prior on where to act does not bias the values.

Exploration while collecting: Gaussian noise of std ``noise_std`` around the CEM action and, with
probability ``random_action_prob`` (decayed linearly to ``random_action_prob_end`` over
``random_action_decay_steps``), a uniformly random action instead. The default is the hindsight paper's Fetch
exploration, ``noise_std=0.2`` with a constant 0.3, and CEM samples and the noise from the normal truncated to
the box (``cem.truncate``): with clipped samples and no noise a third of the stored action components sat on a
bound, and with clipped noise a sixth.

Diagnostics (every update, averaged per metrics row): ``action_on_bound`` (share of the batch's stored action
components on a bound of the box), ``batch_reward`` (the batch's mean reward: with 0/1 rewards, times the batch size,
the positives per batch), ``q_spread`` (standard deviation of Q_target1(s', .) over the target CEM's first
candidates, mean over rows: how much Q tells actions apart) and ``twin_clip_rate`` (share of rows where the second
target is below the first, so the minimum clips).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

import torch
import torch.nn.functional as F

from taskrl.agents.base import Agent
from taskrl.agents.cem import CEMConfig, CrossEntropyMethod
from taskrl.agents.parts import (
    ActionBox,
    check_learning_settings,
    check_non_negative,
    check_probability,
    explore_in_box,
    gradient_step,
    linear_schedule,
    negative_return_bounds,
    polyak_update,
    share_on_bound,
    td_target,
)
from taskrl.agents.spec import AlgorithmSpec
from taskrl.encoders import (
    DRQ_SHIFT,
    GlimpseInput,
    ImageStateInput,
    PictureCoordinate,
    picture_encoder,
    picture_values,
    shift_pictures,
)
from taskrl.errors import ConfigError, one_of, require
from taskrl.fused_q import FUSIONS, PictureActionQ
from taskrl.nets import StateActionQ
from taskrl.replay.batch import Batch, Obs
from taskrl.types import PicturePose, state_rows


def validate_search(search: CEMConfig) -> None:
    """`CEMConfig.validate`, its errors named by the setting's path (``cem.elites``), as the command line spells it."""
    try:
        search.validate()
    except ConfigError as error:
        raise ConfigError(f"cem.{error.field}", error.message) from None


@dataclasses.dataclass
class QTOptConfig:
    """QT-Opt hyperparameters.

    Attributes:
        lr: Adam learning rate.
        gamma: discount factor.
        hidden_sizes: widths of the Q-network's hidden layers.
        loss: ``huber``, ``mse`` (the goal-env presets'), or ``cross_entropy`` (log loss on Q = sigmoid(logit),
            rewards in [0, 1], targets clipped to [0, 1], as in the paper).
        tau: Polyak factor of the target networks at every update.
        twin: ``lagged`` (the paper's: the second target network is a copy of the first taken every
            ``target2_interval`` updates) or ``independent`` (two online networks regressed to the
            same target, each with its own Polyak target network).
        target2_interval: with ``twin=lagged``, updates between copies of the first target network into the second.
        clip_target: clip targets to [-1/(1-gamma), 0], bounding Q for rewards in {-1, 0} (huber/mse;
            on in the QT-Opt presets on goal envs; ``cross_entropy`` bounds Q to [0, 1] for rewards in [0, 1]).
        max_grad_norm: gradient-norm clip (0 disables).
        normalize_inputs: standardise observation inputs with running mean/std (clipped to +-5).
        noise_std: while collecting, std of Gaussian noise added to the CEM action (half-widths of the box); drawn from
            the normal truncated to the box when ``cem.truncate``, else clipped to it.
        random_action_prob: while collecting, probability of a uniformly random action instead, when collecting starts.
        random_action_prob_end: that probability after ``random_action_decay_steps``.
        random_action_decay_steps: environment steps over which it decays linearly (0: ``random_action_prob_end`` throughout).
        cem: cross-entropy-method settings of acting (and of a Bellman updater's warm-started search).
        target_samples: candidate actions per row in the Bellman target's maximum (its CEM's samples per round).
        target_iterations: CEM rounds in the Bellman target's maximum.
        target_elites: elites of the Bellman target's CEM (its refit between rounds).
        encoder: on envs with a camera, the registered picture encoder (`taskrl.encoders`) in every Q-network; with
            ``fusion=flat`` the action joins after it, with ``fusion=conv`` at the layer the encoder declares for a
            late input (``conv``, ``resnet``); either way CEM encodes a picture once per state however many actions it
            scores.
        image_features: the encoded picture's size (a linear layer, LayerNorm and tanh after the encoder).
        fusion: on envs with a camera, where the action meets the picture: ``flat`` (after the encoder's
            ``image_features``), ``conv`` (QT-Opt's network: the action and the state vector embedded and added to
            the ``encoder``'s intermediate feature map, then one more convolution; `taskrl.fused_q.PictureActionQ`)
            or ``glimpse`` (flat, after the whole picture's features and those of the picture around the gripper
            turned into the jaws' frame, `taskrl.encoders.GlimpseInput`; for envs that declare the gripper's pose in
            the picture, ``picture_pose``, which then reaches the network unnormalised).
    """

    lr: float = 1e-3
    gamma: float = 0.98
    hidden_sizes: tuple[int, ...] = (256, 256)
    loss: Literal["huber", "mse", "cross_entropy"] = "huber"
    tau: float = 0.005
    twin: Literal["lagged", "independent"] = "independent"
    target2_interval: int = 200
    clip_target: bool = False
    max_grad_norm: float = 10.0
    normalize_inputs: bool = True
    noise_std: float = 0.2
    random_action_prob: float = 0.3
    random_action_prob_end: float = 0.3
    random_action_decay_steps: int = 0
    cem: CEMConfig = dataclasses.field(default_factory=lambda: CEMConfig(truncate=True))
    target_samples: int = 32
    target_iterations: int = 1
    target_elites: int = 4
    encoder: str = "conv"
    image_features: int = 50
    fusion: Literal["flat", "conv", "glimpse"] = "flat"

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting."""
        check_learning_settings(self)
        one_of(self.loss, ("huber", "mse", "cross_entropy"), "loss", "loss")
        one_of(self.twin, ("lagged", "independent"), "twin", "twin")
        one_of(self.fusion, FUSIONS, "fusion", "fusion")
        picture_encoder(self.encoder, late_input=self.fusion == "conv")
        require(self.image_features >= 1, "image_features", f"must be >= 1 (got {self.image_features})")
        require(
            not (self.clip_target and self.loss == "cross_entropy"),
            "clip_target",
            "bounds Q to [-1/(1-gamma), 0] for huber/mse; loss=cross_entropy bounds it to [0, 1] already: turn one off",
        )
        require(self.target2_interval >= 1, "target2_interval", f"must be >= 1 (got {self.target2_interval})")
        check_non_negative(self, "noise_std", "random_action_decay_steps")
        check_probability(self, "random_action_prob", "random_action_prob_end")
        require(self.target_iterations >= 1, "target_iterations", f"must be >= 1 (got {self.target_iterations})")
        require(
            1 <= self.target_elites <= self.target_samples,
            "target_elites",
            f"must be in [1, target_samples={self.target_samples}] (got {self.target_elites})",
        )
        validate_search(self.cem)


class QTOptAgent(Agent):
    """QT-Opt agent: a Q(s, a) network, two lagged target networks, CEM to act and to target.

    Args:
        input_keys: observation keys the Q-network reads (e.g. ``("observation", "desired_goal")``).
        input_dim: total flattened size of those keys.
        action_space: a gymnasium ``Box`` or a ``(low, high)`` pair of tensors / arrays.
        config: hyperparameters, see `QTOptConfig`.
        device: torch device of the networks.
        image_shape: ``(H, W, C)`` of an ``image`` observation (the last of ``input_keys``), or None.
        picture_shift: pixels of DrQ's random shift of the pictures in every update (0: none; None: DrQ's 4).
        picture_coordinates: vector entries that are positions in the picture's frame, moved with the shift
            (`taskrl.encoders.PictureCoordinate`).
        picture_pose: where the gripper's pose is in the state vector (`taskrl.types.PicturePose`, columns counted
            in the vector), or None; what ``fusion=glimpse`` reads.
    """

    acting = ("q", "normalize")
    #: what bellman_target reads: a Bellman updater's copy of the trainer's state
    bellman_parts = ("q_target1", "q_target2", "normalize")
    checkpointed = {
        "q": "q",
        "q_target1": "q_target1",
        "q_target2": "q_target2",
        "normalize": "inputs.normalize",
        "optimizer": "optimizer",
    }

    def __init__(
        self,
        input_keys: tuple[str, ...],
        input_dim: int,
        action_space: Any,
        config: QTOptConfig,
        device: str | torch.device = "cpu",
        image_shape: tuple[int, ...] | None = None,
        picture_shift: int | None = None,
        picture_coordinates: tuple[PictureCoordinate, ...] = (),
        picture_pose: PicturePose | None = None,
    ) -> None:
        self.image_shape = tuple(image_shape) if image_shape is not None else None
        self.picture_shift = DRQ_SHIFT if picture_shift is None else int(picture_shift)
        self.picture_coordinates = tuple(picture_coordinates)
        glimpse = config.fusion == "glimpse"
        if glimpse:
            require(
                self.image_shape is not None and picture_pose is not None,
                "fusion",
                "glimpse looks around the gripper: it needs a camera and an env that declares the gripper's pose in the "
                "picture (picture_pose, as the grasp bin does); use flat or conv",
            )
            require(
                self.picture_shift == 0 or bool(self.picture_coordinates),
                "shift_coordinates",
                "must be on with fusion=glimpse, which reads the gripper's position from the state: the shift must "
                "move it with the pictures (or be 0: --shift 0)",
            )
        raw = picture_values(self.image_shape) if self.image_shape is not None else 0
        self.setup(config, device, input_keys, input_dim, picture_dim=raw, raw_columns=picture_pose.columns if glimpse else ())
        self.box = ActionBox(action_space, self.device)
        self.action_dim = self.box.dim
        self.unit_low, self.unit_high = -torch.ones_like(self.box.low), torch.ones_like(self.box.high)

        def q_net() -> StateActionQ:
            state_input = None
            if self.image_shape is not None and config.fusion == "conv":  # QT-Opt's network: the action in the convs
                return PictureActionQ(input_dim - raw, self.image_shape, self.action_dim, config.hidden_sizes, config.encoder).to(
                    self.device
                )
            if glimpse:
                state_input = GlimpseInput(input_dim - raw, self.image_shape, config.encoder, config.image_features, picture_pose)
            elif self.image_shape is not None:  # every network, targets included, has its own encoder
                state_input = ImageStateInput(input_dim - raw, self.image_shape, config.encoder, config.image_features)
            return StateActionQ(input_dim, self.action_dim, config.hidden_sizes, state_input).to(self.device)

        self.q = q_net()
        self.independent = config.twin == "independent"
        # the second online network (independent twins only); lagged twins copy target1 instead
        self.q2 = q_net() if self.independent else None
        self.q_target1, self.q_target2 = q_net(), q_net()
        self.q_target1.load_state_dict(self.q.state_dict())
        self.q_target2.load_state_dict((self.q2 or self.q).state_dict())
        for target in (self.q_target1, self.q_target2):
            target.requires_grad_(False)
        if self.independent:
            self.checkpointed = {**type(self).checkpointed, "q2": "q2"}
        self.use_search(config.cem)
        self._q1_params = list(self.q.parameters())
        self._q2_params = list(self.q2.parameters()) if self.independent else []
        self._params = self._q1_params + self._q2_params
        self._target1_params, self._target2_params = list(self.q_target1.parameters()), list(self.q_target2.parameters())
        self.optimizer = torch.optim.Adam(self._params, lr=config.lr, fused=True)
        self.updates = 0

    def use_search(self, search: CEMConfig) -> None:
        """Act (and search the Bellman maximum) with ``search``; `ConfigError` naming ``cem.FIELD`` if it is refused."""
        validate_search(search)
        require(
            len(search.init_mean) in (0, self.action_dim),
            "cem.init_mean",
            f"needs one value per action dimension ({self.action_dim}) or none (got {search.init_mean})",
        )
        self.cem = CrossEntropyMethod(search)
        # the Bellman maximum's cold search covers the whole box whatever prior the acting search has (the benchmark's
        # config drew its 16 target candidates uniformly): an acting prior must not bias the learned values
        self.target_cem = CrossEntropyMethod(dataclasses.replace(search, init_mean=(), init_std=1.0))

    # ---------------------------------------------------------------- helpers
    def q_value(self, out: torch.Tensor) -> torch.Tensor:
        """Network output -> Q: a probability sigmoid(logit) for the cross-entropy loss."""
        return torch.sigmoid(out) if self.config.loss == "cross_entropy" else out

    def argmax(
        self,
        net: StateActionQ,
        x: torch.Tensor,
        generator: torch.Generator | None = None,
        warm_start: torch.Tensor | None = None,
        target: bool = False,
        first_scores: list[torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """CEM over [-1, 1]^A: ``(a* [B, A] in [-1, 1], net output at a* [B])``, one forward pass per round.

        ``warm_start`` (``[B, A]`` in [-1, 1]) starts the search there (``cem.warm_std``, ``cem.warm_iterations``).
        ``target``: the Bellman target's search (``target_samples`` x ``target_iterations``, ``target_elites``).
        ``first_scores``: a list the first round's scores ``[B, N]`` are appended to.
        """

        def score(actions: torch.Tensor) -> torch.Tensor:
            scores = net.score_actions(x, actions)
            if first_scores is not None and not first_scores:
                first_scores.append(scores)
            return scores

        c = self.config
        search, sizes = self.cem, {}
        if target and warm_start is None:
            search = self.target_cem
            sizes = {"iterations": c.target_iterations, "samples": c.target_samples, "elites": c.target_elites}
        return search.maximize(
            score, state_rows(x), self.unit_low, self.unit_high, init_mean=warm_start, generator=generator, **sizes
        )

    # ---------------------------------------------------------------- acting
    def random_action_prob(self, env_steps: int) -> float:
        """The probability of a uniformly random action at ``env_steps`` while collecting."""
        c = self.config
        return linear_schedule(c.random_action_prob, c.random_action_prob_end, c.random_action_decay_steps, env_steps)

    def exploration(self, env_steps: int) -> dict[str, float]:
        return {"random_action_prob": self.random_action_prob(env_steps)}

    def policy(self, obs: Obs, explore: bool, generator: torch.Generator | None, env_steps: int) -> torch.Tensor:
        """CEM-greedy actions [B, A] in the action box; while exploring, Gaussian noise of std
        ``noise_std`` around them and, with probability ``random_action_prob`` per state, a
        uniformly random action in the box instead (epsilon-greedy over a continuous box)."""
        unit, _ = self.argmax(self.q, self.inputs(obs), generator)
        if explore:
            c = self.config
            unit = explore_in_box(unit, c.noise_std, self.random_action_prob(env_steps), generator, truncated=c.cem.truncate)
        return self.box.from_unit(unit)

    # ---------------------------------------------------------------- learning
    def bellman_target(
        self,
        batch: Batch,
        generator: torch.Generator | None = None,
        warm_start: torch.Tensor | None = None,
        return_action: bool = False,
        diagnostics: dict[str, torch.Tensor] | None = None,
    ):
        """y = r + gamma (1 - terminated) min(Q_target1(s', a*), Q_target2(s', a*)), a* = CEM argmax of Q_target1.

        Reads only the batch, the two target networks and the input normaliser (a Bellman
        updater can run it on its own copy of those). A Bellman updater that recomputes targets
        for the same transitions can pass the previous ``a*`` (box units) as ``warm_start`` to
        search near it with fewer rounds, and gets ``(y, a*)`` back with ``return_action``. ``diagnostics``: a
        dict given ``q_spread`` and ``twin_clip_rate`` (module docstring).
        """
        cfg = self.config
        with torch.no_grad():
            next_x = self.inputs(batch.next_obs)
            warm = None if warm_start is None else self.box.to_unit(warm_start)
            first = [] if diagnostics is not None else None
            # out1 = Q_target1(s', a*), from CEM
            next_action, out1 = self.argmax(self.q_target1, next_x, generator, warm, target=True, first_scores=first)
            out2 = self.q_target2(next_x, next_action)
            next_value = self.q_value(torch.minimum(out1, out2))  # sigmoid is monotone
            if diagnostics is not None:
                diagnostics["q_spread"] = self.q_value(first[0]).std(dim=1).mean()
                diagnostics["twin_clip_rate"] = (out2 < out1).float().mean()
            if cfg.loss == "cross_entropy":
                clip = (0.0, 1.0)
            else:
                clip = negative_return_bounds(cfg.gamma) if cfg.clip_target else None
            target = td_target(batch.reward, batch.terminated, next_value, cfg.gamma, clip)
        return (target, self.box.from_unit(next_action)) if return_action else target

    def regress(
        self, batch: Batch, target: torch.Tensor | None, generator: torch.Generator | None = None
    ) -> dict[str, torch.Tensor]:
        """One gradient step of Q(s, a) towards ``target`` (the trainer's step; ``None``: the Bellman
        target computed here); refreshes the targets.

        Returns detached scalars: ``loss``, ``q_mean`` (Q of the batch's actions), ``target_mean``.
        """
        return self.counted_step(batch, target, generator)

    def schedule(self, update: int) -> tuple[bool]:
        """``(copy_target2,)``: every ``target2_interval`` updates (never with independent twins)."""
        return (not self.independent and update % self.config.target2_interval == 0,)

    def learn(
        self,
        batch: Batch,
        copy_target2: bool,
        target: torch.Tensor | None = None,
        generator: torch.Generator | None = None,
    ) -> dict[str, torch.Tensor]:
        """The update itself (what ``--compile`` compiles): the target if not given, the regression, the target networks."""
        cfg = self.config
        if self.image_shape is not None and self.picture_shift:  # DrQ: every picture shifted on its own
            shift = lambda obs: shift_pictures(obs, self.picture_shift, generator, self.picture_coordinates)  # noqa: E731
            batch = batch.replace(obs=shift(batch.obs), next_obs=shift(batch.next_obs))
        diagnostics: dict[str, torch.Tensor] = {}
        if target is None:
            target = self.bellman_target(batch, generator, diagnostics=diagnostics)
        self.inputs.update_statistics(batch.obs)
        x, action = self.inputs(batch.obs), self.box.to_unit(batch.action)
        diagnostics["action_on_bound"] = share_on_bound(action)
        diagnostics["batch_reward"] = batch.reward.mean()
        out = self.q(x, action)
        loss = self.loss(out, target)
        if self.independent:  # both twins regress onto the same target
            loss = loss + self.loss(self.q2(x, action), target)

        gradient_step(self.optimizer, loss, self._params, cfg.max_grad_norm)
        self.update_targets(copy_target2)
        return {
            "loss": loss.detach(),
            "q_mean": self.q_value(out.detach()).mean(),
            "target_mean": target.mean(),
            **diagnostics,
        }

    def loss(self, out: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """The regression loss of network outputs ``out`` towards ``target`` (``loss`` setting)."""
        if self.config.loss == "cross_entropy":
            return F.binary_cross_entropy_with_logits(out, target)
        if self.config.loss == "huber":
            return F.smooth_l1_loss(out, target)
        return F.mse_loss(out, target)

    def check_batch(self, batch: Batch) -> None:
        """Refuse rewards outside the range the chosen bound on Q assumes (one line naming the setting)."""
        cfg, reward = self.config, batch.reward
        if cfg.loss == "cross_entropy":
            low, high, setting, what = 0.0, 1.0, "loss", "cross_entropy bounds Q to [0, 1]"
        elif cfg.clip_target:
            low, high, setting, what = -1.0, 0.0, "clip_target", "clip_target bounds Q to [-1/(1-gamma), 0]"
        else:
            return
        lo, hi = reward.min().item(), reward.max().item()
        require(
            low <= lo and hi <= high,
            setting,
            f"{what} and needs rewards in [{low:g}, {high:g}], but a batch has rewards in [{lo:g}, {hi:g}]: "
            + ("use --loss huber" if setting == "loss" else "use --no-clip-target"),
        )

    def update(self, batch: Batch, generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
        """Bellman target then regression: ``regress(batch, bellman_target(batch))``."""
        return self.regress(batch, None, generator)

    def update_targets(self, copy_target2: bool | None = None) -> None:
        """target1 <- tau * q + (1 - tau) * target1. Lagged twins: every target2_interval updates (or
        as ``copy_target2`` says) target2 <- target1. Independent twins: target2 <- tau * q2 + (1 - tau) * target2."""
        polyak_update(self._target1_params, self._q1_params, self.config.tau)
        if self.independent:
            polyak_update(self._target2_params, self._q2_params, self.config.tau)
            return
        if copy_target2 is None:
            copy_target2 = self.updates % self.config.target2_interval == 0
        if copy_target2:
            polyak_update(self._target2_params, self._target1_params, 1.0)


SPEC = AlgorithmSpec(
    name="qtopt",
    description="QT-Opt: Q-learning over continuous actions with a CEM argmax and clipped double-Q targets",
    config=QTOptConfig,
    build=lambda inputs, config, device, conditioning: QTOptAgent(
        inputs.keys,
        inputs.dim,
        inputs.action_space,
        config,
        device,
        inputs.image_shape,
        inputs.picture_shift,
        inputs.picture_coordinates,
        inputs.picture_pose,
    ),
    loop="off_policy",
    actions=("box",),
    bellman_updaters=True,
    compiles=True,
    images=True,
)
