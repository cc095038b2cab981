"""Run an image kernel band by band, so long passes show progress.

The first band is rendered alone and timed as ``compile_s`` when it triggers JIT
compilation (Numba compiles on first call), so compile time is reported
separately from the camera pass.
"""
from __future__ import annotations

import time


def render_in_tiles(render_rows, height: int, progress, label: str, bands: int = 32) -> dict:
    """Call ``render_rows(r0, r1)`` over the image in bands; returns phase timings in seconds."""
    step = max(1, -(-height // bands))
    t0 = time.perf_counter()
    render_rows(0, min(1, height))  # one row: compiles if needed, costs nothing otherwise
    t1 = time.perf_counter()
    bar = progress(total=height, desc=label, unit="row")
    bar.update(min(1, height))
    r = min(1, height)
    while r < height:
        r1 = min(height, r + step)
        render_rows(r, r1)
        bar.update(r1 - r)
        r = r1
    bar.close()
    t2 = time.perf_counter()
    return {"first_row_s": t1 - t0, f"{label.replace(' ', '_')}_s": t2 - t0}
