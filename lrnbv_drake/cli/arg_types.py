"""Argument types shared by the commands: argparse reports a bad value with the flag named and
exits with code 2, before anything runs."""

from __future__ import annotations

import argparse


def _int_at_least(text: str, lowest: int, expected: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = lowest - 1
    if value < lowest:
        raise argparse.ArgumentTypeError(f"expected {expected}, got '{text}'")
    return value


def positive_int(text: str) -> int:
    """A count: 1, 2, ..."""
    return _int_at_least(text, 1, "a positive integer")


def spread_count(text: str) -> int:
    """A number of samples a spread is measured from: 2, 3, ..."""
    return _int_at_least(text, 2, "an integer >= 2")


def seed(text: str) -> int:
    """A random seed: numpy's generators take 0, 1, ..."""
    return _int_at_least(text, 0, "an integer >= 0")
