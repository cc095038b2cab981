"""Refuse work that would exhaust memory, before allocating it."""
from __future__ import annotations

import os

from .errors import ParameterError

#: Share of physical memory one render may plan to use.
BUDGET_FRACTION = 0.6


def physical_memory_bytes() -> int:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 8 << 30


def check_budget(bytes_needed: int, what: str, hint: str) -> None:
    """Raise ParameterError when ``bytes_needed`` exceeds the budget, with the estimate."""
    budget = int(physical_memory_bytes() * BUDGET_FRACTION)
    if bytes_needed > budget:
        raise ParameterError(
            f"{what} would need about {bytes_needed / 1e9:.1f} GB, more than the "
            f"{budget / 1e9:.1f} GB this machine allows ({BUDGET_FRACTION:.0%} of "
            f"{physical_memory_bytes() / 1e9:.1f} GB); {hint}")
