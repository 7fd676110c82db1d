"""Named, documented starting points for ``taskrl train PRESET``."""

from __future__ import annotations

import dataclasses

from taskrl.config import TrainConfig
from taskrl.envs.tabletop import HELD_OUT as TABLETOP_HELD_OUT
from taskrl.errors import ConfigError
from taskrl.overrides import with_overrides

# Goal reaching with continuous actions: the hindsight paper's Fetch settings where they apply
# (gamma 0.98, lr 1e-3, batch 256, relabelling future with k = 4; episodes never end on success,
# the default of PointReach and Fetch). Each algorithm explores its own way (its section's
# defaults): SAC samples its policy, QT-Opt adds Gaussian noise (0.2) to its CEM action and takes a
# uniformly random action with probability 0.3 (the hindsight paper's Fetch exploration).
_CONTINUOUS_HER = {"her": "future", "her_k": 4, "batch_size": 256}
_SAC = {"algo": "sac"}
# QT-Opt bounds Q as its paper does; the goal envs' rewards are -1 / 0, so by clipping targets to
# [-1/(1-gamma), 0] (the hindsight paper's clip), not by the paper's sigmoid for 0/1 rewards.
_QTOPT = {"algo": "qtopt", "clip_target": True}
_POINTREACH = {
    **_CONTINUOUS_HER,
    "env": "pointreach",
    "num_envs": 16,
    "updates_per_step": 0.25,
    "learning_starts": 1_000,
    "eval_interval": 3_000,
    "total_steps": 40_000,
    "hidden_sizes": (64, 64),
    "lr": 1e-3,
    "gamma": 0.95,
}
# PixelPush: PointReach's scale with FetchPush's network width (an object to move needs more than reaching)
_PIXELPUSH = {
    **_POINTREACH,
    **_SAC,
    "env": "pixelpush",
    "hidden_sizes": (256, 256),
    "total_steps": 300_000,
    "eval_interval": 10_000,
}
# the pybullet grasping benchmark: 6 copies in their own processes (stepped in lockstep, two copies leave a core
# idle while the other settles or lifts), one attempt per episode (at most 15 steps)
_KUKAGRASP = {
    "env": "kukagrasp",
    "her": "none",
    "num_envs": 6,
    "buffer_size": 200_000,
    "eval_episodes": 50,  # the benchmark's num_eval
    "checkpoint_minutes": 5.0,
}
_FETCH = {
    **_CONTINUOUS_HER,
    "num_envs": 2,
    "updates_per_step": 0.5,
    "learning_starts": 1_000,
    "eval_interval": 2_000,
    "eval_episodes": 100,
    "lr": 1e-3,
    "gamma": 0.98,
}
# FetchPush: the hindsight paper's 8 parallel workers and 2M-step scale. Learning is most of a
# training step on CPU (an update costs ~20x a simulated step), so the update ratio sets the pace.
_FETCHPUSH = {
    "env": "fetchpush",
    "num_envs": 8,
    "total_steps": 2_000_000,
    "eval_interval": 25_000,
    "checkpoint_interval": 100_000,
}

# Multi-task SAC (Meta-World and the native multi-task PointReach): no relabelling, the policy's own
# entropy explores, task-balanced batches. Meta-World: gamma 0.99, lr 3e-4, one copy per task at
# 0.1 updates per env step (one update per step of all copies, as multi-task SAC on MT10 does),
# language contexts projected to 50-d as CARE's context encoder does.
_MULTITASK_SAC = {**_SAC, "her": "none", "sampling": "task_balanced"}
_METAWORLD = {
    **_MULTITASK_SAC,
    "lr": 3e-4,
    "gamma": 0.99,
    "learning_starts": 5_000,
    "eval_episodes": 10,
    "checkpoint_interval": 100_000,
    "buffer_size": 1_000_000,
}
_MT1 = {
    **_METAWORLD,
    "env": "mt1",
    "num_envs": 10,
    "hidden_sizes": (256, 256),
    "batch_size": 256,
    "updates_per_step": 0.5,
    "total_steps": 200_000,
    "eval_interval": 10_000,
    "stop_at_success": 0.0,
}
_MT10 = {
    **_METAWORLD,
    "env": "mt10",
    "num_envs": 10,
    "hidden_sizes": (400, 400, 400),
    "batch_size": 1280,
    "updates_per_step": 0.1,
    "total_steps": 20_000_000,
    "eval_interval": 100_000,
}
_LANGUAGE = {"task_encoder": "language", "projection_dim": 50}
_POINTREACH_MT = {
    **_MULTITASK_SAC,
    "env": "pointreach-mt",
    "reward": "dense",
    "num_envs": 16,
    "updates_per_step": 0.25,
    "learning_starts": 500,
    "eval_interval": 2_000,
    "eval_episodes": 20,
    "total_steps": 20_000,
    "hidden_sizes": (64, 64),
    "lr": 1e-3,
    "gamma": 0.95,
    "batch_size": 256,
}
# Multi-task behaviour cloning (BC-Z's choices): FiLM in every hidden layer, noise of std 0.1 on
# sentence and demo embeddings, batches stratified over tasks; total_steps and the intervals count
# gradient updates (an offline run steps no env while it trains). Each preset reads the dataset
# `taskrl demos collect <source> --out data/<source>` writes; --dataset DIR points elsewhere.
_BC = {
    "algo": "bc",
    "her": "none",
    "sampling": "uniform",
    "architecture": "film",
    "batch_size": 256,
    "eval_episodes": 10,
    "checkpoint_interval": 10_000,
}
# Meta-World evaluation episodes end at their first success: the same outcomes, several times faster.
_BC_METAWORLD = {**_BC, "total_steps": 5_000, "eval_interval": 2_500, "hidden_sizes": (256, 256, 256), "eval_until_success": True}
_BC_LANGUAGE = {"task_encoder": "language", "embedding_noise": 0.1}
_BC_DEMO = {"task_encoder": "language", "task_input": "demo", "embedding_noise": 0.1}

# Data sharing between tasks (docs/sharing.md): tasks that are known reward functions, one task with
# a tenth of the others' episodes (MT-Opt's imbalance), task-balanced batches whose rows for a task
# come half from other tasks' data by the --sharing strategy. Rewards are 0 / 1 and episodes end at
# success, so targets are not clipped to [-1/(1-gamma), 0].
_SHARING = {"her": "none", "sampling": "task_balanced", "clip_target": False, "share_fraction": 0.5}
_GRID_SHARING = {
    **_SHARING,
    "env": "gridtasks",
    "algo": "dqn",
    "sharing": "all",
    "low_data_tasks": "top-left-avoid",
    "low_data_fraction": 0.1,
    "num_envs": 16,
    "total_steps": 10_000,
    "learning_starts": 500,
    "updates_per_step": 0.25,
    "batch_size": 256,
    "hidden_sizes": (128,),
    "gamma": 0.9,
    "epsilon_start": 1.0,
    "epsilon_end": 0.1,
    "epsilon_decay_steps": 5_000,
    "eval_interval": 2_500,
    "eval_episodes": 20,
}
_POINT_SHARING = {
    **_SHARING,
    "env": "pointtasks",
    "algo": "sac",
    "sharing": "all",
    "low_data_tasks": "right-edge",
    "low_data_fraction": 0.1,
    "num_envs": 16,
    "total_steps": 15_000,
    "learning_starts": 500,
    "updates_per_step": 0.5,
    "init_alpha": 0.1,  # a reward of 1 once per episode: an entropy bonus starting at 1.0 drowns it
    "batch_size": 256,
    "hidden_sizes": (64, 64),
    "lr": 1e-3,
    "gamma": 0.95,
    "eval_interval": 2_500,
    "eval_episodes": 20,
}
# Offline (CDS's setting): no collection, per-task datasets of mixed quality, SAC with a CQL penalty.
_POINT_OFFLINE = {
    **_POINT_SHARING,
    "offline": True,
    "sharing": "conservative",
    "low_data_tasks": "",
    "dataset_quality": "top-left=expert,top-right=medium,bottom-left=random,bottom-right=random,centre=medium,right-edge=random",
    "dataset_steps": 2_000,
    "cql_alpha": 1.0,
    "init_alpha": 1.0,  # SAC's default: the penalty, not the entropy bonus, keeps the policy near the data
    "total_steps": 10_000,
    "eval_interval": 2_500,
    "checkpoint_interval": 10_000,
}

# Multi-task PPO: on-policy, so no replay, relabelling or task-balanced batches (every rollout holds
# every copy's task in proportion to its copies: one copy per task on Meta-World).
_PPO = {"algo": "ppo", "her": "none", "sampling": "uniform"}


@dataclasses.dataclass(frozen=True)
class Preset:
    description: str
    overrides: dict


PRESETS: dict[str, Preset] = {
    "bitflip-her": Preset(
        "DQN + hindsight relabelling (future, k=4) on 15-bit flipping with random start and target",
        {"n_bits": 15, "her": "future", "her_k": 4, "total_steps": 60_000},
    ),
    "bitflip50-her": Preset(
        "DQN + hindsight relabelling on 50-bit flipping, the paper's hardest case: 64 envs and the "
        "paper's 0.05 updates per env step (more fresh data per update)",
        {
            "n_bits": 50,
            "her": "future",
            "her_k": 4,
            "num_envs": 64,
            "updates_per_step": 0.05,
            "total_steps": 2_000_000,
            "eval_interval": 20_000,
        },
    ),
    "pointreach-sac-her": Preset(
        "SAC + hindsight relabelling on PointReach, a 2-D point moving to a random goal (sparse reward)",
        {**_POINTREACH, **_SAC},
    ),
    "pixelreach-sac-her": Preset(
        "SAC + hindsight relabelling on PixelReach: PointReach seen as a 32x32 picture, the goal given as a picture; "
        "random shifts of up to 2 pixels",
        {**_POINTREACH, **_SAC, "env": "pixelreach", "augment_pad": 2, "total_steps": 100_000},
    ),
    "pixelpush-sac-her": Preset(
        "SAC + hindsight relabelling on PixelPush: push a block to a goal shown as a picture (32x32 scene and goal "
        "pictures, the pusher's position), random shifts of up to 2 pixels",
        {**_PIXELPUSH, "augment_pad": 2},
    ),
    "pixelpush-state-sac-her": Preset(
        "SAC + hindsight relabelling on PixelPush from positions (pusher, block, goal): the control without pictures",
        {**_PIXELPUSH, "observation": "state"},
    ),
    "pixelpush-state-qtopt-her": Preset(
        "QT-Opt + hindsight relabelling on PixelPush from positions (pusher, block, goal): the five-minute check that "
        "QT-Opt learns to push (64x64 Q-network, 0.25 updates per env step, 150k env steps)",
        {**_PIXELPUSH, **_QTOPT, "observation": "state", "hidden_sizes": (64, 64), "total_steps": 150_000},
    ),
    "pointreach-qtopt-her": Preset(
        "QT-Opt (Q-learning, CEM argmax) + hindsight relabelling on PointReach (sparse reward)",
        {**_POINTREACH, **_QTOPT},
    ),
    "fetchreach-sac-her": Preset(
        "SAC + hindsight relabelling on FetchReach-v4 (gymnasium-robotics, MuJoCo)",
        {**_FETCH, **_SAC, "env": "fetchreach", "total_steps": 20_000},
    ),
    "fetchreach-qtopt-her": Preset(
        "QT-Opt + hindsight relabelling on FetchReach-v4; a 128x128 Q-network keeps CEM targets affordable",
        {**_FETCH, **_QTOPT, "env": "fetchreach", "total_steps": 20_000, "hidden_sizes": (128, 128)},
    ),
    "fetchpush-sac-her": Preset(
        "SAC + hindsight relabelling on FetchPush-v4 (the paper's scale: 8 copies, up to 2M env steps; hours on CPU)",
        {**_FETCH, **_SAC, **_FETCHPUSH, "hidden_sizes": (256, 256, 256), "updates_per_step": 0.25},
    ),
    "fetchpush-qtopt-her": Preset(
        "QT-Opt + hindsight relabelling on FetchPush-v4 (8 copies, up to 2M env steps; hours on CPU); a 128x128 "
        "Q-network and 0.1 updates per env step keep its CEM targets within SAC's time per env step",
        {**_FETCH, **_QTOPT, **_FETCHPUSH, "hidden_sizes": (128, 128), "updates_per_step": 0.1},
    ),
    "fetchpickandplace-sac-her": Preset(
        "SAC + hindsight relabelling on FetchPickAndPlace-v4 (~4M env steps in the paper; hours on CPU)",
        {
            **_FETCH,
            **_SAC,
            "env": "fetchpickandplace",
            "num_envs": 8,
            "total_steps": 4_000_000,
            "eval_interval": 50_000,
            "hidden_sizes": (256, 256, 256),
        },
    ),
    "grasp-qtopt-pixels": Preset(
        "QT-Opt from the camera: grasp objects in a bin from 64x64 pictures (conv encoder, random shifts, the paper's "
        "sigmoid Q with a log loss on the 0/1 grasp reward)",
        {
            **_QTOPT,
            "env": "grasp",
            "her": "none",
            "loss": "cross_entropy",
            "clip_target": False,  # the sigmoid bounds Q to [0, 1] for the 0/1 reward
            "gamma": 0.9,
            "lr": 3e-4,
            "hidden_sizes": (256, 256),
            "num_envs": 16,
            "batch_size": 64,
            "buffer_size": 100_000,
            "learning_starts": 1_000,
            "updates_per_step": 0.25,
            "total_steps": 200_000,
            "eval_interval": 5_000,
            "eval_episodes": 100,
        },
    ),
    "kukagrasp-qtopt": Preset(
        "QT-Opt on the pybullet grasping benchmark (Quillen et al. 2018): Kuka arm, 5 random objects, 64x64 camera; "
        "its config's gamma 0.9, Adam 1e-3, 16 samples for the Bellman maximum; sigmoid Q with a log loss",
        {
            **_KUKAGRASP,
            "algo": "qtopt",
            "loss": "cross_entropy",
            "clip_target": False,  # the sigmoid bounds Q to [0, 1] for the 0/1 grasp reward
            "gamma": 0.9,
            "lr": 1e-3,
            "hidden_sizes": (256, 256),
            "target_samples": 16,
            "batch_size": 64,
            "learning_starts": 0,
            "updates_per_step": 1.0,
            "total_steps": 15_000,
            "eval_interval": 5_000,
        },
    ),
    "kukagrasp-random": Preset(
        "the benchmark's random grasps (uniform actions, moving down 9 times in 10) stored as pictures, for "
        "--offline-data: about 3 env steps per grasp, so 31,000 steps are about 10,000 grasps; no learning",
        {
            **_KUKAGRASP,
            "algo": "qtopt",
            "scripted_exploration": 1.0,
            "learning_starts": 10**9,  # collection only: no update
            "total_steps": 31_000,
            "eval_interval": 10**9,
            "eval_episodes": 1,
        },
    ),
    "pointreach-mt-sac-onehot": Preset(
        "multi-task SAC on the native multi-task PointReach (5 regions named in words), one-hot task context",
        {**_POINTREACH_MT, "task_encoder": "onehot", "architecture": "concat"},
    ),
    "pointreach-mt-sac-care": Preset(
        "multi-task SAC with CARE (encoders mixed by attention on the sentence embedding) on multi-task PointReach",
        {**_POINTREACH_MT, **_LANGUAGE, "architecture": "care"},
    ),
    "pointreach-mt-ppo-onehot": Preset(
        "multi-task PPO on multi-task PointReach, one-hot task context (32 copies, rollouts of 64 steps)",
        {**_POINTREACH_MT, **_PPO, "num_envs": 32, "total_steps": 150_000, "eval_interval": 10_000},
    ),
    "mt1-reach-sac": Preset(
        "SAC on Meta-World v3 reach (MT1: one task, goal positions resampled every episode), 10 copies",
        {**_MT1, "task": "reach"},
    ),
    "mt1-push-sac": Preset(
        "SAC on Meta-World v3 push (MT1), 10 copies; needs more steps than reach",
        {**_MT1, "task": "push", "total_steps": 1_000_000, "eval_interval": 25_000},
    ),
    "mt10-sac-onehot": Preset(
        "multi-task SAC on Meta-World MT10: one network, one-hot task appended to the state, per-task temperature",
        {**_MT10, "task_encoder": "onehot", "architecture": "concat"},
    ),
    "mt10-sac-film-language": Preset(
        "multi-task SAC on MT10, hidden layers FiLM-modulated by the sentence embedding of the task description",
        {**_MT10, **_LANGUAGE, "architecture": "film"},
    ),
    "mt10-sac-care": Preset(
        "CARE on MT10: k=4 state encoders mixed by attention on the description's sentence embedding",
        {**_MT10, **_LANGUAGE, "architecture": "care", "care_encoders": 4},
    ),
    "mt10-ppo-onehot": Preset(
        "multi-task PPO on MT10 with a one-hot task context: one 500-step episode per task per rollout, 10 epochs of 10 minibatches",
        {
            **_MT10,
            **_PPO,
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
            **_MT10,
            **_LANGUAGE,
            "env": "mt50",
            "num_envs": 50,
            "batch_size": 6400,
            "architecture": "care",
            "care_encoders": 6,
            "total_steps": 100_000_000,
            "eval_interval": 500_000,
        },
    ),
    "pointreach-mt-bc": Preset(
        "behaviour cloning on multi-task PointReach from scripted demonstrations, one-hot task, FiLM (data/pointreach-mt)",
        {
            **_BC,
            "env": "pointreach-mt",
            "dataset": "data/pointreach-mt",
            "task_encoder": "onehot",
            "embedding_noise": 0.0,
            "hidden_sizes": (64, 64),
            "total_steps": 2_000,
            "eval_interval": 500,
            "eval_episodes": 20,
        },
    ),
    "bc-mt10-onehot": Preset(
        "multi-task behaviour cloning on MT10 from scripted demonstrations, one-hot task, FiLM (data/mt10)",
        {
            **_BC_METAWORLD,
            "env": "mt10",
            "num_envs": 10,
            "dataset": "data/mt10",
            "task_encoder": "onehot",
            "embedding_noise": 0.0,
        },
    ),
    "bc-mt10-language": Preset(
        "BC-Z on MT10: FiLM by the sentence embedding of the task description, embedding noise 0.1 (data/mt10)",
        {**_BC_METAWORLD, **_BC_LANGUAGE, "env": "mt10", "num_envs": 10, "dataset": "data/mt10"},
    ),
    "bc-mt10-demo": Preset(
        "BC-Z on MT10 prompted by one demonstration (a demo encoder), aligned to the description's embedding (data/mt10)",
        {**_BC_METAWORLD, **_BC_DEMO, "env": "mt10", "num_envs": 10, "dataset": "data/mt10"},
    ),
    "bc-mt50-language": Preset(
        "BC-Z on MT50, language-conditioned (data/mt50)",
        {
            **_BC_METAWORLD,
            **_BC_LANGUAGE,
            "env": "mt50",
            "num_envs": 50,
            "dataset": "data/mt50",
            "total_steps": 15_000,
            "eval_interval": 5_000,
        },
    ),
    "bc-ml45-language": Preset(
        "BC-Z on ML45's 45 training tasks, prompted by the description or one demonstration (demo encoder aligned to the "
        "description's embedding); its 5 test tasks held out for zero-shot prompts (data/ml45)",
        {
            **_BC_METAWORLD,
            **_BC_DEMO,
            "env": "ml45",
            "num_envs": 45,
            "held_out_tasks": "bin-picking,box-close,hand-insert,door-lock,door-unlock",
            "dataset": "data/ml45",
            "total_steps": 15_000,
            "eval_interval": 5_000,
        },
    ),
    "bc-tabletop-language": Preset(
        "BC-Z from pixels on the tabletop: 32x32 camera pictures through a conv encoder FiLM-modulated by the sentence "
        "embedding in every block, random shifts; six verb-colour tasks trained, three combinations held out for "
        "zero-shot prompts (data/tabletop: taskrl demos collect tabletop --episodes 100 --noise 0.2 --out data/tabletop)",
        {
            **_BC,
            **_BC_LANGUAGE,
            "env": "tabletop",
            "num_envs": 6,
            "dataset": "data/tabletop",
            "held_out_tasks": ",".join(TABLETOP_HELD_OUT),
            "hidden_sizes": (256, 256),
            "total_steps": 4_000,
            "eval_interval": 1_000,
            "eval_episodes": 20,
        },
    ),
    "grid-sharing-dqn": Preset(
        "DQN on the grid tasks, top-left-avoid with 10x less data, every task's batch half from all tasks' data",
        _GRID_SHARING,
    ),
    "point-sharing-sac": Preset(
        "SAC on the point tasks, right-edge with 10x less data, every task's batch half from all tasks' data",
        _POINT_SHARING,
    ),
    "point-sharing-offline": Preset(
        "offline SAC + CQL on the point tasks from expert / medium / random datasets, conservative sharing (CDS)",
        _POINT_OFFLINE,
    ),
    "bitflip-dqn": Preset(
        "plain DQN, no relabelling, on 15-bit flipping: the contrast case that fails beyond ~13 bits",
        {"n_bits": 15, "her": "none", "total_steps": 60_000},
    ),
}


def preset_config(name: str) -> TrainConfig:
    """The configuration of a named preset; unknown names raise `ConfigError`."""
    if name not in PRESETS:
        raise ConfigError("preset", f"unknown preset {name!r}; allowed: {', '.join(PRESETS)}")
    return with_overrides(TrainConfig(), PRESETS[name].overrides)
