"""``rdnet simulate`` end to end, as a user runs it (issue 13, part 2).

Workload: a 346 x 260 (DAVIS346) textured clip panning 1 px per frame at 1 kHz, stored
as an HDF5 recording with uint8 frames (a blobs texture of :func:`rdnet.sim.scenes.procedural_texture`,
luminance, gamma-encoded to 8 bits). The real CLI runs as a subprocess::

    python -m rdnet.cli simulate IN OUT --params params.yaml [--set interpolate.max_upsample=1]

with the repository's ``params.yaml`` (the study's ``degrade`` section: every degradation
on; its ``interpolate`` section: DIS flow, max_upsample 16). Reported: the marginal rate
``(1600 - 400) / (t_1600 - t_400)`` in input frames per second (start-up and imports do
not count), per mode, the median over ``--repeat`` alternated runs, and the same per
CPU-second of the CLI process (user + system, all threads: steadier when other jobs share
the cores, blind to parallel speed-up); the load average before each run (the machine may
be shared) and every run's wall and CPU time are kept.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_simulate_cli.py [--repeat 3] [--label after]

``--label`` names the entry in ``benchmarks/results/simulate_cli.json`` (other labels in
the file are kept); ``--compare before DIR`` runs another checkout's CLI too, with that
checkout's own ``params.yaml`` (its sensor, degrade and interpolate sections must match) (e.g. the
code before the speed-ups: ``git archive <rev> | tar -x -C DIR``), A/B alternated in
every repeat so both see the same load; ``--extra-set`` adds a ``--set`` to this
checkout's runs (e.g. ``--extra-set interpolate.dis_finest_scale=2``).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
W, H = 346, 260
STEP_US = 1000
SIZES = (400, 1600)
MODES = {"no_interpolation": ["--set", "interpolate.max_upsample=1"], "default_interpolation": []}


def render_clip(path: Path, n_frames: int, seed: int = 0, tex_frames: int = max(SIZES)) -> None:
    """Uint8 frames of a texture panned 1 px per frame (integer shifts), t = k ms; the
    texture is ``W + tex_frames`` wide, so shorter clips are prefixes of the longest."""
    from rdnet.events.io import H5RecordingWriter
    from rdnet.sim.scenes import procedural_texture

    rng = np.random.default_rng(seed)
    tex = procedural_texture("blobs", H, W + max(tex_frames, n_frames), rng) @ np.array([0.299, 0.587, 0.114], np.float32)
    tex8 = np.clip(np.power(tex, 1 / 2.2) * 255 + 0.5, 0, 255).astype(np.uint8)
    with H5RecordingWriter(path, W, H, "davis346-pan") as w:
        for s in range(0, n_frames, 200):
            k = np.arange(s, min(s + 200, n_frames))
            ims = np.stack([tex8[:, i:i + W] for i in k])
            w.append_frames(ims, k.astype(np.int64) * STEP_US, np.zeros(len(k), np.int64))


def _children_cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def params_files(codes: list[Path]) -> dict[Path, Path]:
    """Each checkout's own ``params.yaml`` (this repository's where a checkout has none):
    the keys of other sections can differ between versions, and a checkout rejects keys it
    does not know. The sections ``rdnet simulate`` reads must be the same in all of them."""
    out = {c: (c / "params.yaml" if (c / "params.yaml").is_file() else ROOT / "params.yaml") for c in codes}
    sections = [{k: v for k, v in yaml.safe_load(p.read_text()).items() if k in ("sensor", "degrade", "interpolate")}
                for p in out.values()]
    if any(s != sections[0] for s in sections[1:]):
        raise SystemExit("the checkouts' params.yaml differ in sensor, degrade or interpolate: "
                         + ", ".join(str(p) for p in out.values()))
    return out


def run_cli(code: Path, src: Path, out: Path, params: Path, extra: list[str]) -> tuple[float, float, str]:
    """(wall s, CPU s (user + system, every thread), the CLI's last line) of one run."""
    env = dict(os.environ, PYTHONPATH=str(code))
    cmd = [sys.executable, "-m", "rdnet.cli", "simulate", str(src), str(out), "--params", str(params), *extra]
    c0 = _children_cpu_s()
    t0 = time.perf_counter()
    res = subprocess.run(cmd, cwd=code, env=env, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{res.stderr[-2000:]}")
    return dt, _children_cpu_s() - c0, res.stdout.strip().splitlines()[-1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--label", default="after", help="name of this checkout's entry")
    ap.add_argument("--code", type=Path, default=ROOT, help="checkout whose CLI runs (default: this one)")
    ap.add_argument("--compare", nargs=2, metavar=("LABEL", "DIR"), default=None,
                    help="also run another checkout (e.g. 'before' /tmp/old), A/B alternated in every repeat")
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    ap.add_argument("--extra-set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="a --set for every run of --code (repeatable)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "simulate_cli.json")
    args = ap.parse_args(argv)
    extra_args = [a for kv in args.extra_set for a in ("--set", kv)]
    codes = {args.label: (args.code, extra_args)}
    if args.compare:
        codes[args.compare[0]] = (Path(args.compare[1]), [])
    params = params_files([code for code, _ in codes.values()])
    command = "python benchmarks/bench_simulate_cli.py " + " ".join(argv or sys.argv[1:])
    entries = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        srcs = {n: tmp / f"pan_{n}.h5" for n in SIZES}
        for n, p in srcs.items():
            render_clip(p, n)
        for code, extra in codes.values():
            for m in args.modes:   # warm-up (numba cache load/compile, disk cache), not timed
                run_cli(code, srcs[SIZES[0]], tmp / "out.h5", params[code], MODES[m] + extra)
        runs = {lb: {m: {n: [] for n in SIZES} for m in args.modes} for lb in codes}
        cpus = {lb: {m: {n: [] for n in SIZES} for m in args.modes} for lb in codes}
        loads = {lb: [] for lb in codes}
        for r in range(args.repeat):
            for m in args.modes:
                for n in SIZES:
                    for lb, (code, extra) in codes.items():
                        loads[lb].append(os.getloadavg()[0])
                        dt, cpu, line = run_cli(code, srcs[n], tmp / "out.h5", params[code], MODES[m] + extra)
                        runs[lb][m][n].append(round(dt, 3))
                        cpus[lb][m][n].append(round(cpu, 3))
                        print(f"[{lb}] {m} {n} frames: {dt:.2f} s, CPU {cpu:.2f} s (load {loads[lb][-1]:.2f}) {line}",
                              flush=True)
        for lb, (code, extra) in codes.items():
            entry = entries[lb] = {"command": command, "code": str(code), "extra_args": extra, "modes": {}}
            for m in args.modes:
                rs = runs[lb][m]
                rates = [(SIZES[1] - SIZES[0]) / (b - a) if b > a else float("nan")
                         for a, b in zip(rs[SIZES[0]], rs[SIZES[1]])]
                cs = cpus[lb][m]
                cpu_rates = [(SIZES[1] - SIZES[0]) / (b - a) if b > a else float("nan")
                             for a, b in zip(cs[SIZES[0]], cs[SIZES[1]])]
                entry["modes"][m] = {
                    "cli_args": MODES[m] + extra,
                    "marginal_frames_per_s_median": round(statistics.median(rates), 1),
                    "marginal_frames_per_s_runs": [round(x, 1) for x in rates],
                    "wall_s": {str(n): rs[n] for n in SIZES},
                    # frames per CPU-second (user + system, all threads): less sensitive to
                    # other jobs on the machine than wall time, but blind to parallel speed-up
                    "marginal_frames_per_cpu_s_median": round(statistics.median(cpu_rates), 1),
                    "marginal_frames_per_cpu_s_runs": [round(x, 1) for x in cpu_rates],
                    "cpu_s": {str(n): cs[n] for n in SIZES},
                    "end_to_end_frames_per_s_1600_median": round(SIZES[1] / statistics.median(rs[SIZES[1]]), 1)}
            entry["load_average_1min"] = {"min": round(min(loads[lb]), 2),
                                          "median": round(statistics.median(loads[lb]), 2),
                                          "max": round(max(loads[lb]), 2)}
    doc = {"benchmark": "simulate_cli", "workload": {
        "size": [W, H], "step_us": STEP_US, "pan_px_per_frame": 1, "frames": list(SIZES),
        "frames_dtype": "uint8", "params": "repository params.yaml (study degrade + interpolate sections)",
        "rate": "marginal: (1600 - 400) / (t_1600 - t_400) input frames per second, median over alternated repeats"},
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "python": platform.python_version()}, "results": {}}
    if args.out.exists():
        doc["results"] = json.loads(args.out.read_text()).get("results", {})
    doc["results"].update(entries)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    for lb, entry in entries.items():
        for m, e in entry["modes"].items():
            print(f"{lb} {m}: {e['marginal_frames_per_s_median']} frames/s marginal "
                  f"(runs {e['marginal_frames_per_s_runs']}), {e['marginal_frames_per_cpu_s_median']} "
                  f"frames per CPU-s (runs {e['marginal_frames_per_cpu_s_runs']}), load {entry['load_average_1min']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
