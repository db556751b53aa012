"""The proof's case lists and its concealed recordings from the circuit generator."""
import collections

import numpy as np
import pytest

from rdnet.calib.effects import EFFECTS
from rdnet.calib.proof import CASES, CIRCUIT_CASES, QUICK, ProofCase, cases_for, make_recording
from rdnet.calib.scene import SceneSpec
from rdnet.errors import ValidationError
from rdnet.sim.interpolate import InterpolateConfig
from rdnet.sim.settings import SensorConfig

SPEC = SceneSpec(width=32, height=32, duration_us=300_000, fps_hz=100.0, period_s=0.3)


def test_every_effect_on_both_generators_two_strengths_two_scenes_and_three_nulls():
    lists = cases_for("both")
    seven = {"refractory_period", "leak_events", "bandwidth", "hot_pixels", "onoff_asymmetry", "latency",
             "threshold_mismatch"}
    for gen, cases in lists.items():
        assert all(c.generator == gen for c in cases)
        per_effect = collections.defaultdict(set)
        for c in cases:
            if c.effect:
                assert c.effect in EFFECTS
                per_effect[c.effect].add((tuple(sorted(c.truth.items())), c.scene))
        assert set(per_effect) == seven
        for effect, variants in per_effect.items():
            truths = {t for t, _ in variants}
            scenes = {s for _, s in variants}
            assert len(truths) >= 2 and len(scenes) >= 2 and len(variants) >= 4, (gen, effect)
        assert sum(c.effect is None for c in cases) >= 3
    names = [c.name for cs in lists.values() for c in cs]
    assert len(names) == len(set(names))
    # the original rdnet cases come first and unchanged (their committed results hold)
    assert lists["rdnet"][:len(CASES)] == CASES
    quick = cases_for("both", quick=True)
    assert {c.name for cs in quick.values() for c in cs} == set(QUICK)
    with pytest.raises(ValidationError):
        cases_for("v2e")


def test_circuit_case_is_concealed_and_records_its_truth():
    case = next(c for c in CIRCUIT_CASES if c.name == "circuit_refractory_vs_lower_thresholds_s1A")
    rec, truth = make_recording(case, SPEC, SensorConfig(), np.random.default_rng(3), 1,
                                InterpolateConfig(method="linear", max_upsample=4))
    assert truth["generator"] == "circuit"
    assert truth["circuit"]["refractory_us"] == 5000.0
    assert truth["degrade"] == {"refractory_us": 5000.0}
    # the dead time removes events; lower thresholds put them back to the base count
    assert truth["uncompensated_count"] < 0.9 * truth["base_count"]
    assert abs(truth["count"] - truth["base_count"]) <= 0.01 * truth["base_count"]
    assert truth["threshold_scale"] < 1.0
    assert len(rec.events) == truth["count"]
    # the recorded frames are at the scene rate; the circuit saw 4x denser ones
    assert len(rec.frames.t_us) == 31


def test_circuit_null_frame_rate_case_records_at_sixty_fps():
    case = next(c for c in CIRCUIT_CASES if c.name == "circuit_null_frame_rate_60")
    rec, truth = make_recording(case, SPEC, SensorConfig(), np.random.default_rng(4))
    assert len(rec.frames.t_us) == 19                       # 0.3 s at 60 fps
    assert truth["count"] == truth["base_count"] == truth["uncompensated_count"]
    assert truth["degrade"] == {"shot_noise_hz": 1.0, "jitter_us": 300.0}


def test_same_case_same_recording():
    case = ProofCase("c", "latency", {"jitter_us": 500.0}, {"jitter_us": 500.0, "latency_us": 2000.0},
                     compensate=None, generator="circuit")
    a, _ = make_recording(case, SPEC, SensorConfig(), np.random.default_rng(5))
    b, _ = make_recording(case, SPEC, SensorConfig(), np.random.default_rng(5))
    assert a.events.array.tobytes() == b.events.array.tobytes()


def _fake_row(case, draws, out_dir, **kw):
    """A stand-in for rdnet.calib.proof.run_case: the row proof_metrics needs, with what it got."""
    import os
    return {"case": case.name, "true_effect": None, "named": [], "outcome": "right (none)", "rank": None,
            "heldout_ratio": 1.0, "heldout_excess_ratio": 1.0, "seed": draws[1], "texture_sum": float(draws[0].sum()),
            "out": None if out_dir is None else str(out_dir), "kw": kw, "pid": os.getpid()}


def _fresh_draws(cases, seed):
    from rdnet.calib.proof import case_draws
    rng = np.random.default_rng(seed)
    return [case_draws(c, SceneSpec(), rng)[1] for c in cases]


def test_run_generators_fresh_rng_per_generator_folders_and_names(monkeypatch, tmp_path):
    """The one loop of the stage and of ``python -m rdnet.calib.proof`` (run_case stubbed):
    each generator's cases take their draws from a fresh default_rng(seed), in order."""
    import rdnet.calib.proof as proof
    monkeypatch.setattr(proof, "run_case", _fake_row)
    out = proof.run_generators(tmp_path, 5, quick=True, interpolate="i")
    assert list(out) == ["rdnet", "circuit"]
    for gen, folder in (("rdnet", tmp_path), ("circuit", tmp_path / "circuit")):
        cases = cases_for(gen, True)[gen]
        rows = out[gen]["cases"]
        assert [r["case"] for r in rows] == [c.name for c in cases]
        assert {r["out"] for r in rows} == {str(folder)} and all(r["kw"] == {"interpolate": "i"} for r in rows)
        assert [r["seed"] for r in rows] == _fresh_draws(cases, 5)
        assert (folder / "proof.json").is_file() and out[gen]["summary"]["null_cases"] == len(cases)
    # only the named cases; a generator left without any is skipped; no folder without out_dir
    out = proof.run_generators(None, 5, names=["null_thresholds"])
    assert list(out) == ["rdnet"] and [r["out"] for r in out["rdnet"]["cases"]] == [None]


def test_named_cases_get_the_draws_of_the_whole_list(monkeypatch):
    """A case run alone (``--cases``) reruns as in the stage: its draws are those it gets
    when every case of its generator runs, not those of a shorter list."""
    import rdnet.calib.proof as proof
    monkeypatch.setattr(proof, "run_case", _fake_row)
    full = cases_for("circuit")["circuit"]
    names = [full[5].name, full[2].name]
    out = proof.run_generators(None, 7, generator="circuit", names=names)["circuit"]["cases"]
    draws = dict(zip([c.name for c in full], _fresh_draws(full, 7)))
    assert [r["case"] for r in out] == [full[2].name, full[5].name]        # in the list's order
    assert [r["seed"] for r in out] == [draws[full[2].name], draws[full[5].name]]
    assert _fresh_draws([full[5]], 7) != [draws[full[5].name]]            # a shorter list draws otherwise


def test_run_blocks_in_processes_equals_serial(monkeypatch, tmp_path):
    """The stage runs the cases of all blocks in worker processes: the same rows in the same
    order as a serial run, each block's draws from its own default_rng(seed) (run_case
    stubbed; the stub reaches the forked workers)."""
    import os

    import rdnet.calib.proof as proof
    monkeypatch.setattr(proof, "run_case", _fake_row)
    blocks = proof.generator_blocks(tmp_path, quick=True, interpolate="i")
    blocks.append(proof.Block("oversample4", blocks[0].cases, tmp_path / "oversample4", {"oversample": 4}))
    serial = proof.run_blocks(blocks, 5, workers=1)
    parallel = proof.run_blocks(blocks, 5, workers=2)
    assert list(serial) == list(parallel) == ["rdnet", "circuit", "oversample4"]

    def strip(runs):
        return {k: [{f: v for f, v in r.items() if f != "pid"} for r in m["cases"]] for k, m in runs.items()}

    assert strip(parallel) == strip(serial)
    pids = {r["pid"] for m in parallel.values() for r in m["cases"]}
    assert os.getpid() not in pids                                       # ran in the workers
    for b in blocks:
        assert [r["seed"] for r in parallel[b.key]["cases"]] == _fresh_draws(b.cases, 5)
    assert parallel["oversample4"]["cases"][0]["kw"] == {"oversample": 4}


def test_case_draws_are_all_a_case_takes_from_the_generator():
    """make_recording takes exactly case_draws from its generator: a recording made from the
    draws equals one made from the generator, and the generator ends where case_draws
    leaves it (so run_proof can take every case's draws first)."""
    from rdnet.calib.proof import case_draws
    case = ProofCase("c", "latency", {"jitter_us": 500.0}, {"jitter_us": 500.0, "latency_us": 2000.0},
                     compensate=None, generator="circuit", scene=(("texture_px", 2.0),))
    rng = np.random.default_rng(8)
    a, _ = make_recording(case, SPEC, SensorConfig(), rng)
    after = int(rng.integers(1 << 30))
    rng2 = np.random.default_rng(8)
    draws = case_draws(case, SPEC, rng2)
    b, _ = make_recording(case, SPEC, SensorConfig(), None, draws=draws)
    assert a.events.array.tobytes() == b.events.array.tobytes()
    assert np.array_equal(a.frames.images, b.frames.images)
    assert int(rng2.integers(1 << 30)) == after


def test_preroll_adds_frames_before_zero_and_keeps_the_recorded_ones():
    """render(preroll_us=): the frames from t = 0 on are those of a rendering without it
    (bit for bit), a frame falls on t = 0, and the scene already moves before it."""
    from rdnet.calib.scene import render
    for fps in (100.0, 60.0, 400.0):
        plain, tex = render(SPEC, np.random.default_rng(7), fps_hz=fps)
        rolled, _ = render(SPEC, np.random.default_rng(7), fps_hz=fps, texture=tex, preroll_us=500_000)
        k = int(np.searchsorted(rolled.t_us, 0))
        assert rolled.t_us[k] == 0 and k == round(0.5 * fps)
        assert np.array_equal(rolled.t_us[k:], plain.t_us)
        assert np.array_equal(rolled.images[k:], plain.images)
        assert abs(int(rolled.t_us[0]) + 500_000) <= 1e6 / fps
        assert np.abs(np.diff(rolled.images[:k], axis=0)).max() > 0.05      # moving before t = 0


@pytest.mark.parametrize("generator", ["rdnet", "circuit"])
def test_truth_with_preroll_and_warm_up_records_from_zero(generator):
    """With a pre-roll and a warm-up (rdnet.calib.proof.make_recording) the recording holds
    the frames from t = 0 and only the events from t = 0; the true sensor saw the scene
    before, so its events differ from a cold start's, and the count is still matched."""
    case = ProofCase("c", "leak_events", {"shot_noise_hz": 1.0}, {"shot_noise_hz": 1.0, "leak_hz": 1.5},
                     compensate="shot_noise_hz", generator=generator)
    interp = InterpolateConfig(method="linear", max_upsample=4)
    kw = dict(truth_warmup_us=2_000_000, truth_preroll_us=200_000)
    rec, truth = make_recording(case, SPEC, SensorConfig(), np.random.default_rng(6), 1, interp, **kw)
    cold, _ = make_recording(case, SPEC, SensorConfig(), np.random.default_rng(6), 1, interp,
                             truth_warmup_us=0, truth_preroll_us=0)
    assert rec.frames.t_us[0] == 0 and len(rec.frames.t_us) == 31
    assert np.array_equal(rec.frames.images, cold.frames.images)
    assert int(rec.events.t.min()) >= 0 and len(rec.events) == truth["count"]
    assert abs(truth["count"] - truth["base_count"]) <= 0.02 * truth["base_count"]
    assert rec.events.array.tobytes() != cold.events.array.tobytes()


def test_unknown_case_names_are_refused(tmp_path):
    """--cases of the stage and of python -m rdnet.calib.proof: a name that is no case of
    the chosen generators is an error naming it, not an empty run."""
    import rdnet.calib.proof as proof
    from rdnet.errors import ConfigError
    with pytest.raises(ConfigError, match="no such case latency_typo"):
        proof.generator_blocks(tmp_path, names=["latency_with_jitter_s2A", "latency_typo"])
    with pytest.raises(ConfigError, match="circuit_null_thresholds"):        # not in the rdnet generator
        proof.generator_blocks(tmp_path, generator="rdnet", names=["circuit_null_thresholds"])
    blocks = proof.generator_blocks(tmp_path, names=["circuit_null_thresholds"])
    assert [b.key for b in blocks] == ["circuit"] and [c.name for c in blocks[0].to_run] == ["circuit_null_thresholds"]
