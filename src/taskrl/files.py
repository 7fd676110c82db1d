"""Reading the settings and task files users write: JSON or YAML, plain data only."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from taskrl.errors import reason

__all__ = ["read_data_file"]


def read_data_file(path: str | Path) -> Any:
    """The data in a JSON file, or a YAML one (``.yaml`` / ``.yml``; ``safe_load`` builds plain data
    only, so no code runs). Any defect (unreadable, not JSON, not YAML) is one ``ValueError`` line
    naming the file."""
    path = Path(path)
    try:
        text = path.read_text()
        if path.suffix.lower() in (".yaml", ".yml"):
            import yaml

            try:
                return yaml.safe_load(text)
            except yaml.YAMLError as error:  # not a ValueError: say it as one
                raise ValueError(str(error)) from None
        return json.loads(text)
    except (OSError, UnicodeDecodeError, ValueError) as error:
        raise ValueError(f"{path} cannot be read ({reason(error)})") from None
