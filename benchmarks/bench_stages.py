"""Wall time of study stages, run as ``dvc repro`` runs them: each stage's command as DVC
resolves it from ``dvc.yaml`` (a training stage: every seed of ``study.seeds``,
``study.parallel`` processes of ``train.threads`` threads), in a temporary folder that
links ``stages/`` of the checkout under test, ``params.yaml`` (``--iterations``
overrides ``train.iterations``) and, entry by entry, the ``data/`` and ``models/`` of an
existing run; what the selected stages write goes to the temporary folder only.

Made for A/Bs of code that must not change what the study computes (the in-memory pairs
of :mod:`rdnet.train.data` and :mod:`rdnet.eval.predict`): run it with ``--root`` at the
checkout before the change (a ``git worktree``) and with this one, on the same data, right
after each other. Every row records the stage's wall time, its CPU time, the peak
resident memory of its largest process (``os.wait4``), the load average before, and the
SHA-256 of what it wrote that must repeat: every ``model.pt`` and every ``.json`` under
its outs (not the wall-time records under ``metrics/train/``, nor dvclive logs);
``--compare DIR`` (a run's folder holding ``data/``, ``models/``, ``metrics/``, ...)
says for each file whether it has the same bytes there. Stages run in ``dvc.yaml``
order; one that needs another's outputs reads them from this run or, when that stage is
not selected, from ``--data`` / ``--models``.

    git worktree add /tmp/before HEAD~1
    .venv/bin/python benchmarks/bench_stages.py --root /tmp/before --data data --models models \\
        --stages stress restoration --label before_eval
    .venv/bin/python benchmarks/bench_stages.py --data data --models models \\
        --stages stress restoration --label eval_in_memory
    .venv/bin/python benchmarks/bench_stages.py --data data --stages train --compare . \\
        --label study_trainings        # every training stage, as dvc repro runs them

``--stages train`` selects every ``train_*`` stage. Each run adds (or replaces) its
``--label`` entry of the out file (default ``benchmarks/results/stages.json``).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_STAGES = ["train_restore", "train_baseline@deblur_degraded", "train_deblur"]


def dvc_stages() -> dict[str, tuple[str, list[str]]]:
    """name -> (command, out paths) of every stage of dvc.yaml, in pipeline order."""
    from dvc.repo import Repo
    with Repo(str(ROOT)) as repo:
        return {s.addressing: (s.cmd if isinstance(s.cmd, str) else " && ".join(s.cmd),
                               [o.def_path for o in s.outs]) for s in repo.index.stages}


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _repeatable(work: Path, outs: list[str]) -> list[str]:
    """The files under ``outs`` that must repeat byte for byte (module docstring)."""
    files = []
    for out in outs:
        if out.startswith("metrics/train/"):
            continue
        p = work / out
        cands = [p] if p.is_file() else sorted(p.rglob("*")) if p.is_dir() else []
        files += [str(f.relative_to(work)) for f in cands
                  if f.is_file() and (f.name == "model.pt" or f.suffix == ".json") and "dvclive" not in f.parts]
    return files


def run_stage(name: str, cmd: str, outs: list[str], root: Path, work: Path) -> dict:
    argv = shlex.split(cmd)
    if argv[0] == "python":
        argv[0] = sys.executable
    env = {**os.environ, "PYTHONPATH": str(root)}
    load = os.getloadavg()[0]
    t = time.perf_counter()
    child = subprocess.Popen(argv, env=env, cwd=work, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(child.pid, 0)       # the stage's own rusage (its workers included)
    wall = time.perf_counter() - t
    if os.waitstatus_to_exitcode(status):
        raise SystemExit(f"bench_stages: {name} failed: {cmd}")
    return {"stage": name, "wall_s": round(wall, 2), "cpu_s": round(usage.ru_utime + usage.ru_stime, 1),
            "load_average_1min_before": round(load, 2),
            "peak_rss_mb_largest_process": round(usage.ru_maxrss / 1024, 1),
            "sha256": {f: _sha(work / f) for f in _repeatable(work, outs)}}


def _link_entries(src: Path | None, dst: Path, written: set[str]) -> None:
    """``dst`` as a folder of links to the entries of ``src``, except those a stage writes."""
    dst.mkdir(parents=True, exist_ok=True)
    if src is None:
        return
    for e in sorted(src.resolve().iterdir()):
        if f"{dst.name}/{e.name}" not in written:
            (dst / e.name).symlink_to(e)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--root", type=Path, default=ROOT, help="checkout whose code runs the stages")
    p.add_argument("--data", type=Path, default=ROOT / "data", help="a run's data/")
    p.add_argument("--models", type=Path, default=None, help="a run's models/, for the stages not selected")
    p.add_argument("--stages", nargs="+", default=DEFAULT_STAGES, help="stages of dvc.yaml, or: train")
    p.add_argument("--iterations", type=int, default=None, help="override train.iterations")
    p.add_argument("--compare", type=Path, default=None,
                   help="a run's folder (data/, models/, metrics/, results/): same bytes there?")
    p.add_argument("--label", required=True)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "stages.json")
    a = p.parse_args(argv)
    import yaml
    stages = dvc_stages()
    names = [n for n in stages if n.startswith("train_")] if a.stages == ["train"] else a.stages
    unknown = sorted(set(names) - set(stages))
    if unknown:
        raise SystemExit(f"bench_stages: not a stage of dvc.yaml: {unknown}")
    names = [n for n in stages if n in names]                      # pipeline order
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    if a.iterations:
        params["train"]["iterations"] = int(a.iterations)
    written = {"/".join(Path(o).parts[:2]) for n in names for o in stages[n][1]}
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_stages_") as tmp:
        work = Path(tmp)
        (work / "stages").symlink_to(a.root.resolve() / "stages")
        (work / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
        _link_entries(a.data, work / "data", written)
        _link_entries(a.models, work / "models", written)
        for d in ("metrics/train", "results/rows"):
            (work / d).mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        for name in names:
            cmd, outs = stages[name]
            row = run_stage(name, cmd, outs, a.root.resolve(), work)
            if a.compare is not None:
                row["same_bytes_as_compare"] = {
                    f: (a.compare / f).is_file() and _sha(a.compare / f) == h for f, h in row["sha256"].items()}
            rows.append(row)
            print(json.dumps(row), flush=True)
        total = time.perf_counter() - t0
    result = json.loads(a.out.read_text()) if a.out.is_file() else {
        "benchmark": "stages", "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                            "platform": platform.platform()}}
    result[a.label] = {"root": str(a.root), "iterations": params["train"]["iterations"],
                       "seeds": params["study"]["seeds"], "parallel": params["study"]["parallel"],
                       "threads": params["train"]["threads"], "wall_s_total": round(total, 1),
                       "compare": None if a.compare is None else str(a.compare), "stages": rows}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
