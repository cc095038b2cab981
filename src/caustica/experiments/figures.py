"""Figures of the experiments, drawn with matplotlib (Agg backend, PNG)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..imageio import atomic_write, to_srgb8

# Close-up boxes (x0, y0, x1, y1 as fractions of the image) for scenes without a caustic
# mask: the pyramid's base on the floor, the bunny.
CLOSEUPS = {"cornell-pyramid": (0.2, 0.45, 0.8, 1.0), "cornell-bunny": (0.25, 0.45, 0.75, 0.95)}


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(fig, path: Path):
    plt = _plt()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight"))
    plt.close(fig)


def fig4_plot(rows, path: Path):
    """Error against streams, a line per r_s, a panel per assoc (the manner of the paper's Fig. 4)."""
    plt = _plt()
    assocs = sorted({r["assoc"] for r in rows})
    radii = sorted({r["stream_radius"] for r in rows})
    fig, axes = plt.subplots(3, len(assocs), figsize=(4 * len(assocs), 9.5), squeeze=False, sharex=True,
                             sharey="row")
    for j, a in enumerate(assocs):
        for i, (key, name) in enumerate((("caustic_block_err", "caustic region block err"),
                                         ("caustic_rel_mse", "caustic region relMSE"),
                                         ("rel_mse", "whole image relMSE"))):
            ax = axes[i, j]
            for rs in radii:
                pts = sorted((r["streams"], r[key]) for r in rows if r["assoc"] == a and r["stream_radius"] == rs)
                if pts:
                    ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=f"r_s = {rs:g}")
            ax.set_xscale("log")
            if all(r[key] > 0 for r in rows if r.get(key) is not None and math.isfinite(r[key])):
                ax.set_yscale("log")
            ax.set_title(f"assoc = {a}: {name}", fontsize=9)
            ax.grid(True, which="both", alpha=0.3)
            if i == 2:
                ax.set_xlabel("streams")
            if j == 0:
                ax.set_ylabel(name)
            ax.legend(fontsize=8)
    fig.suptitle("SPM parameter sweep: error against the number of streams")
    _save(fig, path)


def budget_plot(sweep, eq, path: Path, scene: str, key: str = "caustic_block_err", name: str = "caustic block err"):
    """The caustic error against render time for each configuration's photon-budget sweep."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4.2))
    for label, rows in sweep.items():
        rows = sorted(rows, key=lambda r: r["budget_factor"])
        ax.plot([r["time_s"] for r in rows], [r[key] for r in rows], marker="o", label=label)
        for r in rows:
            ax.annotate(f"x{r['budget_factor']:g}", (r["time_s"], r[key]), fontsize=6,
                        xytext=(3, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("render time (s)")
    ax.set_ylabel(name)
    ax.set_title(f"{scene}: photon budget x0.25 .. x4 of the paper's")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    _save(fig, path)


def _crop_box(mask, scene, w, h):
    if mask is not None and mask.any():
        ys, xs = np.nonzero(mask)
        cx, cy = (xs.min() + xs.max()) / 2, (ys.min() + ys.max()) / 2
        half = max(xs.max() - xs.min(), ys.max() - ys.min()) * 0.75 + max(4, w // 32)
    else:
        x0, y0, x1, y1 = CLOSEUPS.get(scene, (0.25, 0.5, 0.75, 1.0))
        cx, cy = (x0 + x1) / 2 * w, (y0 + y1) / 2 * h
        half = max(x1 - x0, y1 - y0) / 2 * max(w, h)
    half = int(min(half, min(w, h) / 2))
    x0 = int(np.clip(cx - half, 0, w - 2 * half))
    y0 = int(np.clip(cy - half, 0, h - 2 * half))
    return x0, y0, x0 + 2 * half, y0 + 2 * half


def side_by_side(panels, path: Path, *, title: str, mask=None, scene: str = ""):
    """The renders in a row, each with a labelled close-up of the caustic below it."""
    plt = _plt()
    from matplotlib.patches import Rectangle
    n = len(panels)
    h, w = panels[0][1].shape[:2]
    x0, y0, x1, y1 = _crop_box(mask, scene, w, h)
    fig, axes = plt.subplots(2, n, figsize=(4 * n, 8.4), squeeze=False)
    for j, (label, image, row) in enumerate(panels):
        srgb = to_srgb8(image)
        ax = axes[0, j]
        ax.imshow(srgb, interpolation="nearest")
        ax.add_patch(Rectangle((x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0, fill=False, edgecolor="yellow", lw=1.2))
        sub = [f"{row['time_s']:.1f} s"]
        if row.get("map_mb") is not None:
            sub.append(f"map {row['map_mb']:.2f} MB")
        ax.set_title(f"{label}\n" + ", ".join(sub), fontsize=10)
        ax.axis("off")
        ax = axes[1, j]
        ax.imshow(srgb[y0:y1, x0:x1], interpolation="nearest")
        cap = "close-up"
        if row.get("caustic_rel_mse") is not None and math.isfinite(row["caustic_rel_mse"]):
            cap += (f": caustic block err {row['caustic_block_err']:.3g}, relMSE {row['caustic_rel_mse']:.3g},\n"
                    f"SSIM {row['caustic_ssim']:.3f}, FLIP {row['caustic_flip']:.3f}")
        ax.set_title(cap, fontsize=9)
        ax.axis("off")
    fig.suptitle(title)
    fig.tight_layout()
    fig.subplots_adjust(hspace=0.3)
    _save(fig, path)


def _loggable(value) -> bool:
    """Whether a log axis can show ``value`` (an undefined error, NaN, or an exact 0 cannot)."""
    return value is not None and math.isfinite(value) and value > 0


def convergence_plot(rows, path: Path, scene: str):
    """Caustic-mask and whole-image relative RMSE against wall time (log-log), a line per method."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    labels = [r["label"] for r in rows if r.get("time_s") is not None]
    palette = plt.get_cmap("tab20").colors   # more methods than the default cycle's 10 colours
    for k, label in enumerate(dict.fromkeys(labels)):
        mine = sorted((r for r in rows if r["label"] == label and r.get("time_s")), key=lambda r: r["time_s"])
        peer = label.startswith("Mitsuba")
        style = "--" if peer else (":" if label.startswith("PM+C") else "-")
        color = "black" if peer else palette[(2 * k) % 20 if k < 10 else (2 * k + 1) % 20]
        for ax, key in zip(axes, ("caustic_rel_rmse", "rel_rmse")):
            pts = [(r["time_s"], r[key]) for r in mine if _loggable(r.get(key))]
            if pts:
                x, y = zip(*pts)
                ax.plot(x, y, style, marker="o", ms=3, color=color, label=label)
    floor = [r for r in rows if r.get("method") == "reference"]
    for ax, key, title in zip(axes, ("caustic_rel_rmse", "rel_rmse"), ("caustic mask", "whole image")):
        if floor and _loggable(floor[0].get(key)):
            ax.axhline(floor[0][key], color="grey", lw=0.8, ls=":", label=floor[0]["label"])
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel("relative RMSE")
        ax.set_title(f"{scene}: {title}")
        ax.grid(True, which="both", alpha=0.3)
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(fontsize=7)
    _save(fig, path)
