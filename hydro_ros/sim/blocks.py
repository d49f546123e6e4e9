"""Stepping a plant in blocks, and changing its faults while it runs."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import TypeVar

from hydro_ros.contract.names import Injection

BLOCK = 1000  # samples per block: bounds memory for long runs
T = TypeVar("T")


def in_blocks(total: int, step: Callable[[int], T], progress: Callable[[int], None] | None = None) -> Iterator[T]:
    """``step(n)`` over ``total`` samples in blocks of at most ``BLOCK``, ``progress(n)`` after each."""
    done = 0
    while done < total:
        n = min(BLOCK, total - done)
        yield step(n)
        done += n
        if progress is not None:
            progress(n)


def replace_injection(holder: list[Injection], name: str, value: float, now_s: float) -> None:
    """A fault set while running: ``name`` at ``value`` from ``now_s`` on in place of its previous size (0: removed)."""
    holder[:] = [i for i in holder if i.name != name]
    if value != 0.0:
        holder.append(Injection(name, value, onset_s=now_s))
