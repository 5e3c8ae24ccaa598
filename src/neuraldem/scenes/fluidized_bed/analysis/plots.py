"""Figures of fluidized-bed trajectories (matplotlib, written as PNG): metric curves and time averages."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np


def plot_curves(series: Mapping[str, Mapping[str, Any]], path: Path, title: str) -> None:
    """Bed height, bubble fraction and Lacey index over time, one line per trajectory.

    series: {label: {"time", "bed_height", "bed_height_particles", "bubble_fraction", "lacey_field",
    "lacey_particles"}} (arrays over the snapshots; heights in m)."""
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    colors = plt.cm.coolwarm(np.linspace(0, 1, max(len(series), 2)))
    for color, (label, s) in zip(colors, series.items(), strict=False):
        t = np.asarray(s["time"])
        axes[0].plot(t, 1000 * np.asarray(s["bed_height"]), color=color, label=f"{label} (field)")
        if "bed_height_particles" in s:
            axes[0].plot(t, 1000 * np.asarray(s["bed_height_particles"]), color=color, ls=":", lw=1,
                         label=f"{label} (particles)")
        axes[1].plot(t, s["bubble_fraction"], color=color, label=label)
        axes[2].plot(t, s["lacey_field"], color=color, label=f"{label} (field)")
        if "lacey_particles" in s:
            axes[2].plot(t, s["lacey_particles"], color=color, ls=":", lw=1, label=f"{label} (particles)")
    axes[0].set(xlabel="t [s]", ylabel="bed height [mm]", title="bed height (95 % of the solid volume below)")
    axes[1].set(xlabel="t [s]", ylabel="bubble fraction", title="void share of the bed volume", ylim=(0, None))
    axes[2].set(xlabel="t [s]", ylabel="Lacey index M", title="mixing (group B = started right)", ylim=(-0.05, 1.1))
    for ax in axes:
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_time_averages(stats: Mapping[str, Mapping[str, np.ndarray]], extent: tuple[float, float, float, float],
                       path: Path, title: str) -> None:
    """Per-cell time mean and std of solid fraction and fluid speed, on the central y slice (x-z maps),
    one row per trajectory. stats: {label: {"solid_fraction_mean", "solid_fraction_std", "fluid_speed_mean",
    "fluid_speed_std"}} each (nx, ny, nz); extent = (x0, x1, z0, z1) [m]."""
    keys = (("solid_fraction_mean", "mean solid fraction", "viridis"),
            ("solid_fraction_std", "std solid fraction", "magma"),
            ("fluid_speed_mean", "mean fluid speed [m/s]", "viridis"),
            ("fluid_speed_std", "std fluid speed [m/s]", "magma"))
    fig, axes = plt.subplots(len(stats), len(keys), figsize=(2.6 * len(keys), 4.2 * len(stats)), squeeze=False)
    vmax = {k: max(float(np.max(s[k])) for s in stats.values()) for k, _, _ in keys}
    mm = [1000 * v for v in extent]
    for row, (label, s) in zip(axes, stats.items(), strict=False):
        for ax, (key, name, cmap) in zip(row, keys, strict=False):
            field = s[key]
            sl = field[:, field.shape[1] // 2, :]  # central y slice (x, z)
            im = ax.imshow(sl.T, origin="lower", extent=mm, cmap=cmap, vmin=0, vmax=vmax[key], aspect="equal")
            ax.set_title(f"{label}\n{name}", fontsize=8)
            ax.set_xlabel("x [mm]", fontsize=7)
            ax.set_ylabel("z [mm]", fontsize=7)
            ax.tick_params(labelsize=6)
            fig.colorbar(im, ax=ax, shrink=0.8).ax.tick_params(labelsize=6)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def lateral_profiles(field: np.ndarray, z_centres: np.ndarray, bands: list[tuple[float, float]]) -> np.ndarray:
    """(len(bands), nx): a per-cell field (nx, ny, nz) averaged over y and over the cells whose centre lies in
    each height band [z0, z1)."""
    out = []
    for z0, z1 in bands:
        inside = (z_centres >= z0) & (z_centres < z1)
        out.append(field[:, :, inside].mean(axis=(1, 2)) if inside.any() else np.full(field.shape[0], np.nan))
    return np.asarray(out)


def plot_lateral_profiles(stats: Mapping[str, Mapping[str, np.ndarray]], x_centres: np.ndarray,
                          z_centres: np.ndarray, bed_height: float, path: Path, title: str) -> None:
    """Time mean and std of the solid fraction across the bed (x) in three height bands (lower and upper half
    of the bed, the splash zone above it), one line style per series: where the bubbles pass, and whether the
    model's are as often at the walls as CFD-DEM's. stats as for `plot_time_averages`."""
    bands = [(0.0, bed_height / 2), (bed_height / 2, bed_height), (bed_height, 1.5 * bed_height)]
    names = ["lower half of the bed", "upper half of the bed", "splash zone (1 - 1.5 bed heights)"]
    colors = plt.cm.viridis(np.linspace(0.0, 0.8, len(bands)))
    styles = ["-", "--", ":", "-."]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, key, name in zip(axes, ("solid_fraction_mean", "solid_fraction_std"),
                             ("time-mean solid fraction", "std of the solid fraction"), strict=True):
        for style, (label, s) in zip(styles, stats.items(), strict=False):
            for color, band, profile in zip(colors, names, lateral_profiles(s[key], z_centres, bands), strict=True):
                ax.plot(1000 * x_centres, profile, color=color, ls=style, marker=".", label=f"{label}, {band}")
        ax.set(xlabel="x [mm]", ylabel=name, title=name, ylim=(0, None))
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=6)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_solid_volume(series: Mapping[str, Mapping[str, Any]], path: Path, title: str) -> None:
    """Total solid volume of the kernel field relative to the particles' volume (mass conservation)."""
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for label, s in series.items():
        ax.plot(s["time"], np.asarray(s["solid_volume"]) / float(s["particle_volume_total"]) - 1.0, label=label)
    ax.set(xlabel="t [s]", ylabel="V_solid(field) / V_particles - 1")
    fig.suptitle(title, fontsize=10)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def animate_fields(times: np.ndarray, solid_fraction: np.ndarray, mixing: np.ndarray,
                   extent: tuple[float, float, float, float], path: Path, title: str, every: int = 5,
                   fps: int = 20, cell_px: int = 10) -> Path:
    """An animated GIF of the solid fraction (viridis, 0 .. 0.65) and the mixing concentration (coolwarm,
    0 = all started left .. 1 = all started right; white where there is no solid) on the central y slice,
    every `every`-th snapshot. Frames are coloured arrays written by Pillow, not matplotlib figures: 60
    frames take well under a second instead of about a minute. `extent` (x0, x1, z0, z1) [m] labels the size."""
    from PIL import Image, ImageDraw

    idx = list(range(0, len(times), every))
    mid = solid_fraction.shape[2] // 2
    sf = solid_fraction[:, :, mid, :]
    mix = mixing[:, :, mid, :]

    def picture(a: np.ndarray, cmap: str, vmax: float, blank: np.ndarray | None = None) -> np.ndarray:
        rgba = plt.get_cmap(cmap)(np.clip(a / vmax, 0.0, 1.0))
        if blank is not None:
            rgba[blank] = 1.0
        img = (255 * rgba[..., :3]).astype(np.uint8).transpose(1, 0, 2)[::-1]  # (z, x), z up
        return np.kron(img, np.ones((cell_px, cell_px, 1), dtype=np.uint8))

    header, gap = 34, 8
    frames = []
    for k in idx:
        left, right = picture(sf[k], "viridis", 0.65), picture(mix[k], "coolwarm", 1.0, blank=sf[k] <= 0.02)
        h, w = left.shape[:2]
        canvas = np.full((h + header, 2 * w + gap, 3), 255, dtype=np.uint8)
        canvas[header:, :w], canvas[header:, w + gap:] = left, right
        im = Image.fromarray(canvas)
        draw = ImageDraw.Draw(im)
        draw.text((2, 1), f"{title}  t = {times[k]:.2f} s", fill=(0, 0, 0))
        draw.text((2, 17), "solid fraction 0-0.65", fill=(0, 0, 0))
        draw.text((w + gap + 2, 17), "mixing: left 0 - right 1", fill=(0, 0, 0))
        frames.append(im)
    size = f"{1000 * (extent[1] - extent[0]):.0f} x {1000 * (extent[3] - extent[2]):.0f} mm"
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0,
                   comment=f"{title}; x-z slice {size}".encode())
    return path
