"""Reading the JSON files the stack writes (dataset and model records), with one kind of error for every way a file
can be unusable."""

import json
from pathlib import Path


def read_json(path: Path, error: type[Exception], remedy: str):
    """The JSON value in `path`; `error` naming the file and `remedy` (what to do) if it is missing, unreadable (a
    directory, no permission), not UTF-8, or not JSON (truncated, damaged)."""
    try:
        return json.loads(path.read_bytes().decode("utf-8"))
    except FileNotFoundError as exc:
        raise error(f"{path.parent} lacks {path.name}: {remedy}") from exc
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise error(f"{path} is not readable UTF-8 JSON ({exc}): {remedy}") from exc
