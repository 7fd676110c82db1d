"""What Stable-Baselines3's DQN + HER makes per second on 15-bit flipping as a user's script runs it (SB3's own
``BitFlippingEnv``) and on taskrl's gymnasium ``taskrl/BitFlip-v0``: 2 envs, one update per env step, one torch
thread, SB3's HER-test settings; each case in a fresh process, 8,000 env steps timed after 2,000 of warm-up.

    .venv/bin/python benchmarks/sb3_env_probe.py                 # all four cases, one after the other
    .venv/bin/python benchmarks/sb3_env_probe.py sb3env 32 64    # one case: env, batch, width
"""

from __future__ import annotations

import json
import subprocess
import sys
import time


def one(variant: str, batch: int, width: int) -> dict:
    import torch

    from her_bitflip import sb3_model  # the harness's own SB3 settings (its budget of 10k gives epsilon's full decay)

    torch.set_num_threads(1)
    model = sb3_model(15, 0, 10_000, batch_size=batch, net_arch=(width, width), own_env=variant == "sb3env")
    model.learn(2000)  # warm-up
    updates, start = model._n_updates, time.perf_counter()
    model.learn(8000, reset_num_timesteps=False)
    seconds = time.perf_counter() - start
    return {"env": variant, "batch": batch, "width": width, "updates_per_s": (model._n_updates - updates) / seconds}


def main() -> None:
    if len(sys.argv) == 4:
        print(json.dumps(one(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]))))
        return
    print("| env | batch / network | SB3 updates/s |\n|---|---|---|")
    for variant in ("sb3env", "taskrl"):
        for batch, width in ((32, 64), (256, 256)):
            out = subprocess.run([sys.executable, __file__, variant, str(batch), str(width)], capture_output=True, text=True)
            r = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"| {variant} | {batch} / ({width}, {width}) | {r['updates_per_s']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
