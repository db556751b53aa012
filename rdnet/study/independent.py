"""Restoration scored against a ground truth that rdnet's simulator did not make (stage
``restoration_circuit``, issue 11).

The study's test split is simulated by :mod:`rdnet.sim.sensor`, and the restorers were trained
on that simulator's streams, so ``metrics/restoration.json`` says how well they invert it. Here
the truth and the degraded stream both come from the independent circuit generator
:mod:`rdnet.circuit` (a continuous-time photoreceptor / source-follower / comparator model that
shares no code with rdnet's simulator), driven by the frames of the study's test sequences:

* undegraded: the circuit at the nominal thresholds of the study's sensor (``sensor``, or the
  fitted one of ``study.degrade_from``) with nothing else (``i_dark`` = ``log_eps``, infinite
  bandwidth, no noise, no refractory hold);
* degraded: the circuit with each sequence's own test degradation where the circuit has a
  counterpart (:func:`rdnet.circuit.from_degrade`: threshold mismatch and ON/OFF ratio, its
  photoreceptor bandwidth for ``cutoff_hz``, refractory hold, shot noise, leak, hot pixels,
  jitter, latency). The readout period has none and is left out.

Those files then go through the study's own code: :func:`rdnet.study.data.make_pairs` (the blur
stage's windows, blurry images and voxel grids) and :func:`rdnet.study.rows.restoration_table`
(raw, the filters, the EDnCNN-style classifier and every stage-1 network, all seeds), so every
number compares with ``metrics/restoration.json``; and every ablation row is scored on the same
pairs (:func:`rdnet.study.rows.evaluate_ablation_row`, all seeds), with each trained row's gap to
row 2 (``degraded_train``) paired by seed, so the deblurring findings are checked there too. The
windows, blurry images and sharp targets are the study's (same seed); only the events differ.
Several circuit draws (pixels, noise, start states) give a spread. Nothing is trained or tuned
on these streams.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import tempfile
from pathlib import Path

import numpy as np

from rdnet.circuit import from_degrade, generate
from rdnet.config import from_dict, section
from rdnet.events.io.hdf5 import H5EventReader, H5RecordingWriter, read_frames, read_header
from rdnet.sim.settings import DegradeConfig
from rdnet.study.data import make_pairs, sequences, simulation_configs
from rdnet.study.report import BASE_ROW, paired_gap, seed_paired
from rdnet.study.rows import EVENT_KEYS, evaluate_ablation_row, restoration_table, seed_spread

log = logging.getLogger(__name__)

#: root attributes carried over from the study's event files (the blur stage reads them)
CARRIED_ATTRS = ("degradation_level", "degrade_json", "scene_background", "scene_spec", "scene_split")
#: event metrics averaged over the draws (and given a spread)
KEYS = tuple(k for k in EVENT_KEYS if k not in ("restored", "reference"))


def circuit_file(src: Path, dst: Path, sensor, seed: int) -> dict:
    """Write ``dst``: the frames and attributes of the study's event file ``src`` with events
    from the circuit generator, ``events_ideal`` (nominal thresholds only) and ``events``
    (``src``'s own degradation, without the readout period). Returns the event counts of both
    generators (the simulator's from the file's index, without reading its events)."""
    width, height, _, attrs = read_header(src)
    frames = read_frames(src)
    deg = from_dict(DegradeConfig, json.loads(attrs["degrade_json"]), "degrade", src)
    rng = np.random.default_rng(seed)
    ideal = generate(frames.images, frames.t_us, from_degrade(sensor, DegradeConfig()), rng)
    degraded = generate(frames.images, frames.t_us,
                        from_degrade(sensor, dataclasses.replace(deg, sample_period_us=0.0)), rng)
    with H5RecordingWriter(dst, width, height, sensor="rdnet-circuit") as w:
        w.write_frames(frames)
        w.append_events(ideal, group="events_ideal")
        w.append_events(degraded, group="events")
        for key in CARRIED_ATTRS:
            if key in attrs:
                w.set_attr(key, attrs[key])
    with H5EventReader(src, "events_ideal") as u, H5EventReader(src, "events") as d:
        simulated = {"undegraded": len(u), "degraded": len(d)}
    return {"sequence": src.name, "circuit": {"undegraded": len(ideal), "degraded": len(degraded)},
            "simulator": simulated}


def circuit_pairs(params: dict, files: list[Path], work: Path, seed: int) -> tuple[Path, list[dict]]:
    """One draw: every study event file of ``files`` rendered by :func:`circuit_file` into
    ``work/events/test`` and made into ``work/pairs/test.h5`` by the blur stage's code.
    Returns the pairs file and the event counts per sequence."""
    sensor = simulation_configs(params)[0]          # the study's thresholds
    (work / "events" / "test").mkdir(parents=True, exist_ok=True)
    counts = [circuit_file(src, work / "events" / "test" / src.name, sensor, seed + i) for i, src in enumerate(files)]
    for c in counts:
        log.info("%s: circuit %d undegraded / %d degraded events (simulator %d / %d)", c["sequence"],
                 c["circuit"]["undegraded"], c["circuit"]["degraded"], c["simulator"]["undegraded"],
                 c["simulator"]["degraded"])
    make_pairs(params, work / "events", work / "pairs", splits=("test",))
    return work / "pairs" / "test.h5", counts


def circuit_restoration(params: dict, events_dir: Path, learned: dict[str, Path], *, draws: int = 3,
                        seed: int = 0, ednccn: Path | None = None, rows: tuple[str, ...] = ()) -> dict:
    """The restoration table (:func:`rdnet.study.rows.restoration_table`) of the test split
    rendered ``draws`` times by the circuit generator: per method the event metrics averaged
    over the draws with their standard deviation (``<key>_draw_std``), the event counts of
    every sequence and draw beside the simulator's, and (``rows``: ablation row ids whose
    networks exist) every row's PSNR (:func:`row_summary`). ``draws`` 0: nothing is rendered
    (a study too large for it, such as the ``paper`` profile's GOPRO split), empty tables."""
    generator = ("rdnet.circuit; undegraded: nominal thresholds only; degraded: each test sequence's "
                 "degradation through rdnet.circuit.from_degrade (no readout period)")
    if draws == 0:               # switched off (study.circuit_draws: 0)
        return {"generator": generator, "draws": 0, "seed": seed, "events": {}, "rows": {}, "sequences": []}
    restore, ablation, seeds = section(params, "restore"), section(params, "ablation"), section(params, "study").seeds
    files = sequences(events_dir, "test")
    if not files:
        from rdnet.errors import ConfigError
        raise ConfigError("events", f"{events_dir}: no test sequences (run the simulate stage)")
    tables, counts, row_runs = [], [], []
    for draw in range(draws):
        with tempfile.TemporaryDirectory() as tmp:
            pairs, drawn = circuit_pairs(params, files, Path(tmp), 1000 * (seed + draw))
            counts.append(drawn)
            events = Path(tmp) / "events" / "test"
            tables.append(restoration_table(ablation, pairs, events, learned, seeds=seeds, baf_dt_us=restore.baf_dt_us,
                                            gef_bins=restore.gef_bins, ednccn=ednccn))
            if rows:
                row_runs.append({r: evaluate_ablation_row(ablation, r, pairs, events, seeds=seeds) for r in rows})
    methods = {}
    for name in tables[0]:
        if "events" not in tables[0][name]:
            continue
        vals = {k: [float(t[name]["events"][k]) for t in tables] for k in KEYS}
        methods[name] = {k: float(np.mean(v)) for k, v in vals.items()}
        methods[name].update({f"{k}_draw_std": float(np.std(v, ddof=1)) if len(v) > 1 else 0.0
                              for k, v in vals.items()})
    return {"generator": generator, "draws": draws, "seed": seed, "events": methods, "rows": row_summary(row_runs) if row_runs else {},
            "sequences": counts}


def row_summary(runs: list[dict[str, dict]]) -> dict:
    """Per row, over the draws ``runs`` (each: row id -> :func:`evaluate_ablation_row`), in
    the layout of ``results/rows/<row>.json`` (so :func:`rdnet.study.report.paired_gap` pairs
    them by seed as it does the study's rows): ``psnr_seeds`` (per seed, mean over the draws),
    ``psnr`` and ``psnr_std`` (their mean and sample spread), ``seeds``, and ``psnr_draw_std``
    (the spread of the draws' seed means)."""
    out = {}
    for row in runs[0]:
        per_draw = np.array([r[row].get("psnr_seeds") or [r[row]["psnr"]] for r in runs], float)   # (draws, seeds)
        per_seed = per_draw.mean(0)
        out[row] = {"psnr": float(per_seed.mean()), "psnr_std": seed_spread(per_seed), "psnr_seeds": per_seed.tolist(),
                    "seeds": runs[0][row]["seeds"],
                    "psnr_draw_std": float(np.std(per_draw.mean(1), ddof=1)) if len(runs) > 1 else 0.0}
    return out


def markdown(result: dict, study: dict | None = None, study_rows: dict | None = None) -> str:
    """The tables of :func:`circuit_restoration` (``study``: ``metrics/restoration.json``,
    ``study_rows``: row id -> ``results/rows/<row>.json``; their values in brackets)."""
    if not result["draws"]:
        return ("# Restoration on the independent circuit generator (stage `restoration_circuit`)\n\n"
                "Not run: `study.circuit_draws` is 0.\n")
    rows = result["events"]
    raw = rows["degraded"]["voxel_l1_all"]
    study = study or {}

    def cell(name, k, fmt):
        s = study.get(name, {}).get("events", {})
        spread = f" ± {rows[name][k + '_draw_std']:{fmt}}" if k in ("f1", "voxel_l1_all") else ""
        return f"{rows[name][k]:{fmt}}{spread}" + (f" ({s[k]:{fmt}})" if k in s else "")
    lines = ["# Restoration on the independent circuit generator (stage `restoration_circuit`)", "",
             f"The study's {len(result['sequences'][0])} test sequences rendered by `rdnet.circuit` in "
             f"{result['draws']} independent draws and scored as `metrics/restoration.json` (events matched per voxel "
             "and polarity against the circuit's undegraded stream; learned rows: mean over the training seeds); "
             "mean over the draws ± their standard deviation. In brackets: the same method on the study's own "
             "test split (rdnet's simulator).", "",
             "| method | F1 | precision | recall | count ratio | all-voxel L1 | vs raw |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name in sorted(rows, key=lambda n: -rows[n]["f1"]):
        lines.append(f"| {name} | {cell(name, 'f1', '.3f')} | {cell(name, 'precision', '.3f')} | "
                     f"{cell(name, 'recall', '.3f')} | {cell(name, 'count_ratio', '.2f')} | "
                     f"{cell(name, 'voxel_l1_all', '.4f')} | {100 * (rows[name]['voxel_l1_all'] / raw - 1):+.1f} % |")
    if result.get("rows"):
        lines += ["", "Every ablation row on the same pairs (PSNR in dB, mean over the circuit draws and the training "
                  "seeds ± seed spread; gap: minus row 2 `degraded_train`, paired by seed). In brackets: the study's "
                  "own test split (`results/rows/<row>.json`).", "",
                  "| row | PSNR | gap to row 2 |", "|---|---:|---:|"]
        study_rows = study_rows or {}
        circuit = result["rows"]

        def gap(rows_: dict, row: str) -> str | None:     # paired by seed, trained rows beside row 2 only
            a, b = rows_.get(row), rows_.get(BASE_ROW)
            if row == BASE_ROW or not seed_paired(a, b):
                return None
            g = paired_gap(a, b)
            return f"{g['mean']:+.2f} ± {g['std']:.2f}"
        for row, r in circuit.items():
            s_row = study_rows.get(row, {})
            psnr = f"{r['psnr']:.2f}" + (f" ± {r['psnr_std']:.2f}" if len(r["seeds"]) > 1 else "")
            psnr += f" ({s_row['psnr']:.2f})" if "psnr" in s_row else ""
            g, sg = gap(circuit, row), gap(study_rows, row)
            lines.append(f"| {row} | {psnr} | {(g or '') + (f' ({sg})' if g and sg else '')} |")
    return "\n".join(lines) + "\n"
