"""``agent.act`` takes observations in every form an env gives them, for every registered algorithm;
``import taskrl`` alone registers the native gymnasium ids."""

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch

from taskrl.agents.registry import ALGORITHMS
from taskrl.config import TrainConfig
from taskrl.envs.meta_world import metaworld_spec
from taskrl.envs.registry import env_family
from taskrl.envs.spec import EnvRequest
from taskrl.overrides import with_overrides
from taskrl.presets import preset_config
from taskrl.run import make_agent

CPU = torch.device("cpu")
# A native family and its gymnasium id for each kind of action space.
ENVS = {"discrete": ("bitflip", "taskrl/BitFlip-v0", {"n_bits": 6}), "box": ("pointreach", "taskrl/PointReach-v0", {})}
CASES = [(algo, kind) for algo, spec in ALGORITHMS.items() for kind in spec.actions]


def built(algo: str, family: str, settings: dict, **more):
    config = with_overrides(
        TrainConfig(), {"env": family, "algo": algo, "her": "none", "hidden_sizes": (16,), **settings, **more}
    )
    env = env_family(family).make(config.env_settings, EnvRequest(num_envs=3, seed=0, device=CPU))
    return make_agent(config, env, CPU), env


@pytest.mark.slow
@pytest.mark.parametrize("algo, kind", CASES)
def test_act_takes_one_observation_a_numpy_batch_or_tensors(algo, kind):
    family, env_id, settings = ENVS[kind]
    agent, native = built(algo, family, settings)
    single = gym.make(env_id, **settings)
    obs, _ = single.reset(seed=0)
    for explore in (False, True):
        action = agent.act(obs, explore=explore)  # one numpy observation -> one numpy action
        assert single.action_space.contains(action if kind == "box" else np.int64(action)), action
        assert isinstance(action, int) if kind == "discrete" else action.shape == single.action_space.shape
    single.step(agent.act(obs))

    vec = gym.make_vec(env_id, num_envs=4, **settings)
    obs, _ = vec.reset(seed=0)
    actions = agent.act(obs, explore=True)  # a numpy batch -> a numpy batch
    assert isinstance(actions, np.ndarray) and actions.shape == vec.action_space.shape
    vec.step(actions)
    vec.close()

    obs = native.reset(seed=0)
    actions = agent.act(obs)  # tensors -> tensors (the loops' path)
    assert isinstance(actions, torch.Tensor) and actions.shape[0] == 3
    native.step(actions)


@pytest.mark.parametrize("algo", [name for name, spec in ALGORITHMS.items() if spec.multitask])
def test_multitask_agents_act_on_gymnasium_observations_with_a_task(algo):
    discrete = "discrete" in ALGORITHMS[algo].actions
    env, env_id = ("gridtasks", "taskrl/GridTasks-v0") if discrete else ("pointreach-mt", "taskrl/MultiTaskPointReach-v0")
    agent, _ = built(algo, env, {})
    single = gym.make(env_id)
    obs, _ = single.reset(seed=0, options={"task": "top-left"})
    assert np.ndim(obs["task"]) == 0 and single.action_space.contains(agent.act(obs))
    vec = gym.make_vec(env_id, num_envs=3)
    obs, _ = vec.reset(seed=0)
    assert agent.act(obs).shape == ((3,) if discrete else (3, 2))
    vec.close()


def test_act_takes_a_bare_array_as_the_observation():
    """Meta-World's own ``gymnasium.make`` gives a plain 39-d array: it is read as ``observation``."""
    config = with_overrides(
        TrainConfig(),
        {
            "env": "mt1",
            "algo": "sac",
            "her": "none",
            "sampling": "uniform",
            "num_envs": 1,
            "eval_episodes": 1,
            "hidden_sizes": (16,),
        },
    )
    agent = make_agent(config, metaworld_spec("MT1", "reach"), CPU)
    assert agent.act(np.zeros(39, dtype=np.float32)).shape == (4,)
    assert agent.act(np.zeros((5, 39), dtype=np.float32)).shape == (5, 4)
    with pytest.raises(ValueError, match="not a multiple of the agent's input size 39"):
        agent.act(np.zeros(40, dtype=np.float32))


def test_td3_on_a_sac_preset_explores_with_its_own_noise():
    config = with_overrides(preset_config("pointreach-sac-her"), {"algo": "td3"})
    env = env_family("pointreach").make(config.env_settings, EnvRequest(num_envs=4000, seed=0, device=CPU))
    agent = make_agent(config, env, CPU)
    obs = env.reset(seed=0)
    greedy, explored = agent.act(obs), agent.act(obs, explore=True, generator=torch.Generator().manual_seed(0))
    inside = (greedy.abs() < 0.5).all(1)  # away from the box's edges, where clipping shrinks the noise
    assert abs((explored - greedy)[inside].std().item() - 0.1) < 0.01  # TD3's 0.1, not a full half-width


@pytest.mark.slow
def test_import_taskrl_alone_registers_every_native_id_and_gymnasiums_checker_passes():
    code = (
        "import gymnasium as gym, taskrl\n"
        "from gymnasium.utils.env_checker import check_env\n"
        "from taskrl.registration import NATIVE_IDS\n"
        "assert NATIVE_IDS\n"
        "for env_id in NATIVE_IDS:\n"
        "    check_env(gym.make(env_id).unwrapped, skip_render_check=True)\n"
        "print(' '.join(sorted(gym.registry.keys() & set(NATIVE_IDS))))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    names = {
        "BitFlip",
        "PointReach",
        "MultiTaskPointReach",
        "GridTasks",
        "PointTasks",
        "Grasp",
        "KukaGrasp",
        "PixelReach",
        "PixelPush",
        "Tabletop",
    }
    assert set(out.stdout.split()) == {f"taskrl/{name}-v0" for name in names}
