"""The ``taskrl`` command line.

    taskrl presets                         list presets with a one-line description each
    taskrl train PRESET [--setting VALUE]  train (every setting of the run, its env and its algorithm is a flag)
    taskrl train PRESET --env-id my/Env-v0 train a preset's algorithm on any gymnasium env (--env-module to register it)
    taskrl train --resume RUN_DIR          continue a run from its last checkpoint
    taskrl eval RUN_DIR                    re-evaluate a saved agent (--json, --video N, --checkpoint STEP)
    taskrl export RUN_DIR --out DIR        write the policy alone (taskrl.load_policy(DIR).predict(obs))
    taskrl train PRESET --seeds 0 1 2      one run per seed into one folder (--parallel N), then compared
    taskrl plot RUN_OR_FOLDER ... --out F  compare runs: mean and 95% band over seeds, per task, a table
    taskrl solve MDP [--method ...]        exact dynamic programming on finite MDPs
    taskrl demos collect SOURCE --out DIR  scripted-expert demonstrations (mt10, mt50, ml45, pointreach-mt) as a Minari dataset
    taskrl demos info DIR                  a demonstration dataset's card

Bad input exits with code 2 and one line naming the setting and the allowed values.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

from taskrl.commands.demos import cmd_demos
from taskrl.commands.evaluation import cmd_eval, cmd_export
from taskrl.commands.parsing import FILES, POSITIONAL, UsageError, as_flag
from taskrl.commands.plot import cmd_plot
from taskrl.commands.train import cmd_presets, cmd_train

COMMANDS = ("train", "eval", "export", "plot", "presets", "solve", "demos")


def cmd_solve(argv: Sequence[str]) -> int:
    from taskrl.tabular.cli import main as solve_main

    return solve_main(list(argv))


def main(argv: Sequence[str] | None = None) -> int:
    try:
        return _main(argv)
    except BrokenPipeError:  # the reader went away (`taskrl presets | head`): nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


def _main(argv: Sequence[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__.strip())
        return 0
    command, rest = argv[0], argv[1:]
    handlers = {
        "train": cmd_train,
        "eval": cmd_eval,
        "export": cmd_export,
        "plot": cmd_plot,
        "presets": cmd_presets,
        "solve": cmd_solve,
        "demos": cmd_demos,
    }
    from taskrl.distributed.loop import RolesLost
    from taskrl.distributed.pools import RoleCannotStart
    from taskrl.errors import ConfigError
    from taskrl.training.bookkeeping import TrainingDiverged

    try:
        if command not in handlers:
            raise UsageError(f"unknown command {command!r}; allowed: {', '.join(COMMANDS)}")
        return handlers[command](rest)
    except UsageError as e:
        print(f"taskrl {command}: error: {e}", file=sys.stderr)
        return 2
    except ConfigError as e:
        label = e.field.upper() if e.field in POSITIONAL else FILES.get(e.field, as_flag(e.field))
        print(f"taskrl {command}: error: {label} {e.message}", file=sys.stderr)
        return 2
    except (FileNotFoundError, NotADirectoryError, IsADirectoryError, PermissionError) as e:
        print(f"taskrl {command}: error: {e}", file=sys.stderr)
        return 2
    except ImportError as e:  # an optional extra not installed, named where taskrl knows it (ConfigError above)
        print(
            f"taskrl {command}: error: a package is missing ({e}); the optional extras install with: "
            "pip install -e '.[robotics,language,metaworld,video,imitation,distributed]'",
            file=sys.stderr,
        )
        return 2
    except (TrainingDiverged, RolesLost, RoleCannotStart) as e:
        print(f"taskrl {command}: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # a second Ctrl-C: the last complete checkpoint stays
        print(f"taskrl {command}: aborted; the run's last complete checkpoint is intact", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
