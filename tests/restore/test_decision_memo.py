"""Runs of the learned restorer that share a DecisionMemo (restore_real's learned row, its
deletions only and its additions only) write the bytes that each run writes on its own, and
the later runs take every window's decision from the memo."""
import json

import numpy as np

from rdnet.events import Events, Recording
from rdnet.events.io import load, write_recording
from rdnet.restore.learned import DecisionMemo
from rdnet.restore.real import Run, score_recording
from rdnet.restore.run import restore_recording

from _streams import edge_noise_hot
from test_learned_speed import PARAMS, WINDOW, _checkpoint

VARIANTS = ({}, {"add_events": False}, {"delete_events": False}, {"hot_pixel_factor": 0})


def _recording(tmp_path):
    ev, _ = edge_noise_hot(seed=3)
    path = tmp_path / "rec.h5"
    write_recording(path, Recording(60, 40, events=Events(ev.array, 60, 40), sensor="SYN"))
    return path


def _params(**restore):
    return {**PARAMS, "restore": {"window_us": WINDOW, "workers": 1, **restore}}


def _events(path):
    return load(path).events.array


def test_shared_decisions_write_the_same_events_and_reuse_every_window(tmp_path):
    rec = _recording(tmp_path)
    ck = _checkpoint(tmp_path / "model.pt", image_channels=0)
    alone = {}
    for i, v in enumerate(VARIANTS):
        out = tmp_path / f"alone{i}.h5"
        restore_recording(rec, out, _params(**v), method="rdnet", checkpoint=ck, progress=False)
        alone[i] = _events(out)
    memo = DecisionMemo()
    for i, v in enumerate(VARIANTS):
        out = tmp_path / f"shared{i}.h5"
        restore_recording(rec, out, _params(**v), method="rdnet", checkpoint=ck, progress=False, memo=memo)
        assert np.array_equal(_events(out), alone[i]), v
    windows = memo.computed // 2      # the plain input's windows, and those with the hot pixel kept
    assert windows >= 4 and memo.computed == 2 * windows
    # the deletions-only and additions-only runs read every window of the first run
    assert memo.reused == 2 * windows
    # what the runs share cannot be changed by one of them
    assert all(not a.flags.writeable for entries in memo._entries.values() for a in entries)
    # the variants are not all the same stream (the filters act)
    assert len({a.tobytes() for a in alone.values()}) >= 3


def test_a_memo_keeps_two_networks_apart(tmp_path):
    rec = _recording(tmp_path)
    a = _checkpoint(tmp_path / "a.pt", image_channels=0, threshold=0.05)
    b = _checkpoint(tmp_path / "b.pt", image_channels=0, threshold=0.95)
    memo = DecisionMemo()
    outs = {}
    for name, ck in (("a", a), ("b", b)):
        out = tmp_path / f"{name}.h5"
        restore_recording(rec, out, _params(), method="rdnet", checkpoint=ck, progress=False, memo=memo)
        outs[name] = _events(out)
        ref = tmp_path / f"{name}_alone.h5"
        restore_recording(rec, ref, _params(), method="rdnet", checkpoint=ck, progress=False)
        assert np.array_equal(outs[name], _events(ref))
    assert memo.reused == 0 and not np.array_equal(outs["a"], outs["b"])


def test_score_recording_shares_the_learned_rows_decisions(tmp_path):
    """restore_real's rows through score_recording: the same scores as separate runs."""
    rec = _recording(tmp_path)
    ck = _checkpoint(tmp_path / "model.pt", image_channels=0)
    runs = [Run("rdnet", "rdnet", checkpoint=ck),
            Run("rdnet_deletions_only", "rdnet", checkpoint=ck, restore={"add_events": False})]
    together = score_recording("x", rec, _params(), runs, tmp_path / "together", keep=False)
    for run in runs:
        one = score_recording("x", rec, _params(), [run], tmp_path / run.key, keep=False)
        # (as JSON: a region with no events scores NaN, which equals nothing)
        assert json.dumps(one.entry["methods"][run.key], sort_keys=True) == \
            json.dumps(together.entry["methods"][run.key], sort_keys=True)
