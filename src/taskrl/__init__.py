"""taskrl: multi-task and goal-conditioned reinforcement learning in PyTorch.

import taskrl
run = taskrl.train("bitflip-her", n_bits=20)   # -> Run(run_dir, config, metrics, agent)
agent = taskrl.load(run.run_dir)               # agent.act(obs) on the env's observations
"""

from taskrl.registration import register_gymnasium_envs

__version__ = "0.1.0"

register_gymnasium_envs()  # gymnasium.make("taskrl/BitFlip-v0") works after `import taskrl`


def train(*args, **kwargs):
    """See [`taskrl.run.train`][taskrl.run.train]."""
    from taskrl.run import train as _train

    return _train(*args, **kwargs)


def train_seeds(*args, **kwargs):
    """See [`taskrl.seeds.train_seeds`][taskrl.seeds.train_seeds] (one run per seed, then their comparison)."""
    from taskrl.seeds import train_seeds as _train_seeds

    return _train_seeds(*args, **kwargs)


def load(*args, **kwargs):
    """See [`taskrl.loading.load`][taskrl.loading.load]."""
    from taskrl.loading import load as _load

    return _load(*args, **kwargs)


def evaluate_run(*args, **kwargs):
    """See [`taskrl.loading.evaluate_run`][taskrl.loading.evaluate_run]."""
    from taskrl.loading import evaluate_run as _evaluate_run

    return _evaluate_run(*args, **kwargs)


def evaluate_prompted(*args, **kwargs):
    """See [`taskrl.prompting.evaluate_prompted`][taskrl.prompting.evaluate_prompted] (held-out tasks of a prompted policy)."""
    from taskrl.prompting import evaluate_prompted as _evaluate_prompted

    return _evaluate_prompted(*args, **kwargs)


def load_policy(*args, **kwargs):
    """See [`taskrl.export.load_policy`][taskrl.export.load_policy]."""
    from taskrl.export import load_policy as _load_policy

    return _load_policy(*args, **kwargs)


__all__ = ["train", "train_seeds", "load", "load_policy", "evaluate_run", "evaluate_prompted", "__version__"]
