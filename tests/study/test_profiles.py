"""The `paper` profile (profiles/paper.yaml) and the GOPRO source of the scenes stage."""
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from rdnet.config import SECTIONS, load_params, section
from rdnet.errors import ConfigError, FormatError

ROOT = Path(__file__).resolve().parents[2]


def _keys(d, prefix=""):
    out = set()
    for k, v in d.items():
        out.add(prefix + k)
        if isinstance(v, dict) and k != "rows":
            out |= _keys(v, f"{prefix}{k}.")
    return out


def test_paper_profile_has_the_same_keys_as_params():
    base = yaml.safe_load((ROOT / "params.yaml").read_text())
    paper = yaml.safe_load((ROOT / "profiles/paper.yaml").read_text())
    assert _keys(paper) == _keys(base)
    assert set(paper["ablation"]["rows"]) == set(base["ablation"]["rows"])


def test_paper_profile_holds_the_papers_settings():
    params = load_params(ROOT / "profiles/paper.yaml")
    for name in SECTIONS:
        if name in params:
            section(params, name)                     # every section validates
    t = section(params, "train")
    assert (t.crop, t.batch_size, t.iterations, t.lr, t.lr_min, t.alpha, t.beta) == (256, 8, 300000, 2e-4, 1e-7, 0.5, 0.5)
    assert t.device == "cuda" and section(params, "voxel").bins == 10
    assert section(params, "model").size == "paper"
    assert section(params, "scenes").source == "gopro"
    assert section(params, "study").launcher.startswith("torchrun")
    from rdnet.nn.models import build_model
    n = sum(p.numel() for p in build_model("rdnet", size="paper", image_channels=3, bins=10).parameters())
    assert abs(n - 7.86e6) / 7.86e6 < 0.02          # the paper's 7.86 M for both stages


def _fake_gopro(root: Path, n_frames=5, h=12, w=16):
    rng = np.random.default_rng(0)
    for split, names in (("train", ("GOPR0001_00_00", "GOPR0002_00_00")), ("test", ("GOPR0003_00_00",))):
        for name in names:
            d = root / split / name
            d.mkdir(parents=True)
            for i in range(n_frames):
                cv2.imwrite(str(d / f"{i:06d}.png"), rng.integers(0, 255, (h, w, 3), dtype=np.uint8))


def test_gopro_source_reads_sequence_folders(tmp_path):
    from rdnet.events.io import read_recording
    from rdnet.study.data import render_scenes
    _fake_gopro(tmp_path / "gopro")
    params = load_params(ROOT / "params.yaml", sets=["scenes.source=gopro", f"scenes.gopro_root={tmp_path / 'gopro'}",
                                                      "scenes.n_train=0", "scenes.n_test=0", "scenes.n_frames=4"])
    stats = render_scenes(params, tmp_path / "scenes")
    assert stats == {"train": 2, "test": 1}
    rec = read_recording(tmp_path / "scenes" / "test" / "seq_000.h5")
    assert rec.frames.images.shape == (4, 12, 16)            # grey (scenes.color false), capped at n_frames
    assert rec.attrs["sequence"] == "GOPR0003_00_00"
    assert np.allclose(np.diff(rec.frames.t_us), 1e6 / 240, atol=1)


def test_gopro_source_errors_name_the_key_or_folder(tmp_path):
    with pytest.raises(ConfigError, match="scenes.gopro_root"):
        section(load_params(ROOT / "params.yaml", sets=["scenes.source=gopro"]), "scenes")
    from rdnet.study.data import render_scenes
    params = load_params(ROOT / "params.yaml", sets=["scenes.source=gopro", f"scenes.gopro_root={tmp_path}"])
    with pytest.raises(FormatError, match="train"):
        render_scenes(params, tmp_path / "out")
