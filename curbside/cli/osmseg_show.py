"""``osmseg show`` sub-command(s)."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add this module's sub-command(s) to ``subparsers``."""
