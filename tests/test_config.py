import dataclasses
import json
import pickle

import pytest

from taskrl.agents.registry import ALGORITHMS
from taskrl.conditioning.networks import ConditioningConfig
from taskrl.config import TrainConfig, from_dict, load, to_dict
from taskrl.envs.registry import ENV_FAMILIES
from taskrl.errors import ConfigError
from taskrl.overrides import with_overrides
from taskrl.plan import validate
from taskrl.presets import PRESETS, preset_config
from taskrl.setting_names import field_help, leaf_fields


def test_round_trip_keeps_both_sections_under_their_names():
    config = with_overrides(
        TrainConfig(), {"env": "pointreach", "algo": "qtopt", "hidden_sizes": (32, 16), "samples": 32, "reward": "dense"}
    )
    data = to_dict(config)
    assert data["qtopt"]["cem"]["samples"] == 32 and data["pointreach"]["reward"] == "dense"
    assert "dqn" not in data and "bitflip" not in data  # only the run's own sections are saved
    again = from_dict(json.loads(json.dumps(data)))
    assert again == config and again.algo_settings.hidden_sizes == (32, 16)


def test_flat_names_address_the_active_sections():
    c = with_overrides(TrainConfig(), {"algo": "sac", "lr": 0.01, "gamma": 0.9, "n_bits": 7})
    assert (c.algo_settings.lr, c.algo_settings.gamma, c.env_settings.n_bits) == (0.01, 0.9, 7)
    with pytest.raises(ConfigError, match="unknown setting for env 'bitflip' and algo 'sac'"):
        with_overrides(TrainConfig(), {"algo": "sac", "double_q": False})
    with pytest.raises(ConfigError, match="unknown setting"):
        with_overrides(TrainConfig(), {"env": "pointreach", "n_bits": 3})  # bit flipping's, not PointReach's


@pytest.mark.parametrize("algo", list(ALGORITHMS))
@pytest.mark.parametrize("env", ["bitflip", "pointreach", "mt10", "gym", "tasks"])
def test_every_setting_has_one_documented_flag(env, algo):
    names = [path[-1] for path, _, _ in leaf_fields(env, algo)]
    assert len(names) == len(set(names)), sorted(n for n in names if names.count(n) > 1)
    docs = field_help(env, algo)
    assert all(docs.get(n) for n in names), [n for n in names if not docs.get(n)]


def test_every_family_and_algorithm_has_a_validated_settings_class():
    for spec in [*ENV_FAMILIES.values(), *ALGORITHMS.values()]:
        settings = spec.settings() if hasattr(spec, "settings") else spec.config()
        assert dataclasses.is_dataclass(settings) and callable(settings.validate)


@pytest.mark.parametrize("name", list(PRESETS))
def test_every_preset_is_valid(name):
    validate(preset_config(name))


@pytest.mark.parametrize(
    "changes, field",
    [
        ({"algo": "qtopt", "env": "pointreach", "elites": 100}, "cem.elites"),  # named by its path, as --cem.elites
        ({"algo": "qtopt", "env": "pointreach", "loss": "l1"}, "loss"),
        ({"algo": "sac", "env": "pointreach", "init_alpha": 0.0}, "init_alpha"),
        ({"algo": "td3", "env": "pointreach", "policy_delay": 0}, "policy_delay"),
        ({"algo": "td3", "env": "pointreach", "noise_std": -0.1}, "noise_std"),
        ({"algo": "dqn", "epsilon_start": 1.5}, "epsilon_start"),
        ({"env": "pointreach", "algo": "sac", "reward": "shaped"}, "reward"),
        ({"n_bits": 0}, "n_bits"),
        ({"env": "mt10", "algo": "sac", "her": "none", "num_envs": 16}, "num_envs"),
        ({"env": "mt10", "algo": "dqn", "her": "none", "num_envs": 10}, "algo"),
        ({"env": "pointreach-mt", "algo": "sac", "her": "future"}, "her"),
        ({"env": "mt1", "algo": "sac", "her": "none", "task": "fly"}, "task"),
        ({"env": "mt1", "algo": "sac", "her": "none", "eval_episodes": 51}, "eval_episodes"),
        ({"env": "bitflip", "algo": "sac"}, "algo"),
        ({"env": "gym", "algo": "sac"}, "env_id"),
        ({"env": "tasks", "algo": "sac", "her": "none", "task_file": "/no/such/tasks.yaml"}, "task_file"),
        ({"sampling": "task_balanced"}, "sampling"),
        ({"task_encoder": "bag-of-words"}, "task_encoder"),
        ({"architecture": "transformer"}, "architecture"),
        ({"care_encoders": 0}, "care_encoders"),
    ],
)
def test_validation_names_the_field(changes, field):
    with pytest.raises(ConfigError) as err:
        validate(with_overrides(TrainConfig(), changes))
    assert err.value.field == field


def test_a_config_error_crosses_processes_whole():
    # a Ray role's ConfigError reaches the trainer pickled: the same field and message, not a broken copy
    error = pickle.loads(pickle.dumps(ConfigError("env_module", "cannot import 'mine'")))
    assert (type(error), error.field, error.message) == (ConfigError, "env_module", "cannot import 'mine'")


def test_a_rule_lives_in_one_place_ppo_may_use_gamma_one_dqn_may_not():
    ppo = with_overrides(preset_config("bitflip-her"), {"algo": "ppo", "her": "none", "gamma": 1.0})
    assert validate(ppo).algo_settings.gamma == 1.0
    with pytest.raises(ConfigError, match=r"must be in \[0, 1\)"):
        validate(with_overrides(preset_config("bitflip-her"), {"gamma": 1.0}))
    with pytest.raises(ConfigError) as err:  # the agent checks with the very same rule
        ALGORITHMS["dqn"].config(gamma=1.0).validate()
    assert err.value.field == "gamma"


def test_switching_algorithm_keeps_shared_settings_and_says_so():
    notes = []
    c = with_overrides(preset_config("pointreach-sac-her"), {"algo": "td3"}, notes)
    assert (c.algo_settings.lr, c.algo_settings.gamma, c.algo_settings.hidden_sizes) == (1e-3, 0.95, (64, 64))
    assert c.algo_settings.noise_std == 0.1  # TD3's own exploration, not a number meant for another algorithm
    assert notes and "kept lr=0.001, gamma=0.95, hidden_sizes=(64, 64)" in notes[0]
    notes = []
    with_overrides(preset_config("bitflip-her"), {"env": "pointreach", "algo": "sac"}, notes)
    assert notes == []  # nothing the preset changed is lost: bitflip's section was at its defaults


def test_a_variant_algorithm_keeps_its_parents_settings_when_switched_to(monkeypatch):
    import dataclasses as dc

    from taskrl.agents.registry import register_algorithm

    @dc.dataclass
    class VariantConfig(ALGORITHMS["dqn"].config):
        extra: float = 1.0

    for parent in (None, "dqn"):
        variant = dc.replace(ALGORITHMS["dqn"], name="dqn-variant", config=VariantConfig, parent=parent)
        monkeypatch.setitem(ALGORITHMS, "dqn-variant", variant) if parent is None else register_algorithm(variant, replace=True)
        base = with_overrides(preset_config("bitflip-her"), {"epsilon_end": 0.2, "epsilon_decay_steps": 500, "double_q": False})
        exploration = {"epsilon_end", "epsilon_decay_steps", "double_q"}  # DQN's own, not shared by every algorithm
        c = with_overrides(base, {"algo": "dqn-variant"})
        kept = {k for k in exploration if getattr(c.algo_settings, k) == getattr(base.algo_settings, k)}
        assert kept == (exploration if parent == "dqn" else set())
    ALGORITHMS.pop("dqn-variant")


def test_moving_a_multitask_preset_to_an_env_without_tasks_turns_its_conditioning_off():
    notes = []
    c = with_overrides(
        preset_config("pointreach-mt-sac-care"), {"env": "pointreach", "her": "future", "sampling": "uniform"}, notes
    )
    assert any("task conditioning (task_encoder=language, architecture=care, projection_dim=50) is off" in n for n in notes)
    assert c.conditioning == ConditioningConfig() and validate(c).env == "pointreach"  # what the note says, done


def test_env_id_alone_selects_the_gymnasium_family():
    notes = []
    c = with_overrides(preset_config("pointreach-sac-her"), {"env_id": "my/Slider-v0"}, notes)
    assert (c.env, c.env_settings.env_id, c.algo) == ("gym", "my/Slider-v0", "sac")


def test_unknown_keys_in_a_saved_config_are_an_error():
    data = to_dict(with_overrides(TrainConfig(), {"algo": "sac", "env": "pointreach"}))
    data["sac"]["leraning_rate"] = 1.0
    with pytest.raises(ConfigError, match="config.sac"):
        from_dict(data)


def test_a_config_saved_with_flat_run_settings_loads_into_the_sections(tmp_path):
    """Run directories written before the replay, evaluation, checkpoint and data settings became sections (their
    settings flat on the run) load with every value in its section. Mutation: the migration skipping a section fails."""
    config = with_overrides(
        TrainConfig(),
        {
            "algo": "qtopt",
            "env": "pointreach",
            "buffer_size": 1234,
            "her_k": 2,
            "eval_interval": 777,
            "save_replay": False,
            "scripted_steps": 5,
            "recent_fraction": 0.25,
            "checkpoint_minutes": 3.0,
        },
    )
    data = to_dict(config)
    flat = {k: v for k, v in data.items() if k not in ("replay", "evaluation", "checkpoints", "data")}
    for section in ("replay", "evaluation", "checkpoints", "data"):
        flat.update(data[section])
    (tmp_path / "config.json").write_text(json.dumps(flat))
    assert load(tmp_path / "config.json") == config


def test_a_config_saved_before_the_registries_still_loads(tmp_path):
    """Run directories written with flat env settings and a loop-level epsilon resume unchanged."""
    old = {
        "env": "pointreach",
        "n_bits": 15,
        "terminate_on_success": False,
        "reward": "dense",
        "vector_strategy": "sync",
        "mt1_task": "reach",
        "max_episode_steps": 500,
        "sampling": "uniform",
        "algo": "qtopt",
        "total_steps": 40000,
        "num_envs": 16,
        "seed": 0,
        "device": "cpu",
        "buffer_size": 1000,
        "her": "future",
        "her_k": 4,
        "batch_size": 256,
        "learning_starts": 1000,
        "updates_per_step": 0.25,
        "epsilon_start": 0.3,
        "epsilon_end": 0.1,
        "epsilon_decay_steps": 20000,
        "eval_interval": 3000,
        "eval_episodes": 100,
        "stop_at_success": 0.0,
        "checkpoint_interval": 50000,
        "save_replay": True,
        "max_hours": 0.0,
        "threads": 1,
        "dqn": {"lr": 0.001},
        "qtopt": {"lr": 0.001, "noise_std": 0.2, "cem": {"samples": 32}},
        "sac": {},
        "td3": {},
        "ppo": {},
        "conditioning": {"task_encoder": "onehot"},
    }
    (tmp_path / "config.json").write_text(json.dumps(old))
    c = load(tmp_path / "config.json")
    assert c.env_settings.reward == "dense" and c.env_settings.terminate_on_success is False
    q = c.algo_settings
    assert (q.random_action_prob, q.random_action_prob_end, q.random_action_decay_steps) == (0.3, 0.1, 20000)
    assert q.noise_std == 0.2 and q.cem.samples == 32
    validate(c)


def test_importing_the_config_loads_no_torch_and_a_run_imports_only_the_pieces_it_names(tmp_path):
    """The registries import each built-in piece's file when a run first names it (`taskrl.registry.Declared`)."""
    import json
    import subprocess
    import sys

    from taskrl.config import TrainConfig, save

    save(TrainConfig(env="bitflip", algo="dqn"), tmp_path / "config.json")
    script = (
        "import json, sys, taskrl.config as c\n"
        "print(json.dumps([m for m in ('torch', 'taskrl.agents.dqn', 'taskrl.envs.bitflip') if m in sys.modules]))\n"
        f"c.load({str(tmp_path / 'config.json')!r})\n"
        "print(json.dumps([m for m in sys.modules if m.startswith(('taskrl.envs.', 'taskrl.agents.'))]))\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout.splitlines()
    assert json.loads(out[0]) == []
    loaded = set(json.loads(out[1]))
    assert {"taskrl.agents.dqn", "taskrl.envs.bitflip"} <= loaded
    other_pieces = {
        "taskrl.agents.sac",
        "taskrl.agents.bc",
        "taskrl.envs.meta_world",
        "taskrl.envs.kuka_grasp",
        "taskrl.envs.fetch",
    }
    assert not loaded & other_pieces
