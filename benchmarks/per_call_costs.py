"""Side-by-side timings of the per-call costs taskrl's compiled update and sampler cut, each against the
path it replaced, in one process and in alternating blocks (the machine's drift falls on both alike):

- ``stance``: a compiled DQN update entered under ``torch.compiler.set_stance("fail_on_recompile")``
  (what ``CompiledStep`` does once a graph exists) against entering Dynamo's compile settings
  (``torch._dynamo.config.patch``) at every call;
- ``size asserts``: the compiled update without Inductor's size asserts (taskrl's option) against with;
- ``C++ wrapper``: the compiled update with the graph's wrapper generated as C++ (taskrl's option on CPU)
  against Inductor's Python wrapper;
- ``Adam scalars``: the compiled update with taskrl's Adam step (the step sizes, bias corrections and clip
  scale computed once into one small buffer) against torch's functional Adam (``capturable=True``), whose
  compiled kernel recomputes them for every 8 elements;
- ``clip norm``: the compiled update with the gradient norms as one ``vector_norm`` per gradient (reductions
  Inductor generates) against ``torch._foreach_norm`` (a call out of the graph);
- ``obs concat``: the compiled update with the integer observation parts cast to float before their concat
  (Inductor generates the concat as one kernel) against concatenating them first (a call out of the graph);
- ``split``: 4 updates per call (``agent.update_many(batch, 4)``) with the 4 batches split out of the drawn
  batch inside the compiled graph (taskrl's path) against split eagerly before the call and passed to the
  graph as 4 batches;
- ``CARE encoders``: the ``mt10-sac-care`` preset's SAC update (batch 1280, 10 tasks, random data), eager and
  compiled, with CARE's k encoders run one at a time (``CAREEncoder.encoding``, taskrl's path) against all k as
  one batched matmul per layer mixed by an ``einsum``;
- ``ReLU in place``: the ``mt10-sac-onehot``, ``mt10-sac-care`` and ``mt10-sac-film-language`` presets' eager SAC updates with the networks'
  ReLUs in place (``nets.activation_after``, taskrl's) against out of place.
- ``picture shift``: DrQ's random shift of 64 pictures of 64x64x3 (uint8, a pad of 4) as one gather of whole pixels
  from the clamped rows and columns (``encoders.random_shift_moves``, taskrl's) against building the replicate-padded
  picture and cropping it with two gathers; then ``grasp-qtopt-pixels``' eager QT-Opt update (batch 64, pictures
  and next pictures shifted) with each, the preset's (the glimpse) and ``--fusion flat --no-shift-coordinates``'.
  Its own section.

    cd benchmarks && ../.venv/bin/python per_call_costs.py [--only stance 'size asserts' 'C++ wrapper' 'Adam scalars' 'clip norm' 'obs concat' split 'CARE encoders' 'ReLU in place' 'picture shift'] [--write]
"""

from __future__ import annotations

import contextlib
import functools
import statistics
import types

import torch

from common import alternating_blocks, append_results, micro_benchmark_args

ROUNDS, BLOCK = 30, 400
#: what ``--only`` can choose
PAIRS = (
    "stance",
    "size asserts",
    "C++ wrapper",
    "Adam scalars",
    "clip norm",
    "obs concat",
    "split",
    "CARE encoders",
    "ReLU in place",
    "picture shift",
)
SHIFT_TITLE = "Per-call costs of the pictures' random shift, side by side"


def _row(what: str, old: str, new: str, a: list[float], b: list[float]) -> str:
    ratios = sorted(y / x for x, y in zip(a, b))
    return (
        f"| {what} | {old}: {statistics.median(a):.3f} | {new}: {statistics.median(b):.3f} | "
        f"{statistics.median(ratios):.3f} ({ratios[len(ratios) // 4]:.3f}-{ratios[3 * len(ratios) // 4]:.3f}) |"
    )


def _patched_every_call(step) -> None:
    """Make ``step`` (a CompiledStep) enter Dynamo's compile settings at every call, as before the stance."""

    from taskrl.agents.compiled import COMPILE_SETTINGS

    def run(self, *args):
        with torch._dynamo.config.patch(**COMPILE_SETTINGS):
            return self.compiled(*args)

    step._run = types.MethodType(run, step)


def _recompiled(**overrides):
    """A patch that recompiles a step with taskrl's compile options but ``overrides`` (the path an option replaced)."""

    def patch(step) -> None:
        from taskrl.agents.compiled import compile_options

        options = {**compile_options(step.mode), **overrides}
        step.compiled = torch.compile(step.fn, fullgraph=True, dynamic=False, options=options)

    return patch


def concat_then_cast(self, obs):
    """The compiled observation concat taskrl's ``nets.ObsConcat`` replaced: the concat, then one cast."""
    parts = [obs[k].flatten(1) for k in self.keys]
    return torch.cat(parts, dim=1).float()


def torch_functional_adam_step(optimizer, loss, clipped, max_grad_norm) -> None:
    """The compiled Adam step taskrl's ``parts.functional_adam_step`` replaced: torch's functional Adam."""
    from torch.optim.adam import adam

    group = optimizer.param_groups[0]
    grads = torch.autograd.grad(loss, group["params"], allow_unused=True)
    reached = [(p, g) for p, g in zip(group["params"], grads) if g is not None]
    with torch.no_grad():
        if max_grad_norm > 0:
            is_clipped = [any(p is c for c in clipped) for p, _ in reached]
            norms = torch._foreach_norm([g for (_, g), c in zip(reached, is_clipped) if c])
            scale = (max_grad_norm / (torch.linalg.vector_norm(torch.stack(norms)) + 1e-6)).clamp(max=1.0)
            reached = [(p, g * scale if c else g) for (p, g), c in zip(reached, is_clipped)]
        state = [optimizer.state[p] for p, _ in reached]
        beta1, beta2 = group["betas"]
        adam(
            *([p for p, _ in reached], [g for _, g in reached]),
            *([s["exp_avg"] for s in state], [s["exp_avg_sq"] for s in state], [], [s["step"] for s in state]),
            foreach=True,
            capturable=True,
            amsgrad=False,
            beta1=beta1,
            beta2=beta2,
            lr=group["lr"],
            weight_decay=group["weight_decay"],
            eps=group["eps"],
            maximize=False,
        )


@contextlib.contextmanager
def _replaced(module: str, name: str, value):
    """While open, ``module.name`` is ``value``: compiled steps trace (and their guards expect) the replaced path."""
    import importlib

    try:
        where = importlib.import_module(module)
    except ModuleNotFoundError:  # a class: module.Class
        module, _, cls = module.rpartition(".")
        where = getattr(importlib.import_module(module), cls)
    ours = getattr(where, name)
    setattr(where, name, value)
    try:
        yield
    finally:
        setattr(where, name, ours)


def compiled_pairs(batch_size: int, hidden: tuple[int, ...], only: list[str]) -> list[str]:
    from learner_speed import bitflip_agent_and_batch

    rows = []
    adam = ("taskrl.agents.parts", "functional_adam_step", torch_functional_adam_step)
    # (what, the replaced path, taskrl's path, a one-time patch of the replaced agent's step, or a function
    # swapped in while the replaced agent traces and runs)
    for what, old, new, patch, swapped in (
        ("stance", "settings every call", "stance", _patched_every_call, None),
        ("size asserts", "with", "without", _recompiled(size_asserts=True), None),
        ("C++ wrapper", "Python wrapper", "C++ wrapper", _recompiled(cpp_wrapper=False), None),
        ("Adam scalars", "torch's functional Adam", "taskrl's Adam", None, adam),
        (
            "clip norm",
            "_foreach_norm",
            "a vector_norm each",
            None,
            ("taskrl.agents.parts", "gradient_norms", torch._foreach_norm),
        ),
        ("obs concat", "concat, then cast", "cast, then concat", None, ("taskrl.nets.ObsConcat", "forward", concat_then_cast)),
    ):
        if what not in only:
            continue
        ours, batch, _ = bitflip_agent_and_batch(batch_size, hidden, False)
        theirs = bitflip_agent_and_batch(batch_size, hidden, False)[0]
        for agent in (ours, theirs):
            agent.compile("default", say=lambda line: None)
        if patch is not None:
            patch(theirs.step)
        replaced = functools.partial(_replaced, *swapped) if swapped else contextlib.nullcontext
        for agent, context in ((ours, contextlib.nullcontext), (theirs, replaced)):
            with context():
                for _ in range(250):  # both graphs of the target schedule, and a warm start
                    agent.update(batch)
        block = BLOCK if batch_size <= 64 else BLOCK // 4

        def run(agent, block=block, batch=batch, context=contextlib.nullcontext):
            with context():
                for _ in range(block):
                    agent.update(batch)
            return block

        ms = alternating_blocks(
            {"a": lambda theirs=theirs, replaced=replaced: run(theirs, context=replaced), "b": lambda ours=ours: run(ours)},
            ROUNDS,
        )
        a, b = ms["a"], ms["b"]
        rows.append(_row(f"compiled DQN {list(hidden)} / {batch_size} update, {what}", old, new, a, b))
        print(rows[-1], flush=True)
    return rows


def split_before_the_call(agent, batch, k: int) -> list:
    """The K-updates call taskrl's in-graph split replaced: ``batch`` split eagerly, the K batches passed to a
    graph of the K updates (``agent.step_each``, made by :func:`split_pairs`)."""
    flags = tuple(agent.schedule(agent.updates + i + 1) for i in range(k))
    agent.updates += k
    return agent.step_each(tuple(batch.split(k)), flags)


def split_pairs(batch_size: int, hidden: tuple[int, ...], k: int = 4) -> list[str]:
    from learner_speed import bitflip_agent_and_batch
    from taskrl.agents.compiled import CompiledStep

    ours, batch, _ = bitflip_agent_and_batch(k * batch_size, hidden, False)  # one drawn batch of K x B rows
    theirs = bitflip_agent_and_batch(k * batch_size, hidden, False)[0]
    ours.compile("default", say=lambda line: None)
    optimizers = [theirs.optimizer]
    theirs.step_each = CompiledStep(
        lambda batches, flags: [theirs.learn(b, *f) for b, f in zip(batches, flags)], "default", optimizers, what="updates"
    )
    calls = {"a": lambda: split_before_the_call(theirs, batch, k), "b": lambda: ours.update_many(batch, k)}
    for _ in range(-(-250 // k)):  # both graphs of the target schedule, and a warm start
        for call in calls.values():
            call()
    assert ours.step_many.active and theirs.step_each.active

    def run(call, block=BLOCK // 4 if batch_size > 64 else BLOCK // k):
        for _ in range(block):
            call()
        return block

    ms = alternating_blocks({name: functools.partial(run, call) for name, call in calls.items()}, ROUNDS)
    row = _row(
        f"compiled DQN {list(hidden)} / {batch_size}, {k} updates per call", "split before", "split inside", ms["a"], ms["b"]
    )
    print(row, flush=True)
    return [row]


def batched_care_forward(self, state, context, return_weights=False):
    """The CARE mixture taskrl's one-encoder-at-a-time ``CAREEncoder.forward`` replaced: the k encoders as one
    batched matmul per layer (``[k, B, hidden]`` activations), mixed by an ``einsum``."""
    weights = self.attention_weights(context)
    mixed = torch.einsum("kbd,bk->bd", self.encodings(state), weights)
    out = torch.cat([mixed, context], dim=-1)
    return (out, weights) if return_weights else out


def _mt10_twins(preset: str):
    """Two agents of an MT10 preset with the same parameters, and a random batch of their shapes."""
    from learner_speed import mt10_agent_and_batch

    (ours, batch, _), (theirs, _, _) = mt10_agent_and_batch(preset), mt10_agent_and_batch(preset)
    theirs.load_state_dict(ours.state_dict())
    return ours, theirs, batch


def care_pairs(rounds: int = 10, block: int = 2) -> list[str]:
    ours, theirs, batch = _mt10_twins("mt10-sac-care")
    replaced = functools.partial(_replaced, "taskrl.conditioning.care.CAREEncoder", "forward", batched_care_forward)
    with torch.no_grad():  # the same encodings either way, on the same parameters
        mixture = next(m for m in ours.actor.modules() if type(m).__name__ == "CAREEncoder")
        state, context = torch.randn(1280, mixture.state_dim), torch.randn(1280, mixture.context_dim)
        with replaced():
            before = mixture(state, context)
        torch.testing.assert_close(mixture(state, context), before)
    rows = []
    for mode in ("off", "default"):
        for agent in (ours, theirs):
            agent.compile(mode, say=lambda line: None)
        for agent, context in ((ours, contextlib.nullcontext), (theirs, replaced)):
            with context():
                for _ in range(3):  # a compile, and a warm start
                    agent.update(batch)

        def run(agent, context=contextlib.nullcontext):
            with context():
                for _ in range(block):
                    agent.update(batch)
            return block

        ms = alternating_blocks({"a": lambda: run(theirs, replaced), "b": lambda: run(ours)}, rounds)
        what = "eager" if mode == "off" else "compiled"
        rows.append(
            _row(f"{what} MT10 SAC CARE update (k = 4, batch 1280)", "k encoders batched", "one at a time", ms["a"], ms["b"])
        )
        print(rows[-1], flush=True)
    return rows


def relu_pairs(rounds: int = 10, block: int = 2) -> list[str]:
    rows = []
    for preset in ("mt10-sac-onehot", "mt10-sac-care", "mt10-sac-film-language"):
        ours, theirs, batch = _mt10_twins(preset)
        relus = [m for net in (theirs.actor, theirs.critics, theirs.critics_target) for m in net.modules()]
        for m in relus:
            if isinstance(m, torch.nn.ReLU):
                m.inplace = False
        torch.manual_seed(0)
        first = ours.update(batch)
        torch.manual_seed(0)
        second = theirs.update(batch)
        assert all(torch.equal(v, second[k]) for k, v in first.items())  # the same update, to the bit
        assert all(torch.equal(a, b) for a, b in zip(ours.actor.parameters(), theirs.actor.parameters()))

        def run(agent, batch=batch):
            for _ in range(block):
                agent.update(batch)
            return block

        ms = alternating_blocks({"a": lambda theirs=theirs: run(theirs), "b": lambda ours=ours: run(ours)}, rounds)
        rows.append(_row(f"eager {preset} SAC update (batch 1280)", "out of place", "in place", ms["a"], ms["b"]))
        print(rows[-1], flush=True)
    return rows


def pad_and_crop_shift(images: torch.Tensor, pad: int, generator: torch.Generator | None = None):
    """The shift taskrl's one-gather ``random_shift_moves`` replaced: the replicate-padded float picture built, then
    cropped at the drawn offsets by a gather of rows and a gather of columns (the same offsets, pixels and moves)."""
    from torch.nn import functional as F

    b, h, w, c = images.shape
    padded = F.pad(images.permute(0, 3, 1, 2).float(), (pad, pad, pad, pad), mode="replicate")
    offset = torch.randint(0, 2 * pad + 1, (b, 2), generator=generator, device=images.device)
    rows = (offset[:, 0:1] + torch.arange(h))[:, None, :, None].expand(b, c, h, w + 2 * pad)
    cols = (offset[:, 1:2] + torch.arange(w))[:, None, None, :].expand(b, c, h, w)
    cropped = padded.gather(2, rows).gather(3, cols)
    return cropped.permute(0, 2, 3, 1).to(images.dtype), pad - offset


def grasp_agent_and_batch(overrides: dict):
    """``grasp-qtopt-pixels``' agent with ``overrides`` and a batch of its size from 4 random steps of its 16 envs."""
    from taskrl.overrides import with_overrides
    from taskrl.presets import preset_config
    from taskrl.replay.batch import Batch
    from taskrl.wiring.parts import make_agent, make_env

    config = with_overrides(preset_config("grasp-qtopt-pixels"), overrides)
    env = make_env(config, "cpu")
    agent = make_agent(config, env, torch.device("cpu"))
    obs, steps = env.reset(seed=0), []
    for _ in range(config.batch_size // env.num_envs):
        action = torch.rand(env.num_envs, env.single_action_space.shape[-1]) * 2 - 1
        next_obs, reward, terminated, truncated, info = env.step(action)
        index = torch.zeros(env.num_envs, dtype=torch.long)
        steps.append(Batch(obs, action, reward, info["final_obs"], terminated, truncated, index, index))
        obs = next_obs
    batch = Batch.interleave(steps)
    agent.inputs.update_statistics(batch.obs)
    return agent, batch


def shift_pairs(rounds: int = ROUNDS, block: int = 20) -> list[str]:
    from taskrl.encoders import random_shift_moves

    images = torch.randint(0, 256, (64, 64, 64, 3), dtype=torch.uint8)
    ours = random_shift_moves(images, 4, torch.Generator().manual_seed(0))
    theirs = pad_and_crop_shift(images, 4, torch.Generator().manual_seed(0))
    assert all(torch.equal(a, b) for a, b in zip(ours, theirs))  # the same pixels and moves, to the bit

    def shifts(shift):
        for _ in range(block * 10):
            shift(images, 4)
        return block * 10

    ms = alternating_blocks({"a": lambda: shifts(pad_and_crop_shift), "b": lambda: shifts(random_shift_moves)}, rounds)
    rows = [_row("shift of 64 pictures of 64x64x3, pad 4", "padded, two gathers", "one gather", ms["a"], ms["b"])]
    print(rows[-1], flush=True)
    replaced = functools.partial(_replaced, "taskrl.encoders.shift", "random_shift_moves", pad_and_crop_shift)
    for name, overrides in (("the flat join", {"fusion": "flat", "shift_coordinates": False}), ("the glimpse", {})):
        agent, batch = grasp_agent_and_batch(overrides)

        def run(context=contextlib.nullcontext, agent=agent, batch=batch):
            with context():
                for _ in range(block):
                    agent.update(batch)
            return block

        for context in (contextlib.nullcontext, replaced):
            run(context)  # a warm start of each path
        ms = alternating_blocks({"a": lambda run=run: run(replaced), "b": run}, rounds)
        what = f"eager grasp-qtopt-pixels QT-Opt update, {name} (batch 64)"
        rows.append(_row(what, "padded, two gathers", "one gather", ms["a"], ms["b"]))
        print(rows[-1], flush=True)
    return rows


def main() -> None:
    args = micro_benchmark_args(__doc__, PAIRS)
    rows = [*compiled_pairs(32, (64, 64), args.only), *compiled_pairs(256, (256, 256), args.only)]
    rows += [*split_pairs(32, (64, 64)), *split_pairs(256, (256, 256))] if "split" in args.only else []
    rows += care_pairs() if "CARE encoders" in args.only else []
    rows += relu_pairs() if "ReLU in place" in args.only else []
    shift_rows = shift_pairs() if "picture shift" in args.only else []
    header = ["| what | replaced path, ms | taskrl's path, ms | taskrl / replaced |", "|---|---|---|---|"]
    blocks = "(MT10 rows: 10 blocks of 2 updates)"
    for title, found, unit in (
        ("Per-call costs of the compiled update and the replay gather, side by side", rows, f"per row {blocks}"),
        (SHIFT_TITLE, shift_rows, "per row, of 200 shifts or 20 updates"),
    ):
        if not found:
            continue
        table = "\n".join(
            [
                f"One torch thread; {ROUNDS} alternating blocks {unit}; ms per call (median over blocks) of the path "
                "replaced and of taskrl's, and the median ratio of taskrl's to it per pair of blocks (quartiles in brackets).",
                "",
                *header,
                *found,
            ]
        )
        print(table)
        if args.write:
            append_results(title, table)


if __name__ == "__main__":
    main()
