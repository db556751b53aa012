"""rdnet.restore.real: restore runs on a recording scored without ground truth."""
import numpy as np

from rdnet.events import Events, Recording
from rdnet.events.io import write_recording
from rdnet.restore.real import Run, recordings, score_recording

from _streams import edge_noise_hot


def test_score_recording_raw_keeps_everything_and_baf_drops_isolated_noise(tmp_path):
    edge, _ = edge_noise_hot(seed=3)           # the edge sweeps x < 60 of a 120-wide sensor ...
    rng = np.random.default_rng(4)
    noise = np.zeros(400, edge.array.dtype)     # ... and isolated noise covers all of it
    noise["t"], noise["x"] = np.sort(rng.integers(0, 60_000, 400)), rng.integers(0, 120, 400)
    noise["y"], noise["p"] = rng.integers(0, 40, 400), rng.integers(0, 2, 400)
    arr = np.concatenate([edge.array, noise])
    ev = Events(arr[np.argsort(arr["t"], kind="stable")], 120, 40)
    path = tmp_path / "rec" / "x" / "x.h5"
    path.parent.mkdir(parents=True)
    write_recording(path, Recording(ev.width, ev.height, events=ev, sensor="SYN"))
    assert recordings([tmp_path / "missing", tmp_path / "rec"]) == [("x", path)]
    runs = [Run("raw", "raw"), Run("baf", "baf"), Run("gef", "gef")]
    sc = score_recording("x", path, {}, runs, tmp_path / "out", keep=False)
    assert list(sc.entry["methods"]) == ["raw", "baf"]          # gef needs frames: no row
    assert list((tmp_path / "out").iterdir()) == []             # keep=False leaves no file
    raw, baf = sc.entry["methods"]["raw"], sc.entry["methods"]["baf"]
    assert raw["events_out"] == len(ev) and raw["kept_fraction"] == 1.0
    assert raw["regions"] == {"activity": 1.0, "background": 1.0}
    assert baf["events_out"] < len(ev) and baf["regions"]["background"] < 0.5 < baf["regions"]["activity"]
    assert sc.entry["events"] == len(ev) and sc.activity.shape == (ev.height, ev.width) and sc.outs == {}
    kept = score_recording("x", path, {}, runs, tmp_path / "kept")
    assert len(kept.outs["baf"]) == baf["events_out"]
    assert sorted(p.name for p in (tmp_path / "kept").iterdir()) == [
        "baf.h5", "baf.json", "baf.summary.json", "raw.h5", "raw.json", "raw.summary.json"]
