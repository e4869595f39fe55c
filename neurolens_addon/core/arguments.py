"""Command-line argument types shared by the project's commands (render, trainer)."""

from __future__ import annotations

import argparse


def int_in(lo: int, hi: int):
    """An argparse type: an integer in [lo, hi] (a one-line usage error otherwise)."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"must be between {lo} and {hi}, got {v}")
        return v
    return parse
