"""Verbs of roi_node.bag (registered by roi_node.cli)."""

from __future__ import annotations

import argparse


def register(verbs: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """No verbs yet."""
