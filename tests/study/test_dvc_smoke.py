"""Smoke test of the study graph: `dvc repro report` (everything up to the report) with minute sizes in a
temporary copy of the repo; a forced rerun of a training leaves everything downstream up to
date (byte-identical network directory); then `dvc exp run evaluate@edi -S
degrade.threshold_sigma=...` reruns the stages downstream of the degradation (simulate, blur,
the evaluation) and not those upstream of it (scenes, interpolate)."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
DVC = Path(sys.executable).with_name("dvc")

pytestmark = [pytest.mark.first,     # about half of the suite's time: started first (tests/conftest.py)
              pytest.mark.skipif(not DVC.exists(), reason="dvc not installed beside this python")]


def _tiny_params(p: dict) -> dict:
    p["scenes"].update(n_train=2, n_test=1, height=24, width=24, n_frames=30, n_objects=1)
    p["interpolate"].update(max_upsample=2)
    p["train"].update(iterations=3, batch_size=2, crop=16, log_every=1, ckpt_every=2, val_sequences=1)
    p["ablation"]["level_bins"] = 2
    p["ednccn"].update(val_sequences=1, max_train_events=3000, epochs=1)
    p["study"].update(seeds=[0, 1], parallel=2,      # two seeds, trained in two processes
                      stress_scales=[0.5, 2.0], stress_rows=["degraded_train", "restored"])
    return p


def _run(cmd, cwd, env):
    r = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, f"{cmd} failed:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r.stdout + r.stderr


def test_dvc_repro_and_exp_run(tmp_path):
    repo = tmp_path / "repo"
    repo.mkdir()
    for name in ("rdnet", "stages"):
        # numba's compiled kernels (*.nbi/*.nbc in __pycache__) travel with the code: their
        # index checks the source file's mtime and size, which copytree keeps, so the stages
        # reuse what the earlier tests compiled (simulate: 33 -> 2.4 s) instead of compiling
        # every kernel again in the copy; bytecode (*.pyc) is left behind
        shutil.copytree(ROOT / name, repo / name, ignore=shutil.ignore_patterns("*.pyc"))
    shutil.copy(ROOT / "dvc.yaml", repo / "dvc.yaml")
    params = _tiny_params(yaml.safe_load((ROOT / "params.yaml").read_text()))
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}:{os.environ['PATH']}",
               PYTHONPATH=str(repo), GIT_AUTHOR_NAME="t", GIT_AUTHOR_EMAIL="t@t",
               GIT_COMMITTER_NAME="t", GIT_COMMITTER_EMAIL="t@t", DVC_NO_ANALYTICS="1")
    _run(["git", "init", "-q"], repo, env)
    _run([str(DVC), "init", "-q"], repo, env)
    shutil.copy(ROOT / ".dvcignore", repo / ".dvcignore")   # as the repo: numba/pyc caches are not code deps
    _run([str(DVC), "config", "core.analytics", "false"], repo, env)
    _run([str(DVC), "repro", "report"], repo, env)

    rows = params["ablation"]["rows"]
    for rid in rows:
        m = json.loads((repo / "metrics" / f"{rid}.json").read_text())
        assert {"psnr", "ssim"} <= set(m), rid
        assert 0 < m["psnr"] < 100 and -1 <= m["ssim"] <= 1
        trained = "checkpoint" in rows[rid]
        assert m["n_seeds"] == (2 if trained else 0), rid
        if trained:      # the two seeds are different trainings: a spread is measured
            d = json.loads((repo / "results" / "rows" / f"{rid}.json").read_text())
            assert len(d["psnr_seeds"]) == 2 and m["psnr_std"] >= 0
            assert abs(m["psnr"] - sum(d["psnr_seeds"]) / 2) < 1e-9
    for net in params["networks"]:
        summary = json.loads((repo / "models" / net / "summary.json").read_text())
        assert [r["seed"] for r in summary["runs"]] == [0, 1]
        factor = params["networks"][net].get("iterations_factor", 1)
        assert all(r["iterations"] == round(3 * factor) for r in summary["runs"])
    rest = json.loads((repo / "metrics" / "restoration.json").read_text())
    assert set(rest) == {"degraded", "stcf", "gef", "baf", "gef_voxel", "ednccn", "rdnet", "rdnet_signed",
                         "rdnet_dual", "restore_image", "restore_events", "restore_frames", "restore_signed"}
    assert all("voxel_l1" in v and 0 <= v["events"]["f1"] <= 1 for v in rest.values())
    assert rest["degraded"]["events"]["reference"] == rest["rdnet"]["events"]["reference"] > 0
    assert (repo / "results" / "ablation.md").read_text().count("| `") == len(rows)
    bars = json.loads((repo / "results" / "plots" / "psnr_rows.json").read_text())
    assert [b["row"] for b in bars] == list(rows)

    _run([str(DVC), "repro", "stress"], repo, env)
    stress = json.loads((repo / "metrics" / "stress.json").read_text())
    assert stress["scales"] == [0.5, 2.0] and set(stress["rows"]) == {"degraded_train", "restored"}
    assert all(len(v) == 2 and len(v[0]["psnr_seeds"]) == 2 for v in stress["rows"].values())
    import h5py
    for scale in (0.5, 2.0):          # every effect of every test sequence at exactly scale x degrade
        for f in sorted((repo / "data" / "stress" / f"scale_{scale:g}" / "events" / "test").glob("*.h5")):
            with h5py.File(f, "r") as h:
                deg = json.loads(h.attrs["degrade_json"])
            assert deg["refractory_us"] == pytest.approx(scale * params["degrade"]["refractory_us"])
            assert deg["shot_noise_hz"] == pytest.approx(scale * params["degrade"]["shot_noise_hz"])
    assert (repo / "results" / "stress" / "psnr_vs_strength.png").stat().st_size > 0

    # a training rerun (killed, or forced) that reproduces its weights leaves its out's hash
    # unchanged, so nothing downstream reruns; its wall times sit outside models/
    _run([str(DVC), "repro", "-f", "-s", "train_restore"], repo, env)
    status = _run([str(DVC), "status", "train_restore", "train_deblur", "evaluate@rdnet", "stress"], repo, env)
    assert "up to date" in status, status
    assert json.loads((repo / "metrics" / "train" / "restore_image.json").read_text())["runs"][0]["wall_s"] > 0
    assert "events_f1" in stress["restoration"]["restore_events"][0]

    _run(["git", "add", "-A"], repo, env)
    _run(["git", "commit", "-qm", "base"], repo, env)
    # one evaluation as the target (the whole graph ran above; this checks what the
    # experiment reruns in about 25 s, where `exp run report` took about 200 s on 2 cores)
    out = _run([str(DVC), "exp", "run", "evaluate@edi", "-S", "degrade.threshold_sigma=0.05"], repo, env)
    ran = {line.split("'")[1] for line in out.splitlines() if line.startswith("Running stage '")}
    assert {"simulate", "blur", "evaluate@edi"} <= ran
    assert "scenes" not in ran and "interpolate" not in ran
