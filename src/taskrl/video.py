"""Videos of a trained agent: ``taskrl eval RUN_DIR --video N`` records N episodes to MP4.

Each env family says how to make one copy that renders RGB frames (``EnvFamily.video_env``): the
native environments draw themselves (``envs/render.py``), gymnasium environments (Fetch, a user's
own) render through MuJoCo or their own ``render``. Frames are written with imageio's ffmpeg (the
``video`` extra, installed by the Makefile).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from taskrl.errors import ConfigError, reason
from taskrl.training.evaluation import episodes_ended

__all__ = ["check_can_record", "record_episodes"]


def check_can_record(config: Any) -> Any:
    """The run's env family, if it can record video and the MP4 writer is installed; else one line."""
    from taskrl.envs.registry import env_family

    family = env_family(config.env)
    if family.video_env is None:
        raise ConfigError("video", f"the {config.env!r} env family cannot record video here (no rgb_array renderer)")
    try:
        import imageio.v2  # noqa: F401
        import imageio_ffmpeg  # noqa: F401  (the MP4 writer)
    except ImportError as error:
        raise ConfigError("video", f"videos need imageio with ffmpeg: pip install 'taskrl[video]' ({error})") from None
    return family


def record_episodes(
    agent: Any, config: Any, out_dir: Path, episodes: int, seed: int = 0, stochastic: bool = False, max_steps: int = 10_000
) -> list[Path]:
    """Run ``episodes`` episodes of ``agent`` on one renderable copy of the run's env; one MP4 each."""
    family = check_can_record(config)
    import imageio.v2 as imageio

    try:
        env = family.video_env(config.env_settings)
    except Exception as error:  # e.g. MuJoCo without an OpenGL backend on this machine
        raise ConfigError(
            "video",
            f"{config.env!r} cannot render here ({reason(error)}); MuJoCo envs "
            f"render off-screen with MUJOCO_GL=egl (or osmesa) set before taskrl starts",
        ) from None
    if env is None:
        raise ConfigError("video", f"this run's env ({config.env!r} from a Python factory) cannot record video")
    out_dir.mkdir(parents=True, exist_ok=True)
    fps = int(env.metadata.get("render_fps", 25) or 25)
    paths = []
    task_names = [t.name for t in _tasks_of(env)]
    try:
        for episode in range(episodes):
            options = {"task": episode % len(task_names)} if task_names else None  # one task after another
            obs, _ = env.reset(seed=seed + episode, options=options)
            episodes_ended(agent, torch.ones(1, dtype=torch.bool))  # a chunked policy starts afresh
            frames = [env.render()]
            for _ in range(max_steps):
                obs, _, terminated, truncated, _ = env.step(agent.act(obs, explore=stochastic))
                frames.append(env.render())
                if terminated or truncated:
                    break
            name = f"episode_{episode:03d}" + (f"_{task_names[episode % len(task_names)]}" if task_names else "")
            path = out_dir / f"{name}.mp4"
            imageio.mimwrite(path, frames, fps=fps, macro_block_size=1)
            paths.append(path)
    finally:
        env.close()
    return paths


def _tasks_of(env: Any) -> list:
    """The tasks of a multi-task gymnasium view (its ``task_set``), or none."""
    task_set = getattr(env.unwrapped, "task_set", None)
    return list(task_set) if task_set is not None else []
