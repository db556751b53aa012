"""End-to-end calibration on a small concealed case: hot pixels hidden in shot noise are
named with their parameters; the report schema and files."""
import dataclasses
import json

import numpy as np
import pytest

from rdnet.calib.calibrate import calibrate, finding
from rdnet.calib.effects import EFFECTS, absent_effects
from rdnet.calib.proof import case_metrics
from rdnet.calib.report import signature_cell, write_report
from rdnet.config import from_dict
from rdnet.sim.settings import DegradeConfig, SensorConfig

import calib_cases
from calib_cases import CFG, HOT, INTERP, SENSOR


@pytest.fixture(scope="module")
def hot_recording():
    return calib_cases.hot_recording()




@pytest.fixture(scope="module")
def hot_cal(hot_recording):
    rec, truth = hot_recording
    # a subset of the candidates keeps the test fast: the effects that also act on the
    # noise floor or the per-pixel rate spread, i.e. the ones hot pixels could be confused with
    cfg = dataclasses.replace(CFG, candidates=("threshold_mismatch", "leak_events", "hot_pixels",
                                               "timestamp_jitter"))
    return calibrate(rec, SENSOR, DegradeConfig(**HOT.base), cfg, seed=0, interpolate=INTERP,
                     source="hot.h5"), truth


def test_concealment_matches_the_base_count(hot_recording):
    _, truth = hot_recording
    assert abs(truth["count"] - truth["base_count"]) <= 0.01 * truth["base_count"]
    # the hot pixels replace part of the base's noise: the true noise rate is lower
    assert truth["degrade"]["shot_noise_hz"] < HOT.base["shot_noise_hz"]


def test_hot_pixels_named_with_parameters(hot_cal):
    cal, truth = hot_cal
    m = case_metrics(HOT, cal.report, truth)
    assert m["named"][0] == "hot_pixels" and m["rank"] == 1
    assert m["param_max_rel_error"] <= 0.25, m["param_rel_error"]
    assert m["heldout_after"] < 0.8 * m["heldout_before"]
    hot = next(e for e in cal.report["effects"] if e["name"] == "hot_pixels")
    assert hot["confidence"] > 0.5
    assert "hot pixels" in finding(cal.report)


def test_a_failed_figure_worker_has_its_figures_drawn_here(hot_cal, tmp_path, caplog):
    """A figure worker that fails (rdnet.runtime.ChildFailed on wait) costs neither the
    report nor a figure: its share is drawn in process, the same bytes as a report drawn
    without workers, and a warning names the figures."""
    from rdnet.runtime import ChildFailed

    class Failing:                      # a ForkedWorker whose child died
        def submit(self, fn, *args):
            self.share = args[2]

        def wait(self):
            raise ChildFailed("a forked worker failed (exit status 1)")

        def kill(self):
            pass

    cal, _ = hot_cal
    here = write_report(cal, tmp_path / "here")
    with caplog.at_level("WARNING", logger="rdnet.calib.report"):
        failed = write_report(cal, tmp_path / "failed", workers=[Failing(), Failing()])
    assert [p.name for p in failed] == [p.name for p in here]
    for a, b in zip(here, failed):
        if a.suffix == ".png":
            assert a.read_bytes() == b.read_bytes(), a.name
    assert "drawing statistics.png here" in caplog.text and "drawing mismatch_maps.png" in caplog.text


def test_report_schema_and_files(hot_cal, tmp_path):
    cal, _ = hot_cal
    paths = write_report(cal, tmp_path / "out")
    names = {p.name for p in paths}
    assert {"report.json", "report.md", "mismatch_maps.png", "statistics.png", "effect_hot_pixels.png"} <= names
    assert not list((tmp_path / "out").glob("*.tmp"))
    r = json.loads((tmp_path / "out" / "report.json").read_text())
    assert r["recording"] == "hot.h5"
    for key in ("base_config", "fitted_config"):
        assert set(r[key]) == {"sensor", "degrade"}
        from_dict(SensorConfig, r[key]["sensor"], "sensor")            # loadable back
        from_dict(DegradeConfig, r[key]["degrade"], "degrade")
    assert r["fitted_config"]["degrade"]["hot_pixel_hz"] > 0
    assert r["base_config"]["degrade"]["hot_pixel_hz"] == 0
    expected = {e.name for e in absent_effects(DegradeConfig(**HOT.base))}
    assert {e["name"] for e in r["effects"]} == expected        # all, the untested ones too
    untested = [e for e in r["effects"] if e["name"] == "bandwidth"][0]
    assert not untested["missing"] and untested["confidence"] == 0.0
    for e in r["effects"]:
        assert set(e) >= {"name", "missing", "parameters", "where", "evidence", "confidence"}
        assert e["name"] in EFFECTS and isinstance(e["missing"], bool)
        assert 0.0 <= e["confidence"] <= 1.0
        assert set(e["parameters"]) <= {p.key for p in EFFECTS[e["name"]].fitted}
        assert isinstance(e["where"], str) and isinstance(e["evidence"], str)
    d = r["discrepancy"]
    assert set(d) >= {"metric", "fit_before", "fit_after", "heldout_before", "heldout_after"}
    assert isinstance(d["metric"], str) and all(isinstance(d[k], float) for k in
                                                ("fit_before", "fit_after", "heldout_before", "heldout_after"))
    # how far the events trail the frames: recorded (no simulator) and an ideal sensor per
    # interpolation tried; the truth has no latency and came from linear frames, so the
    # latency range these give is near 0
    lt = r["latency_timing"]
    assert set(lt["ideal_lag_us"]) == set(CFG.interpolation)
    lo, hi = lt["latency_range_us"]
    assert lo == pytest.approx(lt["recorded_lag_us"] - max(lt["ideal_lag_us"].values()))
    assert hi == pytest.approx(lt["recorded_lag_us"] - min(lt["ideal_lag_us"].values()))
    assert lt["recorded_ci95_us"][0] <= lt["recorded_lag_us"] <= lt["recorded_ci95_us"][1]
    assert abs(lt["ideal_lag_us"]["linear"] - lt["recorded_lag_us"]) < 1000.0 and lt["frame_interval_us"] == 10000.0
    md = (tmp_path / "out" / "report.md").read_text()
    assert "Events behind the frames" in md
    assert md.splitlines()[2].startswith("The simulator is missing hot pixels")
    # the named effect's row shows its own statistic before -> after, as in report.json
    hot = next(e for e in r["effects"] if e["name"] == "hot_pixels")
    sig = hot["signature"]
    assert hot["statistic"] == EFFECTS["hot_pixels"].statistic and sig["heldout_after"] < sig["heldout_before"]
    row = next(ln for ln in md.splitlines() if ln.startswith("| hot_pixels |"))
    assert f"| {hot['statistic']} {sig['heldout_before']:.3f} -> {sig['heldout_after']:.3f} (z " in row
    # every effect lists its look-alikes (only a named one can have any), and report.md says them
    assert all(isinstance(e["look_alikes"], list) for e in r["effects"])
    assert all(not e["look_alikes"] for e in r["effects"] if not e["missing"])
    assert "## Look-alikes" in md
    for a in hot["look_alikes"]:
        assert f"**hot_pixels** is not told apart from **{a['name']}**" in md
    # the frame interpolation is a nuisance choice: the recording's events were simulated
    # from linearly blended frames, so flow is far off and linear blending fits as well as
    # the best ('selected' mixes flow in only where it predicts the frames better: on this
    # small scene their reachable fits are within 1.5 % of each other, and which of the two
    # wins moves with the concealment's shot-noise rate, 1.618 or 1.658 Hz for the same count)
    fi = r["frame_interpolation"]
    cands = fi["candidates"]
    assert set(cands) == {"flow", "linear", "selected"} and fi["chosen"] in ("linear", "selected")
    assert cands["linear"]["fit_reachable"] <= 1.05 * cands[fi["chosen"]]["fit_reachable"]
    assert cands["flow"]["fit_reachable"] > 2 * cands["linear"]["fit_reachable"]
    assert all(c["fit_reachable"] <= c["fit_after_basic_refit"] for c in fi["candidates"].values())
    assert "Frame interpolation" in md


def test_search_on_a_coarser_pixel_sample(hot_recording):
    """Over the search budget the fits run on every 2nd row/column; the verdict, the additive
    effect's fit and the report stay on the whole sample."""
    rec, truth = hot_recording
    cfg = dataclasses.replace(CFG, candidates=("threshold_mismatch", "hot_pixels"),
                              search_max_sim_steps=150_000)
    cal = calibrate(rec, SENSOR, DegradeConfig(**HOT.base), cfg, seed=0, interpolate=INTERP, source="hot.h5",
                    progress=False)
    s = cal.report["setup"]
    assert s["pixel_stride"] == 1 and s["search"]["search_stride"] == 2
    assert s["search"]["search_pixels"] == 24 * 24
    m = case_metrics(HOT, cal.report, truth)
    assert m["named"] == ["hot_pixels"] and m["param_max_rel_error"] <= 0.25, m
    screened = [e for e in cal.report["effects"] if not e["fitted"]]
    assert all(not e["missing"] and e["confidence"] < 0.5 for e in screened)


def test_contexts_built_side_by_side_equal_sequential_builds(hot_recording):
    """The contexts of the interpolation choice are built in threads; each equals its
    sequential build, and every index comes once."""
    from rdnet.calib.calibrate import contexts_as_built, interpolation_configs
    from rdnet.calib.context import build_context

    rec, _ = hot_recording
    cfg = dataclasses.replace(calib_cases.CFG, interpolation=("flow", "linear"))
    interps = interpolation_configs(cfg, calib_cases.INTERP)
    got = dict(contexts_as_built(rec, cfg, calib_cases.SENSOR.log_eps, interps, "test"))
    assert sorted(got) == [0, 1]
    for i, icfg in enumerate(interps):
        ref = build_context(rec, cfg, calib_cases.SENSOR.log_eps, interpolate=icfg, source="test")
        assert np.array_equal(got[i].sim_images, ref.sim_images) and np.array_equal(got[i].sim_t, ref.sim_t)



def test_contexts_then_runs_in_the_worker_with_the_configured_numba_threads(hot_recording):
    """``then`` runs in each context's own thread (where the candidates' refits run side by
    side), with ``calibrate.threads`` numba threads there (the setting is per thread), and
    its result is yielded in place of the context."""
    import threading

    import numba

    from rdnet.calib.calibrate import contexts_as_built, interpolation_configs

    rec, _ = hot_recording
    cfg = dataclasses.replace(calib_cases.CFG, interpolation=("flow", "linear"), threads=1)
    interps = interpolation_configs(cfg, calib_cases.INTERP)

    def then(i, ctx):
        return i, threading.current_thread().name, numba.get_num_threads(), len(ctx.sim_t)

    got = dict(contexts_as_built(rec, cfg, calib_cases.SENSOR.log_eps, interps, "test", then=then))
    assert sorted(got) == [0, 1]
    for i, (j, thread, n_threads, n_frames) in got.items():
        assert j == i and thread.startswith("rdnet-calib-context") and n_threads == 1 and n_frames > 2

def test_a_figure_for_every_effect_and_the_still_pixels_rate_in_hz(hot_cal, tmp_path):
    """Every effect's own statistic can be drawn (one figure per named effect), and the
    still-pixel panel shows each series' rate in events / pixel / s on its own axis: a
    ratio to the recording's rate is meaningless when its still pixels hardly fire."""
    from rdnet.calib.report import FigureData, _plot_statistic, figures
    from rdnet.eval.report import _figure
    cal, _ = hot_cal
    every = dataclasses.replace(cal, report={**cal.report,
                                             "effects": [{**e, "missing": True} for e in cal.report["effects"]]})
    names = figures(every, tmp_path)
    assert {f"effect_{e['name']}.png" for e in cal.report["effects"]} <= set(names)
    assert all((tmp_path / n).stat().st_size > 1000 for n in names)
    fig, ax = _figure(figsize=(6, 4))
    _plot_statistic(ax, "static_rate", FigureData.of(cal))
    rate_ax = next(a for a in fig.axes if a is not ax)
    heights = [b.get_height() for b in rate_ax.patches]
    assert heights == pytest.approx([float(s["static_rate"]) for s in
                                     (cal.real_stats, cal.base_stats, cal.fitted_stats)])
    fractions = [b.get_height() for b in ax.patches]
    assert fractions[:2] == pytest.approx([float(cal.real_stats["static_on_fraction"]),
                                           float(cal.real_stats["on_fraction"])])
    # latency's panel is the correlation curve of base and fitted against the recording
    fig, ax = _figure(figsize=(6, 4))
    _plot_statistic(ax, "lag_smoothed", FigureData.of(cal))
    curves = [ln for ln in ax.lines if ln.get_label().startswith(("base vs real", "fitted vs real"))]
    assert len(curves) == 2
    for ln in curves:
        y = np.asarray(ln.get_ydata(), float)
        assert np.nanmax(np.abs(y)) <= 1.0 + 1e-9 and np.isfinite(y).any()


def test_caveat_when_the_bandwidth_floor_moves_from_the_declared_one(hot_cal):
    """A fitted dark-current floor is flagged (interpolation error in the dark looks the
    same), with both values; a floor kept at the declared value, or another effect, is not."""
    from rdnet.calib.calibrate import caveats
    from rdnet.calib.report import markdown
    declared = DegradeConfig(cutoff_floor=0.078)
    (text,) = caveats("bandwidth", {"cutoff_hz": 120.0, "cutoff_floor": 0.03}, declared, "flow")
    assert "cutoff_floor fitted 0.03 against the declared 0.078: a lower floor slows" in text
    assert "flow interpolation" in text
    (text,) = caveats("bandwidth", {"cutoff_hz": 120.0, "cutoff_floor": 0.3}, declared, None)
    assert "a higher floor speeds up" in text and "error of the frames" in text
    assert caveats("bandwidth", {"cutoff_hz": 120.0, "cutoff_floor": 0.078}, declared, "flow") == []
    assert caveats("bandwidth", {"cutoff_hz": 120.0, "cutoff_floor": 0.0785}, declared, "flow") == []   # < 1 %
    assert caveats("latency", {"latency_us": 800.0}, declared, "flow") == []
    # latency, against the frames' timing: the range is recorded lag - each ideal lag
    timing = {"recorded_lag_us": 6000.0, "recorded_ci95_us": [5500.0, 6500.0], "frame_interval_us": 40000.0,
              "ideal_lag_us": {"flow": 4000.0, "linear": 5500.0}, "latency_range_us": [500.0, 2000.0]}
    (text,) = caveats("latency", {"latency_us": 8300.0}, declared, "flow", timing)
    assert "trail the frames by 6 ms" in text and "flow 4 ms, linear 5.5 ms" in text
    assert "between 0.5 and 2 ms" in text and "outside that range give or take 2 ms" in text
    assert "40 ms between frames" in text
    for inside in (1200.0, 4000.0, -1500.0):         # 2 ms (5 % of 40 ms) beyond the range still counts
        (text,) = caveats("latency", {"latency_us": inside}, declared, "flow", timing)
        assert "inside that range" in text
    (text,) = caveats("latency", {"latency_us": 4100.0}, declared, "flow", timing)
    assert "outside that range" in text
    assert caveats("latency", {"latency_us": 1200.0}, declared, "flow",
                   {**timing, "latency_range_us": [None, None]}) == []
    cal, _ = hot_cal
    assert all(e["caveats"] == [] for e in cal.report["effects"])      # hot pixels: nothing to flag
    assert "## Caveats" not in markdown(cal, [])
    flagged = {**cal.report, "effects": [{**e, "caveats": ["a note"]} if e["missing"] else e
                                         for e in cal.report["effects"]]}
    md = markdown(dataclasses.replace(cal, report=flagged), [])
    assert "## Caveats\n\n- **hot_pixels**: a note" in md


def test_every_tuning_parameter_has_its_look_alike():
    """A tuning parameter (``Effect.tuning``) is searched freely, so when it moves from its
    declared value the report must say what else moves the events the same way."""
    from rdnet.calib.calibrate import TUNING_LOOK_ALIKES
    keys = {p.key for e in EFFECTS.values() for p in e.tuning}
    assert keys == {"cutoff_floor"} and keys == set(TUNING_LOOK_ALIKES)
    for t in TUNING_LOOK_ALIKES.values():
        assert set(t) == {"lower", "higher", "look_alike", "shown", "measure", "separate_with"}


def test_signature_cell_known_values():
    e = {"statistic": "lag", "signature": {"heldout_before": 1.23456, "heldout_after": 0.2, "z": 8.04,
                                           "vetoed": False}}
    assert signature_cell(e) == "lag 1.235 -> 0.200 (z 8.0)"
    e["signature"] = {"heldout_before": 0.5, "heldout_after": 0.5, "z": -0.3, "vetoed": True}
    assert signature_cell(e) == "lag 0.500 -> 0.500 (z -0.3), vetoed"
    # a statistic the recording lacks (NaN in the report: None); an effect never evaluated
    e["signature"] = {"heldout_before": None, "heldout_after": None, "z": None, "vetoed": False}
    assert signature_cell(e) == "lag - -> -"
    assert signature_cell({"statistic": "lag", "signature": None}) == "-"


def test_weak_onoff_asymmetry_found_from_the_on_off_odds():
    """A ratio between the screen grid's points (1.2; the grid holds 1 and 1.58) concealed by
    count-matched thresholds under back-and-forth motion: the ON:OFF odds of the moving pixels
    give the first guess, so it is fitted and named (on the grid alone it was screened out:
    nothing named, fitted ratio 32 % off)."""
    case = calib_cases.ProofCase("asymmetry_back_and_forth", "onoff_asymmetry", {}, {"onoff_ratio": 1.2},
                                 motion="backforth")
    rec, truth = calib_cases.make_recording(case, calib_cases.SPEC, SENSOR, np.random.default_rng(13), 1, INTERP)
    cfg = dataclasses.replace(CFG, candidates=("onoff_asymmetry", "threshold_mismatch"))
    cal = calibrate(rec, SENSOR, DegradeConfig(), cfg, seed=0, interpolate=INTERP, source="asym.h5")
    m = case_metrics(case, cal.report, truth)
    assert m["named"] == ["onoff_asymmetry"] and m["rank"] == 1
    assert m["param_max_rel_error"] <= 0.25, m["param_rel_error"]


def test_on_only_hot_pixels_are_fitted_with_their_on_share_not_as_an_asymmetry():
    """Hot pixels that fire ON events only (as the circuit generator's do, and nearly as some
    real ones): the hot-pixel fit reads their ON share off the data (the shape parameter
    ``hot_pixel_on_fraction``, guessed from what the excess pixels fire beyond the
    simulation), so no ON/OFF asymmetry is needed to explain the ON excess."""
    from rdnet.calib.proof import ProofCase, make_recording
    case = ProofCase("hot_pixels_on_only", "hot_pixels", {"shot_noise_hz": 3.0},
                     {"hot_pixel_fraction": 0.01, "hot_pixel_hz": 100.0, "shot_noise_hz": 2.0,
                      "hot_pixel_on_fraction": 1.0}, compensate="shot_noise_hz")
    rec, truth = make_recording(case, calib_cases.SPEC, SENSOR, np.random.default_rng(11), 1, INTERP)
    cfg = dataclasses.replace(CFG, candidates=("hot_pixels", "onoff_asymmetry", "leak_events"))
    cal = calibrate(rec, SENSOR, DegradeConfig(**case.base), cfg, seed=0, interpolate=INTERP, source="on_only")
    named = [e["name"] for e in cal.report["effects"] if e["missing"]]
    hot = next(e for e in cal.report["effects"] if e["name"] == "hot_pixels")
    assert named == ["hot_pixels"], named
    assert hot["parameters"]["hot_pixel_on_fraction"] > 0.85, hot["parameters"]
    assert cal.report["fitted_config"]["degrade"]["hot_pixel_on_fraction"] > 0.85


def test_selection_threads_known_values(monkeypatch):
    """The forward selection gets the threads the interpolation candidates had together,
    at most the cores; 0 leaves numba alone."""
    from rdnet.calib import calibrate as cal_mod
    monkeypatch.setattr(cal_mod.os, "cpu_count", lambda: 2)
    assert cal_mod.selection_threads(dataclasses.replace(CFG, threads=1), 3) == 2
    assert cal_mod.selection_threads(dataclasses.replace(CFG, threads=1), 1) == 1
    assert cal_mod.selection_threads(dataclasses.replace(CFG, threads=0), 3) == 0
    monkeypatch.setattr(cal_mod.os, "cpu_count", lambda: 16)
    assert cal_mod.selection_threads(dataclasses.replace(CFG, threads=2), 3) == 6


def test_mixed_polarity_hot_pixels_get_their_concentration():
    """Hot pixels that fire both polarities, as real ones do (ON share per pixel ~ Beta with
    mean 0.7 and concentration 3; DVXplorer: 0.66, 2.9): the fit reads the concentration off
    the pixels it finds and simulates them alike, so their number comes out right. Held at
    one polarity per pixel (k = 0) the simulated hot pixels' net rate |ON - OFF| is their whole
    rate, the fewer of them match the recording's tail and the fraction came out 35-42 % low
    (three scene seeds); with the concentration read off, 7-17 % (same seeds)."""
    from rdnet.calib.proof import ProofCase, make_recording
    from rdnet.calib.scene import SceneSpec
    case = ProofCase("hot_pixels_mixed", "hot_pixels", {"shot_noise_hz": 3.0},
                     {"hot_pixel_fraction": 0.01, "hot_pixel_hz": 100.0, "shot_noise_hz": 2.0,
                      "hot_pixel_on_fraction": 0.7, "hot_pixel_polarity_concentration": 3.0},
                     compensate="shot_noise_hz")
    rec, _ = make_recording(case, SceneSpec(), SENSOR, np.random.default_rng(13), 1, INTERP)
    cfg = dataclasses.replace(CFG, candidates=("hot_pixels", "onoff_asymmetry", "leak_events", "threshold_mismatch"))
    cal = calibrate(rec, SENSOR, DegradeConfig(**case.base), cfg, seed=0, interpolate=INTERP, source="mixed")
    assert [e["name"] for e in cal.report["effects"] if e["missing"]] == ["hot_pixels"]
    p = next(e for e in cal.report["effects"] if e["name"] == "hot_pixels")["parameters"]
    assert abs(p["hot_pixel_fraction"] - 0.01) <= 0.25 * 0.01, p
    assert abs(p["hot_pixel_hz"] - 100.0) <= 25.0, p
    assert abs(p["hot_pixel_on_fraction"] - 0.7) < 0.15 and 1.0 < p["hot_pixel_polarity_concentration"] < 6.0, p


def test_interpolation_choice_read_on_the_final_pixel_sample():
    """The true events come from flow frames, which drag bright texture across the still
    illumination edge into the dark column next to it (column 23 of 48: odd, so a search
    sample of every 2nd column never sees it). Judged on the search sample, 'selected'
    (linear blending along the edge) looked as good as flow and could be kept by seed noise;
    judged on the final sample, flow is kept, and its basic refit fits better there."""
    flow = dataclasses.replace(INTERP, method="flow")
    case = calib_cases.ProofCase("asymmetry_back_and_forth", "onoff_asymmetry", {}, {"onoff_ratio": 1.25},
                                 motion="backforth")
    rec, truth = calib_cases.make_recording(case, calib_cases.SPEC, SENSOR, np.random.default_rng(21), 1, flow)
    # the dark column at the edge holds far more of the events than any even column
    cols = np.bincount(rec.events.x, minlength=48)
    assert cols[23] > 3 * np.max(cols[0:22:2])
    cfg = dataclasses.replace(CFG, candidates=("onoff_asymmetry",), interpolation=("flow", "selected"),
                              search_max_sim_steps=300_000)
    cal = calibrate(rec, SENSOR, DegradeConfig(), cfg, seed=0, interpolate=flow, source="edge.h5",
                    progress=False)
    assert cal.report["setup"]["search"]["search_stride"] == 2
    fi = cal.report["frame_interpolation"]
    assert fi["chosen"] == "flow" and fi["level"].startswith("final pixel sample")
    c = fi["candidates"]
    assert c["flow"]["fit_after_basic_refit"] < c["selected"]["fit_after_basic_refit"]
    assert c["flow"]["fit_reachable"] < c["selected"]["fit_reachable"]


def test_caveat_when_a_parameter_stops_at_the_end_of_its_range():
    """A search that ran into its range's end found no minimum: the value is flagged as a
    bound (latency's range is 50 us - 50 ms); a value inside the range is not."""
    from rdnet.calib.calibrate import caveats
    declared = DegradeConfig()
    (text,) = caveats("latency", {"latency_us": 50000.0}, declared, "flow")
    assert "latency_us fitted 5e+04, at the top of its search range [50, 50000]" in text
    assert "a bound, not a measurement" in text
    (text,) = caveats("refractory_period", {"refractory_us": 20.1}, declared, "flow")
    assert "at the bottom of its search range" in text
    assert caveats("latency", {"latency_us": 8300.0}, declared, "flow") == []
    assert caveats("latency", {"latency_us": 49000.0}, declared, "flow") == []
    assert caveats("latency", {"latency_us": 50000.0}, declared, "flow", fitted=False) == []   # a screen point
    # an effect with a tuning parameter too (its loop once reused the name `fitted`)
    assert caveats("bandwidth", {"cutoff_hz": 1.0, "cutoff_floor": 0.078}, DegradeConfig(cutoff_floor=0.078),
                   "flow", fitted=False) == []
    (text,) = caveats("bandwidth", {"cutoff_hz": 1.0, "cutoff_floor": 0.078}, DegradeConfig(cutoff_floor=0.078), "flow")
    assert "at the bottom of its search range [1, 3000]" in text


def test_refit_caveat_when_the_refit_leaves_the_ranges():
    """A basic refit that moved the threshold factor or a configured effect's parameter to or
    past an end of its declared range (params.yaml's study degradation on DAVIS346: thresholds
    x6.99, ON/OFF ratio 0.28) is flagged once, with the event counts; values inside the ranges,
    and effects the base config does not have, are not."""
    from rdnet.calib.calibrate import refit_caveats
    base = DegradeConfig(onoff_ratio=1.3, shot_noise_hz=5.0)
    (text,) = refit_caveats({"threshold_scale": 6.99, "onoff_ratio": 0.2785, "shot_noise_hz": 0.7}, base,
                            150021.0, 9696.0)
    assert text.startswith("The re-fit moved threshold_scale to 6.99 (above its range [0.4, 2.5]) and onoff_ratio "
                           "to 0.279 (below its range [0.4, 2.5]).")
    assert "it simulates 150021 events where the recording has 9696" in text and "--base ideal" in text
    (text,) = refit_caveats({"threshold_scale": 2.49, "shot_noise_hz": 30.0}, base, 1.0, 1.0)
    assert "threshold_scale to 2.49 (at the top of its range" in text and "shot_noise_hz to 30 (at the top" in text
    assert refit_caveats({"threshold_scale": 2.3, "onoff_ratio": 0.41, "shot_noise_hz": 0.7}, base, 1.0, 1.0) == []
    # latency is not in the base config: its value is an effect's fit (caveats()), not a refit
    assert refit_caveats({"latency_us": 50000.0}, base, 1.0, 1.0) == []


def test_the_report_has_no_refit_caveat_when_the_refit_stays_inside(hot_cal):
    cal, _ = hot_cal
    assert cal.report["refit_caveats"] == []
    assert "cannot be trusted" not in finding(cal.report)
