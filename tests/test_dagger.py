"""HG-DAgger: the intervention gate, the corrections it records, merging datasets."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from helpers import cli, small_run
from taskrl.demos.collect import collect_demos
from taskrl.demos.dagger import InterventionRule, _Gate, collect_interventions, merge_datasets
from taskrl.demos.dataset import dataset_card, read_demonstrations, read_episodes
from taskrl.errors import ConfigError
from taskrl.loading import load_run


def test_the_expert_takes_over_after_patience_drifting_steps_and_hands_back_after_patience_agreeing_ones():
    gate = _Gate(1, InterventionRule(threshold=0.5, patience=3), torch.device("cpu"))
    expert = torch.zeros(1, 2)
    far, near = torch.ones(1, 2), torch.full((1, 2), 0.1)  # RMS disagreement 1.0 and 0.1
    drivers = [bool(gate.decide(a, expert)) for a in (far, far, near, far, far, far, far, near, near, far, near, near, near)]
    # two drifting steps then an agreeing one: no take-over; three in a row: the third is the expert's
    assert drivers == [False, False, False, False, False, True, True, True, True, True, True, True, False]
    gate.decide(far, expert), gate.decide(far, expert)
    assert bool(gate.decide(far, expert))
    gate.episodes_ended(torch.tensor([True]))  # a new episode starts with the policy driving
    assert not bool(gate.decide(far, expert))


@pytest.fixture(scope="module")
def weak_run(tmp_path_factory):
    """BC on two demonstrations per region, 200 updates: it reaches some regions and drifts in others."""
    folder = tmp_path_factory.mktemp("dagger")
    collect_demos("pointreach-mt", 2, folder / "demos", seed=3)
    small_run("pointreach-mt-bc", folder / "run", dataset=str(folder / "demos"), total_steps=200, eval_episodes=5)
    return folder


def test_corrections_are_the_experts_labels_on_the_states_it_drove(weak_run, tmp_path):
    card = collect_interventions(load_run(weak_run / "run"), tmp_path / "c", episodes=4, seed=5)
    episodes = read_episodes(tmp_path / "c")
    steps = sum(len(e) for e in episodes)
    assert 0 < card["expert_steps_total"] == steps < card["expert_steps_total"] + card["policy_steps_total"]
    assert card["expert_steps_total"] + card["policy_steps_total"] == 5 * 4 * 50  # 5 regions, 4 episodes, horizon 50
    assert len(episodes) == sum(card["interventions"].values())
    # each label is what the scripted expert does in that state (its goal is the region's centre)
    from taskrl.demos.experts import demo_source

    source = demo_source("pointreach-mt")
    demos = read_demonstrations(tmp_path / "c")
    expert = source.expert(source.make_env(list(demos.task_names), 1, 0, 0))
    assert torch.allclose(demos.actions, expert({"observation": demos.observations, "task": demos.tasks}), atol=1e-6)


def test_an_expert_that_never_agrees_drives_everything_and_one_that_always_does_nothing(weak_run, tmp_path):
    always = collect_interventions(
        load_run(weak_run / "run"), tmp_path / "all", episodes=2, rule=InterventionRule(1e-9, 1), seed=5
    )
    assert always["policy_steps_total"] == 0 and min(always["success_rate_with_interventions"].values()) == 1.0
    never = collect_interventions(
        load_run(weak_run / "run"), tmp_path / "none", episodes=2, rule=InterventionRule(10.0, 1), seed=5
    )
    assert never["expert_steps_total"] == 0 and not (tmp_path / "none" / "data").exists()


def test_merging_keeps_the_order_and_cuts_at_max_steps(weak_run, tmp_path):
    collect_interventions(load_run(weak_run / "run"), tmp_path / "c", episodes=2, seed=5)
    first = read_episodes(weak_run / "demos")
    merged = merge_datasets([weak_run / "demos", tmp_path / "c"], tmp_path / "m")
    assert merged["card"]["steps"] == sum(len(e) for e in first) + sum(len(e) for e in read_episodes(tmp_path / "c"))
    budget = sum(len(e) for e in first[:3]) + 7
    merge_datasets([weak_run / "demos", tmp_path / "c"], tmp_path / "cut", max_steps=budget)
    cut = read_episodes(tmp_path / "cut")
    assert sum(len(e) for e in cut) == budget and len(cut) == 4 and len(cut[3]) == 7
    assert np.array_equal(cut[0].actions, first[0].actions) and not cut[3].terminated
    assert dataset_card(tmp_path / "cut")["card"]["merged_from"][0] == str(weak_run / "demos")
    with pytest.raises(ConfigError, match="max_steps"):
        merge_datasets([weak_run / "demos"], tmp_path / "x", max_steps=0)


def test_cli_dagger_and_merge(weak_run, tmp_path):
    done = cli("demos", "dagger", str(weak_run / "run"), "--out", str(tmp_path / "c"), "--episodes", "2", "--no-progress")
    assert done.returncode == 0 and "expert drove" in done.stdout, done.stderr
    done = cli("demos", "merge", str(weak_run / "demos"), str(tmp_path / "c"), "--out", str(tmp_path / "m"))
    assert done.returncode == 0 and (tmp_path / "m" / "data").exists(), done.stderr
    bad = cli("demos", "dagger", str(weak_run / "run"), "--out", str(tmp_path / "d"), "--patience", "0")
    assert bad.returncode == 2 and "patience" in bad.stderr and "Traceback" not in bad.stderr


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_corrections_of_a_pixel_run_keep_their_pictures_and_merge_with_its_demonstrations(weak_run, tmp_path):
    """A pixel tabletop policy's corrections hold the camera's pictures of the states the expert drove (the old
    recorder wrote none, and merging them with the pictures' demonstrations crashed); datasets of different kinds are
    refused in one line."""
    collect_demos("tabletop", 1, tmp_path / "demos", seed=3)
    small_run(
        "bc-tabletop-language",
        tmp_path / "run",
        dataset=str(tmp_path / "demos"),
        total_steps=20,
        eval_interval=20,
        eval_episodes=1,
    )
    card = collect_interventions(load_run(tmp_path / "run"), tmp_path / "c", episodes=1, rule=InterventionRule(1e-9, 1), seed=5)
    corrections = read_demonstrations(tmp_path / "c")
    assert card["expert_steps_total"] > 0 and corrections.images is not None
    assert corrections.images.shape == (corrections.num_steps, 32, 32, 3)
    merged = merge_datasets([tmp_path / "demos", tmp_path / "c"], tmp_path / "m")
    assert read_demonstrations(tmp_path / "m").images.shape[0] == merged["card"]["steps"]
    done = cli("demos", "merge", str(weak_run / "demos"), str(tmp_path / "demos"), "--out", str(tmp_path / "x"))
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "pictures none in" in done.stderr and not (tmp_path / "x").exists()
