"""Counters by reason and event lines to log: what the C37.118 server and client cores report to their nodes."""

from __future__ import annotations

import collections


def add(counts: dict, key: str, n: int = 1) -> None:
    counts[key] = counts.get(key, 0) + n


def merge(total: dict, counts: dict) -> None:
    for key, n in counts.items():
        add(total, key, n)


def drain(lines: collections.deque) -> list[str]:
    """Every line queued so far, oldest first (the deque is safe to append to from another thread meanwhile)."""
    taken = []
    while lines:
        taken.append(lines.popleft())
    return taken
