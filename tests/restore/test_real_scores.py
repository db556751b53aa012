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


def test_read_facts_gives_hot_pixels_and_sizes_and_names_a_bad_field(tmp_path):
    import pytest

    from rdnet.errors import ConfigError
    from rdnet.restore.real import read_facts
    f = tmp_path / "facts.yaml"
    f.write_text("hot_pixels:\n  cam: [[1, 2], [3, 4]]\nsensor_size:\n  txt: [240, 180]\n")
    facts = read_facts(f)
    assert facts.hot_pixels == {"cam": [(1, 2), (3, 4)]} and facts.sensor_size == {"txt": (240, 180)}
    f.write_text("sensor_size:\n  txt: [240]\n")
    with pytest.raises(ConfigError, match="facts.sensor_size.txt"):
        read_facts(f)
    f.write_text("hot_pixel: {}\n")
    with pytest.raises(ConfigError, match="facts.yaml"):
        read_facts(f)


def test_score_recording_scores_the_known_hot_pixels_it_is_given(tmp_path):
    from rdnet.restore.real import RecordingFacts
    edge, _ = edge_noise_hot(seed=3)
    path = tmp_path / "x" / "x.h5"
    path.parent.mkdir(parents=True)
    write_recording(path, Recording(edge.width, edge.height, events=edge, sensor="SYN"))
    hot = [(int(edge.x[0]), int(edge.y[0]))]
    sc = score_recording("x", path, {}, [Run("raw", "raw")], tmp_path / "out", keep=False,
                         facts=RecordingFacts(hot_pixels={"x": hot}))
    assert sc.entry["hot_pixels"] == hot and sc.entry["methods"]["raw"]["regions"]["hot_pixels"] == 1.0
