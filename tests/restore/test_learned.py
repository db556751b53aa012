"""rdnet.restore.learned: checkpoints found and validated (ConfigError naming the file
and field), an identity restorer passes a stream through unchanged, windows are
half-open."""
import numpy as np
import pytest
import torch

from rdnet.errors import ConfigError
from rdnet.events import Events
from rdnet.events.select import shared_count
from rdnet.events.voxel import voxel_grid
from rdnet.nn.decision import decision_dict
from rdnet.restore.learned import load_restorer
from rdnet.restore.settings import RestoreConfig
from rdnet.train.checkpoint import make_checkpoint, save_checkpoint
from rdnet.train.loop import build_seeded

torch.set_num_threads(1)
PARAMS = {"voxel": {"bins": 3, "mode": "hard", "normalize": None}}
W, H = 20, 12


def _save(path, kind="restore", image_channels=0, output="counts", decision=0.5, bins=3, mode="hard"):
    args = {"kind": kind, "size": "tiny", "image_channels": image_channels, "bins": bins, "width": 4}
    if output != "signed":
        args["restore_output"] = output
    net = build_seeded(args, 0)
    extra = {"voxel": {"bins": bins, "mode": mode, "normalize": None}, "window_us": 30000}
    if decision is not None:
        extra["decision"] = decision if isinstance(decision, dict) else decision_dict(decision)
    save_checkpoint(path, make_checkpoint(net, kind, args, step=1, extra=extra, with_rng=False))
    return path


def _events(seed=0, n=300):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 60000, n))
    t[-1] = 30000                                       # on the window boundary
    return Events.from_columns(t, rng.integers(0, W, n), rng.integers(0, H, n), rng.integers(0, 2, n),
                               W, H, sort=True)


def test_identity_restorer_passes_the_stream_through(tmp_path):
    r = load_restorer(_save(tmp_path / "m" / "seed0" / "model.pt"), has_frames=False, params=PARAMS)
    assert (r.name, r.needs_frames, r.window_us) == ("rdnet-events", False, 30000)
    ev = _events()
    out = r.restore(ev, 0, 30000, None)
    inside = ev.slice_time(0, 30000)
    assert len(out) == len(inside) and out.t.max() < 30000          # half-open window
    np.testing.assert_array_equal(voxel_grid(out, 3, 0, 30000, polarity="split"),
                                  voxel_grid(inside, 3, 0, 30000, polarity="split"))
    # a folder with seed<k>/model.pt is found too
    assert load_restorer(tmp_path / "m", has_frames=True, params=PARAMS).name == "rdnet-events"
    info = r.info                                       # what OUT.json records under "model"
    assert info["source"].endswith("model.pt") and info["output"] == "counts" and not info["image_guided"]
    assert info["decision"]["threshold"] == 0.5 and info["decision"]["drops_unsupported"] is False


def test_kept_events_keep_their_times_or_move_to_the_bins(tmp_path):
    """restore.event_times: with ``input`` (the default) the identity restorer gives the
    window's events back exactly, timestamps included; with ``bins`` the same voxels, every
    event spread over its bin. An unknown value is a ConfigError naming the key."""
    path = _save(tmp_path / "m.pt")
    ev = _events(3)
    inside = ev.slice_time(0, 30000)
    kept = load_restorer(path, has_frames=False, params=PARAMS).restore(ev, 0, 30000, None)
    np.testing.assert_array_equal(kept.array, inside.array)
    r = load_restorer(path, has_frames=False, params=PARAMS, event_times="bins")
    assert r.info["event_times"] == "bins"
    spread = r.restore(ev, 0, 30000, None)
    np.testing.assert_array_equal(voxel_grid(spread, 3, 0, 30000, polarity="split"),
                                  voxel_grid(inside, 3, 0, 30000, polarity="split"))
    assert not np.array_equal(spread.t, inside.t)
    with pytest.raises(ConfigError, match="restore.event_times"):
        load_restorer(path, has_frames=False, params=PARAMS, event_times="exact")


def test_bilinear_network_spreads_its_events_and_records_bins(tmp_path):
    """restore.event_times: input keeps recorded timestamps only for hard voxel bins; a
    network on bilinear voxels spreads its events over the bins, and ``info`` (OUT.json's
    ``model``) records the rule applied, ``bins``, not the one asked for."""
    path = _save(tmp_path / "bil.pt", mode="bilinear")
    ev = _events(5)
    asked_input = load_restorer(path, has_frames=False, params=PARAMS)
    asked_bins = load_restorer(path, has_frames=False, params=PARAMS, event_times="bins")
    assert asked_input.info["event_times"] == asked_bins.info["event_times"] == "bins"
    a, b = asked_input.restore(ev, 0, 30000, None), asked_bins.restore(ev, 0, 30000, None)
    assert len(a) > 0
    np.testing.assert_array_equal(a.array, b.array)
    assert load_restorer(_save(tmp_path / "hard.pt"), has_frames=False, params=PARAMS).info["event_times"] == "input"


def test_add_events_false_caps_every_voxel_at_its_input(tmp_path):
    """restore.add_events: a decision with threshold 0 keeps every voxel with at least one
    event, so the restorer adds events everywhere; capped at the input it deletes nothing here
    and gives the window's events back exactly."""
    path = _save(tmp_path / "m.pt", decision=0.0)
    ev = _events(4)
    inside = ev.slice_time(0, 30000)
    adds = load_restorer(path, has_frames=False, params=PARAMS).restore(ev, 0, 30000, None)
    assert len(adds) > 10 * len(inside)
    r = load_restorer(path, has_frames=False, params=PARAMS, add_events=False)
    assert r.info["add_events"] is False
    np.testing.assert_array_equal(r.restore(ev, 0, 30000, None).array, inside.array)
    spread = load_restorer(path, has_frames=False, params=PARAMS, add_events=False, event_times="bins")
    np.testing.assert_array_equal(voxel_grid(spread.restore(ev, 0, 30000, None), 3, 0, 30000, polarity="split"),
                                  voxel_grid(inside, 3, 0, 30000, polarity="split"))
    with pytest.raises(ConfigError, match=r"bil\.pt.*extra\.voxel\.mode.*add_events"):
        load_restorer(_save(tmp_path / "bil.pt", mode="bilinear"), has_frames=False, params=PARAMS, add_events=False)


def test_delete_events_false_keeps_every_input_event(tmp_path):
    """restore.delete_events: a decision threshold of 1 empties every voxel, so the restorer
    deletes the whole window; raised to the input it gives the window's events back exactly,
    timestamps included. With a decision that adds (threshold 0) the input events are all in
    the output, beside the added ones. Bilinear voxels are refused (no voxel per event)."""
    path = _save(tmp_path / "m.pt", decision=1.0)
    ev = _events(6)
    inside = ev.slice_time(0, 30000)
    assert len(load_restorer(path, has_frames=False, params=PARAMS).restore(ev, 0, 30000, None)) == 0
    r = load_restorer(path, has_frames=False, params=PARAMS, delete_events=False)
    assert r.info["delete_events"] is False and r.info["add_events"] is True
    np.testing.assert_array_equal(r.restore(ev, 0, 30000, None).array, inside.array)
    adds = load_restorer(_save(tmp_path / "a.pt", decision=0.0), has_frames=False, params=PARAMS,
                         delete_events=False).restore(ev, 0, 30000, None)
    assert len(adds) > 5 * len(inside)
    assert shared_count(inside, adds) == len(inside)
    with pytest.raises(ConfigError, match=r"bil\.pt.*extra\.voxel\.mode.*delete_events"):
        load_restorer(_save(tmp_path / "bil.pt", mode="bilinear"), has_frames=False, params=PARAMS,
                      delete_events=False)


def test_restore_config_refuses_neither_adding_nor_deleting():
    assert RestoreConfig(delete_events=False).delete_events is False
    with pytest.raises(ConfigError, match="restore.delete_events.*method: raw"):
        RestoreConfig(add_events=False, delete_events=False)


def test_image_guided_restorer_needs_frames_and_reads_one(tmp_path):
    path = _save(tmp_path / "img.pt", image_channels=1)
    with pytest.raises(ConfigError, match=r"img\.pt.*image_channels.*needs frames"):
        load_restorer(path, has_frames=False, params=PARAMS)
    r = load_restorer(path, has_frames=True, params=PARAMS)
    assert r.name == "rdnet-image" and r.needs_frames
    ev = _events(1)
    frame = np.full((H, W), 128, np.uint8)
    assert len(r.restore(ev, 0, 30000, frame)) == len(ev.slice_time(0, 30000))


def test_wrong_checkpoints_are_config_errors_naming_file_and_field(tmp_path):
    with pytest.raises(ConfigError, match=r"deb\.pt.*model_kind"):
        load_restorer(_save(tmp_path / "deb.pt", kind="deblur", image_channels=1, output="signed",
                            decision=None), has_frames=True, params=PARAMS)
    with pytest.raises(ConfigError, match=r"b4\.pt.*bins"):
        load_restorer(_save(tmp_path / "b4.pt", bins=4), has_frames=False, params=PARAMS)
    with pytest.raises(ConfigError, match=r"nodec\.pt.*decision"):
        load_restorer(_save(tmp_path / "nodec.pt", decision=None), has_frames=False, params=PARAMS)
    with pytest.raises(ConfigError, match=r"rule\.pt.*support rule"):
        load_restorer(_save(tmp_path / "rule.pt", decision=decision_dict(0.5, support={"rule": "x", "drop": True})),
                      has_frames=False, params=PARAMS)
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ConfigError, match="junk.pt"):
        load_restorer(tmp_path / "junk.pt", has_frames=False, params=PARAMS)
    with pytest.raises(ConfigError, match="no model.pt"):
        load_restorer(tmp_path / "empty_dir_missing", has_frames=False, params=PARAMS)


def test_signed_restorer_rounds(tmp_path):
    r = load_restorer(_save(tmp_path / "s.pt", output="signed", decision=None), has_frames=False, params=PARAMS)
    ev = _events(2)
    out = r.restore(ev, 0, 30000, None)            # fresh signed net = identity on signed voxels
    inside = ev.slice_time(0, 30000)
    np.testing.assert_array_equal(voxel_grid(out, 3, 0, 30000), voxel_grid(inside, 3, 0, 30000))
    # ON and OFF events of one voxel cancel; the rest are the input's own events
    assert np.isin(out.t * 1000 + out.y * 50 + out.x, inside.t * 1000 + inside.y * 50 + inside.x).all()


def test_export_writes_model_and_card_and_package_fallback_reads_it(tmp_path, monkeypatch):
    import json
    from rdnet.restore import learned
    from rdnet.restore.learned import export_restorer
    src = _save(tmp_path / "src" / "model.pt")
    out = export_restorer(tmp_path / "src", tmp_path / "pkg", kind="events", metrics={"f1": 0.5})
    card = json.loads((tmp_path / "pkg" / "restore_events.json").read_text())
    assert out.name == "restore_events.pt" and card["decision"]["threshold"] == 0.5 and card["metrics"] == {"f1": 0.5}
    with pytest.raises(ConfigError, match=r"image_channels.*'events' restorer.*exported as the 'frame' one"):
        export_restorer(src, tmp_path / "pkg2", kind="frame")
    with pytest.raises(ConfigError, match="kind"):
        export_restorer(src, tmp_path / "pkg2", kind="image")
    # no study model in the working directory: the packaged model is used
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(learned, "_package_file", lambda name: tmp_path / "pkg" / f"{name}.pt"
                        if (tmp_path / "pkg" / f"{name}.pt").is_file() else None)
    r = load_restorer(None, has_frames=True, params=PARAMS)       # falls back to events-only
    assert r.name == "rdnet-events" and r.source.startswith("package model")
    (tmp_path / "models" / "restore_events").mkdir(parents=True)
    _save(tmp_path / "models" / "restore_events" / "model.pt")
    assert load_restorer(None, has_frames=False, params=PARAMS).source.startswith("study model")


def test_load_restorer_resolves_device_auto(tmp_path):
    """restore.device defaults to 'auto': it becomes a real torch device, and the restorer runs."""
    r = load_restorer(_save(tmp_path / "m.pt"), has_frames=False, params=PARAMS, device="auto")
    assert str(r.device) == ("cuda:0" if torch.cuda.is_available() else "cpu")
    assert len(r.restore(_events(), 0, 30000, None)) > 0
