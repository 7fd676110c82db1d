"""Contracts generated from the registries: every registered env family × algorithm × run mode that
declares it fits builds, acts, updates, saves and loads; every sharing strategy runs; no two settings
sections share a flag. A family, algorithm or mode added to a registry is in these tests at once; one
with nothing here to run it on fails :func:`test_every_registered_family_has_a_smallest_setting`."""

from __future__ import annotations

import dataclasses
import functools
import itertools
from pathlib import Path
from typing import Any

import pytest
import torch

import taskrl
from taskrl.agents.registry import ALGORITHMS
from taskrl.config import TrainConfig
from taskrl.encoders import PICTURE_ENCODERS
from taskrl.envs.registry import ENV_FAMILIES
from taskrl.errors import ConfigError
from taskrl.fit import check_fit
from taskrl.overrides import with_overrides
from taskrl.runmodes import distributed as distributed_mode
from taskrl.runmodes.registry import RUN_MODES, run_mode
from taskrl.setting_names import leaf_fields
from taskrl.sharing.registry import SHARING_STRATEGIES
from taskrl.tasks import TaskSet, TaskSpec

#: env ids for the families built on gymnasium ids, by the algorithm's action space (a task set's envs need
#: Box observations: CartPole for discrete actions there)
GYM_IDS = {"discrete": "taskrl/BitFlip-v0", "box": "taskrl/PointReach-v0"}
TASK_IDS = {"discrete": "CartPole-v1", "box": "taskrl/PointReach-v0"}
#: MuJoCo families: one generated run is 5 s (Fetch) to minutes (Meta-World's 500-step episodes, 10-50 copies), past
#: what the suite can hold for every algorithm and mode; their own tests train them (test_metaworld_runs,
#: test_multitask_sac, test_imitation, test_distributed's FetchReach runs). Generated here: building and acting.
HEAVY = {"fetchreach", "fetchpush", "fetchpickandplace", "fetchslide", "mt1", "mt10", "mt50", "ml45"}
#: each family's smallest settings (a family missing here fails the test below)
SMALLEST: dict[str, dict[str, Any]] = {
    "bitflip": {"n_bits": 4},
    "pointreach": {},
    "pixelreach": {"image_size": 16},
    "pixelpush": {"image_size": 16},
    "tabletop": {"image_size": 32},  # its datasets are collected at 32
    "fetchreach": {},
    "fetchpush": {},
    "fetchpickandplace": {},
    "fetchslide": {},
    "pointreach-mt": {"num_envs": 5},
    "gridtasks": {"num_envs": 4},
    "pointtasks": {"num_envs": 4},
    "grasp": {"image_size": 16},
    "kukagrasp": {"image_size": 16, "num_objects": 1, "vector_strategy": "sync"},
    "mt1": {},
    "mt10": {"num_envs": 10},
    "mt50": {"num_envs": 50},
    "ml45": {"num_envs": 45},
    "gym": {},
    "tasks": {"num_envs": 2},
}
#: what each run mode needs beyond a family and an algorithm (``None``: not generated here, with the reason)
MODE_SETTINGS: dict[str, dict[str, Any]] = {
    "off_policy": {},
    "on_policy": {"rollout_steps": 4},
    "dataset": {},  # a dataset of the family's scripted experts: the `demos` fixture
    "stored_data": {"offline": True, "dataset_quality": "top-left=expert", "dataset_steps": 40},
    "distributed": {"distributed": True, "collectors": 1, "collector_steps": 4},
}


def _task_set(kind: str) -> TaskSet:
    return TaskSet([TaskSpec(f"t{i}", f"Task {i}.", i, TASK_IDS[kind], {}) for i in range(2)])


def _fits(family: str, algo: str, mode: str) -> bool:
    """Whether the family, algorithm and mode declare that they run together (before anything is built)."""
    spec, env = ALGORITHMS[algo], ENV_FAMILIES[family]
    if spec.loop not in RUN_MODES[mode].loops:
        return False
    if mode == "stored_data" and not hasattr(env.settings(), "dataset_quality"):
        return False  # stored data comes from the family's datasets here (or another run's replay)
    if mode == "dataset" and env.demos is None:
        return False  # an offline algorithm learns from demonstrations of the family's scripted expert
    config = with_overrides(TrainConfig(), {"env": family, "algo": algo, "her": "none"})
    try:
        check_fit(config, env.kind, env.actions, env.images)
    except ConfigError:
        return False
    return True


CASES = [
    pytest.param(f, a, m, id=f"{f}-{a}-{m}")
    for f, a, m in itertools.product(ENV_FAMILIES, ALGORITHMS, RUN_MODES)
    if f not in HEAVY and _fits(f, a, m)
]


def test_every_registered_family_has_a_smallest_setting():
    assert set(SMALLEST) == set(ENV_FAMILIES), "add the new family's smallest settings to SMALLEST"
    assert set(MODE_SETTINGS) == set(RUN_MODES), "add what the new run mode needs to MODE_SETTINGS"
    modes = {m for _, _, m in (c.values for c in CASES)}
    assert modes == set(RUN_MODES)  # every mode runs on at least one family and algorithm


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    """``family -> dataset folder`` of two demonstrations per task of the family's scripted expert."""
    from taskrl.cli import main

    made: dict[str, Path] = {}

    def of(family: str) -> Path:
        if family not in made:
            out = tmp_path_factory.mktemp("demos") / family
            assert main(["demos", "collect", family, "--out", str(out), "--episodes", "2", "--no-progress"]) == 0
            made[family] = out
        return made[family]

    return of


@pytest.fixture
def local_roles(monkeypatch):
    """The distributed mode with its roles in this process (the same loop, no Ray): Ray itself is tested in
    test_distributed."""
    local = dataclasses.replace(
        RUN_MODES["distributed"],
        make_loop=functools.partial(distributed_mode.distributed_loop, pool=distributed_mode.local_pool),
        prepare=None,
    )
    monkeypatch.setitem(RUN_MODES, "distributed", local)
    return local


@pytest.mark.parametrize("family, algo, mode", CASES)
def test_every_fitting_family_algorithm_and_run_mode_trains_saves_and_loads(family, algo, mode, tmp_path, request):
    kind = ALGORITHMS[algo].actions[0]
    settings: dict[str, Any] = {**SMALLEST[family], **MODE_SETTINGS[mode]}
    env: Any = family
    if family == "gym":
        env = GYM_IDS[kind]
    elif family == "tasks":
        env = _task_set(kind)
    if mode == "dataset":
        settings["dataset"] = str(request.getfixturevalue("demos")(family))
    if mode == "distributed":
        request.getfixturevalue("local_roles")
    num_envs = settings.pop("num_envs", 2)
    budget = 60 * num_envs if mode != "on_policy" else 8 * num_envs  # past the first complete episodes
    smallest_run = dict(
        tensorboard=False,
        her="none",
        hidden_sizes=(16,),
        total_steps=budget if mode not in ("dataset", "stored_data") else 3,
        learning_starts=num_envs,
        updates_per_step=1,
        batch_size=4,
        eval_episodes=1,
        eval_interval=10**6,
    )
    # a mode's own settings win over the smallest run's (a mode may need, say, its own update ratio)
    run = taskrl.train(
        None, base=TrainConfig(), out=tmp_path / "run", env=env, algo=algo, num_envs=num_envs, **{**smallest_run, **settings}
    )
    assert run_mode(run.config).name == mode
    assert run.metrics["updates"] >= 1, run.metrics  # it learned from something
    source = env if family == "tasks" else None
    agent = taskrl.load(run.run_dir, env=source)
    for mine, loaded in zip(run.agent.state_dict().values(), agent.state_dict().values()):
        if isinstance(mine, torch.Tensor):
            assert torch.equal(mine.cpu(), loaded.cpu())  # saved and loaded as trained


@pytest.mark.parametrize("strategy", list(SHARING_STRATEGIES))
def test_every_sharing_strategy_runs(strategy, tmp_path):
    run = taskrl.train(
        "grid-sharing-dqn",
        out=tmp_path / "run",
        tensorboard=False,
        sharing=strategy,
        total_steps=64,
        learning_starts=16,
        batch_size=8,
        eval_interval=10**6,
        eval_episodes=1,
    )
    assert run.metrics["updates"] >= 1


def test_every_setting_of_every_section_pair_has_its_own_flag_and_reaches_its_own_field():
    """Every family's section beside every algorithm's and the run's: each setting's dotted flag sets that
    setting and nothing else, whatever the other sections are called."""
    from taskrl.commands.parsing import Parser, add_config_flags
    from taskrl.setting_names import dotted_name, setting_names

    unreached = {}
    for env, algo in itertools.product(ENV_FAMILIES, ALGORITHMS):
        parser = Parser()
        add_config_flags(parser, env, algo)
        dests = {f: a.dest for a in parser._actions for f in a.option_strings}
        names = setting_names(env, algo)
        for path, _, _ in leaf_fields(env, algo):
            dotted = dotted_name(path, env, algo)
            flag = "--" + dotted.replace("_", "-")
            if dests.get(flag) != dotted or names.resolve(dotted, env, algo) != path:
                unreached.setdefault((env, algo), []).append(flag)
    assert not unreached


def test_a_short_name_two_sections_share_is_refused_in_one_line_naming_both_dotted_flags(monkeypatch, capsys):
    """A variant algorithm with a setting named like the env's (``n_bits``): both stay reachable by their
    dotted names, the short name is no alias of either, and using it names both spellings."""
    import dataclasses as dc

    from taskrl.cli import main

    @dc.dataclass
    class Clashing(ALGORITHMS["dqn"].config):
        n_bits: int = 3

    monkeypatch.setitem(ALGORITHMS, "dqn-clash", dc.replace(ALGORITHMS["dqn"], name="dqn-clash", config=Clashing))
    config = with_overrides(TrainConfig(), {"algo": "dqn-clash", "env.n_bits": 7, "algo.n_bits": 5})
    assert config.env_settings.n_bits == 7 and config.algo_settings.n_bits == 5
    with pytest.raises(ConfigError, match=r"n_bits.*env\.n_bits or algo\.n_bits"):
        with_overrides(TrainConfig(), {"algo": "dqn-clash", "n_bits": 7})
    assert main(["train", "bitflip-her", "--algo", "dqn-clash", "--n-bits", "7", "--print-config"]) == 2
    assert "--n-bits is a setting of several sections here: say --env.n-bits or --algo.n-bits" in capsys.readouterr().err


HEAVY_CASES = [
    pytest.param(f, a, id=f"{f}-{a}", marks=pytest.mark.slow)
    for f, a in itertools.product(sorted(HEAVY), ALGORITHMS)
    if any(_fits(f, a, m) for m in RUN_MODES)
]


@pytest.mark.parametrize("family, algo", HEAVY_CASES)
def test_every_fitting_algorithm_builds_and_acts_on_the_mujoco_families(family, algo):
    """The MuJoCo families' spaces (without building Meta-World) give every fitting algorithm an agent that acts."""
    from taskrl.envs.spec import EnvRequest
    from taskrl.wiring.parts import make_agent

    config = with_overrides(TrainConfig(), {"env": family, "algo": algo, "her": "none", "hidden_sizes": (16,)})
    spec = ENV_FAMILIES[family]
    request = EnvRequest(num_envs=1, seed=0, device=torch.device("cpu"))
    env = spec.spec(config.env_settings, request) if spec.spec is not None else spec.make(config.env_settings, request)
    try:
        agent = make_agent(config, env, torch.device("cpu"))
        obs = {k: torch.as_tensor(v[None]) for k, v in env.single_observation_space.sample().items()}
        action = agent.act(obs)
        assert env.single_action_space.contains(action[0].numpy().astype(env.single_action_space.dtype))
    finally:
        env.close()


@pytest.mark.parametrize("strategy", [name for name, spec in SHARING_STRATEGIES.items() if spec.shares])
def test_what_a_sharing_strategy_needs_is_refused_from_the_declarations_before_anything_is_built(strategy, monkeypatch):
    from taskrl.plan import validate

    refused = 0
    for family in ENV_FAMILIES.values():
        if family.task_rewards is False and family.kind == "multitask" and family.name not in HEAVY:
            settings = {"env": family.name, "algo": "sac", "her": "none", "sampling": "task_balanced", "sharing": strategy}
            config = with_overrides(TrainConfig(), {**settings, **SMALLEST[family.name]})
            with pytest.raises(ConfigError, match="reward functions"):
                validate(config)
            refused += 1
    assert refused >= 2
    # an algorithm that declares no Q-values, on a strategy that ranks rows by them
    monkeypatch.setitem(ALGORITHMS, "sac", dataclasses.replace(ALGORITHMS["sac"], q_values=False))
    config = with_overrides(
        TrainConfig(),
        {"env": "pointtasks", "algo": "sac", "her": "none", "sampling": "task_balanced", "sharing": strategy, "num_envs": 6},
    )
    if SHARING_STRATEGIES[strategy].needs_q_value:
        with pytest.raises(ConfigError, match="ranks shared data by Q-values"):
            validate(config)
    else:
        validate(config)


def test_two_settings_that_switch_on_two_run_modes_are_one_line_naming_both():
    """A user's collect-only mode switched on by its own setting, beside --offline: refused, never one of the
    two picked by registration order."""
    import dataclasses

    from taskrl.overrides import with_overrides
    from taskrl.presets import preset_config
    from taskrl.runmodes.registry import register_run_mode
    from taskrl.runmodes.spec import RunMode

    collect = RunMode(
        name="collect_only",
        summary="a test's mode: collects, never updates",
        applies=lambda config: config.data.scripted_exploration == 1.0,
        make_loop=lambda parts, books: None,
        loops=("off_policy",),
        selected_by="scripted_exploration",
    )
    register_run_mode(collect)
    try:
        config = with_overrides(preset_config("grasp-qtopt-pixels"), {"scripted_exploration": 1.0})
        assert run_mode(config) is collect  # alone it is chosen
        both = dataclasses.replace(config, data=dataclasses.replace(config.data, offline=True))
        with pytest.raises(
            ConfigError,
            match=r"^scripted_exploration: --scripted-exploration selects the collect_only run mode and --offline the stored_data one",
        ):
            run_mode(both)
    finally:
        RUN_MODES.pop("collect_only")


def test_a_named_run_mode_is_used_where_it_fits_and_refused_in_one_line_where_it_does_not(capsys):
    """``--mode NAME`` picks a mode that applies over the one registration order would (a user's mode registered
    before a built-in), and one that does not apply is one line naming the mode the settings select."""
    import dataclasses

    from taskrl.cli import main
    from taskrl.presets import preset_config
    from taskrl.runmodes.spec import RunMode

    early = RunMode(
        "early", "a test's mode: off-policy, registered first", lambda c: True, lambda parts, books: None, ("off_policy",)
    )
    saved = dict(RUN_MODES)
    RUN_MODES.clear()
    RUN_MODES.update({"early": early, **saved})  # registered before every built-in: auto never picks it
    try:
        config = preset_config("bitflip-her")
        assert run_mode(config).name == "off_policy"
        assert run_mode(dataclasses.replace(config, mode="early")) is early
        assert run_mode(dataclasses.replace(config, mode="off_policy")).name == "off_policy"
    finally:
        RUN_MODES.clear()
        RUN_MODES.update(saved)
    with pytest.raises(ConfigError, match=r"names the distributed run mode \(switched on by --distributed\).*select off_policy"):
        run_mode(dataclasses.replace(config, mode="distributed"))
    assert main(["train", "bitflip-her", "--mode", "stored_data", "--total-steps", "10"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("taskrl train: error: --mode names the stored_data run mode"), err


#: the algorithms that read pictures, and the picture family each trains on here
PICTURE_RUNS = {"qtopt": "grasp", "sac": "grasp", "bc": "tabletop"}


def test_every_algorithm_that_reads_pictures_is_generated_here():
    assert set(PICTURE_RUNS) == {name for name, spec in ALGORITHMS.items() if spec.images}


#: each picture-reading algorithm, and QT-Opt again with the action inside the encoder (``fusion=conv``) and with a
#: glimpse around the gripper beside the whole picture (``fusion=glimpse``, the pose moved with the shift)
PICTURE_ARMS = [(algo, {}) for algo in PICTURE_RUNS] + [
    ("qtopt", {"fusion": "conv"}),
    ("qtopt", {"fusion": "glimpse", "shift_coordinates": True}),
]


@pytest.mark.parametrize(
    "encoder, algo, arm",
    [(e, a, arm) for e in PICTURE_ENCODERS for a, arm in PICTURE_ARMS] if "PICTURE_ENCODERS" in globals() else [],
    ids=lambda v: ",".join(f"{k}={x}" for k, x in v.items()) if isinstance(v, dict) else str(v),
)
def test_every_picture_encoder_trains_with_every_algorithm_that_reads_pictures(encoder, algo, arm, tmp_path, request):
    """A registered encoder is one every picture-reading algorithm trains with (the named encoder is the one built), or
    refuses in one line before building (behaviour cloning: an encoder without FiLM blocks; QT-Opt's ``fusion=conv``:
    one that declares no layer for a late input). Mutations: every name building the conv stack (`picture_encoder`)
    fails it; the fused network building the conv stack's early layers whatever the encoder fails it."""
    encoder_name = encoder
    family = PICTURE_RUNS[algo]
    settings: dict[str, Any] = {**SMALLEST[family], "encoder": encoder, **arm}
    if algo == "bc":
        settings["dataset"] = str(request.getfixturevalue("picture_demos"))
    train = functools.partial(
        taskrl.train, None, base=TrainConfig(), out=tmp_path / "run", env=family, algo=algo, num_envs=2, tensorboard=False
    )
    tiny = dict(
        her="none", hidden_sizes=(16,), learning_starts=2, updates_per_step=1, batch_size=4, eval_episodes=1, eval_interval=10**6
    )
    spec, size = PICTURE_ENCODERS[encoder_name], SMALLEST[family]["image_size"]
    fused = arm.get("fusion") == "conv"
    if (algo == "bc" and spec.film_blocks is None) or (fused and spec.late_input is None):
        with pytest.raises(ConfigError, match="encoder"):
            train(total_steps=3, **{**tiny, **settings})
        assert not (tmp_path / "run").exists()
        return
    run = train(total_steps=3 if algo == "bc" else 40, **{**tiny, **settings})
    assert run.metrics["updates"] >= 1 and run.config.algo_settings.encoder == encoder
    loaded = taskrl.load(run.run_dir)
    encoder = (lambda agent: agent.q.state_input) if algo == "qtopt" else (lambda agent: agent.encoder)  # noqa: E731
    if fused:
        built, named = encoder(run.agent).convs, spec.late_input(3, True)
    elif algo == "bc":
        built, named = encoder(run.agent).blocks, torch.nn.ModuleList(b for b, _ in spec.film_blocks(3, False))
    elif arm.get("fusion") == "glimpse":  # the whole picture's encoder and the glimpse's, both of the named kind
        glimpse = encoder(run.agent)
        built = torch.nn.ModuleList([glimpse.whole.trunk, glimpse.local.trunk])
        named = torch.nn.ModuleList([spec.trunk(3, size, size, True), spec.trunk(3, glimpse.size, glimpse.size, True)])
    else:
        built, named = encoder(run.agent).trunk, spec.trunk(3, size, size, True)
    assert [p.shape for p in built.parameters()] == [p.shape for p in named.parameters()]  # the named encoder was built
    for mine, saved in zip(encoder(run.agent).state_dict().values(), encoder(loaded).state_dict().values()):
        assert torch.equal(mine, saved)


@pytest.fixture(scope="module")
def picture_demos(tmp_path_factory):
    """Two tabletop demonstrations per task, with their 32x32 pictures."""
    from taskrl.cli import main

    out = tmp_path_factory.mktemp("picture-demos") / "tabletop"
    assert main(["demos", "collect", "tabletop", "--out", str(out), "--episodes", "2", "--no-progress"]) == 0
    return out


def test_every_family_with_a_camera_shares_one_camera_setting_validated_in_one_place():
    """The families whose settings have a picture size take it from `CameraSettings`, and refuse a size outside its
    one range with the same line."""
    from taskrl.envs.camera import IMAGE_SIZES, CameraSettings

    cameras = [f for f in ENV_FAMILIES.values() if "image_size" in {x.name for x in dataclasses.fields(f.settings)}]
    assert {f.name for f in cameras} >= {"pixelreach", "pixelpush", "tabletop", "grasp", "kukagrasp", "fetchreach", "mt10"}
    messages = set()
    for family in cameras:
        assert issubclass(family.settings, CameraSettings), family.name
        named = {"env_id": GYM_IDS["box"]} if "env_id" in {x.name for x in dataclasses.fields(family.settings)} else {}
        for size in (IMAGE_SIZES[0] - 1, IMAGE_SIZES[1] + 1):
            with pytest.raises(ConfigError) as refused:
                family.settings(image_size=size, **named).validate()
            assert refused.value.field == "image_size", family.name
            messages.add(refused.value.message.replace(str(size), "N"))
        family.settings(image_size=IMAGE_SIZES[0], **named).validate()
    assert len(messages) == 1, messages


@pytest.mark.parametrize(
    "family, algo, own",
    [("grasp", "sac", 4), ("grasp", "qtopt", 4), ("tabletop", "bc", 2)],
)
def test_the_cameras_shift_is_the_one_the_agent_trains_with(family, algo, own, tmp_path):
    """``--shift`` is the camera's (one setting for every algorithm that reads pictures); -1, its default, is the
    algorithm's own (DrQ's 4, behaviour cloning's 2). A run directory written when the shift was each algorithm's
    ``augment_pad`` loads with that shift on the camera. Mutation: `make_agent` not passing the camera's shift fails."""
    import json

    from taskrl.config import load, save
    from taskrl.wiring.parts import make_agent, make_env

    base = with_overrides(TrainConfig(), {"env": family, "algo": algo, "her": "none", "image_size": 16, "num_envs": 2})
    env = make_env(base, "cpu")
    try:
        for shift, expected in ((-1, own), (0, 0), (3, 3)):
            config = with_overrides(base, {"shift": shift})
            assert make_agent(config, env, torch.device("cpu")).picture_shift == expected, shift
    finally:
        env.close()
    for bad in (-2, 9):
        with pytest.raises(ConfigError) as refused:
            with_overrides(base, {"shift": bad}).env_settings.validate()
        assert refused.value.field == "shift" and "-1" in refused.value.message
    save(base, tmp_path / "config.json")
    old = json.loads((tmp_path / "config.json").read_text())
    old[base.env_section].pop("shift")
    old[algo]["augment_pad"] = 1
    (tmp_path / "config.json").write_text(json.dumps(old))
    assert load(tmp_path / "config.json").env_settings.shift == 1
