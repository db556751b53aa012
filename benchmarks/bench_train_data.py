"""Wall time of the study's training stages, run as ``dvc repro`` runs them: each stage's
command as DVC resolves it from ``dvc.yaml`` (``python stages/train.py ...``: every seed of
``study.seeds``, ``study.parallel`` processes of ``train.threads`` threads), in a
temporary folder that links ``stages/`` of the checkout under test and ``data/`` of an
existing run, with ``params.yaml`` (``--iterations`` overrides ``train.iterations``).

Made for an A/B of code that must not change what is trained (the in-memory pairs of
:mod:`rdnet.train.data`): run it with ``--root`` at the checkout before the change (a
``git worktree``) and with this one, on the same data, right after each other. Every row
records the stage's wall time, its CPU time, the peak resident memory of its largest
process (``os.wait4``), the load average before, and the SHA-256 of every
``model.pt`` it wrote (one per seed), so the two runs show whether the trained bytes are equal
(and, at the study's iterations, whether they equal a ``dvc repro``'s: ``--compare
MODELS``). Stages run in ``dvc.yaml`` order; one that needs another's models (RDNet's
stage 1, its stage 2 start) reads them from this run or, when that stage is not selected,
from ``--models``.

    git worktree add /tmp/before HEAD~1
    .venv/bin/python benchmarks/bench_train_data.py --root /tmp/before --data data --models models \\
        --iterations 200 --label before --out benchmarks/results/train_data.json
    .venv/bin/python benchmarks/bench_train_data.py --data data --models models \\
        --iterations 200 --label preload --out benchmarks/results/train_data.json
    .venv/bin/python benchmarks/bench_train_data.py --data data --stages all --compare models \\
        --label study --out benchmarks/results/train_data.json      # every training, as dvc repro

Each run adds (or replaces) its ``--label`` entry of the out file.
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


def training_stages() -> dict[str, str]:
    """name -> command of every ``train_*`` stage of dvc.yaml, in pipeline order."""
    from dvc.repo import Repo
    with Repo(str(ROOT)) as repo:
        stages = {s.addressing: s.cmd if isinstance(s.cmd, str) else " && ".join(s.cmd)
                  for s in repo.index.stages if s.addressing.startswith("train_")}
    return stages


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _out_dir(cmd: list[str]) -> str:
    return cmd[cmd.index("--out") + 1]


def run_stage(name: str, cmd: str, root: Path, work: Path) -> dict:
    argv = shlex.split(cmd)
    if argv[0] == "python":
        argv[0] = sys.executable
    env = {**os.environ, "PYTHONPATH": str(root)}
    load = os.getloadavg()[0]
    t = time.perf_counter()
    child = subprocess.Popen(argv, env=env, cwd=work, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(child.pid, 0)       # the stage's own rusage (its seed workers included)
    wall = time.perf_counter() - t
    if os.waitstatus_to_exitcode(status):
        raise SystemExit(f"bench_train_data: {name} failed: {cmd}")
    out = work / _out_dir(argv)
    return {"stage": name, "wall_s": round(wall, 2), "cpu_s": round(usage.ru_utime + usage.ru_stime, 1),
            "load_average_1min_before": round(load, 2),
            "peak_rss_mb_largest_process": round(usage.ru_maxrss / 1024, 1),
            "model_sha256": {str(p.relative_to(out)): _sha(p) for p in sorted(out.rglob("model.pt"))}}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--root", type=Path, default=ROOT, help="checkout whose code runs the stages")
    p.add_argument("--data", type=Path, default=ROOT / "data", help="a run's data/ (pairs, events)")
    p.add_argument("--models", type=Path, default=None, help="a run's models/, for the stages not selected")
    p.add_argument("--stages", nargs="+", default=DEFAULT_STAGES, help="training stages of dvc.yaml, or: all")
    p.add_argument("--iterations", type=int, default=None, help="override train.iterations")
    p.add_argument("--compare", type=Path, default=None,
                   help="a run's models/: report whether each seed's model.pt has the same bytes")
    p.add_argument("--label", required=True)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "train_data.json")
    a = p.parse_args(argv)
    import yaml
    stages = training_stages()
    names = list(stages) if a.stages == ["all"] else a.stages
    unknown = sorted(set(names) - set(stages))
    if unknown:
        raise SystemExit(f"bench_train_data: not a training stage of dvc.yaml: {unknown}; one of {list(stages)}")
    names = [n for n in stages if n in names]                      # pipeline order
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    if a.iterations:
        params["train"]["iterations"] = int(a.iterations)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_train_data_") as tmp:
        work = Path(tmp)
        (work / "stages").symlink_to(a.root.resolve() / "stages")
        (work / "data").symlink_to(a.data.resolve())
        (work / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
        (work / "metrics" / "train").mkdir(parents=True)
        (work / "models").mkdir()
        written = {Path(_out_dir(shlex.split(stages[n]))).name for n in names}
        if a.models is not None:
            for m in sorted(a.models.resolve().iterdir()):
                if m.is_dir() and m.name not in written:
                    (work / "models" / m.name).symlink_to(m)
        t0 = time.perf_counter()
        for name in names:
            row = run_stage(name, stages[name], a.root.resolve(), work)
            if a.compare is not None:
                ref = a.compare / Path(_out_dir(shlex.split(stages[name]))).name
                row["same_bytes_as_compare"] = {
                    f: (ref / f).is_file() and _sha(ref / f) == h for f, h in row["model_sha256"].items()}
            rows.append(row)
            print(json.dumps(row), flush=True)
        total = time.perf_counter() - t0
    result = json.loads(a.out.read_text()) if a.out.is_file() else {
        "benchmark": "train_data", "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
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
