import json

import numpy as np
import pytest
import torch
from rich.console import Console

from taskrl.console import per_task_table
from taskrl.envs.meta_world import (
    METAWORLD_DESCRIPTIONS,
    MT10_TASKS,
    MT50_TASKS,
    metaworld_id,
    metaworld_spec,
    metaworld_task_set,
    version_free,
)
from taskrl.training.per_task import TooManyEpisodes, evaluate_per_task


# ------------------------------------------------------------------ no Meta-World needed
def test_descriptions_are_one_sentence_each_and_unique():
    assert len(METAWORLD_DESCRIPTIONS) == 50 and len(MT50_TASKS) == 50
    assert set(MT10_TASKS) <= set(MT50_TASKS) and len(MT10_TASKS) == 10
    for name, sentence in METAWORLD_DESCRIPTIONS.items():
        assert name == version_free(name) and not name.endswith("-v3")
        assert sentence[0].isupper() and sentence.endswith(".") and sentence.count(".") == 1, name
        assert 4 <= len(sentence.split()) <= 20, name
    assert len(set(METAWORLD_DESCRIPTIONS.values())) == 50


def test_task_sets_and_names():
    assert metaworld_task_set("MT10").names == list(MT10_TASKS)
    mt50 = metaworld_task_set("MT50")
    assert len(mt50) == 50 and mt50["reach"].description == METAWORLD_DESCRIPTIONS["reach"]
    assert metaworld_task_set("MT1", task="pick-place-v3").names == ["pick-place"]
    custom = metaworld_task_set(["reach-v3", "push", "window-close"])
    assert custom.names == ["reach", "push", "window-close"] and custom["push"].index == 1
    assert version_free("button-press-topdown-v3") == "button-press-topdown" and metaworld_id("reach") == "reach-v3"


def test_bad_benchmarks_and_names_are_rejected_with_the_allowed_values():
    with pytest.raises(ValueError, match="allowed names: assembly, basketball"):
        metaworld_task_set(["reach", "fly"])
    with pytest.raises(ValueError, match="MT1 needs task"):
        metaworld_task_set("MT1")
    with pytest.raises(ValueError, match="benchmark must be one of MT1, MT10, MT50"):
        metaworld_task_set("MT20")
    with pytest.raises(ValueError, match="Meta-World v3"):
        metaworld_task_set(["reach-v2"])
    with pytest.raises(ValueError, match="more than once"):
        metaworld_task_set(["reach", "reach-v3"])
    with pytest.raises(ValueError, match="MT1 only"):
        metaworld_task_set("MT10", task="reach")


def test_table_of_a_result():
    result = {
        "mean_success_rate": 0.5,
        "tasks": {
            "reach": {"index": 0, "success_rate": 1.0, "episodes": 2, "mean_return": 3.0},
            "push": {"index": 1, "success_rate": 0.0, "episodes": 2, "mean_return": 1.0},
        },
    }
    console = Console(record=True, width=100)
    console.print(per_task_table(result))
    text = console.export_text()
    assert "reach" in text and "push" in text and "0.500" in text


# ------------------------------------------------------------------ with Meta-World
metaworld = pytest.importorskip("metaworld")
from taskrl.envs.meta_world import MetaWorldMultiTaskEnv  # noqa: E402


def test_names_and_order_match_the_installed_metaworld():
    from metaworld.env_dict import ALL_V3_ENVIRONMENTS, MT10_V3

    assert [version_free(n) for n in ALL_V3_ENVIRONMENTS] == list(MT50_TASKS)
    assert [version_free(n) for n in MT10_V3] == list(MT10_TASKS)


@pytest.mark.slow
def test_mt10_builds_with_one_hot_and_the_one_hot_matches_the_task_index():
    with MetaWorldMultiTaskEnv("MT10", use_one_hot=True, max_episode_steps=3, seed=0, num_goals=3) as env:
        assert env.num_envs == 10 and env.horizon == 3 and env.task_set.names == list(MT10_TASKS)
        assert env.slot_tasks.tolist() == list(range(10))
        obs = env.reset(seed=0)
        assert obs["observation"].shape == (10, 39) and obs["observation"].dtype == torch.float32
        assert obs["task"].dtype == torch.int64 and obs["task"].tolist() == list(range(10))
        for i, slot in enumerate(env.vector_env.envs):  # Meta-World's own one-hot, per slot
            one_hot = np.asarray(slot.get_wrapper_attr("one_hot"))
            assert one_hot.shape == (10,) and one_hot[i] == 1 and one_hot.sum() == 1
            assert len(slot.get_wrapper_attr("tasks")) == 3 and env.goal_positions() == 3
        obs, reward, terminated, truncated, info = env.step(torch.zeros(10, 4))
        assert obs["task"].tolist() == list(range(10)) and reward.dtype == torch.float32
        assert info["is_success"].dtype == torch.bool and info["is_success"].shape == (10,)
        spec = metaworld_spec("MT10")  # what loading an agent builds instead of the env
        assert spec.single_observation_space == env.single_observation_space
        assert spec.single_action_space == env.single_action_space and spec.task_set == env.task_set


def test_goal_positions_are_resampled_at_every_reset():
    with MetaWorldMultiTaskEnv("MT1", task="reach", use_one_hot=False, envs_per_task=2, max_episode_steps=2, seed=0) as env:
        obs = env.reset(seed=1)
        assert obs["task"].tolist() == [0, 0]
        goals = [tuple(np.round(g, 4)) for g in obs["observation"][:, 36:39].tolist()]
        for _ in range(8):  # four more episodes per slot, autoreset
            obs, _, _, truncated, info = env.step(torch.zeros(2, 4))
            if truncated.all():
                goals += [tuple(np.round(g, 4)) for g in obs["observation"][:, 36:39].tolist()]
        assert len(goals) == 10 and len(set(goals)) >= 6  # 50 goal positions, drawn at random


def test_success_comes_from_metaworld_info_success():
    from metaworld.policies import SawyerReachV3Policy

    expert = SawyerReachV3Policy()
    with MetaWorldMultiTaskEnv("MT1", task="reach", use_one_hot=True, max_episode_steps=150, seed=0, num_goals=5) as env:
        obs = env.reset(seed=0)
        successes = []
        for _ in range(150):
            action = expert.get_action(obs["observation"][0].double().numpy())
            obs, _, _, _, info = env.step(torch.as_tensor(action).reshape(1, 4))
            successes.append(bool(info["is_success"][0]))
        assert not successes[0] and any(successes)


def test_a_hidden_goal_is_zeroed_as_metaworlds_ml_benchmarks_zero_it_and_the_expert_is_still_told_it():
    from taskrl.envs.meta_world import hide_goal, metaworld_expert

    kwargs = dict(use_one_hot=True, max_episode_steps=150, seed=0, num_goals=5, terminate_on_success=True)
    with (
        MetaWorldMultiTaskEnv(["reach"], **kwargs) as seen,
        MetaWorldMultiTaskEnv(["reach"], hidden_goal=True, **kwargs) as hidden,
    ):
        full, blind = seen.reset(seed=0)["observation"], hidden.reset(seed=0)["observation"]
        assert full[0, 36:39].abs().min() > 0 and torch.equal(blind, hide_goal(full))
        # Meta-World's own partially observable observation of the same state hides the same three numbers
        raw = seen.vector_env.envs[0].unwrapped
        previous = raw._prev_obs.copy()
        raw._partially_observable = True
        own = raw._get_obs()
        raw._prev_obs, raw._partially_observable = previous, False
        assert np.allclose(own, hide_goal(torch.as_tensor(raw._get_obs())).numpy())
        # the scripted expert acts on the true goal, so demonstrations can be collected under the protocol
        assert torch.equal(hidden.goals(), full[:, 36:39])
        expert, obs, reached = metaworld_expert(hidden), {"observation": blind}, False
        for _ in range(150):
            obs, _, terminated, _, info = hidden.step(expert(obs))
            reached = reached or bool(info["is_success"][0])
            if terminated.any():
                break
        assert reached


def test_pixels_from_the_meta_world_camera_replace_the_state_and_match_the_spec():
    with MetaWorldMultiTaskEnv(["reach"], observation="pixels", image_size=32, num_goals=2, max_episode_steps=3) as env:
        obs = env.reset(seed=0)
        assert set(obs) == {"task", "image"} and obs["image"].shape == (1, 32, 32, 3) and obs["image"].dtype == torch.uint8
        assert obs["image"].float().std() > 10  # a scene, not a blank frame
        assert (
            env.single_observation_space
            == metaworld_spec(["reach"], observation="pixels", image_size=32).single_observation_space
        )
        after, *_ = env.step(torch.ones(1, 4))
        assert not torch.equal(after["image"], obs["image"])  # the arm moved in the picture
    both = metaworld_spec(["reach"], observation="pixels+state", image_size=32).single_observation_space
    assert set(both.spaces) == {"observation", "task", "image"}


@pytest.mark.slow
def test_seeding_repeats_and_horizons_past_500():
    def make():
        return MetaWorldMultiTaskEnv("MT1", task="reach", use_one_hot=True, max_episode_steps=505, seed=3, num_goals=10)

    with make() as a, make() as b:
        oa, ob = a.reset(seed=5), b.reset(seed=5)
        assert torch.equal(oa["observation"], ob["observation"])
        assert torch.equal(a.reset(seed=5)["observation"], oa["observation"])  # reset(seed) repeats the goal too
        for _ in range(504):  # past Meta-World's max_path_length of 500
            _, _, _, truncated, _ = a.step(torch.zeros(1, 4))
            assert not truncated.any()
        _, _, _, truncated, _ = a.step(torch.zeros(1, 4))
        assert truncated.all()


def test_per_task_evaluation_on_a_tiny_budget(tmp_path):
    seen: dict[int, set] = {0: set(), 1: set()}

    def policy(obs):
        for task, goal in zip(obs["task"].tolist(), obs["observation"][:, 36:39].tolist()):
            seen[task].add(tuple(np.round(goal, 4)))
        return torch.zeros(obs["task"].shape[0], 4)

    env = MetaWorldMultiTaskEnv(["reach", "push"], use_one_hot=True, max_episode_steps=4, seed=0, num_goals=5)
    with env:
        result = evaluate_per_task(policy, env, episodes_per_task=3, seed=0, save_to=tmp_path / "eval.json")
        Console(file=open(tmp_path / "t.txt", "w")).print(per_task_table(result))
        assert result["distinct_goals"] and set(result["tasks"]) == {"reach", "push"}
        assert all(r["episodes"] == 3 and r["mean_length"] == 4 for r in result["tasks"].values())
        assert len(seen[0]) == 3 and len(seen[1]) == 3  # three distinct goal positions per task
        rates = [r["success_rate"] for r in result["tasks"].values()]
        assert result["mean_success_rate"] == pytest.approx(sum(rates) / 2)  # the headline is the mean over tasks
        assert json.loads((tmp_path / "eval.json").read_text())["tasks"]["push"]["index"] == 1
        assert "reach" in (tmp_path / "t.txt").read_text()
        with pytest.raises(TooManyEpisodes, match="distinct goal positions"):  # prompted eval: one line on --episodes
            evaluate_per_task(policy, env, episodes_per_task=6)
        # After evaluation, goals are random again.
        obs = env.reset(seed=0)
        assert obs["observation"].shape == (2, 39)
