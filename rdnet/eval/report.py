"""Tables and figures of the study (matplotlib figures drawn on the Agg
canvas without pyplot; pandas for tables).

``rows`` everywhere is a mapping ``row name -> metrics dict`` as returned by
:func:`rdnet.eval.predict.evaluate_row` (keys ``psnr``, ``ssim``, ``by_level`` ...).
Every file is written to a temporary name in its folder and then renamed.

Event images (:func:`event_image`): the signed sum of a voxel grid over its bins,
positive (ON) in red and negative (OFF) in blue on white, saturating at ``scale``
(default: the 99th percentile of the absolute sum, shared by all event columns of a
sample so that degraded and restored events are comparable).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

DEFAULT_COLUMNS = ("psnr", "ssim")


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` via a temporary file in the same folder + os.replace."""
    from rdnet.events.io._common import atomic_output
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as tmp:
        tmp.write_text(text)
    return path



def _save_figure(fig, path: str | Path) -> Path:
    from rdnet.events.io._common import atomic_output
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fmt = path.suffix.lstrip(".") or "png"
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format=fmt, dpi=120, bbox_inches="tight")
    return path


def prepare_figures() -> None:
    """Import what :func:`_figure` needs (about 0.2 s) and draw a tiny figure with a log
    axis, a legend and a colour bar into memory, so that the fonts, the mathtext parser of
    the log axis's labels and the colour maps are loaded before the first real figure
    (about 0.04 s of a forked worker's first figure, :class:`rdnet.runtime.ForkedWorker`)."""
    import io
    fig, axes = _figure(1, 2, figsize=(3, 2))
    axes[0].plot([1, 2], [1, 100], label="a")
    axes[0].set_yscale("log")
    axes[0].set_title("a", y=1.0)
    axes[0].legend()
    fig.colorbar(axes[1].imshow([[0.0, 1.0]]), ax=axes[1])
    fig.savefig(io.BytesIO(), dpi=20, format="png")


def _figure(nrows: int = 1, ncols: int = 1, *, figsize, squeeze: bool = True):
    """A standalone Figure on the Agg canvas (no pyplot, no global backend state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, squeeze=squeeze)


# --- tables ---------------------------------------------------------------------------
def metrics_frame(rows: Mapping[str, Mapping], columns: Sequence[str] = DEFAULT_COLUMNS):
    """pandas DataFrame, one row per entry of ``rows``, the scalar ``columns`` (a dotted
    name such as ``restoration.voxel_l1`` reads a nested dict; missing values are NaN)."""
    import pandas as pd

    def get(d, key):
        for part in key.split("."):
            if not isinstance(d, Mapping) or part not in d:
                return float("nan")
            d = d[part]
        return d
    data = {name: {c: get(m, c) for c in columns} for name, m in rows.items()}
    frame = pd.DataFrame.from_dict(data, orient="index", columns=list(columns))
    frame.index.name = "method"
    return frame


def markdown_table(rows: Mapping[str, Mapping], columns: Sequence[str] = DEFAULT_COLUMNS,
                   floatfmt: str = ".4f") -> str:
    """Markdown table (pandas ``to_markdown``, needs ``tabulate``) of ``rows``."""
    return metrics_frame(rows, columns).to_markdown(floatfmt=floatfmt) + "\n"


def write_table(path: str | Path, rows: Mapping[str, Mapping],
                columns: Sequence[str] = DEFAULT_COLUMNS, title: str | None = None) -> Path:
    text = markdown_table(rows, columns)
    if title:
        text = f"# {title}\n\n{text}"
    return write_text_atomic(path, text)


# --- figures --------------------------------------------------------------------------
def plot_metric_bars(path: str | Path, rows: Mapping[str, Mapping], metric: str = "psnr",
                     ylabel: str = "PSNR (dB)") -> Path:
    """Bar chart of one scalar metric per row (value printed on each bar, the spread
    ``<metric>_std`` over seeds as an error bar when present); rows without the metric
    are left out."""
    names = [n for n in rows if metric in rows[n]]
    vals = [float(rows[n].get(metric, float("nan"))) for n in names]
    errs = [float(rows[n].get(f"{metric}_std") or 0.0) for n in names]
    fig, ax = _figure(figsize=(max(4.0, 0.9 * len(names) + 1.5), 3.5))
    finite = [v for v in vals if math.isfinite(v)]
    bars = ax.bar(range(len(names)), [v if math.isfinite(v) else 0.0 for v in vals], color="tab:blue",
                  yerr=errs if any(errs) else None, capsize=3)
    for b, v in zip(bars, vals):
        ax.annotate(f"{v:.2f}", (b.get_x() + b.get_width() / 2, b.get_height()),
                    ha="center", va="bottom", fontsize=8)
    if finite:
        lo, hi = min(finite), max(finite)
        pad = max(0.5, 0.15 * (hi - lo))
        ax.set_ylim(max(0.0, lo - 3 * pad) if metric == "psnr" else max(0.0, lo - pad), hi + pad)
    ax.set_xticks(range(len(names)), names, rotation=30, ha="right")
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3)
    return _save_figure(fig, path)


def plot_metric_vs_level(path: str | Path, rows: Mapping[str, Mapping], metric: str = "psnr",
                         ylabel: str = "PSNR (dB)", xlabel: str = "degradation level") -> Path:
    """One line per row: ``metric`` of each ``by_level`` bin against the bin centre."""
    fig, ax = _figure(figsize=(5.5, 3.8))
    for name, m in rows.items():
        pts = [(b["level_bin"], b[metric]) for b in m.get("by_level", []) if metric in b]
        if pts:
            x, y = zip(*pts)
            ax.plot(x, y, marker="o", label=name)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    return _save_figure(fig, path)


def event_image(voxel, scale: float | None = None) -> np.ndarray:
    """(H, W, 3) float RGB of a (B, H, W) voxel grid: white background, red where the
    signed sum over bins is positive, blue where negative, saturating at ``scale``."""
    s = np.asarray(voxel, np.float64).sum(0)
    if scale is None:
        nz = np.abs(s[s != 0])
        scale = float(np.percentile(nz, 99)) if nz.size else 1.0
    a = np.clip(np.abs(s) / max(scale, 1e-12), 0.0, 1.0)
    rgb = np.ones(s.shape + (3,))
    pos, neg = s > 0, s < 0
    rgb[..., 1] -= a                      # both colours lose green
    rgb[..., 2] -= np.where(pos, a, 0.0)  # red  = (1, 1-a, 1-a)
    rgb[..., 0] -= np.where(neg, a, 0.0)  # blue = (1-a, 1-a, 1)
    return np.clip(rgb, 0.0, 1.0)


def _image_rgb(img) -> np.ndarray:
    a = np.clip(np.asarray(img, np.float64), 0.0, 1.0)
    if a.ndim == 3 and a.shape[0] == 1:
        a = a[0]
    elif a.ndim == 3:
        a = np.moveaxis(a, 0, -1)
    return a


def sample_grid(path: str | Path, blurry, voxel_degraded, voxel_restored, deblurred, sharp,
                *, titles: Sequence[str] | None = None, row_labels: Sequence[str] | None = None) -> Path:
    """PNG grid, one row per sample: blurry | degraded events | restored events |
    deblurred | sharp. Images (n, C, H, W) in [0, 1], voxels (n, B, H, W);
    ``voxel_restored`` and ``sharp`` may be None (column left out; e.g. real recordings
    have no sharp frame)."""
    cols = [("blurry", blurry, "image"), ("degraded events", voxel_degraded, "events")]
    if voxel_restored is not None:
        cols.append(("restored events", voxel_restored, "events"))
    cols.append(("deblurred", deblurred, "image"))
    if sharp is not None:
        cols.append(("sharp", sharp, "image"))
    if titles is not None:
        if len(titles) != len(cols):
            raise ValueError(f"expected {len(cols)} titles, got {len(titles)}")
        cols = [(t, a, k) for t, (_, a, k) in zip(titles, cols)]
    n = len(blurry)
    for t, a, _ in cols:
        if len(a) != n:
            raise ValueError(f"column '{t}' has {len(a)} samples, expected {n}")
    h, w = np.asarray(blurry[0]).shape[-2:]
    cell = 2.2
    fig, axes = _figure(n, len(cols), figsize=(cell * len(cols) * w / max(h, w) + 0.4,
                                               cell * n * h / max(h, w) + 0.4), squeeze=False)
    for i in range(n):
        ev = [np.asarray(a[i]) for _, a, k in cols if k == "events"]
        sums = np.concatenate([np.abs(e.sum(0)).ravel() for e in ev])
        nz = sums[sums != 0]
        scale = float(np.percentile(nz, 99)) if nz.size else 1.0
        for j, (title, arr, k) in enumerate(cols):
            ax = axes[i, j]
            if k == "events":
                ax.imshow(event_image(arr[i], scale), interpolation="nearest")
            else:
                im = _image_rgb(arr[i])
                ax.imshow(im, cmap="gray" if im.ndim == 2 else None, vmin=0, vmax=1,
                          interpolation="nearest")
            ax.set_xticks([]); ax.set_yticks([])
            if i == 0:
                ax.set_title(title, fontsize=9)
            if j == 0 and row_labels is not None:
                ax.set_ylabel(str(row_labels[i]), fontsize=8)
    return _save_figure(fig, path)
