"""Regime sweep of the RDNet row (rdnet.study.regimes) at minute sizes."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from rdnet.config import load_params
from rdnet.errors import ConfigError, FormatError
from rdnet.study import regimes
from rdnet.study.data import interpolate_scenes, make_pairs, render_scenes, simulate_sequences

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """params.yaml at minute sizes and its study data (data/pairs, data/events) as
    `dvc repro blur` makes them."""
    p = yaml.safe_load((ROOT / "params.yaml").read_text())
    p["scenes"].update(n_train=2, n_test=1, height=24, width=24, n_frames=30, n_objects=1)
    p["interpolate"].update(max_upsample=2)
    p["train"].update(iterations=2, batch_size=2, crop=16, log_every=1, dvclive=False, val_sequences=1)
    p["ablation"]["level_bins"] = 2
    p["study"].update(seeds=[0, 1], parallel=1)
    params = load_params(None, base=p)
    d = tmp_path_factory.mktemp("study") / "data"
    render_scenes(params, d / "scenes")
    interpolate_scenes(params, d / "scenes", d / "interp")
    simulate_sequences(params, d / "scenes", d / "interp", d / "events")
    make_pairs(params, d / "events", d / "pairs")
    return params, d


def test_variants_are_valid_params_changes():
    base = load_params(ROOT / "params.yaml")
    for name, v in regimes.VARIANTS.items():
        p = regimes.variant_params(base, v)
        assert p != base, name
        assert regimes.changes_data(base, p) == (name == "data_x4"), name
    assert base["scenes"]["n_train"] == 12                  # the base dict is not mutated
    with pytest.raises(ConfigError, match="train.nope"):
        regimes.variant_params(base, regimes.Variant(("train.nope=1",)))


def test_rows_point_at_the_variant_models(study):
    params, _ = study
    cfg = regimes._ablation(params, Path("/w/models"))
    assert cfg.row("rdnet").checkpoint == "/w/models/rdnet"
    assert cfg.row("restored").filter_checkpoint == "/w/models/rdnet"
    assert cfg.row("upper_bound").checkpoint == "/w/models/deblur_undegraded"
    assert params["ablation"]["rows"]["rdnet"]["checkpoint"] == "models/rdnet"     # params untouched


def test_training_data_guard(study, tmp_path):
    params, d = study
    same = regimes.train_pairs(params, params, d, tmp_path / "a")
    assert same == d / "pairs" / "train.h5"
    with pytest.raises(FormatError, match="dvc repro blur"):
        regimes.train_pairs(params, params, tmp_path / "nothing", tmp_path / "b")
    # a variant that changes the degradation changes the test set too: refused
    harder = regimes.variant_params(params, regimes.Variant(("degrade.threshold_sigma=0.3",)))
    with pytest.raises(ConfigError, match="test set"):
        regimes.train_pairs(params, harder, d, tmp_path / "c")
    # more training scenes: new training pairs, the same test set
    more = regimes.variant_params(params, regimes.Variant(("scenes.n_train=3",)))
    pairs = regimes.train_pairs(params, more, d, tmp_path / "d")
    assert pairs == tmp_path / "d" / "data" / "pairs" / "train.h5"
    assert regimes._n_samples(pairs) > regimes._n_samples(same)


def test_run_variant_trains_scores_and_reports(study, tmp_path):
    params, d = study
    res = regimes.run_variant("short", regimes.Variant(("train.iterations=3",), "test"), params,
                              data_dir=d, work=tmp_path, progress=False)
    assert res["sets"] == ["train.iterations=3"] and not res["own_training_data"]
    assert set(res["rows"]) == set(regimes.ROWS)
    for rid, r in res["rows"].items():
        assert r["seeds"] == [0, 1] and len(r["psnr_seeds"]) == 2, rid
    g = res["gaps"]["rdnet_minus_row2"]
    per = [a - b for a, b in zip(res["rows"]["rdnet"]["psnr_seeds"], res["rows"]["degraded_train"]["psnr_seeds"])]
    assert g["per_seed"] == pytest.approx(per) and g["n"] == 2
    assert res["networks"]["rdnet"]["iterations"] == 3
    assert res["networks"]["rdnet"]["parameters"] > res["networks"]["deblur_degraded"]["parameters"]
    for name, *_ in regimes.NETWORKS:
        assert (tmp_path / "short" / "models" / name / "seed1" / "model.pt").is_file()
    md = regimes.markdown({"short": res})
    assert md.count("\n") == 3 and "`short`" in md and "`train.iterations=3`" in md
    png = regimes.plot({"short": res}, tmp_path / "p.png")
    assert png.read_bytes()[:4] == b"\x89PNG"
    json.dumps(res)                                            # JSON-ready


def test_study_reference_reads_the_committed_rows(tmp_path):
    assert regimes.study_reference(tmp_path) is None           # nothing there
    for rid, psnr in zip(regimes.ROWS, (20.0, 21.0, 21.5, 25.0, 20.5)):
        (tmp_path / f"{rid}.json").write_text(json.dumps(
            {"psnr": psnr, "psnr_std": 0.1, "psnr_seeds": [psnr - 0.1, psnr + 0.1], "ssim": 0.5,
             "ssim_std": 0.0, "seeds": [0, 1]}))
    ref = regimes.study_reference(tmp_path)
    assert ref["gaps"]["rdnet_minus_row2"]["mean"] == pytest.approx(0.5)
    assert ref["gaps"]["row2_minus_row1"]["positive"] == 2


def test_readme_quotes_the_committed_sweep_table():
    md = (ROOT / "benchmarks" / "results" / "rdnet_regimes.md").read_text()
    readme = (ROOT / "docs" / "study.md").read_text()   # the sweep table moved there from README.md
    block = readme.split("<!-- regimes:start (benchmarks/results/rdnet_regimes.md) -->\n")[1].split("<!-- regimes:end -->")[0]
    assert block == md
