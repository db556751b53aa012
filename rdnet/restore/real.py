"""Restore methods on real recordings, scored without ground truth (stage ``restore_real``,
``benchmarks/restore_training_scenes.py``).

Per recording and run: events kept, the share of the output that is not in the recording
(events a restorer added or moved), ESR (E-MLB), event-frame consistency (with frames), and
region fractions: the share of the raw events kept inside the *activity mask* (where the
scene moves; :func:`rdnet.eval.noref.activity_mask` with :data:`~rdnet.eval.noref.ACTIVITY_MASK`,
one rule for every recording), outside it (background activity), and on the known hot
pixels of the recording when given.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping, Sequence

log = logging.getLogger(__name__)

#: file suffixes of a recording folder that are not recordings
SKIP = {".md", ".png", ".jpg", ".json", ".yaml", ".dvc"}


def recordings(roots: Iterable[Path | None]) -> list[tuple[str, Path]]:
    """(folder name, first recording file) of every recording folder under ``roots``; one
    per folder name, first root first (missing roots are skipped)."""
    seen, out = set(), []
    for root in roots:
        if root is None or not root.is_dir():
            continue
        for d in sorted(p for p in root.iterdir() if p.is_dir()):
            files = sorted(f for f in d.iterdir() if f.is_file() and f.suffix.lower() not in SKIP)
            if files and d.name not in seen:
                seen.add(d.name)
                out.append((d.name, files[0]))
    return out


@dataclass(frozen=True)
class RecordingFacts:
    """What the events alone do not say about some recordings, per recording folder name:
    known hot pixels ((x, y) lists) and sensor sizes ((width, height)) for formats that do not
    store one. The study keeps them beside its stage (``stages/real_recordings.yaml``)."""

    hot_pixels: Mapping[str, list] = field(default_factory=dict)
    sensor_size: Mapping[str, tuple] = field(default_factory=dict)


def read_facts(path: str | Path) -> RecordingFacts:
    """:class:`RecordingFacts` from a YAML file with the keys ``hot_pixels`` and
    ``sensor_size`` (both optional); a ConfigError naming the file and the field otherwise."""
    import yaml

    from rdnet.errors import ConfigError
    path = Path(path)
    try:
        raw = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as e:
        raise ConfigError("facts", f"{path}: cannot read: {e}") from None
    if not isinstance(raw, dict) or set(raw) - {"hot_pixels", "sensor_size"}:
        raise ConfigError("facts", f"{path}: expected a mapping with hot_pixels and sensor_size, got {raw!r}")

    def pairs(key, one):
        out = {}
        for name, v in (raw.get(key) or {}).items():
            try:
                out[str(name)] = one(v)
            except (TypeError, ValueError):
                raise ConfigError(f"facts.{key}.{name}", f"{path}: bad value {v!r}") from None
        return out

    def xy(v):
        x, y = v
        return int(x), int(y)
    return RecordingFacts(hot_pixels=pairs("hot_pixels", lambda v: [xy(p) for p in v]),
                          sensor_size=pairs("sensor_size", xy))


@dataclass(frozen=True)
class Run:
    """One restore run: ``key`` (its name and output file stem), ``method``, an optional
    ``checkpoint``, overrides of the ``restore`` params section and a ``suffix`` for its label."""

    key: str
    method: str
    checkpoint: Path | None = None
    restore: Mapping = field(default_factory=dict)
    suffix: str = ""
    #: run only on recordings with frames (e.g. a frame-pair restorer)
    needs_frames: bool = False


@dataclass
class Scored:
    """What :func:`score_recording` returns: the summary ``entry``, the raw events, the
    restored events per run key (kept only when asked) and the activity mask."""

    entry: dict
    raw: object
    outs: dict
    activity: object


def score_recording(name: str, path: Path, params: Mapping, runs: Sequence[Run], out_dir: Path, *,
                    keep: bool = True, facts: RecordingFacts | None = None) -> Scored:
    """Run every ``runs`` entry of ``rdnet restore`` on ``path`` (``out_dir/<key>.h5`` and
    ``<key>.summary.json``, the OUT.json; removed again unless ``keep``) and score it. A learned
    run whose model is absent is skipped with a warning (a broken one raises). ``facts``: the
    known hot pixels and sensor size of recording ``name``, if any."""
    from rdnet.errors import ModelNotFoundError
    from rdnet.eval.noref import ACTIVITY_MASK, activity_mask, mask_fractions, pixel_mask
    from rdnet.events.io import load
    from rdnet.restore.learned import DecisionMemo
    from rdnet.restore.run import json_path_for, restore_recording

    facts = facts or RecordingFacts()
    size = facts.sensor_size.get(name)
    rec = load(path, sensor_size=size)
    raw = rec.require_events(str(path))
    act = activity_mask(raw, **ACTIVITY_MASK)
    masks = {"activity": act, "background": ~act}
    hot = facts.hot_pixels.get(name)
    if hot:
        masks["hot_pixels"] = pixel_mask(rec.width, rec.height, hot)
    entry = {"path": str(path), "width": rec.width, "height": rec.height,
             "has_frames": rec.frames is not None and len(rec.frames) > 0, "events": len(raw),
             "duration_us": int(raw.t[-1] - raw.t[0]), "activity_mask_pixels": int(act.sum()),
             "activity_mask": dict(ACTIVITY_MASK), "hot_pixels": hot or [], "methods": {}}
    out_dir.mkdir(parents=True, exist_ok=True)
    outs = {}
    # the learned runs share the decided entries of each window: the deletions-only and
    # additions-only rows take the same decision as the learned restorer before their filter
    memo = DecisionMemo()
    for run in runs:
        if (run.method == "gef" or run.needs_frames) and not entry["has_frames"]:
            continue
        out = out_dir / f"{run.key.replace('/', '_')}.h5"
        run_params = {**params, "restore": {**params.get("restore", {}), **run.restore}}
        try:
            res = restore_recording(path, out, run_params, method=run.method, checkpoint=run.checkpoint,
                                    progress=False, sensor_size=size, memo=memo)
        except ModelNotFoundError as e:               # a broken model fails; an absent one
            log.warning("%s: method %s skipped: %s", name, run.key, e)   # only loses its row
            continue
        restored = load(out).events
        cons = res["scores"]["consistency"] or {}
        entry["methods"][run.key] = {
            "name": res["method"] + run.suffix, "events_out": res["events_out"],
            "kept_fraction": res["kept_fraction"],
            "not_recorded_fraction": res["events_not_recorded"] / res["events_out"] if res["events_out"] else 0.0,
            "hot_pixels_flagged": (res["hot_pixels"] or {}).get("count", 0),
            "esr": res["scores"]["esr"]["restored"],
            "consistency_r2": (cons.get("restored") or {}).get("r2_fitted"),
            "regions": {k: v["fraction"] for k, v in mask_fractions(raw, restored, masks).items()}}
        # (speed is not recorded here, so a committed summary is reproducible: bench_restore.py)
        summary = out.with_suffix(".summary.json")
        if keep:
            outs[run.key] = restored
            summary.write_text(json.dumps(res, indent=2) + "\n")
        else:
            out.unlink()
            json_path_for(out).unlink(missing_ok=True)
    return Scored(entry, raw, outs, act)
