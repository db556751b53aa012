"""Prophesee RAW decoders compared: rdnet's own (numba) against the maintained packages
that have wheels here (faery, expelliarmus, evlib; iniVation's dv-processing reads AEDAT 4
only, not RAW).

For each decoder that is importable: the two shared RAW files (EVT 2.0 sparklers,
EVT 3.0 night) decoded whole, best of 3 (events/s), the count, ON fraction and duration
against ../shared/real/README.md, whether the events equal rdnet's exactly, and the
sensor size it reports. Then streaming: a multi-GB EVT 3.0 file (night.raw's data
repeated; time keeps going forward across the copies) is read chunk by chunk in a fresh
process per decoder and the peak RSS recorded, plus ``rdnet info`` and a 100 ms
``slice_time`` on it (both must not load the file whole).

The candidates are not dependencies of rdnet; install them in a scratch environment
that also sees rdnet's, e.g.::

    python -m venv --system-site-packages /tmp/candenv
    /tmp/candenv/bin/pip install faery expelliarmus evlib dv-processing
    python -c "import site; print(site.getsitepackages()[0])" > /tmp/candenv/lib/python3.*/site-packages/rdnet.pth
    PYTHONPATH=$PWD /tmp/candenv/bin/python benchmarks/bench_formats.py   # -> benchmarks/results/formats.json
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SHARED = ROOT.parent / "shared" / "real"
FILES = {"sparklers_evt2": (SHARED / "prophesee_gen3_sparklers" / "sparklers.raw",
                           {"events": 521_252, "on_fraction": 0.36, "size": [640, 480], "duration_s": 0.0959}),
         "night_evt3": (SHARED / "prophesee_evk4_night" / "night.raw",
                        {"events": 1_218_618, "on_fraction": 0.45, "size": [1280, 720], "duration_s": 10.77})}
META = {  # licence from the wheel's metadata / LICENSE file; last release from the PyPI listing
    "rdnet": {"licence": "MIT (this project)", "release": "-", "dependencies": "numpy, numba (already used)"},
    "faery": {"licence": "LGPL-3.0", "release": "0.7.1 (2026-09)", "dependencies": "numpy (Rust extension)"},
    "expelliarmus": {"licence": "GPL-2.0", "release": "1.1.12 (2023-02)", "dependencies": "numpy (C extension)"},
    "evlib": {"licence": "MIT", "release": "0.13.2 (2026-08)",
              "dependencies": "polars, pyarrow, pandera, h5py, hdf5plugin (Rust extension)"},
    "dv_processing": {"licence": "Apache-2.0", "release": "2.0.4 (2026-07)", "dependencies": "numpy (C++ extension)"},
}


# --- decoders: whole file -> dict of columns t, x, y, p (+ reported size) ----------------------
def _rdnet(path):
    from rdnet.events.io import ProphReader
    with ProphReader(path) as r:
        a = r.read().array
        return {k: a[k] for k in "txyp"}, [r.width, r.height]


def _faery(path):
    import faery
    s = faery.events_stream_from_file(path)
    a = np.concatenate(list(s))
    return {"t": a["t"], "x": a["x"], "y": a["y"], "p": a["on"]}, list(s.dimensions())


def _expelliarmus(path):
    from expelliarmus import Wizard
    a = Wizard(encoding="evt2" if "sparklers" in str(path) else "evt3").read(path)
    return {k: a[k] for k in "txyp"}, None


def _evlib(path):
    import evlib
    df = evlib.load_events(str(path)).collect()
    t = df["t"]
    t = t.dt.total_microseconds().to_numpy() if str(t.dtype).startswith("Duration") else t.to_numpy()
    p = df["polarity"].to_numpy()
    return {"t": t, "x": df["x"].to_numpy(), "y": df["y"].to_numpy(), "p": (p > 0).astype(np.uint8)}, None


def _dv_processing(path):
    import dv_processing as dv
    dv.io.MonoCameraRecording(str(path))          # raises: AEDAT 4 only
    raise RuntimeError("unreachable")


DECODERS = {"rdnet": _rdnet, "faery": _faery, "expelliarmus": _expelliarmus, "evlib": _evlib,
            "dv_processing": _dv_processing}


# --- decoders: streaming a big file in chunks -> event count ----------------------------------
def _stream_count(name: str, path: str) -> int:
    n = 0
    if name == "rdnet":
        from rdnet.events.io import open_events
        with open_events(path) as s:
            for ch in s.chunks(1_000_000):
                n += len(ch)
    elif name == "faery":
        import faery
        for packet in faery.events_stream_from_file(path):
            n += len(packet)
    elif name == "expelliarmus":
        from expelliarmus import Wizard
        w = Wizard(encoding="evt3", fpath=path)
        w.set_chunk_size(1_000_000)
        for ch in w.read_chunk():
            n += len(ch)
    else:
        raise ValueError(name)
    return n


def _vm_hwm_mb() -> float:
    """Peak resident memory of this process (VmHWM; unlike ru_maxrss it restarts at exec,
    so a spawned child does not report its parent's peak)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return round(int(line.split()[1]) / 1024, 1)
    return float("nan")


_IMPORTS = {"rdnet": "rdnet.events.io", "faery": "faery", "expelliarmus": "expelliarmus"}


def _child(task: str, name: str, path: str, q) -> None:
    try:
        import importlib
        importlib.import_module(_IMPORTS[name])
        imported_mb = _vm_hwm_mb()
        t = time.perf_counter()
        if task == "stream":
            out = {"events": _stream_count(name, path)}
        elif task == "info":
            import contextlib
            import io

            from rdnet.cli import main
            with contextlib.redirect_stdout(io.StringIO()) as buf:
                rc = main(["info", path, "--json"])
            s = json.loads(buf.getvalue())
            out = {"rc": rc, "events": s["events"], "duration_s": round(s["duration_s"], 2)}
        else:  # slice
            from rdnet.events.io import open_events
            with open_events(path) as s:
                t0 = 11_200_224 + 1_000_000
                out = {"events": len(s.slice_time(t0, t0 + 100_000)), "window_us": [t0, t0 + 100_000]}
        out.update(wall_s=round(time.perf_counter() - t, 2), peak_rss_mb=_vm_hwm_mb(),
                   peak_rss_after_imports_mb=imported_mb)
    except Exception as e:  # noqa: BLE001 - recorded in the results
        out = {"error": f"{type(e).__name__}: {str(e)[:200]}"}
    q.put(out)


def _in_child(task: str, name: str, path: Path) -> dict:
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    pr = ctx.Process(target=_child, args=(task, name, str(path), q))
    pr.start()
    out = q.get()
    pr.join()
    return out


def _big_file(folder: Path, gb: float) -> tuple[Path, int]:
    src = FILES["night_evt3"][0].read_bytes()
    head_end = src.index(b"\n", src.index(b"% system_ID")) + 1
    head, data = src[:head_end], src[head_end:]
    copies = max(1, int(gb * 2**30 / len(data)))
    path = folder / "big.raw"
    with open(path, "wb") as fh:
        fh.write(head)
        for _ in range(copies):
            fh.write(data)
    return path, copies


def _streaming(gb: float, repeats: int) -> dict:
    with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_TMP")) as work:
        big, copies = _big_file(Path(work), gb)
        out = {"file": {"bytes": big.stat().st_size, "copies_of_night_raw": copies,
                        "events": copies * FILES["night_evt3"][1]["events"]}}
        for _ in range(repeats):             # interleaved, best wall time kept (shared machine)
            for name in ("rdnet", "faery", "expelliarmus"):
                r = _in_child("stream", name, big)
                print("stream", name, r, flush=True)
                if name not in out or r.get("wall_s", 1e9) < out[name].get("wall_s", 1e9):
                    out[name] = r
        out["rdnet_info"] = _in_child("info", "rdnet", big)
        out["rdnet_slice_100ms"] = _in_child("slice", "rdnet", big)
        print(out, flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--big-gb", type=float, default=2.0, help="size of the streamed EVT 3.0 file")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--stream-repeats", type=int, default=2)
    ap.add_argument("--skip-streaming", action="store_true", help="only the whole-file comparison")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "formats.json")
    args = ap.parse_args()
    for path, _ in FILES.values():
        if not path.is_file():
            sys.exit(f"{path} missing (../shared must sit beside the repository)")
    ref = {k: _rdnet(p)[0] for k, (p, _) in FILES.items()}
    rows = []
    for name, fn in DECODERS.items():
        row = {"decoder": name, **META[name], "files": {}}
        for key, (path, readme) in FILES.items():
            try:
                best = float("inf")
                for _ in range(args.repeats):
                    t = time.perf_counter()
                    cols, size = fn(path)
                    best = min(best, time.perf_counter() - t)
            except Exception as e:  # noqa: BLE001 - an import error or an unsupported file
                row["files"][key] = {"error": f"{type(e).__name__}: {str(e)[:160]}"}
                continue
            tt = np.asarray(cols["t"], np.int64)
            n = len(tt)
            same = n == len(ref[key]["t"]) and all(
                np.array_equal(np.asarray(cols[k]).astype(np.int64), ref[key][k].astype(np.int64)) for k in "txyp")
            on = float(np.mean(cols["p"]))
            dur_s = (int(tt[-1]) - int(tt[0])) * 1e-6
            row["files"][key] = {
                "events": n, "on_fraction": round(on, 4),
                "duration_s": round(dur_s, 4), "size_reported": size,
                "time_sorted": bool(np.all(np.diff(tt) >= 0)), "equal_to_rdnet": bool(same),
                "matches_readme": bool(n == readme["events"] and round(on, 2) == readme["on_fraction"]
                                       and abs(dur_s - readme["duration_s"]) < 0.01),
                "best_s": round(best, 4), "mev_per_s": round(n / best / 1e6, 1)}
            print(name, key, row["files"][key], flush=True)
        rows.append(row)
    streaming = {} if args.skip_streaming else _streaming(args.big_gb, args.stream_repeats)
    out = {"benchmark": "formats", "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                               "load_avg": [round(v, 2) for v in os.getloadavg()]},
           "readme": {k: v for k, (_, v) in FILES.items()}, "decoders": rows, "streaming": streaming}
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    print("wrote", args.out)


if __name__ == "__main__":
    main()
