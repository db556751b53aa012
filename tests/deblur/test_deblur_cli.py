"""``rdnet deblur``: outputs on a synthetic HDF5 recording and on the DAVIS346 file, the
consistency score, and bad input (exit 2, one line naming the file and the field, no
partial output). The networks are fresh RDNets: both stages start as the exact identity
(zero-initialised residual outputs), so restored voxels = input voxels and deblurred =
input frames, which gives known answers."""
from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from rdnet.cli import main
from rdnet.events import EVENT_DTYPE, Events, Frames, Recording, voxel_grid
from rdnet.events.io import load, read_events, save
from rdnet.nn.models import build_model
from rdnet.train.checkpoint import make_checkpoint, save_checkpoint

W, H, N, PERIOD_US = 32, 24, 6, 40_000


def _checkpoint(path, kind="rdnet", bins=4, width=4, voxel=True, channels=1, counts=False, mode="hard", **more):
    args = {"kind": kind, "size": "tiny", "image_channels": channels, "bins": bins, "width": width, **more}
    extra = {"voxel": {"bins": bins, "mode": mode, "normalize": None}} if voxel else {}
    if counts:                    # count-output stage 1 with its fitted decision
        args["restore_output"] = "counts"
        extra["decision"] = {"rule": "occupancy_threshold", "threshold": 0.5}
    return save_checkpoint(path, make_checkpoint(build_model(**args), kind, args, extra=extra, with_rng=False))


def _params(tmp_path, bins=4, mode="hard", **deblur):
    p = tmp_path / "params.yaml"
    d = {"threads": 1, "device": "cpu", "batch_size": 4, "montage_frames": 2, **deblur}
    p.write_text(f"model: {{size: tiny, width: 4}}\nvoxel: {{bins: {bins}, mode: {mode}}}\n"
                 f"sensor: {{threshold_on: 0.2, threshold_off: 0.2, log_eps: 0.01}}\ndeblur: {json.dumps(d)}\n")
    return p


def _recording(rng, exposure_us=0, frames=True, n_events=3000):
    """A bright bar moving right over a textured background; events at odd microseconds
    (never on a frame time or a window edge, which are even)."""
    t = 100_000 + PERIOD_US * np.arange(N, dtype=np.int64)
    yy, xx = np.mgrid[0:H, 0:W]
    base = 0.3 + 0.2 * np.sin(xx / 3.0) * np.cos(yy / 4.0)
    images = np.stack([np.where(np.abs(xx - 6 - 3 * k) < 3, 0.9, base) for k in range(N)]).astype(np.float32)
    ev = np.empty(n_events, EVENT_DTYPE)
    ev["t"] = np.sort(rng.integers(t[0] - PERIOD_US // 2, t[-1] + PERIOD_US // 2, n_events)) // 2 * 2 + 1
    ev["x"], ev["y"], ev["p"] = rng.integers(0, W, n_events), rng.integers(0, H, n_events), rng.integers(0, 2, n_events)
    fr = Frames(images, t, np.full(N, exposure_us, np.int64)) if frames else None
    return Recording(W, H, events=Events(ev, W, H), frames=fr, sensor="TEST")


def _run(capsys, argv):
    """(exit code, stdout, stderr) of ``rdnet`` with ``argv``; never a traceback."""
    code = main(argv)
    captured = capsys.readouterr()
    assert "Traceback" not in captured.out + captured.err
    return code, captured.out, captured.err


@pytest.mark.parametrize("exposure_us", [0, 10_000])
def test_outputs_and_identity_network(capsys, tmp_path, rng, exposure_us):
    rec_path = tmp_path / "rec.h5"
    rec = _recording(rng, exposure_us)
    save(rec_path, rec)
    ck = _checkpoint(tmp_path / "rdnet.pt")
    out, data = tmp_path / "out", tmp_path / "data"
    rc, stdout, err = _run(capsys, ["deblur", str(rec_path), str(out), "--checkpoint", str(ck),
                                    "--data-out", str(data), "--params", str(_params(tmp_path)), "--no-progress"])
    assert rc == 0, err
    assert "raw" in stdout and "restored" in stdout
    assert sorted(p.name for p in out.iterdir()) == ["consistency.json", "montage.png"]
    res = json.loads((out / "consistency.json").read_text())
    assert res["better"] == "higher" and res["frame_pairs"] == N - 1
    assert isinstance(res["raw"], float) and isinstance(res["restored"], float)
    assert set(res["details"]["raw"]) >= {"r2_fitted", "r2_nominal", "correlation", "active", "events"}
    # identity stage 1 + even bins centred on the frames: every restored event stays in its
    # frame interval, so both streams get the same score
    assert res["restored"] == pytest.approx(res["raw"], abs=1e-9)
    assert res["details"]["restored"]["active"] == res["details"]["raw"]["active"]
    assert res["deblur"]["mean_abs_change"] == 0.0               # identity stage 2
    assert res["windows"]["restored_events"] == "interval"
    assert res["windows"]["deblur"] == ("interval" if exposure_us == 0 else "exposure")
    assert ("fallback" in res["windows"]["deblur_note"]) == (exposure_us == 0)

    back = load(data / "restored.h5")
    np.testing.assert_array_equal(back.frames.images, rec.frames.images)
    np.testing.assert_array_equal(back.frames.t_us, rec.frames.t_us)
    # identity: the restored events are the raw ones, net of ON/OFF pairs in one bin and pixel
    grids = [voxel_grid(rec.events, 4, int(t) - PERIOD_US // 2, PERIOD_US) for t in rec.frames.t_us]
    assert len(back.events) == int(sum(np.abs(g).sum() for g in grids))
    with h5py.File(data / "restored.h5") as f:
        assert ("events_deblur" in f) == (exposure_us > 0)
        assert json.loads(f.attrs["deblur_json"])["voxel"]["bins"] == 4
    if exposure_us:
        exp = [voxel_grid(rec.events, 4, int(t) - exposure_us // 2, exposure_us) for t in rec.frames.t_us]
        assert len(read_events(data / "restored.h5", "events_deblur")) == int(sum(np.abs(g).sum() for g in exp))
    pngs = sorted(p.name for p in (data / "deblurred").iterdir())
    assert pngs == [f"{k:05d}.png" for k in range(N)]
    assert not list(tmp_path.glob(".*.tmp"))                     # no staging folders left


@pytest.mark.parametrize("exposure_us", [0, 10_000])
def test_count_output_stage1_keeps_every_raw_event(capsys, tmp_path, rng, exposure_us):
    """A fresh count-output stage 1 is the identity on each polarity (occupancy logit
    +gain where there are events): with its decision every raw event of the interval
    windows comes back -- ON and OFF events of one voxel no longer cancel -- and stage 2
    (the identity) reads ON - OFF."""
    rec = _recording(rng, exposure_us)
    save(tmp_path / "rec.h5", rec)
    ck = _checkpoint(tmp_path / "rdnet.pt", counts=True)
    out, data = tmp_path / "out", tmp_path / "data"
    rc, _, err = _run(capsys, ["deblur", str(tmp_path / "rec.h5"), str(out), "--checkpoint", str(ck),
                               "--data-out", str(data), "--params", str(_params(tmp_path)), "--no-progress"])
    assert rc == 0, err
    back = load(data / "restored.h5")
    t = rec.frames.t_us
    inside = (rec.events.t >= t[0] - PERIOD_US // 2) & (rec.events.t <= t[-1] + PERIOD_US // 2)
    assert len(back.events) == int(inside.sum())
    assert int(back.events.p.sum()) == int(rec.events.p[inside].sum())      # polarities kept
    np.testing.assert_array_equal(back.events.array, rec.events.array[inside])   # deblur.event_times: input
    res = json.loads((out / "consistency.json").read_text())
    assert res["deblur"]["mean_abs_change"] == 0.0
    assert res["run"]["event_times"] == "input" and not any("event_times" in n for n in res["run"]["notes"])
    # event_times: bins -- the same voxels, the times moved to the bins
    rc, _, err = _run(capsys, ["deblur", str(tmp_path / "rec.h5"), str(tmp_path / "out2"), "--checkpoint", str(ck),
                               "--data-out", str(tmp_path / "data2"), "--no-progress",
                               "--params", str(_params(tmp_path, event_times="bins"))])
    assert rc == 0, err
    spread = load(tmp_path / "data2" / "restored.h5").events
    assert len(spread) == int(inside.sum()) and not np.array_equal(spread.t, rec.events.t[inside])


def test_an_output_name_taken_by_a_folder_is_refused_before_the_work(capsys, tmp_path, rng, monkeypatch):
    save(tmp_path / "rec.h5", _recording(rng))
    (tmp_path / "out" / "restored.h5").mkdir(parents=True)
    import rdnet.deblur.run as run_mod
    monkeypatch.setattr(run_mod, "prepare", lambda *a, **k: pytest.fail("the work started"))
    rc, _, err = _run(capsys, ["deblur", str(tmp_path / "rec.h5"), str(tmp_path / "out"), "--no-progress",
                               "--checkpoint", str(_checkpoint(tmp_path / "rdnet.pt")),
                               "--params", str(_params(tmp_path))])
    assert rc == 2 and "restored.h5: exists and is a folder" in err
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["restored.h5"]


def test_frames_that_miss_every_event_are_refused(capsys, tmp_path, rng):
    """Frames 10 s after the last event: no frame interval holds an event, so there is
    nothing to restore or score (this once wrote 'deblurred' frames and n/a scores)."""
    rec = _recording(rng)
    late = Frames(rec.frames.images, rec.frames.t_us + 10_000_000, rec.frames.exposure_us)
    save(tmp_path / "rec.h5", Recording(W, H, events=rec.events, frames=late, sensor="TEST"))
    rc, _, err = _run(capsys, ["deblur", str(tmp_path / "rec.h5"), str(tmp_path / "out"), "--no-progress",
                               "--checkpoint", str(_checkpoint(tmp_path / "rdnet.pt")),
                               "--params", str(_params(tmp_path))])
    assert rc == 2 and "field 'events': no event falls in any frame's window" in err
    assert not (tmp_path / "out").exists()


def test_dual_stage2_checkpoint_deblurs(capsys, tmp_path, rng):
    """An RDNet whose stage 2 reads restored and raw voxels (train.stage2_input: dual, the
    study's rdnet_dual) loads: the checkpoint describes that itself, the model section does
    not name it. Its stage 2 starts as the identity too."""
    save(tmp_path / "rec.h5", _recording(rng))
    ck = _checkpoint(tmp_path / "rdnet.pt", stage2_input="dual")
    rc, _, err = _run(capsys, ["deblur", str(tmp_path / "rec.h5"), str(tmp_path / "out"), "--checkpoint", str(ck),
                               "--params", str(_params(tmp_path)), "--no-progress"])
    assert rc == 0, err
    assert json.loads((tmp_path / "out" / "consistency.json").read_text())["deblur"]["mean_abs_change"] == 0.0


def test_bilinear_voxels_spread_the_events_and_say_so(capsys, tmp_path, rng):
    """deblur.event_times: input needs hard voxel bins (an event of a bilinear grid weighs on
    two bins): with voxel.mode bilinear the restored events are spread over the bins, and
    consistency.json and the HDF5 record that rule, with a note, not the one asked for."""
    rec = _recording(rng)
    save(tmp_path / "rec.h5", rec)
    ck = _checkpoint(tmp_path / "rdnet.pt", counts=True, mode="bilinear")
    out, data = tmp_path / "out", tmp_path / "data"
    rc, _, err = _run(capsys, ["deblur", str(tmp_path / "rec.h5"), str(out), "--checkpoint", str(ck),
                               "--data-out", str(data), "--no-progress",
                               "--params", str(_params(tmp_path, mode="bilinear"))])
    assert rc == 0, err
    res = json.loads((out / "consistency.json").read_text())
    assert res["run"]["event_times"] == "bins"
    assert any("event_times=input" in n and "bilinear" in n for n in res["run"]["notes"])
    with h5py.File(data / "restored.h5") as f:
        assert json.loads(f.attrs["deblur_json"])["event_times"] == "bins"
    back = load(data / "restored.h5").events
    assert len(back) and not np.isin(back.t, rec.events.t).all()     # bin times, not the recorded ones


def test_defaults_to_one_output_folder_and_keeps_other_files(capsys, tmp_path, rng):
    save(tmp_path / "rec.h5", _recording(rng))
    ck = _checkpoint(tmp_path / "rdnet.pt")
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    rc, _, err = _run(capsys, ["deblur", str(tmp_path / "rec.h5"), str(out), "--checkpoint", str(ck),
                               "--params", str(_params(tmp_path, png=False, montage_frames=0))])
    assert rc == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["consistency.json", "keep.txt", "restored.h5"]


def test_colour_network_on_grey_frames(capsys, tmp_path, rng):
    import cv2
    rec = _recording(rng)
    save(tmp_path / "rec.h5", rec)
    ck = _checkpoint(tmp_path / "rgb.pt", channels=3)
    rc, _, err = _run(capsys, ["deblur", str(tmp_path / "rec.h5"), str(tmp_path / "out"), "--checkpoint", str(ck),
                               "--params", str(_params(tmp_path, montage_frames=1))])
    assert rc == 0, err
    back = load(tmp_path / "out" / "restored.h5").frames.images
    assert back.shape == (N, H, W, 3)
    np.testing.assert_array_equal(back, np.repeat(rec.frames.images[..., None], 3, -1))   # identity, R = G = B
    assert cv2.imread(str(tmp_path / "out" / "deblurred" / "00000.png"), cv2.IMREAD_UNCHANGED).shape == (H, W, 3)


def test_davis346_first_frames(capsys, tmp_path, davis346_path):
    ck = _checkpoint(tmp_path / "rdnet.pt", bins=10)
    out = tmp_path / "out"
    rc, _, err = _run(capsys, ["deblur", str(davis346_path), str(out), "--checkpoint", str(ck),
                               "--params", str(_params(tmp_path, bins=10, max_frames=4, png=False))])
    assert rc == 0, err
    res = json.loads((out / "consistency.json").read_text())
    assert res["run"]["frames"] == 4 and (res["run"]["width"], res["run"]["height"]) == (346, 260)
    assert res["windows"]["deblur"] == "exposure"               # AEDAT 4 stores the exposure (500 us)
    assert 0 < res["deblur"]["events_per_window_median"] < 100 and res["deblur"]["mean_abs_change"] == 0.0
    assert res["frame_pairs"] == 2 and 0 < res["raw"] < 1     # events start after frame 0
    assert res["restored"] == pytest.approx(res["raw"], abs=0.02)  # identity, up to events on bin edges
    assert (out / "montage.png").stat().st_size > 0


def _bad(tmp_path, rng, case):
    """(argv tail, words the message must contain) for one bad-input case."""
    rec = tmp_path / "rec.h5"
    save(rec, _recording(rng))
    ck = tmp_path / "rdnet.pt"
    params = _params(tmp_path)
    if case == "deblur_checkpoint":
        _checkpoint(ck, kind="deblur")
        return [str(rec), "--checkpoint", str(ck), "--params", str(params)], ["rdnet.pt", "model_kind", "'deblur'"]
    _checkpoint(ck)
    if case == "other_size":
        _checkpoint(ck, width=8)
        return [str(rec), "--checkpoint", str(ck), "--params", str(params)], ["rdnet.pt", "model_args", "width=8"]
    if case == "bins":
        return ([str(rec), "--checkpoint", str(ck), "--params", str(params), "--set", "voxel.bins=5"],
                ["rdnet.pt", "model_args.bins", "voxel.bins is 5"])
    if case == "voxel_mode":
        return ([str(rec), "--checkpoint", str(ck), "--params", str(params), "--set", "voxel.mode=bilinear"],
                ["rdnet.pt", "extra.voxel.mode", "bilinear"])
    if case == "no_frames":
        save(rec, _recording(rng, frames=False))
        return [str(rec), "--checkpoint", str(ck), "--params", str(params)], ["rec.h5", "frames"]
    if case == "sizes_differ":                 # frames of another size than the sensor's events
        with h5py.File(rec, "r+") as f:
            f.attrs["width"] = W + 8
        return [str(rec), "--checkpoint", str(ck), "--params", str(params)], ["rec.h5", "frames/images", "32x24"]
    if case == "exposure_missing":
        return ([str(rec), "--checkpoint", str(ck), "--params", str(params), "--set", "deblur.window=exposure"],
                ["rec.h5", "frames/exposure_us"])
    if case == "missing_checkpoint":
        return [str(rec), "--checkpoint", str(tmp_path / "nope.pt"), "--params", str(params)], ["nope.pt", "not found"]
    if case == "empty_model_folder":
        (tmp_path / "models").mkdir()
        return [str(rec), "--checkpoint", str(tmp_path / "models"), "--params", str(params)], ["models", "model.pt"]
    raise AssertionError(case)


@pytest.mark.parametrize("case", ["deblur_checkpoint", "other_size", "bins", "voxel_mode", "no_frames",
                                  "sizes_differ", "exposure_missing", "missing_checkpoint",
                                  "empty_model_folder"])
def test_bad_input_exits_2_naming_file_and_field(capsys, tmp_path, rng, case):
    argv, words = _bad(tmp_path, rng, case)
    out = tmp_path / "out"
    rc, stdout, err = _run(capsys, ["deblur", argv[0], str(out), *argv[1:], "--data-out", str(tmp_path / "data")])
    assert rc == 2 and stdout == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rdnet deblur: error: ")
    for w in words:
        assert w in lines[0], (w, lines[0])
    assert not out.exists() and not (tmp_path / "data").exists()
    assert not list(tmp_path.glob(".*.tmp"))


def test_failure_while_writing_leaves_no_partial_output(capsys, tmp_path, rng, monkeypatch):
    save(tmp_path / "rec.h5", _recording(rng))
    ck = _checkpoint(tmp_path / "rdnet.pt")
    import rdnet.eval.report as report

    def boom(*a, **k):
        raise OSError("disk full")
    monkeypatch.setattr(report, "sample_grid", boom)          # fails after frames and events are written
    with pytest.raises(OSError, match="disk full"):
        main(["deblur", str(tmp_path / "rec.h5"), str(tmp_path / "out"), "--checkpoint", str(ck),
              "--data-out", str(tmp_path / "data"), "--params", str(_params(tmp_path))])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["params.yaml", "rdnet.pt", "rec.h5"]


def test_trained_checkpoint_records_its_voxels(tmp_path, rng):
    from rdnet.config import load_params
    from rdnet.deblur.run import deblur_recording
    from rdnet.errors import FormatError
    from rdnet.train.config import ModelConfig, TrainConfig
    from rdnet.train.loop import train
    from rdnet.train.synthetic import write_synthetic_pairs
    pairs = write_synthetic_pairs(tmp_path / "pairs.h5", n=2, bins=4, height=16, width=16, seed=0)
    cfg = TrainConfig(iterations=1, batch_size=2, crop=16, device="cpu", dvclive=False, threads=1)
    ck = train("rdnet", cfg, ModelConfig(size="tiny", width=4), pairs, tmp_path / "run", progress=False)
    save(tmp_path / "rec.h5", _recording(rng, exposure_us=10_000))
    params = load_params(_params(tmp_path, png=False, montage_frames=0))
    res = deblur_recording(tmp_path / "rec.h5", tmp_path / "out", params, checkpoint=tmp_path / "run")
    assert res["run"]["checkpoint"] == str(ck) and res["run"]["notes"] == []   # mode/normalize checked
    with pytest.raises(FormatError, match="extra.voxel.normalize"):
        deblur_recording(tmp_path / "rec.h5", tmp_path / "out2", load_params(_params(tmp_path), ["voxel.normalize=maxabs"]),
                         checkpoint=ck)


@pytest.mark.parametrize("given", [[], ["--checkpoint", "models/rdnet"], ["--checkpoint", "./models/../models/rdnet"],
                                   ["--checkpoint", "ABSOLUTE"]])
def test_without_the_study_trained_the_default_checkpoint_says_how_to_get_one(capsys, tmp_path, rng, monkeypatch,
                                                                             given):
    """A fresh install (no `dvc repro` yet) has no models/rdnet: one line that says how to
    train it or to pass --checkpoint, exit 2, no output (this once said only 'checkpoint not
    found'); the same when that place is given, as the deblur_real stage gives it, however
    the path is spelt."""
    given = [str(tmp_path / "models" / "rdnet") if a == "ABSOLUTE" else a for a in given]
    save(tmp_path / "rec.h5", _recording(rng))
    monkeypatch.chdir(tmp_path)
    rc, _, err = _run(capsys, ["deblur", "rec.h5", "out", "--params", str(_params(tmp_path)), "--no-progress",
                               *given])
    assert rc == 2
    assert "models/rdnet" in err and "dvc repro train_deblur" in err and "--checkpoint" in err
    assert not (tmp_path / "out").exists()
