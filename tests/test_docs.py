"""The front door stays true: the README's commands parse, its quick tour runs, the guides' code runs,
the generated reference documents every setting, RESULTS.md is laid out as a report, and W&B logging
gets what metrics.csv gets."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
import types
from pathlib import Path

import pytest

import taskrl
from helpers import cli, metrics, run_cli, small_run
from taskrl.reference import pages, undocumented_settings

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
# every `taskrl train` of the quick tour gets these last (the last value of a flag wins)
TINY = ["--total-steps", "400", "--eval-interval", "200", "--eval-episodes", "4", "--learning-starts", "50", "--no-tensorboard"]


def fenced_commands(path: Path, section: str | None = None) -> list[list[str]]:
    """The ``taskrl ...`` lines of a markdown file's bash blocks (of one ``## section`` if named), comments cut."""
    text = path.read_text()
    if section is not None:
        text = text.split(f"## {section}\n", 1)[1].split("\n## ", 1)[0]
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", text, re.S):
        for line in block.splitlines():
            line = line.split("#", 1)[0].strip()
            if line.startswith("taskrl "):
                commands.append(shlex.split(line)[1:])
    return commands


def parse_only(args: list[str]) -> list[str]:
    """The command with what makes it stop after parsing: ``--print-config`` for a new training run, else ``--help``."""
    if args[0] == "presets":
        return args
    if args[0] == "train" and "--resume" not in args and "--seeds" not in args and "--help" not in args:
        return [*args, "--print-config"]
    return [*args, "--help"] if "--help" not in args else args


def test_readme_lists_its_commands():
    assert len(fenced_commands(README)) >= 10
    assert len(fenced_commands(README, "Quick tour")) == 10


@pytest.mark.parametrize("args", fenced_commands(README), ids=lambda a: " ".join(a)[:60])
def test_every_readme_command_parses(args, capsys):
    try:
        code, out, err = run_cli(capsys, *parse_only(args))
    except SystemExit as done:  # argparse's --help
        code, (out, err) = done.code, capsys.readouterr()
    assert code in (0, None), err
    assert out.strip()


@pytest.mark.slow
def test_the_quick_tour_runs_at_tiny_budgets(tmp_path):
    for args in fenced_commands(README, "Quick tour"):
        if args[0] == "train" and "--help" not in args:
            args = [*args, *TINY]
            if "--resume" in args:  # extend the run a little past where it stopped
                args = [*args, "--total-steps", "600"]
            if "--seeds" in args:
                args = [*args, "--eval-episodes", "2"]
            else:
                args = [*args, "--no-progress"]
        done = cli(*args, cwd=tmp_path)
        assert done.returncode == 0, f"taskrl {' '.join(args)}\n{done.stderr[-2000:]}"
    assert (tmp_path / "runs" / "bf20" / "metrics.csv").exists() and (tmp_path / "seeds.png").exists()


@pytest.mark.slow
def test_the_new_algorithm_guide_runs(tmp_path):
    page = (ROOT / "docs" / "guides" / "new_algorithm.md").read_text()
    code = "\n".join(re.findall(r"```python\n(.*?)```", page, re.S))
    script = tmp_path / "guide.py"
    script.write_text(
        code.replace("print(run.metrics", "assert run.metrics['success_rate'] >= 0.9, run.metrics\nprint(run.metrics")
    )
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    # and from the command line, the registering module named by --env-module
    (tmp_path / "myalgos.py").write_text(code.split("run = taskrl.train")[0])
    done = cli(
        "train", "bitflip-her", "--env-module", "myalgos", "--algo", "plain-q", "--n-bits", "5", *TINY, "--no-progress", cwd=tmp_path,
        env={"PYTHONPATH": str(tmp_path)},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]


def test_the_new_sharing_strategy_guide_runs(tmp_path):
    page = (ROOT / "docs" / "guides" / "new_sharing_strategy.md").read_text()
    code = "\n".join(re.findall(r"```python\n(.*?)```", page, re.S))
    script = tmp_path / "guide.py"
    script.write_text(
        code
        + "\nimport taskrl\nfrom taskrl.sharing import register_sharing_strategy\n"
        + "register_sharing_strategy(ANY_SUCCESS)\n"
        + "run = taskrl.train('grid-sharing-dqn', out='run', sharing='any-success', min_goals=2, total_steps=800,"
        + " learning_starts=200, eval_interval=10**6, eval_episodes=1, tensorboard=False)\n"
        + "assert run.metrics['updates'] > 0 and run.config.data_sharing.sharing == 'any-success', run.metrics\n"
        + "from taskrl.config import load\nassert load(run.run_dir / 'config.json').data_sharing.strategy_settings.min_goals == 2\n"
    )
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]


def guide_code(name: str) -> str:
    page = (ROOT / "docs" / "guides" / name).read_text()
    return "\n".join(re.findall(r"```python\n(.*?)```", page, re.S))


@pytest.mark.slow
def test_the_new_image_encoder_guide_runs(tmp_path):
    """The guide's encoder, registered from the user's module: QT-Opt, SAC and behaviour cloning train with it from the
    command line, and its weights are saved and loaded."""
    (tmp_path / "my_encoders.py").write_text(guide_code("new_image_encoder.md"))
    env = {"PYTHONPATH": str(tmp_path)}
    tiny = ["--env-module", "my_encoders", "--encoder", "pooled", "--image-size", "16", "--num-envs", "2", "--batch-size", "8"]
    tiny += ["--learning-starts", "8", "--eval-episodes", "1", "--no-tensorboard", "--no-progress"]
    for preset, algo in (("grasp-qtopt-pixels", "qtopt"), ("grasp-qtopt-pixels", "sac")):
        done = cli("train", preset, "--algo", algo, *tiny, "--total-steps", "40", "--eval-interval", "40", "--out", algo, cwd=tmp_path, env=env)  # fmt: skip
        assert done.returncode == 0, done.stderr[-2000:]
        loaded = subprocess.run(
            [sys.executable, "-c", f"import my_encoders, taskrl; a = taskrl.load('{algo}'); print(type(a).__name__)"],
            cwd=tmp_path, env={**__import__("os").environ, **env}, capture_output=True, text=True,
        )  # fmt: skip
        assert loaded.returncode == 0, loaded.stderr[-2000:]
    demos = cli("demos", "collect", "tabletop", "--episodes", "2", "--out", "demos", "--no-progress", cwd=tmp_path)
    assert demos.returncode == 0, demos.stderr[-2000:]
    done = cli(
        "train", "bc-tabletop-language", "--dataset", "demos", *tiny[:4], "--image-size", "32", "--total-steps", "3",
        "--eval-interval", "3", "--eval-episodes", "1", "--no-tensorboard", "--no-progress", "--out", "bc", cwd=tmp_path, env=env,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "bc" / "checkpoints" / "latest").exists()


def test_the_new_run_mode_guide_runs(tmp_path):
    """The guide's collect-only mode, registered from the user's code: the run resolves to it, stores its transitions,
    makes no update and no evaluation before its first step; what it asks of the settings is one line."""
    script = tmp_path / "guide.py"
    script.write_text(
        guide_code("new_run_mode.md")
        + "\nimport taskrl\nfrom taskrl.config import TrainConfig\nfrom taskrl.errors import ConfigError\n"
        + "from taskrl.overrides import with_overrides\nfrom taskrl.plan import resolve\n"
        + "from taskrl.presets import preset_config\n"
        + "config = with_overrides(preset_config('bitflip-her'), {'learning_starts': 10_000, 'total_steps': 400})\n"
        + "assert resolve(config).mode.name == 'collect_only'\n"
        + "assert resolve(with_overrides(config, {'learning_starts': 100})).mode.name == 'off_policy'\n"
        + "run = taskrl.train('bitflip-her', out='run', n_bits=5, learning_starts=10_000, total_steps=400,"
        + " eval_interval=200, eval_episodes=2, tensorboard=False)\n"
        + "rows = list(__import__('csv').DictReader(open('run/metrics.csv')))\n"
        + "assert run.metrics['updates'] == 0 and int(rows[0]['env_steps']) >= 200, rows  # first evaluation at eval_interval\n"
        + "try:\n    resolve(with_overrides(config, {'save_replay': False}))\n    raise SystemExit('not refused')\n"
        + "except ConfigError as error:\n    assert error.field == 'save_replay', error\n"
    )
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]


def test_the_reference_documents_every_setting_family_algorithm_and_preset():
    from taskrl.agents.registry import ALGORITHMS
    from taskrl.envs.registry import ENV_FAMILIES
    from taskrl.presets import PRESETS

    assert undocumented_settings() == []
    generated = pages()
    assert all(f"## `{name}`" in generated["reference/env_families.md"] for name in ENV_FAMILIES)
    assert all(f"## `{name}`" in generated["reference/algorithms.md"] for name in ALGORITHMS)
    assert all(f"| `{name}` |" in generated["reference/presets.md"] for name in PRESETS)
    assert (
        "| `--replay.buffer-size` (`--buffer-size`) | int | `1_000_000` | replay capacity in transitions. |"
        in generated["reference/settings.md"]
    )
    assert "usage: taskrl eval" in generated["reference/commands.md"]


def test_results_are_laid_out_as_a_report():
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "report.py"), "--check"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    titles = re.findall(r"^### (.+)$", (ROOT / "benchmarks" / "RESULTS.md").read_text(), re.M)
    assert len(titles) == len(set(titles))  # one current section per question


def test_report_keeps_the_newest_section_of_a_question(tmp_path):
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        from report import organise
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    flat = "# x\n\n## Data sharing: a\n\nstale figure\n\n## Tabular dynamic programming\n\nt\n\n## Data sharing: a\n\nnew\n"
    laid = organise(flat)
    assert "new" in laid and "stale figure" not in laid
    assert laid.index("## Exact dynamic programming") < laid.index("## Data sharing between tasks")
    assert organise(laid) == laid


def test_wandb_gets_the_rows_and_the_settings(tmp_path, monkeypatch):
    logged, inits = [], []

    class FakeRun:
        def log(self, values):
            logged.append(values)

        def define_metric(self, *args, **kwargs):
            pass

        def finish(self):
            logged.append("finished")

    fake = types.SimpleNamespace(init=lambda **kw: inits.append(kw) or FakeRun(), Settings=lambda **kw: kw)
    monkeypatch.setitem(sys.modules, "wandb", fake)
    monkeypatch.delenv("WANDB_MODE", raising=False)
    monkeypatch.delenv("WANDB_API_KEY", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))  # no `wandb login` here
    run = small_run("bitflip-her", tmp_path / "run", n_bits=5, total_steps=600, eval_interval=200, eval_episodes=10, wandb=True)
    assert inits[0]["mode"] == "offline" and inits[0]["config"]["bitflip"]["n_bits"] == 5
    assert inits[0]["id"] == (run.run_dir / "wandb_id").read_text().strip()
    rows = [r for r in logged if isinstance(r, dict) and "taskrl/success_rate" in r]
    assert [r["taskrl/success_rate"] for r in rows] == [r["success_rate"] for r in metrics(run.run_dir)]
    assert logged[-1] == "finished"


def test_wandb_without_the_package_is_one_line_and_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "wandb", None)  # import fails
    with pytest.raises(taskrl.errors.ConfigError, match="wandb"):
        small_run("bitflip-her", tmp_path / "run", total_steps=100, wandb=True)
    assert not (tmp_path / "run").exists()


def _report():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import report
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    return report


def test_the_report_shows_its_figures_and_refuses_repeats_and_pasted_data():
    report = _report()
    body = "Curves: `benchmarks/figures/mt10_curves.png`."
    shown = report.show_figures(body)
    assert "[mt10_curves.png](figures/mt10_curves.png)" in shown and "![mt10_curves](figures/mt10_curves.png)" in shown
    assert report.show_figures(shown) == shown  # once
    laid = report.organise((ROOT / "benchmarks" / "RESULTS.md").read_text())
    assert report.problems(laid) == []
    paragraph = "A protocol paragraph long enough to count as provenance, " * 3
    repeated = laid.replace("## Contents", f"## Contents\n\n{paragraph}\n\n{paragraph}\n", 1)
    assert any("repeats a paragraph" in p for p in report.problems(repeated))
    pasted = laid.rstrip("\n") + "\n\nRaw: " + "[1.0, 2.0] " * 200 + "\n"
    assert any("raw data goes to" in p for p in report.problems(pasted))
    unshown = laid.replace("![mt10_curves](figures/mt10_curves.png)", "")
    assert any("mt10_curves.png is shown nowhere" in p for p in report.problems(unshown))
    assert laid.index("## Summary") < laid.index("## Contents")


def test_the_docs_build_fails_on_a_raw_sphinx_role_and_the_source_has_none():
    import importlib.util
    from types import SimpleNamespace

    from mkdocs.exceptions import PluginError

    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    page = SimpleNamespace(file=SimpleNamespace(src_uri="reference/python.md"))
    assert hooks.on_page_content("<p>see <code>x</code></p>", page, None, None) == "<p>see <code>x</code></p>"
    with pytest.raises(PluginError, match="raw Sphinx role"):
        hooks.on_page_content("<p>see :func:<code>taskrl.train</code></p>", page, None, None)
    raw = re.compile(r":(func|class|meth|mod|attr|data|exc|obj):`")
    offenders = [str(p) for p in (ROOT / "src").rglob("*.py") if raw.search(p.read_text())]
    assert offenders == []


def test_preset_help_reads_as_plain_text_in_a_terminal(capsys):
    from taskrl.cli import main

    with pytest.raises(SystemExit):
        main(["train", "grasp-qtopt-pixels", "--help"])
    out = capsys.readouterr().out
    assert "--algo.target-samples" in out and "``" not in out and "][taskrl." not in out
