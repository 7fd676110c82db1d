"""Compiled updates (``--compile``): the same step as eager, the fused helpers against their formulas."""

import copy
import dataclasses
import json

import pytest
import torch

from agent_batches import bandit_batch
from helpers import small_run
from taskrl.agents.compiled import CompiledStep
from taskrl.agents.dqn import DQNAgent, DQNConfig
from taskrl.agents.parts import functional_adam_step, gradient_step, init_adam_state, polyak_update
from taskrl.agents.qtopt import QTOptAgent, QTOptConfig
from taskrl.agents.sac import SACAgent, SACConfig
from taskrl.agents.td3 import TD3Agent, TD3Config
from taskrl.conditioning.networks import TaskConditioning
from taskrl.errors import ConfigError
from taskrl.replay.batch import Batch

BOX = (torch.tensor([-2.0]), torch.tensor([1.0]))


def discrete_batch(n: int = 64, seed: int = 0, tasks: int = 0) -> Batch:
    g = torch.Generator().manual_seed(seed)
    obs = {"observation": torch.randn(n, 6, generator=g)}
    next_obs = {"observation": torch.randn(n, 6, generator=g)}
    if tasks:
        obs["task"] = next_obs["task"] = torch.randint(0, tasks, (n,), generator=g)
    return Batch(
        obs=obs,
        action=torch.randint(0, 4, (n,), generator=g),
        reward=-torch.rand(n, generator=g),
        next_obs=next_obs,
        terminated=torch.rand(n, generator=g) < 0.2,
        truncated=torch.zeros(n, dtype=torch.bool),
        episode=torch.zeros(n, dtype=torch.long),
        step=torch.zeros(n, dtype=torch.long),
    )


def agents():
    """One small agent of each kind whose updates compile, with a batch it learns from."""
    bandit = bandit_batch(torch.tensor([0.5, -0.5]), torch.Generator().manual_seed(0))
    box = dict(input_keys=("observation",), input_dim=2, action_space=BOX)
    return {
        "dqn": (DQNAgent(("observation",), 6, 4, DQNConfig(hidden_sizes=(16, 16), target_update_interval=2)), discrete_batch()),
        "sac": (SACAgent(**box, config=SACConfig(hidden_sizes=(16, 16), max_grad_norm=1.0)), bandit),
        "td3": (TD3Agent(**box, config=TD3Config(hidden_sizes=(16, 16))), bandit),
        "qtopt": (QTOptAgent(**box, config=QTOptConfig(hidden_sizes=(16, 16), target2_interval=2)), bandit),
    }


def learned(agent) -> list[torch.Tensor]:
    return [t.detach().clone() for name, t in agent.state_dict().items() if name != "updates" for t in _tensors(t)]


def _tensors(state) -> list[torch.Tensor]:
    if isinstance(state, torch.Tensor):
        return [state]
    if isinstance(state, dict):
        return [t for v in state.values() for t in _tensors(v)]
    if isinstance(state, (list, tuple)):
        return [t for v in state for t in _tensors(v)]
    return []


@pytest.fixture
def same_random_numbers():
    """Compiled randomness from torch's own generator, so a compiled SAC draws what eager draws."""
    with torch._inductor.config.patch(fallback_random=True):
        yield


@pytest.mark.slow
@pytest.mark.parametrize("name", ["dqn", "sac", "td3", "qtopt"])
def test_compiled_updates_give_the_eager_parameters(name, same_random_numbers):
    torch.manual_seed(0)
    eager, batch = agents()[name]
    compiled = copy.deepcopy(eager)
    notices = []
    compiled.compile("default", say=notices.append)
    for step in range(4):
        torch.manual_seed(step)
        m_eager = eager.update(batch)
        torch.manual_seed(step)
        m_compiled = compiled.update(batch)
        assert m_compiled.keys() == m_eager.keys()
        for key in m_eager:
            torch.testing.assert_close(m_compiled[key], m_eager[key], rtol=1e-4, atol=1e-5)
    assert compiled.step.active and len(notices) == 1 and notices[0].startswith("compiled the update (default) in "), notices
    assert compiled.step.compile_seconds > 0
    assert compiled.updates == eager.updates == 4
    before = learned(agents()[name][0])
    after_eager, after_compiled = learned(eager), learned(compiled)
    assert len(after_eager) == len(after_compiled)
    assert any(not torch.equal(a, b) for a, b in zip(before, after_eager) if a.shape == b.shape)  # it learned
    for a, b in zip(after_eager, after_compiled):
        torch.testing.assert_close(b, a, rtol=1e-4, atol=1e-5)


@pytest.mark.slow
def test_a_multitask_sac_update_compiles_to_the_eager_one(same_random_numbers):
    from taskrl.conditioning.networks import make_conditioning
    from taskrl.config import ConditioningConfig

    conditioning: TaskConditioning = make_conditioning(ConditioningConfig(), 3, None)
    torch.manual_seed(0)
    eager = SACAgent(("observation",), 6, BOX, SACConfig(hidden_sizes=(16, 16)), conditioning=conditioning)
    compiled = copy.deepcopy(eager)
    compiled.compile("default", say=lambda line: None if line.startswith("compiled") else pytest.fail(line))
    batch = discrete_batch(tasks=3).replace(action=torch.rand(64, 1) * 3 - 2)
    for step in range(3):
        torch.manual_seed(step)
        eager.update(batch)
        torch.manual_seed(step)
        compiled.update(batch)
    for a, b in zip(learned(eager), learned(compiled)):
        torch.testing.assert_close(b, a, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("weight_decay", [0.0, 0.1])
def test_the_functional_adam_step_is_torchs_adam_with_the_norm_clip(weight_decay):
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(5, 7), torch.nn.Tanh(), torch.nn.Linear(7, 1), torch.nn.Linear(2, 2))
    twin = copy.deepcopy(net)
    opt = torch.optim.Adam(net.parameters(), lr=1e-2, weight_decay=weight_decay)
    opt_twin = torch.optim.Adam(twin.parameters(), lr=1e-2, weight_decay=weight_decay)
    init_adam_state(opt_twin)
    x = torch.randn(32, 5)
    clipped = list(net.parameters())[:2]  # the clip sees only the first layer, as gradient_step's list says
    for _ in range(5):  # the last layer is not reached by the loss: left alone, its step count too
        gradient_step(opt, net[:3](x).square().mean() * 100, clipped, 0.5)
        functional_adam_step(opt_twin, twin[:3](x).square().mean() * 100, list(twin.parameters())[:2], 0.5)
    for a, b in zip(net.parameters(), twin.parameters()):
        torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-6)
    unreached = list(twin.parameters())[-1]
    assert opt_twin.state[unreached]["step"] == 0 and opt_twin.state[list(twin.parameters())[0]]["step"] == 5


def test_the_fused_target_update_is_the_polyak_formula():
    torch.manual_seed(0)
    target, online = [torch.randn(3, 4), torch.randn(7)], [torch.randn(3, 4), torch.randn(7)]
    expected = [0.1 * p + 0.9 * t for t, p in zip(target, online)]
    polyak_update(target, online, 0.1)
    for t, e in zip(target, expected):
        torch.testing.assert_close(t, e)
    polyak_update(target, online, 1.0)  # tau = 1: a copy
    assert all(torch.equal(t, p) for t, p in zip(target, online))


def test_a_failed_compilation_says_so_in_one_line_and_updates_eagerly():
    agent, batch = agents()["dqn"]
    twin = copy.deepcopy(agent)
    notices = []

    def refuse(*args):
        raise RuntimeError("no C++ compiler found\nsecond line")

    agent.compile("default", say=notices.append)
    agent.step.compiled = refuse  # what torch.compile does where it cannot compile
    agent.update(batch)
    twin.update(batch)
    assert len(notices) == 1 and "\n" not in notices[0] and "updating eagerly" in notices[0]
    assert "no C++ compiler found" in notices[0]
    assert not agent.step.active
    agent.update(batch)  # stays eager, says nothing more
    assert len(notices) == 1
    for a, b in zip(learned(twin), learned(agent)):
        assert a.shape == b.shape
    agent.compile("off")
    assert not isinstance(agent.step, CompiledStep)


def test_a_call_that_needs_another_graph_compiles_it_and_later_calls_reuse_the_graphs():
    from taskrl.agents.compiled import _graphs_compiled

    notices = []
    step = CompiledStep(lambda x, double: x * 2 if double else x + 1, "default", [], say=notices.append, what="test step")
    x = torch.arange(4.0)
    before = _graphs_compiled()
    outputs = [step(x, double) for double in (False, False, True, True, False)]
    assert _graphs_compiled() - before == 2  # one graph per flag, each compiled once
    assert step.active and step.calls == 5 and len(notices) == 1, notices
    for out, double in zip(outputs, (False, False, True, True, False)):
        torch.testing.assert_close(out, x * 2 if double else x + 1)


def test_unknown_compile_modes_are_refused():
    agent, _ = agents()["dqn"]
    with pytest.raises(ConfigError, match="compile"):
        agent.compile("fastest")
    with pytest.raises(ConfigError, match="compile"):
        CompiledStep(agent.learn, "turbo", [])


@pytest.mark.slow
def test_each_agent_runs_its_own_graph():
    """Two agents of one class share the update's code: each must still run with its own settings."""
    batch = discrete_batch()
    torch.manual_seed(0)
    plain = DQNAgent(("observation",), 6, 4, DQNConfig(hidden_sizes=(16,), double_q=False, gamma=0.5))
    double = DQNAgent(("observation",), 6, 4, DQNConfig(hidden_sizes=(16,), double_q=True, gamma=0.9))
    double.load_state_dict(plain.state_dict())
    for eager in (plain, double):
        compiled = copy.deepcopy(eager)
        compiled.compile("default", say=lambda line: None)
        for _ in range(2):
            torch.testing.assert_close(compiled.update(batch)["loss"], eager.update(batch)["loss"], rtol=1e-4, atol=1e-6)


@pytest.mark.slow
def test_a_compiled_dqn_update_is_one_graph_and_refreshes_its_target_on_schedule():
    """The target refresh runs after the compiled step, so the refreshes add no second graph (a quarter to a third of
    the compile seconds); the target is still copied at every third update and only then."""
    torch.manual_seed(0)
    agent = DQNAgent(("observation",), 6, 4, DQNConfig(hidden_sizes=(16,), target_update_interval=3, tau=1.0))
    agent.compile("default", say=lambda line: None)
    graphs = torch._dynamo.utils.counters["stats"]["unique_graphs"]
    for update in range(1, 8):
        agent.update(discrete_batch(seed=update))
        copied = all(torch.equal(t, p) for t, p in zip(agent._target_params, agent._params))
        assert copied == (update % 3 == 0), update
    assert agent.step.active
    assert torch._dynamo.utils.counters["stats"]["unique_graphs"] - graphs == 1


@pytest.mark.slow
@pytest.mark.parametrize("name", ["dqn", "td3", "qtopt", "sac"])
def test_k_updates_in_one_call_are_k_updates(name, same_random_numbers):
    """Eagerly K = 4; compiled K = 2, which holds both schedule flags of each agent (a target refresh or a
    delayed actor every second update) in one graph at half the compile time of 4."""
    torch.manual_seed(0)
    one_by_one, batch = agents()[name]
    batches = [batch.replace(reward=batch.reward + 0.1 * i) for i in range(4)]
    eager_many, compiled_many = copy.deepcopy(one_by_one), copy.deepcopy(one_by_one)
    compiled_many.compile("default", say=lambda line: None)
    torch.manual_seed(1)
    singles = [one_by_one.update(b) for b in batches]
    torch.manual_seed(1)
    many = eager_many.update_many(Batch.interleave(batches), 4)
    torch.manual_seed(1)
    many_compiled = [m for pair in (batches[:2], batches[2:]) for m in compiled_many.update_many(Batch.interleave(pair), 2)]
    assert compiled_many.step_many.active
    assert one_by_one.updates == eager_many.updates == compiled_many.updates == 4
    for single, m, c in zip(singles, many, many_compiled):
        for key in single:
            torch.testing.assert_close(m[key], single[key], rtol=0, atol=0)  # eager: the same numbers
            torch.testing.assert_close(c[key], single[key], rtol=1e-4, atol=1e-5)
    for a, b, c in zip(learned(one_by_one), learned(eager_many), learned(compiled_many)):
        assert torch.equal(b, a)
        torch.testing.assert_close(c, a, rtol=1e-4, atol=1e-5)


@pytest.mark.slow
def test_a_compiled_run_with_several_updates_per_call_learns_bit_flipping(tmp_path, capsys):

    # 2 per call: the path of any K > 1 (4 is the documented choice), at half the compile time of 4
    run = small_run(
        "bitflip-her",
        tmp_path / "run",
        n_bits=6,
        total_steps=3_000,
        eval_interval=3_000,
        updates_per_step=0.25,
        updates_per_call=2,
        compile="default",
    )
    assert run.agent.step_many.active
    assert run.metrics["updates"] == pytest.approx(0.25 * (3_000 - run.config.learning_starts), abs=2 + 32)
    assert run.metrics["updates"] % 2 == 0
    assert run.metrics["success_rate"] >= 0.9  # a random policy: about 0.1 on 6 bits
    assert "compiled the updates (default) in" in capsys.readouterr().err
    from taskrl.agents.compile_rule import cached_calls

    assert cached_calls(run.config) == {2}  # a later run of these shapes expects a later run's compile


def test_updates_per_call_is_refused_where_no_loop_takes_it():
    import taskrl

    with pytest.raises(ConfigError, match="updates_per_call"):
        taskrl.train("pointreach-mt-ppo-onehot", updates_per_call=2)
    with pytest.raises(ConfigError, match="updates_per_call"):
        taskrl.train("bitflip-her", updates_per_call=-1)
    with pytest.raises(ConfigError, match="compile"):
        taskrl.train("pointreach-mt-ppo-onehot", compile="default")


def test_k_batches_drawn_together_are_k_task_balanced_batches():
    import gymnasium as gym

    from taskrl.replay import EpisodeReplay
    from taskrl.replay.sampling import TaskBalancedSampler
    from taskrl.training.offpolicy import batch_sampler

    space = gym.spaces.Dict({"observation": gym.spaces.Box(-1, 1, (2,)), "task": gym.spaces.Discrete(4)})
    replay = EpisodeReplay(space, gym.spaces.Discrete(3), 4_000, num_envs=4, horizon=10)
    g = torch.Generator().manual_seed(0)
    for _ in range(20):  # episodes of every task, task i in env i
        obs = {"observation": torch.rand(4, 2, generator=g), "task": torch.arange(4)}
        replay.start(obs)
        for t in range(10):
            replay.add(torch.zeros(4), -torch.ones(4), torch.zeros(4, dtype=torch.bool), torch.full((4,), t == 9), obs, obs)
    draw = batch_sampler(TaskBalancedSampler(replay, 4), 4 * 32, g)
    batches = draw().split(4)
    assert [len(b) for b in batches] == [32] * 4
    for b in batches:  # each of the 4 keeps the balance: 8 rows of every task
        assert torch.bincount(b.obs["task"], minlength=4).tolist() == [8, 8, 8, 8]
        assert torch.equal(b.next_obs["task"], b.obs["task"])
    rows = torch.cat([b.episode * 10 + b.step for b in batches])
    assert rows.unique().numel() > 100  # distinct draws, not one batch four times


# ---------------------------------------------------------------------- --compile auto (the default)


def _settled(preset: str, **settings):
    from taskrl.overrides import with_overrides
    from taskrl.plan import resolve
    from taskrl.presets import preset_config
    from taskrl.wiring.calls import settle_compile

    notes: list[str] = []
    plan = resolve(with_overrides(preset_config(preset), settings))
    config = settle_compile(plan.config, plan.algorithm, plan.family, notes)
    return config, notes


def test_auto_keeps_a_short_run_eager_and_compiles_a_long_one_four_updates_per_call():
    short, notes = _settled("bitflip-her")  # make demo's run: 5,900 updates, less than compiling would save
    assert (short.compile, short.updates_per_call) == ("off", 1)
    assert len(notes) == 1 and notes[0].startswith("compile: eager (5,900 planned updates")
    long, notes = _settled("bitflip-her", total_steps=2_000_000, updates_per_step=1.0, batch_size=32, hidden_sizes=(64, 64))
    assert (long.compile, long.updates_per_call) == ("default", 4)
    assert "compiled (default), 4 updates per call" in notes[0] and "DQN (64, 64) / 32" in notes[0]


def test_auto_follows_what_is_set_and_stays_eager_where_nothing_was_measured():
    assert _settled("bitflip-her", total_steps=2_000_000, compile="off")[0].updates_per_call == 1
    explicit, notes = _settled("bitflip-her", compile="default", updates_per_call=2)
    assert (explicit.compile, explicit.updates_per_call, notes) == ("default", 2, [])
    chosen, _ = _settled("bitflip-her", total_steps=2_000_000, updates_per_call=1)  # the mode chosen for 1 per call
    assert (chosen.compile, chosen.updates_per_call) == ("default", 1)
    distributed, _ = _settled("fetchpush-sac-her", offline=True, offline_data="x", total_steps=1_000_000)
    assert distributed.updates_per_call == 1  # an offline loop takes one update per call
    assert _settled("grasp-qtopt-pixels", total_steps=10**7)[0].compile == "off"  # conv encoders: not measured
    ppo, notes = _settled("pointreach-mt-ppo-onehot")
    assert ppo.compile == "off" and "no compiled update" in notes[0]


def test_the_estimate_compiles_where_the_planned_updates_pass_the_break_even():
    from taskrl.agents.compile_rule import COMPILE_MARGIN, MEASURED, choose_compile, planned_updates

    dqn = MEASURED[0]  # DQN (64, 64) / 32
    # compiled must be estimated at most COMPILE_MARGIN of eager's time: 0.9x of this is past the margin-free break-even
    break_even = dqn.compile_seconds / ((COMPILE_MARGIN * dqn.eager_ms - dqn.compiled_ms) / 1e3)
    for factor, expected in ((0.9, "off"), (1.1, "default")):
        config, _ = _settled(
            "bitflip-her", batch_size=32, hidden_sizes=(64, 64), updates_per_step=1.0, learning_starts=0, updates_per_call=1
        )
        config = dataclasses.replace(config, compile="auto", total_steps=int(factor * break_even))
        assert planned_updates(config) == int(factor * break_even)
        assert choose_compile(config, compiles=True, many_allowed=False).mode == expected


def test_a_compile_an_earlier_run_made_is_estimated_at_a_later_runs_cost(monkeypatch, tmp_path):
    """Between the break-even of a first compile and that of a later one, auto compiles only where a run of the same
    shapes compiled before (its marker), and says so; other shapes (another n_bits) stay estimated as a first run."""
    from taskrl.agents.compile_rule import LATER_RUN_FACTOR, MEASURED, cached_calls, choose_compile, remember_compiled

    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path))
    dqn = MEASURED[0]  # DQN (64, 64) / 32
    saved = (dqn.eager_ms - dqn.compiled_ms) / 1e3
    updates = int(0.5 * (1 + LATER_RUN_FACTOR) * dqn.compile_seconds / saved)  # between the two break-evens
    config, _ = _settled(
        "bitflip-her", batch_size=32, hidden_sizes=(64, 64), updates_per_step=1.0, learning_starts=0, updates_per_call=1
    )
    config = dataclasses.replace(config, compile="auto", total_steps=updates)
    assert cached_calls(config) == set()
    assert choose_compile(config, compiles=True, many_allowed=False).mode == "off"
    remember_compiled(config, 1)
    assert cached_calls(config) == {1}
    warm = choose_compile(config, compiles=True, many_allowed=False, cached=cached_calls(config))
    assert warm.mode == "default" and "compiled before on this machine" in warm.reason
    other = dataclasses.replace(config, env_settings=dataclasses.replace(config.env_settings, n_bits=9))
    assert cached_calls(other) == set()


def test_a_machines_first_compile_is_estimated_with_its_one_time_cost(monkeypatch, tmp_path):
    """Where nothing compiled on the machine before, a compile costs `MACHINE_FIRST_SECONDS` more: between the two
    break-evens auto stays eager on a fresh machine and compiles on one that compiled other shapes before."""
    from taskrl.agents.compile_rule import (
        MACHINE_FIRST_SECONDS,
        MEASURED,
        choose_compile,
        machine_compiled_before,
        remember_compiled,
    )

    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path))
    dqn = MEASURED[0]  # DQN (64, 64) / 32
    updates = int((dqn.compile_seconds + 0.5 * MACHINE_FIRST_SECONDS) / ((dqn.eager_ms - dqn.compiled_ms) / 1e3))
    config, _ = _settled(
        "bitflip-her", batch_size=32, hidden_sizes=(64, 64), updates_per_step=1.0, learning_starts=0, updates_per_call=1
    )
    config = dataclasses.replace(config, compile="auto", total_steps=updates)
    assert not machine_compiled_before()
    fresh = choose_compile(config, compiles=True, many_allowed=False, machine_compiled=machine_compiled_before())
    assert fresh.mode == "off" and "nothing compiled on this machine before" in fresh.reason
    other = dataclasses.replace(config, env_settings=dataclasses.replace(config.env_settings, n_bits=9))
    remember_compiled(other, 1)  # another network compiled here before
    assert machine_compiled_before()
    assert choose_compile(config, compiles=True, many_allowed=False, machine_compiled=machine_compiled_before()).mode == "default"


def test_the_command_line_takes_auto_and_a_run_says_its_choice_first(tmp_path):
    from helpers import cli_train

    done = cli_train("bitflip-her", "--n-bits", "4", "--total-steps", "300", "--eval-interval", "300", "--eval-episodes", "4", "--learning-starts", "100",
                     "--updates-per-call", "auto", "--out", str(tmp_path / "run"))  # fmt: skip
    assert done.returncode == 0, done.stderr
    first = done.stderr.strip().splitlines()[0]
    assert first.startswith("note: compile: eager (")
    saved = json.loads((tmp_path / "run" / "config.json").read_text())
    assert (saved["compile"], saved["updates_per_call"]) == ("off", 1)  # what the run did, for --resume


def test_compiled_graphs_are_kept_in_the_users_cache_directory(monkeypatch, tmp_path):
    from taskrl.agents.compiled import compile_cache_dir

    monkeypatch.delenv("TORCHINDUCTOR_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert compile_cache_dir() == str(tmp_path / "taskrl" / "torch-compile")
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", "/elsewhere")
    assert compile_cache_dir() == "/elsewhere"  # the user's own setting wins
