"""Behaviour cloning (BC-Z) presets: PointReach-MT, Meta-World and the tabletop from pixels."""

from __future__ import annotations

from taskrl.envs.tabletop import HELD_OUT as TABLETOP_HELD_OUT
from taskrl.presets.fragments import BC, BC_DEMO, BC_LANGUAGE, BC_METAWORLD
from taskrl.presets.spec import Preset

PRESETS: dict[str, Preset] = {
    "pointreach-mt-bc": Preset(
        "behaviour cloning on multi-task PointReach from scripted demonstrations, one-hot task, FiLM (data/pointreach-mt)",
        {
            **BC,
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
            **BC_METAWORLD,
            "env": "mt10",
            "num_envs": 10,
            "dataset": "data/mt10",
            "task_encoder": "onehot",
            "embedding_noise": 0.0,
        },
    ),
    "bc-mt10-language": Preset(
        "BC-Z on MT10: FiLM by the sentence embedding of the task description, embedding noise 0.1 (data/mt10)",
        {**BC_METAWORLD, **BC_LANGUAGE, "env": "mt10", "num_envs": 10, "dataset": "data/mt10"},
    ),
    "bc-mt10-demo": Preset(
        "BC-Z on MT10 prompted by one demonstration (a demo encoder), aligned to the description's embedding (data/mt10)",
        {**BC_METAWORLD, **BC_DEMO, "env": "mt10", "num_envs": 10, "dataset": "data/mt10"},
    ),
    "bc-mt50-language": Preset(
        "BC-Z on MT50, language-conditioned (data/mt50)",
        {
            **BC_METAWORLD,
            **BC_LANGUAGE,
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
            **BC_METAWORLD,
            **BC_DEMO,
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
            **BC,
            **BC_LANGUAGE,
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
}
