"""Options shared by several commands, declared once."""

from __future__ import annotations

from typing import Annotated

import typer

__all__ = ["Overwrite"]

Overwrite = Annotated[
    bool,
    typer.Option("--overwrite", help="Replace an existing result that supportnet wrote (nothing else)."),
]
