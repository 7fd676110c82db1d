"""Images through the stack: the encoders, DrQ's random shift, the flat input, QT-Opt from pixels."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from torch.nn import functional as F

import taskrl
from helpers import small_run
from taskrl.agents.parts import ObservationInput
from taskrl.agents.qtopt import QTOptAgent, QTOptConfig
from taskrl.encoders import ImageStateInput, random_shift, random_shift_moves
from taskrl.envs.grasp import Grasp, GraspSettings
from taskrl.errors import ConfigError
from taskrl.nets import StateActionQ
from taskrl.replay.batch import Batch
from taskrl.types import PictureState


def one_step(env: Grasp, obs: dict, action: torch.Tensor) -> Batch:
    """The batch of one step of every copy of ``env`` from ``obs``."""
    _, reward, terminated, truncated, info = env.step(action)
    index = torch.zeros(env.num_envs, dtype=torch.long)
    return Batch(obs, action, reward, info["final_obs"], terminated, truncated, index, index)


def test_random_shift_moves_each_picture_by_its_own_offset_within_the_pad():
    images = torch.zeros(64, 12, 12, 3, dtype=torch.uint8)
    images[:, 6, 5] = 255  # one bright pixel, away from the border
    shifted = random_shift(images, 2, torch.Generator().manual_seed(0))
    assert shifted.shape == images.shape and shifted.dtype == torch.uint8
    where = (shifted[..., 0] == 255).nonzero()[:, 1:]  # [64, (row, col)]: exactly one bright pixel each
    assert where.shape == (64, 2)
    moves = where - torch.tensor([6, 5])
    assert moves.abs().max() <= 2 and len({tuple(m) for m in moves.tolist()}) > 10
    assert torch.equal(random_shift(images, 0), images)


def test_random_shift_is_a_crop_of_the_replicate_padded_picture_and_says_how_far_it_moved():
    """DrQ's definition written out picture by picture (pad by repeating the border, crop at the drawn offset):
    the gather that never builds the padded picture gives the same pixels, borders included, and the moves."""
    images = torch.randint(0, 256, (16, 9, 11, 3), dtype=torch.uint8)
    pad = 3
    shifted, moves = random_shift_moves(images, pad, torch.Generator().manual_seed(1))
    offsets = torch.randint(0, 2 * pad + 1, (16, 2), generator=torch.Generator().manual_seed(1))
    padded = F.pad(images.permute(0, 3, 1, 2).float(), (pad, pad, pad, pad), mode="replicate").permute(0, 2, 3, 1)
    for picture, (row, col) in enumerate(offsets.tolist()):
        assert torch.equal(shifted[picture], padded[picture, row : row + 9, col : col + 11].to(torch.uint8))
    assert torch.equal(moves, pad - offsets)


def test_pictures_stay_stored_uint8_pictures_beside_the_normalised_vector():
    inputs = ObservationInput(("observation", "image"), 3 + 2 * 2 * 3, normalize=True, picture_dim=12)
    obs = {"observation": torch.randn(32, 3) * 10 + 5, "image": torch.randint(0, 256, (32, 2, 2, 3), dtype=torch.uint8)}
    inputs.update_statistics(obs)
    x = inputs(obs)
    assert isinstance(x, PictureState) and x.pictures.dtype == torch.uint8
    assert torch.equal(x.pictures, obs["image"][:, None])  # [B, K=1, H, W, C], never flattened into the vector
    assert x.vector.shape == (32, 3) and x.vector.mean().abs() < 0.5 and x.vector.std() < 2
    alone = ObservationInput(("image",), 12, normalize=True, picture_dim=12)({"image": obs["image"]})
    assert alone.vector.shape == (32, 0) and torch.equal(alone.pictures, obs["image"][:, None])


def test_cem_scores_encode_each_picture_once_and_match_the_plain_forward_pass():
    torch.manual_seed(0)
    encoder = ImageStateInput(2, (16, 16, 3), "conv", 8)
    q = StateActionQ(2 + 16 * 16 * 3, 4, (32,), encoder)
    calls = []
    encoder.register_forward_hook(lambda module, args, out: calls.append(args[0].rows))
    x = PictureState(torch.randn(5, 2), torch.randint(0, 256, (5, 1, 16, 16, 3), dtype=torch.uint8))
    actions = torch.rand(5, 7, 4) * 2 - 1
    with torch.no_grad():
        scores = q.score_actions(x, actions)
        assert calls == [5]  # one encoding per state, not per scored action
        plain = q(PictureState(*(t.repeat_interleave(7, 0) for t in x)), actions.reshape(35, 4)).view(5, 7)
    torch.testing.assert_close(scores, plain, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("encoder", ["conv", "resnet", "keypoints"])
def test_qtopt_from_pixels_trains_its_encoder_and_each_target_has_its_own(encoder):
    env = Grasp(GraspSettings(image_size=16), num_envs=8, seed=0)
    obs = env.reset(seed=0)
    space = env.single_observation_space
    dim = 5 + 16 * 16 * 3
    agent = QTOptAgent(
        ("observation", "image"),
        dim,
        env.single_action_space,
        QTOptConfig(hidden_sizes=(32,), encoder=encoder),
        image_shape=(16, 16, 3),
    )
    assert space["image"].shape == (16, 16, 3)
    g = torch.Generator().manual_seed(0)
    batch = one_step(env, obs, agent.act(obs, explore=True, generator=g))
    before = [p.clone() for p in agent.q.state_input.parameters()]
    agent.update(batch, generator=g)
    assert all(not torch.equal(a, b) for a, b in zip(agent.q.state_input.parameters(), before))
    assert agent.q_target1.state_input is not agent.q.state_input and agent.q_target2.state_input is not agent.q.state_input


def test_every_update_shifts_the_pictures_of_both_states_unless_turned_off(monkeypatch):
    """The online network's encoder is handed the shifted pictures of s, the target's those of s'. Mutation: QT-Opt
    computes the shifted batch, then updates on the stored one (``qtopt.py``'s ``learn``) fails."""
    import taskrl.agents.qtopt as qtopt

    shifted = []
    shift = qtopt.shift_pictures
    monkeypatch.setattr(
        qtopt,
        "shift_pictures",
        lambda obs, pad, generator, coordinates=(): shifted.append(shift(obs, pad, generator, coordinates)) or shifted[-1],
    )
    env = Grasp(GraspSettings(image_size=16), num_envs=4, seed=0)
    batch = one_step(env, env.reset(seed=0), torch.zeros(4, 4))
    for pad in (4, 0):
        shifted.clear()
        config = QTOptConfig(hidden_sizes=(8,))
        agent = QTOptAgent(
            ("observation", "image"), 5 + 768, env.single_action_space, config, image_shape=(16, 16, 3), picture_shift=pad
        )
        seen = {"online": [], "target": []}
        agent.q.state_input.register_forward_hook(lambda m, args, out, seen=seen: seen["online"].append(args[0].pictures))
        agent.q_target1.state_input.register_forward_hook(lambda m, args, out, seen=seen: seen["target"].append(args[0].pictures))
        agent.update(batch, generator=torch.Generator().manual_seed(0))
        pictures = {"online": batch.obs["image"], "target": batch.next_obs["image"]}
        if pad:
            assert len(shifted) == 2
            pictures = {"online": shifted[0]["image"], "target": shifted[1]["image"]}
            assert not torch.equal(shifted[0]["image"], batch.obs["image"])
        for who, picture in pictures.items():
            assert seen[who] and torch.equal(seen[who][-1], picture[:, None]), who


def test_with_shift_coordinates_an_update_moves_the_grippers_state_with_its_shifted_picture():
    """``--shift-coordinates``: the run's agent gets the env's picture coordinates and its update hands the networks
    the gripper's x, y moved with each shifted picture; off (the default), the state as stored. Mutation: the agent
    not passing its coordinates to the shift fails."""
    from taskrl.config import TrainConfig
    from taskrl.overrides import with_overrides
    from taskrl.wiring.parts import make_agent, make_env

    base = with_overrides(TrainConfig(), {"env": "grasp", "algo": "qtopt", "her": "none", "image_size": 16, "num_envs": 4})
    env = make_env(base, "cpu")
    try:
        batch = one_step(env, env.reset(seed=0), torch.zeros(4, 4))
        for moved in (False, True):
            agent = make_agent(with_overrides(base, {"shift_coordinates": moved}), env, torch.device("cpu"))
            assert agent.picture_coordinates == (env.picture_coordinates if moved else ())
            seen = []
            agent.q.state_input.register_forward_hook(lambda m, args, out, seen=seen: seen.append(args[0]))
            agent.update(batch, generator=torch.Generator().manual_seed(0))
            normalized = agent.inputs.normalize(batch.obs["observation"])  # the vector as stored, normalised
            vector = seen[-1].vector
            assert torch.equal(vector[:, 2:], normalized[:, 2:])  # the yaw and the time left never move
            assert torch.equal(vector[:, :2], normalized[:, :2]) != moved
    finally:
        env.close()
    tabletop = with_overrides(TrainConfig(), {"env": "tabletop", "algo": "bc", "image_size": 16, "shift_coordinates": True})
    env = make_env(tabletop, "cpu")
    try:
        with pytest.raises(ConfigError, match="picture_coordinates") as refused:
            make_agent(tabletop, env, torch.device("cpu"))
        assert refused.value.field == "shift_coordinates"
    finally:
        env.close()


def test_sac_from_pixels_shares_one_encoder_trained_by_the_critics_only_and_targets_read_a_lagged_copy(monkeypatch):
    import taskrl.agents.sac as sac
    import taskrl.encoders.shift as encoders

    seen = []
    shift = encoders.random_shift_moves
    monkeypatch.setattr(
        encoders, "random_shift_moves", lambda images, pad, generator: seen.append(pad) or shift(images, pad, generator)
    )
    env = Grasp(GraspSettings(image_size=16), num_envs=8, seed=0)
    config = sac.SACConfig(hidden_sizes=(32,), tau=0.5)
    agent = sac.SACAgent(("observation", "image"), 5 + 768, env.single_action_space, config, image_shape=(16, 16, 3))
    g = torch.Generator().manual_seed(0)
    obs = env.reset(seed=0)
    batch = one_step(env, obs, agent.act(obs, explore=True, generator=g))
    assert agent.actor.body.body[0].in_features == agent.critics[0].body.body[0].in_features - 4 == 5 + 50  # features, not pixels
    before = [p.clone() for p in agent.encoder.parameters()]
    grads = {}  # the encoder's gradient when each optimiser steps: the actor's backward must add nothing to it
    for name in ("critic", "actor"):
        optimizer = getattr(agent, f"{name}_optimizer")
        monkeypatch.setattr(
            optimizer,
            "step",
            lambda o=optimizer, n=name: (
                grads.__setitem__(n, [p.grad.clone() for p in agent.encoder.parameters()]) or type(o).step(o)
            ),
        )
    target_reads = []
    agent.encoder_target.register_forward_hook(lambda *args: target_reads.append(1))
    agent.update(batch, generator=g)
    assert target_reads == [1]  # the target critics read s' through the lagged encoder
    assert seen == [4, 4]  # both states' pictures shifted
    assert all(not torch.equal(a, b) for a, b in zip(agent.encoder.parameters(), before))  # the critic loss trains it
    assert any(g.any() for g in grads["critic"]) and all(torch.equal(a, b) for a, b in zip(grads["critic"], grads["actor"]))
    online, target = list(agent.encoder.parameters()), list(agent.encoder_target.parameters())
    assert all(torch.allclose(t, 0.5 * o + 0.5 * b) for o, t, b in zip(online, target, before))  # Polyak, tau 0.5


def _fetchreach_from_pixels(preset: str, tmp_path) -> taskrl.Run:
    """A run of ``preset`` on FetchReach from 16x16 pictures at a test budget."""
    pytest.importorskip("gymnasium_robotics")
    return small_run(
        preset,
        tmp_path / "run",
        observation="pixels",
        image_size=16,
        total_steps=120,
        learning_starts=60,
        eval_interval=120,
        eval_episodes=1,
        num_envs=2,
        threads=1,
    )


@pytest.mark.timeout(300)
def test_sac_her_from_fetchreach_pixels_runs_and_saves_its_encoder(tmp_path):
    run = _fetchreach_from_pixels("fetchreach-sac-her", tmp_path)
    assert run.metrics["updates"] > 0 and run.agent.encoder.image_shape == (16, 16, 3)
    loaded = taskrl.load(tmp_path / "run")
    assert all(torch.equal(a, b) for a, b in zip(loaded.encoder.parameters(), run.agent.encoder.parameters()))


# ---------------------------------------------------------------------- pixels from any env that renders
class _DotEnv(gym.Env):
    """A point on a 48x48 canvas: the frame is white with a black dot where the point is; a goal env."""

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(self, render_mode: str | None = None) -> None:
        box = gym.spaces.Box(0.0, 1.0, (2,), np.float32)
        self.observation_space = gym.spaces.Dict({"observation": box, "achieved_goal": box, "desired_goal": box})
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.render_mode, self.point = render_mode, np.zeros(2, np.float32)

    def _obs(self):
        return {"observation": self.point.copy(), "achieved_goal": self.point.copy(), "desired_goal": np.full(2, 0.5, np.float32)}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.point = self.np_random.uniform(0, 1, 2).astype(np.float32)
        return self._obs(), {}

    def step(self, action):
        self.point = np.clip(self.point + 0.1 * np.asarray(action, np.float32), 0, 1)
        return self._obs(), 0.0, False, False, {}

    def render(self):
        frame = np.full((48, 48, 3), 255, np.uint8)
        r, c = (self.point * 44).astype(int)
        frame[r : r + 4, c : c + 4] = 0
        return frame


def test_pixel_observations_render_the_scene_keep_the_goals_and_drop_the_state_unless_asked():
    from taskrl.envs.pixels import PixelObservation, pixel_factory

    env = pixel_factory(_DotEnv, "pixels", 24)()  # _DotEnv takes no size: its 48x48 frame is resized
    assert set(env.observation_space.spaces) == {"achieved_goal", "desired_goal", "image"}
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs) and obs["image"].shape == (24, 24, 3) and obs["image"].dtype == np.uint8
    r, c = (env.unwrapped.point * 44).astype(int) // 2  # the dot, at half the scale, is where the point is
    dark = 255 - obs["image"].astype(float)
    assert obs["image"][r : r + 3, c : c + 3].min() == 0 and dark[r : r + 3, c : c + 3].sum() == pytest.approx(dark.sum())
    assert dark.sum() == pytest.approx(4 * 4 * 255 * 3 / 4, rel=0.02)  # area averaging keeps the dot's ink
    both = PixelObservation(_DotEnv(render_mode="rgb_array"), 48, keep_state=True)
    assert set(both.observation_space.spaces) == {"observation", "achieved_goal", "desired_goal", "image"}
    with pytest.raises(ValueError, match="rgb_array"):
        PixelObservation(_DotEnv(), 48)


@pytest.mark.timeout(300)
def test_fetchreach_from_pixels_runs_with_the_picture_in_the_replay_and_through_a_conv_encoder(tmp_path):
    run = _fetchreach_from_pixels("fetchreach-qtopt-her", tmp_path)
    assert run.metrics["updates"] > 0
    modules = [m for net in (run.agent.q, run.agent.q_target1) for m in net.modules()]
    assert any(isinstance(m, ImageStateInput) and m.image_shape == (16, 16, 3) for m in modules)
    assert run.agent.inputs.keys[-1] == "image" and "observation" not in run.agent.inputs.keys


@pytest.mark.timeout(300)
def test_multitask_sac_from_the_meta_world_camera_runs_at_a_small_budget(tmp_path):
    pytest.importorskip("metaworld")
    run = small_run(
        "mt10-sac-onehot",
        tmp_path / "run",
        env="mt1",
        task="reach",
        num_envs=1,
        observation="pixels",
        image_size=32,
        total_steps=60,
        learning_starts=30,
        eval_interval=60,
        eval_episodes=1,
        max_episode_steps=20,
        threads=1,
    )
    assert run.metrics["updates"] > 0 and run.agent.inputs.keys == ("image",)
    assert taskrl.load(tmp_path / "run").encoder.image_shape == (32, 32, 3)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_bc_from_the_meta_world_camera_records_pictures_and_trains_on_them_alone(tmp_path):
    pytest.importorskip("metaworld")
    from taskrl.demos.collect import collect_demos
    from taskrl.demos.dataset import read_demonstrations

    card = collect_demos("mt50:reach", 1, tmp_path / "demos", pictures=32)
    demos = read_demonstrations(tmp_path / "demos")
    assert demos.images.shape == (demos.num_steps, 32, 32, 3) and demos.observations.shape[1] == 39
    assert card["card"]["pictures"].startswith("32x32")
    assert (demos.images[1:].float() - demos.images[:-1].float()).abs().sum((1, 2, 3)).min() > 0  # the arm moves
    run = small_run(
        "bc-mt10-onehot",
        tmp_path / "run",
        env="mt1",
        task="reach",
        num_envs=1,
        dataset=str(tmp_path / "demos"),
        observation="pixels",
        image_size=32,
        total_steps=10,
        eval_interval=10,
        eval_episodes=1,
        max_episode_steps=10,
        threads=1,
    )
    agent = taskrl.load(tmp_path / "run")
    assert run.metrics["updates"] == 10 and agent.inputs.keys == ("image",) and agent.encoder is not None
    with pytest.raises(ConfigError, match="pictures"):
        collect_demos("pointreach-mt", 1, tmp_path / "no", pictures=32)


# ---------------------------------------------------------------------- goals given as pictures
def test_pixelreach_draws_the_point_and_its_goal_where_they_are():
    from taskrl.envs.pixel_reach import POINT, TABLE, PixelReach

    env = PixelReach(image_size=32, num_envs=3, seed=0)
    obs = env.reset(seed=0)
    assert env.single_observation_space.contains({k: v[0].numpy() for k, v in obs.items()})
    assert torch.equal(obs["goal_image"], env.picture(obs["desired_goal"]))
    for picture, where in ((obs["image"], obs["achieved_goal"]), (obs["goal_image"], obs["desired_goal"])):
        red = (picture[..., 0].float() - TABLE[0]) / (POINT[0] - TABLE[0])  # [B, 32, 32]: how much of a pixel is disc
        rows, cols = torch.arange(32.0) + 0.5, torch.arange(32.0) + 0.5
        weight = red.sum((1, 2))
        centre_x = (red * cols.view(1, 1, -1)).sum((1, 2)) / weight / 16 - 1
        centre_y = (red * rows.view(1, -1, 1)).sum((1, 2)) / weight / 16 - 1
        inside = (where.abs() < 0.85).all(1)  # discs cut by the border are off-centre
        # anti-aliased, so the disc's centre is found to well under the success radius (0.05; a pixel is 0.0625)
        assert torch.allclose(torch.stack([centre_x, centre_y], 1)[inside], where[inside], atol=0.01)
    moved = env.picture(obs["achieved_goal"] + torch.tensor([0.02, 0.0]))
    assert (moved.float() - obs["image"].float()).abs().sum((1, 2, 3)).min() > 100  # a third of a pixel shows


def test_pixelreach_passes_gymnasiums_env_checker_and_records_what_the_policy_sees():
    from gymnasium.utils.env_checker import check_env

    env = gym.make("taskrl/PixelReach-v0", render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=False)
    obs, _ = env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (128, 256, 3)  # the scene and the goal picture side by side, 4x
    assert np.array_equal(frame[::4, :128:4], obs["image"]) and np.array_equal(frame[::4, 128::4], obs["goal_image"])


def test_hindsight_gives_the_goal_picture_of_the_state_whose_position_became_the_goal(tmp_path):
    from taskrl.overrides import with_overrides
    from taskrl.presets import preset_config
    from taskrl.run import build
    from taskrl.training.offpolicy import batch_sampler

    config = with_overrides(preset_config("pixelreach-sac-her"), {"num_envs": 4, "her_k": 1000, "threads": 1})
    parts = build(config)
    try:
        env, replay, g = parts.env, parts.replay, torch.Generator().manual_seed(0)
        obs = env.reset(seed=0)
        replay.start(obs)
        for _ in range(120):
            action = torch.rand(4, 2, generator=g) * 2 - 1
            next_obs, reward, terminated, truncated, info = env.step(action)
            replay.add(action, reward, terminated, truncated, info["final_obs"], next_obs)
            obs = next_obs
        batch = batch_sampler(parts.sampler, 256, g)()
        relabelled = (batch.obs["desired_goal"] != batch.obs["achieved_goal"]).any(1)
        assert torch.equal(batch.obs["goal_image"], env.picture(batch.obs["desired_goal"]))  # every row, relabelled or not
        assert torch.equal(batch.next_obs["goal_image"], batch.obs["goal_image"]) and relabelled.float().mean() > 0.5
        assert parts.agent.inputs.keys == ("image", "goal_image")  # the state goal is never read
        assert parts.agent.encoder.image_shape == (2, 32, 32, 3) and parts.agent.encoder.trunk[0].in_channels == 6
    finally:
        parts.close()


@pytest.mark.timeout(300)
def test_sac_her_from_goal_pictures_runs_saves_and_loads(tmp_path):
    run = small_run(
        "pixelreach-sac-her",
        tmp_path / "run",
        total_steps=1200,
        learning_starts=800,
        eval_interval=1200,
        batch_size=32,
        threads=1,
    )
    assert run.metrics["updates"] > 0
    loaded = taskrl.load(tmp_path / "run")
    obs = {k: torch.as_tensor(v[None]) for k, v in loaded_obs(tmp_path).items()}
    assert loaded.act(obs).shape == (1, 2)


def loaded_obs(tmp_path):
    from taskrl.envs.pixel_reach import PixelReach

    env = PixelReach(image_size=32, num_envs=1, seed=1)
    return {k: v[0].numpy() for k, v in env.reset(seed=1).items()}


def test_a_scene_and_its_goal_picture_are_shifted_together():
    from taskrl.encoders import shift_pictures

    image = torch.zeros(64, 12, 12, 3, dtype=torch.uint8)
    image[:, 6, 5] = 255
    goal = torch.zeros_like(image)
    goal[:, 4, 7] = 255
    shifted = shift_pictures(
        {"image": image, "goal_image": goal, "achieved_goal": torch.zeros(64, 2)}, 2, torch.Generator().manual_seed(0)
    )
    scene_at = (shifted["image"][..., 0] == 255).nonzero()[:, 1:]
    goal_at = (shifted["goal_image"][..., 0] == 255).nonzero()[:, 1:]
    assert len({tuple(m) for m in scene_at.tolist()}) > 10  # shifted, by offsets that vary over the rows
    assert torch.equal(
        goal_at - scene_at, torch.tensor([[-2, 2]]).expand(64, 2)
    )  # the goal kept where it was relative to the scene


def test_a_shift_moves_the_positions_the_state_gives_in_the_pictures_frame_with_the_picture():
    """With ``coordinates``, a state entry that says where something is in the picture follows the shifted picture;
    other entries, and every entry without ``coordinates``, stay. Mutation: the moves' sign flipped fails."""
    from taskrl.encoders import PictureCoordinate, shift_pictures

    image = torch.zeros(64, 12, 12, 3, dtype=torch.uint8)
    image[:, 6, 5] = 255  # row 6, column 5: x = 5.5 / 12, y = 6.5 / 12
    state = torch.tensor([[5.5 / 12, 6.5 / 12, 7.0]]).expand(64, 3)
    coordinates = (PictureCoordinate("observation", 0, "col", 1 / 12), PictureCoordinate("observation", 1, "row", 1 / 12))
    shifted = shift_pictures({"image": image, "observation": state}, 2, torch.Generator().manual_seed(0), coordinates)
    at = (shifted["image"][..., 0] == 255).nonzero()[:, 1:].float()  # [64, (row, col)]
    assert len({tuple(m) for m in at.tolist()}) > 10
    torch.testing.assert_close(shifted["observation"][:, 0], (at[:, 1] + 0.5) / 12)
    torch.testing.assert_close(shifted["observation"][:, 1], (at[:, 0] + 0.5) / 12)
    assert torch.equal(shifted["observation"][:, 2], state[:, 2]) and torch.equal(state[:, 0], torch.full((64,), 5.5 / 12))
    plain = shift_pictures({"image": image, "observation": state}, 2, torch.Generator().manual_seed(0))
    assert torch.equal(plain["observation"], state)


def test_the_grasp_bins_state_puts_the_gripper_where_its_picture_shows_it():
    """The grasp env's declared picture coordinates (the gripper's x -> columns, y -> rows, 1/size per pixel) agree
    with its camera: the fingers' pixels are centred on the gripper, and moving it 3 pixels' worth moves them 3."""
    from taskrl.envs.grasp import FINGER

    env = Grasp(GraspSettings(image_size=64, num_objects=1), num_envs=1, seed=0)
    env.reset(seed=0)
    env.gripper[:] = torch.tensor([[0.5, 0.4]])
    env.yaw[:] = 0.3
    declared = {c.axis: (c.key, c.index, c.per_pixel) for c in env.picture_coordinates}
    assert declared == {"col": ("observation", 0, 1 / 64), "row": ("observation", 1, 1 / 64)}

    def fingers_centre() -> torch.Tensor:
        where = (env.render()[0] == torch.tensor(FINGER, dtype=torch.uint8)).all(-1).nonzero().float()
        return where.mean(0)  # (row, col)

    row, col = fingers_centre()
    assert abs((col + 0.5) / 64 - 0.5) < 1 / 64 and abs((row + 0.5) / 64 - 0.4) < 1 / 64
    env.gripper[:] = torch.tensor([[0.5 + 3 / 64, 0.4 - 3 / 64]])
    moved = fingers_centre()
    torch.testing.assert_close(moved - torch.stack([row, col]), torch.tensor([-3.0, 3.0]), atol=0.3, rtol=0)


def test_the_rl_encoders_start_orthogonal_as_drqs_and_behaviour_cloning_keeps_torchs_default():
    from taskrl.encoders import FiLMPictureEncoder

    def orthogonal(conv: torch.nn.Conv2d) -> bool:
        w = conv.weight.detach().flatten(1)  # [out, in * 9]: rows (or columns, if fewer) orthonormal up to ReLU's gain
        gram = w @ w.T if w.shape[0] <= w.shape[1] else w.T @ w
        return torch.allclose(gram, 2.0 * torch.eye(len(gram)), atol=1e-4) and not conv.bias.detach().any()

    for kind in ("conv", "resnet"):
        rl = ImageStateInput(2, (32, 32, 3), kind, 16)
        bc = FiLMPictureEncoder((32, 32, 3), kind, 16, context_dim=4)
        rl_convs = [m for m in rl.modules() if isinstance(m, torch.nn.Conv2d)]
        bc_convs = [m for m in bc.modules() if isinstance(m, torch.nn.Conv2d)]
        assert len(rl_convs) >= 4 and all(orthogonal(c) for c in rl_convs)
        assert len(bc_convs) == len(rl_convs) and not any(orthogonal(c) for c in bc_convs)


def test_spatial_softmax_reads_where_each_channel_is_brightest_to_a_fraction_of_a_pixel():
    from taskrl.encoders import SpatialSoftmax

    softmax = SpatialSoftmax(9, 17)  # 9 rows, 17 columns: x steps by 1/8, y by 1/4
    maps = torch.zeros(2, 2, 9, 17)
    maps[0, 0, 2, 12] = 50.0  # row 2, column 12: x = 0.5, y = -0.5
    maps[0, 1, 6, 3] = 50.0  # row 6, column 3: x = -0.625, y = 0.5
    maps[1, :, 4, 8] = 50.0  # the centre
    maps[1, 1, 4, 9] = 50.0  # and one column right of it, as bright: halfway between
    keypoints = softmax(maps).view(2, 2, 2)  # [B, C, (x, y)]
    expected = torch.tensor([[[0.5, -0.5], [-0.625, 0.5]], [[0.0, 0.0], [1 / 16, 0.0]]])
    torch.testing.assert_close(keypoints, expected, atol=1e-4, rtol=0)


def test_the_keypoint_encoder_hands_coordinates_on_and_follows_an_object_across_the_picture():
    torch.manual_seed(0)
    encoder = ImageStateInput(2, (16, 16, 3), "keypoints", 50)
    assert encoder.out_dim == 2 + 64 and isinstance(encoder.head, torch.nn.Identity)
    encoder.trunk[-1].log_temperature.data.fill_(-4.0)  # a sharp softmax, as training makes it (it starts at 1)
    pictures = torch.zeros(2, 1, 16, 16, 3, dtype=torch.uint8)
    pictures[0, 0, 2:5, 2:5] = 255  # a white square top left, then bottom right
    pictures[1, 0, 10:13, 10:13] = 255
    x = PictureState(torch.zeros(2, 2), pictures)
    with torch.no_grad():
        keypoints = encoder(x)[:, 2:].view(2, 32, 2)
    moved = (keypoints[1] - keypoints[0]).mean(0)  # averaged over channels: every one sees the square move
    assert (moved > 0.2).all(), moved  # 8 pixels of 16: 1.07 in [-1, 1] were every channel to follow it
    with pytest.raises(ConfigError, match="encoder"):
        QTOptConfig(encoder="spatial").validate()
    from taskrl.agents.bc import BCConfig

    with pytest.raises(ConfigError, match="encoder"):  # behaviour cloning's FiLM encoder has no keypoint form
        BCConfig(encoder="keypoints").validate()


def test_the_fused_q_adds_the_action_to_the_conv_map_and_scores_candidates_on_one_encoding():
    """QT-Opt's network (``--fusion conv``): CEM's scores match the plain forward pass, the early convolutions run
    once per state, and the action changes Q through the feature map (the state's own columns held fixed)."""
    from taskrl.fused_q import PictureActionQ

    torch.manual_seed(0)
    q = PictureActionQ(5, (16, 16, 3), 4, (32,))
    calls = []
    q.state_input.register_forward_hook(lambda module, args, out: calls.append(args[0].rows))
    x = PictureState(torch.randn(3, 5), torch.randint(0, 256, (3, 1, 16, 16, 3), dtype=torch.uint8))
    actions = torch.rand(3, 6, 4) * 2 - 1
    with torch.no_grad():
        scores = q.score_actions(x, actions)
        assert calls == [3] and scores.shape == (3, 6)
        plain = q(PictureState(*(t.repeat_interleave(6, 0) for t in x)), actions.reshape(18, 4)).view(3, 6)
    torch.testing.assert_close(scores, plain, rtol=1e-4, atol=1e-5)
    assert scores.std(dim=1).min() > 0  # candidates differ


def test_qtopt_with_the_fused_network_trains_it_and_its_targets_keep_their_own():
    env = Grasp(GraspSettings(image_size=16), num_envs=8, seed=0)
    obs = env.reset(seed=0)
    config = QTOptConfig(
        hidden_sizes=(32,), fusion="conv", target_samples=8, cem=__import__("taskrl").agents.cem.CEMConfig(samples=8, elites=2)
    )
    agent = QTOptAgent(("observation", "image"), 5 + 768, env.single_action_space, config, image_shape=(16, 16, 3))
    g = torch.Generator().manual_seed(0)
    batch = one_step(env, obs, agent.act(obs, explore=True, generator=g))
    before = [p.clone() for p in agent.q.parameters()]
    agent.update(batch, generator=g)
    assert all(not torch.equal(a, b) for a, b in zip(agent.q.parameters(), before))
    assert agent.q_target1.state_input is not agent.q.state_input
    with pytest.raises(ConfigError, match="fusion"):
        QTOptConfig(fusion="late").validate()


@pytest.mark.parametrize(
    "preset, settings",
    [
        ("grasp-qtopt-pixels", {}),
        ("grasp-qtopt-pixels", {"fusion": "conv"}),
        ("grasp-qtopt-pixels", {"fusion": "flat", "shift_coordinates": False}),
        ("grasp-qtopt-pixels", {"algo": "sac"}),
        ("pixelreach-sac-her", {}),  # the scene and its goal picture: two pictures, stacked
    ],
)
def test_every_picture_reading_agent_hands_its_encoder_the_stored_uint8_pictures_shifted(preset, settings, monkeypatch):
    """Built as a run builds it (``make_agent``), each agent's picture encoder receives the pictures as the replay
    stores them (uint8 ``[B, K, H, W, C]``), shifted by the update's own shift, and unshifted when acting. Mutation:
    `ObservationInput` flattening the pictures into the float vector (taskrl's old layout) fails it."""
    import importlib

    from taskrl.overrides import with_overrides
    from taskrl.presets import preset_config
    from taskrl.wiring.parts import make_agent, make_env

    config = with_overrides(preset_config(preset), {"image_size": 16, "hidden_sizes": (8,), "num_envs": 4, **settings})
    module = importlib.import_module(f"taskrl.agents.{config.algo}")
    shifted = []
    shift = module.shift_pictures
    monkeypatch.setattr(
        module,
        "shift_pictures",
        lambda obs, pad, generator=None, coordinates=(): shifted.append(shift(obs, pad, generator, coordinates)) or shifted[-1],
    )
    env = make_env(config, "cpu")
    agent = make_agent(config, env, torch.device("cpu"))
    encoder = agent.encoder if config.algo == "sac" else agent.q.state_input
    seen = []
    encoder.register_forward_hook(lambda m, args, out: seen.append(args[0].pictures))
    obs = env.reset(seed=0)
    keys = [k for k in ("image", "goal_image") if k in obs]
    stored = lambda o: torch.stack([o[k] for k in keys], 1)  # noqa: E731

    agent.act(obs)
    assert seen[-1].dtype == torch.uint8 and torch.equal(seen[-1], stored(obs))
    batch = one_step(env, obs, agent.act(obs, explore=True, generator=torch.Generator().manual_seed(0)))
    seen.clear()
    agent.update(batch, generator=torch.Generator().manual_seed(1))
    assert shifted and not torch.equal(stored(shifted[0]), stored(batch.obs))
    assert any(s.dtype == torch.uint8 and torch.equal(s, stored(shifted[0])) for s in seen)  # the shifted s
    assert not any(torch.equal(s, stored(batch.obs)) for s in seen)  # never the stored s unshifted
    env.close()
