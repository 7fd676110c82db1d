"""Multi-task presets: PointReach-MT and Meta-World (MT1, MT10, MT50), SAC and PPO."""

from __future__ import annotations

from taskrl.presets.fragments import LANGUAGE, MT1, MT10, POINTREACH_MT, PPO
from taskrl.presets.spec import Preset

PRESETS: dict[str, Preset] = {
    "pointreach-mt-sac-onehot": Preset(
        "multi-task SAC on the native multi-task PointReach (5 regions named in words), one-hot task context",
        {**POINTREACH_MT, "task_encoder": "onehot", "architecture": "concat"},
    ),
    "pointreach-mt-sac-care": Preset(
        "multi-task SAC with CARE (encoders mixed by attention on the sentence embedding) on multi-task PointReach",
        {**POINTREACH_MT, **LANGUAGE, "architecture": "care"},
    ),
    "pointreach-mt-ppo-onehot": Preset(
        "multi-task PPO on multi-task PointReach, one-hot task context (32 copies, rollouts of 64 steps)",
        {**POINTREACH_MT, **PPO, "num_envs": 32, "total_steps": 150_000, "eval_interval": 10_000},
    ),
    "mt1-reach-sac": Preset(
        "SAC on Meta-World v3 reach (MT1: one task, goal positions resampled every episode), 10 copies",
        {**MT1, "task": "reach"},
    ),
    "mt1-push-sac": Preset(
        "SAC on Meta-World v3 push (MT1), 10 copies; needs more steps than reach",
        {**MT1, "task": "push", "total_steps": 1_000_000, "eval_interval": 25_000},
    ),
    "mt10-sac-onehot": Preset(
        "multi-task SAC on Meta-World MT10: one network, one-hot task appended to the state, per-task temperature",
        {**MT10, "task_encoder": "onehot", "architecture": "concat"},
    ),
    "mt10-sac-film-language": Preset(
        "multi-task SAC on MT10, hidden layers FiLM-modulated by the sentence embedding of the task description",
        {**MT10, **LANGUAGE, "architecture": "film"},
    ),
    "mt10-sac-care": Preset(
        "CARE on MT10: k=4 state encoders mixed by attention on the description's sentence embedding",
        {**MT10, **LANGUAGE, "architecture": "care", "care_encoders": 4},
    ),
    "mt10-ppo-onehot": Preset(
        "multi-task PPO on MT10 with a one-hot task context: one 500-step episode per task per rollout, 10 epochs of 10 minibatches",
        {
            **MT10,
            **PPO,
            "task_encoder": "onehot",
            "architecture": "concat",
            "hidden_sizes": (256, 256),
            "lr": 3e-4,
            "gamma": 0.99,
            "rollout_steps": 500,
            "epochs": 10,
            "minibatches": 10,
            "entropy_coef": 0.0,
        },
    ),
    "mt50-sac-care": Preset(
        "CARE on MT50 (k=6 encoders; 50 copies, one per task)",
        {
            **MT10,
            **LANGUAGE,
            "env": "mt50",
            "num_envs": 50,
            "batch_size": 6400,
            "architecture": "care",
            "care_encoders": 6,
            "total_steps": 100_000_000,
            "eval_interval": 500_000,
        },
    ),
}
