"""Where every benchmark writes its numbers: ``benchmarks/results/<name>.json``."""

from __future__ import annotations

import json
from pathlib import Path

RESULTS = Path(__file__).parent / "results"
"""Where the JSON files go."""


def save_results(name: str, rows: dict) -> Path:
    """Write ``rows`` as ``benchmarks/results/<name>.json`` and return the path."""
    out = RESULTS / f"{name}.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(rows, indent=2) + "\n")
    return out
