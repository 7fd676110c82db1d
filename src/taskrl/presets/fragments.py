"""Settings several presets share (the hindsight paper's Fetch settings, each family's scale, ...)."""

from __future__ import annotations

# Goal reaching with continuous actions: the hindsight paper's Fetch settings where they apply
# (gamma 0.98, lr 1e-3, batch 256, relabelling future with k = 4; episodes never end on success,
# the default of PointReach and Fetch). Each algorithm explores its own way (its section's
# defaults): SAC samples its policy, QT-Opt adds Gaussian noise (0.2) to its CEM action and takes a
# uniformly random action with probability 0.3 (the hindsight paper's Fetch exploration).
CONTINUOUS_HER = {"her": "future", "her_k": 4, "batch_size": 256}
SAC = {"algo": "sac"}
# QT-Opt bounds Q as its paper does; the goal envs' rewards are -1 / 0, so by clipping targets to
# [-1/(1-gamma), 0] (the hindsight paper's clip), not by the paper's sigmoid for 0/1 rewards. The
# squared loss, not the Huber loss: Q spans [-1/(1-gamma), 0], errors above 1 are common, and the
# Huber loss weighs each of those by its sign alone; on FetchPush it learnt 3-5x slower offline and
# never took off online (benchmarks/RESULTS.md, "QT-Opt + HER learning to push (fetchpush)").
QTOPT = {"algo": "qtopt", "clip_target": True, "loss": "mse"}
POINTREACH = {
    **CONTINUOUS_HER,
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
PIXELPUSH = {
    **POINTREACH,
    **SAC,
    "env": "pixelpush",
    "hidden_sizes": (256, 256),
    "total_steps": 300_000,
    "eval_interval": 10_000,
}
# the pybullet grasping benchmark: 6 copies in their own processes (stepped in lockstep, two copies leave a core
# idle while the other settles or lifts), one attempt per episode (at most 15 steps)
KUKAGRASP = {
    "env": "kukagrasp",
    "her": "none",
    "num_envs": 6,
    "buffer_size": 200_000,
    "eval_episodes": 50,  # the benchmark's num_eval
    "checkpoint_minutes": 5.0,
}
FETCH = {
    **CONTINUOUS_HER,
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
FETCHPUSH = {
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
MULTITASK_SAC = {**SAC, "her": "none", "sampling": "task_balanced"}
METAWORLD = {
    **MULTITASK_SAC,
    "lr": 3e-4,
    "gamma": 0.99,
    "learning_starts": 5_000,
    "eval_episodes": 10,
    "checkpoint_interval": 100_000,
    "buffer_size": 1_000_000,
}
MT1 = {
    **METAWORLD,
    "env": "mt1",
    "num_envs": 10,
    "hidden_sizes": (256, 256),
    "batch_size": 256,
    "updates_per_step": 0.5,
    "total_steps": 200_000,
    "eval_interval": 10_000,
    "stop_at_success": 0.0,
}
MT10 = {
    **METAWORLD,
    "env": "mt10",
    "num_envs": 10,
    "hidden_sizes": (400, 400, 400),
    "batch_size": 1280,
    "updates_per_step": 0.1,
    "total_steps": 20_000_000,
    "eval_interval": 100_000,
}
LANGUAGE = {"task_encoder": "language", "projection_dim": 50}
POINTREACH_MT = {
    **MULTITASK_SAC,
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
BC = {
    "algo": "bc",
    "her": "none",
    "sampling": "uniform",
    "architecture": "film",
    "batch_size": 256,
    "eval_episodes": 10,
    "checkpoint_interval": 10_000,
}
# Meta-World evaluation episodes end at their first success: the same outcomes, several times faster.
BC_METAWORLD = {**BC, "total_steps": 5_000, "eval_interval": 2_500, "hidden_sizes": (256, 256, 256), "eval_until_success": True}
BC_LANGUAGE = {"task_encoder": "language", "embedding_noise": 0.1}
BC_DEMO = {"task_encoder": "language", "task_input": "demo", "embedding_noise": 0.1}

# Data sharing between tasks (docs/sharing.md): tasks that are known reward functions, one task with
# a tenth of the others' episodes (MT-Opt's imbalance), task-balanced batches whose rows for a task
# come half from other tasks' data by the --sharing strategy. Rewards are 0 / 1 and episodes end at
# success, so targets are not clipped to [-1/(1-gamma), 0].
SHARING = {"her": "none", "sampling": "task_balanced", "clip_target": False, "share_fraction": 0.5}
GRID_SHARING = {
    **SHARING,
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
POINT_SHARING = {
    **SHARING,
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
POINT_OFFLINE = {
    **POINT_SHARING,
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
PPO = {"algo": "ppo", "her": "none", "sampling": "uniform"}
