"""Tabulated data the scene loader reads (colour matching functions, named conductors), as CSV files beside this one.

Each file starts with ``#`` lines that say what it holds and where it comes from, then a header row, then one row a
record.  Kept out of the code so that a table is data to read, cite and check, not lines of Python.
"""
from __future__ import annotations

from pathlib import Path

FOLDER = Path(__file__).resolve().parent


def read_csv(name: str) -> tuple[list[str], list[list[str]]]:
    """(the header's column names, the rows as lists of strings) of the CSV file ``name`` in this folder."""
    lines = [line for line in (FOLDER / name).read_text(encoding="utf-8").splitlines()
             if line.strip() and not line.startswith("#")]
    return lines[0].split(","), [line.split(",") for line in lines[1:]]
