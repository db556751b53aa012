"""Markdown tables and figures of the study."""
import numpy as np
import pytest
from matplotlib.image import imread

from rdnet.eval.report import (event_image, markdown_table, plot_metric_bars, plot_metric_vs_level,
                               sample_grid, write_table)

ROWS = {
    "blurry": {"psnr": 25.0, "ssim": 0.8,
               "by_level": [{"level_bin": 0.25, "n": 2, "psnr": 26.0}, {"level_bin": 0.75, "n": 2, "psnr": 24.0}]},
    "rdnet": {"psnr": 30.123456, "ssim": 0.9, "restoration": {"voxel_l1": 0.25},
              "by_level": [{"level_bin": 0.25, "n": 2, "psnr": 31.0}, {"level_bin": 0.75, "n": 2, "psnr": 29.0}]},
    "restore": {"restoration": {"voxel_l1": 0.5}},
}


def test_markdown_table(tmp_path):
    text = markdown_table(ROWS, ["psnr", "ssim", "restoration.voxel_l1"])
    lines = text.strip().splitlines()
    assert [c.strip() for c in lines[0].split("|")[1:-1]] == ["method", "psnr", "ssim", "restoration.voxel_l1"]
    assert len(lines) == 2 + 3
    assert "30.1235" in lines[3] and "0.2500" in lines[3] and "nan" in lines[4]
    p = write_table(tmp_path / "t.md", ROWS, title="Results")
    assert p.read_text().startswith("# Results\n\n|")


def test_figures_are_written(tmp_path):
    bars = plot_metric_bars(tmp_path / "f" / "bars.png", ROWS)
    lines = plot_metric_vs_level(tmp_path / "f" / "level.png", ROWS)
    for p in (bars, lines):
        im = imread(p)
        assert im.ndim == 3 and im.shape[0] > 100 and im.shape[1] > 100
        assert im[..., :3].std() > 0.01        # not a blank canvas
    assert sorted(x.name for x in (tmp_path / "f").iterdir()) == ["bars.png", "level.png"]  # no temp files


def test_event_image_colours():
    v = np.zeros((2, 2, 3))
    v[0, 0, 0] = 2.0; v[1, 0, 0] = 2.0     # +4 -> saturated red
    v[:, 0, 1] = -1.0                      # -2 -> half blue at scale 4
    rgb = event_image(v, scale=4.0)
    assert rgb[0, 0].tolist() == [1.0, 0.0, 0.0]
    assert rgb[0, 1].tolist() == [0.5, 0.5, 1.0]
    assert rgb[1, 2].tolist() == [1.0, 1.0, 1.0]


@pytest.mark.parametrize("channels,restored", [(1, True), (3, False)])
def test_sample_grid(tmp_path, channels, restored):
    rng = np.random.default_rng(0)
    n = 2
    img = lambda: rng.random((n, channels, 16, 20))
    vox = lambda: rng.integers(-2, 3, (n, 3, 16, 20)).astype(np.float32)
    path = sample_grid(tmp_path / "grid.png", img(), vox(), vox() if restored else None, img(), img(),
                       row_labels=["a", "b"])
    im = imread(path)
    assert im.shape[0] > 100 and im.shape[1] > 4 * 100 * (16 / 20) * 0.8
    with pytest.raises(ValueError, match="samples"):
        sample_grid(tmp_path / "bad.png", img(), vox()[:1], None, img(), img())
