"""Command-line options that several `pixie` commands share, defined once."""
from __future__ import annotations

import argparse

DROP_INVALID_HELP = "remove Gaussians with NaN/inf/absurd values (and say how many) instead of failing"


def add_drop_invalid_option(p: argparse.ArgumentParser, prefix: str = "") -> None:
    """`--drop-invalid`: drop bad Gaussians on read instead of refusing the file (see docs/reliability.md)."""
    p.add_argument("--drop-invalid", action="store_true", help=prefix + DROP_INVALID_HELP)
