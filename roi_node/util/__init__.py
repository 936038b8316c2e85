"""Plumbing shared by the drivers and tools: atomic outputs, progress lines, argparse types, process memory."""
