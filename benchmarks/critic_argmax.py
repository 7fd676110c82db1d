"""Is QT-Opt's acting the problem on FetchPush, or its learning? CEM's argmax over a critic that works.

A SAC + HER run that solves FetchPush-v4 has an actor and twin critics trained together. This loads such a
run and plays greedy episodes three ways, on the same episode seeds:

- ``actor``: SAC's own deterministic action, tanh(mean) (what its evaluation reports);
- ``cem``: QT-Opt's way of acting on the same critics: the CEM argmax (the preset's 64 samples x 2 rounds,
  6 elites) of min(Q1, Q2)(s, a) over the whole action box;
- ``cem-near-actor``: CEM started at the actor's action with std 0.1 of the half-width, one round of 64:
  a local refinement of the actor's choice.

If ``cem`` succeeds about as often as ``actor``, the argmax of a learned critic is a good policy and QT-Opt's
failure lies in learning Q (its CEM-made targets); if ``cem`` fails where ``actor`` succeeds, the critic's
maximum over the box is not where the actor's gradient ascent takes it, and acting by argmax is part of it.
Also reported: the critic's value at each way's action (mean over visited states), so "CEM found a higher Q
but a worse action" shows as such.

    .venv/bin/python benchmarks/critic_argmax.py RUN_DIR --episodes 100 --write
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).parent))
from common import append_results  # noqa: E402

WAYS = ("actor", "cem", "cem-near-actor")


def play(run_dir: Path, episodes: int, seed: int = 1000) -> dict:
    import gymnasium as gym
    import gymnasium_robotics  # noqa: F401  (registers Fetch)

    import taskrl
    from taskrl.agents.cem import maximize

    torch.set_num_threads(1)
    agent = taskrl.load(run_dir)
    assert agent.config.__class__.__name__ == "SACConfig", "critic_argmax.py reads a SAC run"
    low, high = -torch.ones(agent.action_dim), torch.ones(agent.action_dim)
    g = torch.Generator().manual_seed(seed)

    def q(x: torch.Tensor, unit: torch.Tensor) -> torch.Tensor:
        """min(Q1, Q2)(x, a) for actions ``unit [B, N, A]`` in [-1, 1] -> [B, N]."""
        b, n, a = unit.shape
        rows, acts = x.repeat_interleave(n, 0), unit.reshape(b * n, a)
        return torch.minimum(*(critic(rows, acts) for critic in agent.critics)).view(b, n)

    def choose(way: str, obs: dict) -> tuple[np.ndarray, float]:
        batched = {k: torch.as_tensor(v, dtype=torch.float32)[None] for k, v in obs.items()}
        with torch.no_grad():
            x = agent.features(batched)
            actor = agent.actor.mode(x)
            if way == "actor":
                unit = actor
            elif way == "cem":
                unit, _ = maximize(lambda a: q(x, a), 1, low, high, iterations=2, samples=64, elites=6, generator=g)
            else:
                unit, _ = maximize(
                    lambda a: q(x, a),
                    1,
                    low,
                    high,
                    iterations=1,
                    samples=64,
                    elites=6,
                    init_mean=actor,
                    init_std=0.1,
                    generator=g,
                )
            value = float(q(x, unit[:, None])[0, 0])
        return agent.box.from_unit(unit)[0].numpy(), value

    found = {}
    for way in WAYS:
        env = gym.make("FetchPush-v4")
        solved, values, at_bound = [], [], []
        for episode in range(episodes):
            obs, _ = env.reset(seed=seed + episode)
            for _ in range(50):
                action, value = choose(way, obs)
                values.append(value)
                at_bound.append(float(np.mean(np.abs(action) > 0.999)))
                obs, _, terminated, truncated, info = env.step(action)
                if terminated or truncated:
                    break
            solved.append(float(info["is_success"]))
        env.close()
        found[way] = {
            "success": float(np.mean(solved)),
            "q_at_action": float(np.mean(values)),
            "at_bound": float(np.mean(at_bound)),
        }
        print(way, found[way], flush=True)
    return {"run": str(run_dir), "step": int(agent.loaded_step), "episodes": episodes, "ways": found}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", type=Path, help="a SAC + HER run on FetchPush-v4")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--write", action="store_true", help="replace the RESULTS section")
    args = parser.parse_args()
    result = play(args.run_dir, args.episodes)
    (Path(__file__).parent / "results" / "critic_argmax_fetchpush.json").write_text(json.dumps(result, indent=2) + "\n")
    if args.write:
        rows = "\n".join(
            f"| {way} | {r['success']:.2f} | {r['q_at_action']:.2f} | {r['at_bound']:.2f} |" for way, r in result["ways"].items()
        )
        append_results(
            "FetchPush-v4: acting by CEM's argmax over a SAC critic that solves it",
            f"`.venv/bin/python benchmarks/critic_argmax.py RUN --episodes {args.episodes}` on the run "
            f"`{Path(result['run']).name}` (its checkpoint at {result['step']:,} env steps), {args.episodes} greedy "
            "episodes per way on the same episode seeds; one torch thread. Ways: `actor` SAC's tanh(mean); `cem` QT-Opt's "
            "CEM (64 samples x 2 rounds, 6 elites) over min(Q1, Q2) in the whole box; `cem-near-actor` one round of 64 "
            "around the actor's action (std 0.1 of the half-width). `Q at action`: min(Q1, Q2) at the chosen action, "
            "mean over visited states; `at bound`: share of action components within 0.001 of the box's bound.\n\n"
            "| way | success | Q at action | at bound |\n|---|---:|---:|---:|\n" + rows,
        )


if __name__ == "__main__":
    main()
