"""Reporting helpers shared by the benchmark scripts (tables, machine line)."""

from __future__ import annotations

import datetime
import os
import platform
from collections.abc import Sequence

import diffrax
import jax
import numpy as np
import scipy


def markdown_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A markdown table with padded columns."""
    widths = [max(len(str(x)) for x in col) for col in zip(headers, *rows, strict=True)]

    def line(cells):
        return (
            "| "
            + " | ".join(str(c).ljust(w) for c, w in zip(cells, widths, strict=True))
            + " |"
        )

    sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    return "\n".join([line(headers), sep, *(line(r) for r in rows)])


def machine_line() -> str:
    """Platform, CPU count, library versions and date."""
    devices = ", ".join(sorted({d.platform for d in jax.devices()}))
    return (
        f"machine: {platform.platform()} ({platform.machine()}), "
        f"{os.cpu_count()} CPUs, jax {jax.__version__} on {devices}, "
        f"diffrax {diffrax.__version__}, scipy {scipy.__version__}, "
        f"numpy {np.__version__}, python {platform.python_version()}, "
        f"{datetime.datetime.now().isoformat(timespec='seconds')}"
    )
