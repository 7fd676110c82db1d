import dataclasses

import pytest

from taskrl.config import (ALGO_CONFIGS, ConfigError, TrainConfig, field_help, from_dict, leaf_fields, to_dict,
                           validate, with_overrides)
from taskrl.presets import PRESETS, preset_config


def test_round_trip_of_every_section():
    config = with_overrides(TrainConfig(), {"algo": "qtopt", "hidden_sizes": (32, 16), "samples": 32})
    again = from_dict(to_dict(config))
    assert again == config and again.qtopt.hidden_sizes == (32, 16) and again.qtopt.cem.samples == 32


def test_flat_names_address_the_active_algorithm():
    c = with_overrides(TrainConfig(), {"algo": "sac", "lr": 0.01, "gamma": 0.9})
    assert (c.sac.lr, c.sac.gamma) == (0.01, 0.9)
    assert c.dqn.lr == TrainConfig().dqn.lr  # other sections untouched
    with pytest.raises(ConfigError, match="unknown setting for algo 'sac'"):
        with_overrides(TrainConfig(), {"algo": "sac", "double_q": False})


@pytest.mark.parametrize("algo", list(ALGO_CONFIGS))
def test_every_algorithm_has_unique_documented_flags(algo):
    names = [path[-1] for path, _, _ in leaf_fields(algo)]
    assert len(names) == len(set(names))
    docs = field_help(algo)
    assert all(docs.get(n) for n in names), [n for n in names if not docs.get(n)]


@pytest.mark.parametrize("name", list(PRESETS))
def test_every_preset_is_valid(name):
    validate(preset_config(name))


@pytest.mark.parametrize("changes, field", [
    ({"algo": "qtopt", "elites": 100}, "elites"),
    ({"algo": "qtopt", "loss": "l1"}, "loss"),
    ({"algo": "sac", "init_alpha": 0.0}, "init_alpha"),
    ({"algo": "td3", "policy_delay": 0}, "policy_delay"),
    ({"reward": "shaped"}, "reward"),
    ({"env": "mt10", "algo": "sac", "her": "none", "num_envs": 16}, "num_envs"),
    ({"env": "mt10", "algo": "dqn", "her": "none", "num_envs": 10}, "algo"),
    ({"env": "pointreach-mt", "algo": "sac", "her": "future"}, "her"),
    ({"env": "mt1", "algo": "sac", "her": "none", "mt1_task": "fly"}, "mt1_task"),
    ({"env": "mt1", "algo": "sac", "her": "none", "eval_episodes": 51}, "eval_episodes"),
    ({"sampling": "task_balanced"}, "sampling"),
    ({"task_encoder": "bag-of-words"}, "task_encoder"),
    ({"architecture": "transformer"}, "architecture"),
    ({"care_encoders": 0}, "care_encoders"),
])
def test_validation_names_the_field(changes, field):
    with pytest.raises(ConfigError) as err:
        validate(with_overrides(TrainConfig(), changes))
    assert err.value.field == field


def test_unknown_keys_in_a_saved_config_are_an_error():
    data = to_dict(TrainConfig())
    data["sac"]["leraning_rate"] = 1.0
    with pytest.raises(ConfigError, match="config.sac"):
        from_dict(data)
