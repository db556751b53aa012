"""Which settings make a training give the same bits on two CPU families (a probe, run on each
host and compared).

The data stages of the study reproduce across the project's two host types: on session 55's
Intel Xeon (AVX-512 FP16) host `dvc repro -s blur` wrote the `data/pairs` files whose md5
`dvc.lock` records from the AMD EPYC (Zen 4) host. The trainings do not: the same
`data/pairs/train.h5`, seed and settings gave stage-1 weights up to 2.3e-3 apart from the AMD
run's (the packaged restorer `rdnet/restore/models/restore_image.pt`, which is the AMD run's
seed 0). The difference comes from oneMKL: with `train.threads: 1` and batches under 16, torch
computes every 1x1 convolution as one MKL SGEMM per sample (`MKL_VERBOSE=1`: about 1,750 SGEMM
calls a step), and oneMKL picks its kernels by CPU. On the Intel host, changing MKL's code path
(`MKL_ENABLE_INSTRUCTIONS`, `MKL_CBWR`) changed the weights, while capping oneDNN's ISA
(`ONEDNN_MAX_CPU_ISA=AVX512_CORE_BF16`, Zen 4's level) or ATen's vector width
(`ATEN_CPU_CAPABILITY=avx2`) changed nothing; with two torch threads every convolution goes
to oneDNN (no SGEMM), and oneDNN's ISA caps down to `AVX512_CORE` give the same bits. oneMKL's conditional numerical reproducibility
(`MKL_CBWR`: one code path on every CPU that supports it; `,STRICT` also for every thread
count) is made for this, but whether its results on an AMD CPU equal those on an Intel one is
what this probe measures: nothing on one host can tell.

Measured (sessions 55-59, both host types, `--compare`): no setting gives the same training
bits on both; the inference hashes agree with `MKL_CBWR=COMPATIBLE`, with two torch threads
(all oneDNN), and with oneDNN off and `MKL_CBWR=COMPATIBLE` whatever vector width ATen and
oneMKL are held to, so the backward passes or the optimizer part the bits even then. Details
in docs/history.md, "Why the trainings differ between the two host types".

`--trace` finds the op: it trains `--iterations` steps per setting under a dispatch mode that
records every ATen op (name, sha256 of the inputs it reads, sha256 of its outputs) to
`benchmarks/results/cross_host_traces/`; `--compare-traces` prints the first op whose inputs
agree between two hosts and whose outputs do not. Traced on the AMD host (session 59) for
`plain` and `no_onednn_mkl_cbwr_compatible_aten_avx2`.

For each setting below, one subprocess trains the image-guided stage 1 (`--task restore`,
seed 0, one thread, `--iterations` steps) on the pairs file, and hashes (sha256) the trained
weights in key order; a second hashes the packaged restorer's heads on a fixed seeded input
(inference alone), and records the code path oneMKL reports for the setting (`MKL_VERBOSE`'s
version line: the ISA it dispatches to, and `CNR:`). Results go to `benchmarks/results/cross_host_training.json`, one entry per
CPU (model name and the flags that pick kernels); `--compare` prints, per setting, whether
every host recorded the same hashes. A setting whose training hashes agree across both host
types is the one to set for the study's trainings (then one full rerun, and `dvc.lock` holds
on both). At `--iterations 800` the plain setting's weights are also compared with the
packaged restorer's (the AMD run's seed 0).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/cross_host_training.py --iterations 800
    PYTHONPATH=$PWD .venv/bin/python benchmarks/cross_host_training.py --compare
    PYTHONPATH=$PWD .venv/bin/python benchmarks/cross_host_training.py --trace --iterations 2 \
        --settings plain no_onednn_mkl_cbwr_compatible_aten_avx2
    PYTHONPATH=$PWD .venv/bin/python benchmarks/cross_host_training.py --compare-traces
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import cpu_info, machine  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "cross_host_training.json"
PACKAGED = ROOT / "rdnet" / "restore" / "models" / "restore_image.pt"

#: no oneDNN at all, and oneMKL on its one code path for every CPU: the setting the last
#: entries below vary
_PORTABLE = {"TORCH_MKLDNN": "0", "MKL_CBWR": "COMPATIBLE"}

#: name -> environment (``TORCH_THREADS``: the training's and the inference's torch threads,
#: 1 unless given; ``TORCH_MKLDNN=0``: ``torch.backends.mkldnn.enabled = False`` in both, so
#: every convolution, forward and backward, is ATen's own im2col + oneMKL GEMM): the default,
#: oneMKL's reproducible code paths, oneDNN's ISA cap, and two torch threads, with which torch
#: sends the 1x1 convolutions to oneDNN instead of oneMKL
SETTINGS = {
    "plain": {},
    "mkl_cbwr_avx2": {"MKL_CBWR": "AVX2"},
    "mkl_cbwr_avx2_strict": {"MKL_CBWR": "AVX2,STRICT"},
    "mkl_cbwr_compatible": {"MKL_CBWR": "COMPATIBLE"},
    "mkl_cbwr_avx512": {"MKL_CBWR": "AVX512"},
    "onednn_avx512_core_bf16": {"ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16"},
    "two_torch_threads": {"TORCH_THREADS": "2"},
    "two_torch_threads_onednn_avx512_core_bf16": {"TORCH_THREADS": "2", "ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16"},
    "two_torch_threads_onednn_avx512_core": {"TORCH_THREADS": "2", "ONEDNN_MAX_CPU_ISA": "AVX512_CORE"},
    "two_torch_threads_onednn_avx2": {"TORCH_THREADS": "2", "ONEDNN_MAX_CPU_ISA": "AVX2"},
    # no oneDNN at all, and oneMKL on its one code path for every CPU (the only setting whose
    # inference agreed across the host types with oneMKL in use): whether the backward passes
    # then agree too is what this pair asks (session 57)
    "no_onednn": {"TORCH_MKLDNN": "0"},
    "no_onednn_mkl_cbwr_compatible": _PORTABLE,
    # the same with ATen's own kernels held to one vector width, in case the two CPUs take
    # different ones (both report AVX-512): AVX2, or the compiler's baseline code (session 58)
    "no_onednn_mkl_cbwr_compatible_aten_avx2": {**_PORTABLE, "ATEN_CPU_CAPABILITY": "avx2"},
    "no_onednn_mkl_cbwr_compatible_aten_default": {**_PORTABLE, "ATEN_CPU_CAPABILITY": "default"},
    # the same as a CPU without AVX-512 would run it (oneMKL and ATen both held to AVX2): a
    # check on one host of whether the setting's bits follow the instruction set at all
    "no_onednn_mkl_cbwr_compatible_as_avx2_cpu": {**_PORTABLE, "MKL_ENABLE_INSTRUCTIONS": "AVX2",
                                                  "ATEN_CPU_CAPABILITY": "avx2"},
    # the two libraries outside torch that pick code by CPU, held to one choice on top of the
    # setting above (session 59): numpy without its AVX-512 targets (the Intel CPU also has
    # numpy's AVX512_SPR, the AMD one does not), numba compiling for a generic x86-64
    "no_onednn_mkl_cbwr_compatible_aten_avx2_numpy_avx2": {
        **_PORTABLE, "ATEN_CPU_CAPABILITY": "avx2", "NPY_DISABLE_CPU_FEATURES": "AVX512_ICL X86_V4"},
    "no_onednn_mkl_cbwr_compatible_aten_avx2_numba_generic": {
        **_PORTABLE, "ATEN_CPU_CAPABILITY": "avx2", "NUMBA_CPU_NAME": "generic"},
}
#: environment variables that change kernels; cleared before each setting's own are applied
KERNEL_ENV = ("MKL_CBWR", "MKL_ENABLE_INSTRUCTIONS", "ONEDNN_MAX_CPU_ISA", "ATEN_CPU_CAPABILITY",
              "MKL_NUM_THREADS", "OMP_NUM_THREADS", "NPY_DISABLE_CPU_FEATURES", "NUMBA_CPU_NAME")
#: CPU flags that decide which kernels the libraries pick
FLAGS = ("avx2", "avx512f", "avx512_bf16", "avx512_fp16", "avx512_vnni", "amx_tile", "amx_bf16")


def cpu_flags() -> list[str]:
    have = set((cpu_info("flags") or "").split())
    return [f for f in FLAGS if f in have]


def weights_hash(path: Path) -> str:
    """sha256 of a checkpoint's state dict, tensor by tensor in key order (names, shapes,
    dtypes and bytes): the file's own bytes also hold the config and the fitted decision."""
    import torch
    sd = torch.load(path, map_location="cpu", weights_only=False)["state_dict"]
    h = hashlib.sha256()
    for k in sorted(sd):
        t = sd[k].detach().cpu().contiguous()
        h.update(f"{k}:{tuple(t.shape)}:{t.dtype}".encode())
        h.update(t.numpy().tobytes())
    return h.hexdigest()


def max_weight_diff(a: Path, b: Path) -> float:
    import torch
    sa = torch.load(a, map_location="cpu", weights_only=False)["state_dict"]
    sb = torch.load(b, map_location="cpu", weights_only=False)["state_dict"]
    return max(float((sa[k].float() - sb[k].float()).abs().max()) for k in sa)


#: run first in the training's and the inference's subprocess: ``TORCH_MKLDNN=0`` in the
#: setting's environment switches oneDNN off before any model is built
_PRELUDE = r"""
import os, torch
torch.backends.mkldnn.enabled = os.environ.get("TORCH_MKLDNN", "1") != "0"
"""

_INFER = _PRELUDE + r"""
import hashlib, sys, numpy as np
from rdnet.train.checkpoint import load_model
torch.set_num_threads(int(sys.argv[2]))
net = load_model(sys.argv[1]).eval()
g = np.random.default_rng(7)
ev = torch.from_numpy(g.poisson(0.3, (4, 20, 64, 64)).astype(np.float32))
img = torch.from_numpy(g.random((4, 1, 64, 64), dtype=np.float32))
with torch.no_grad():
    out = net.heads(img, ev)
h = hashlib.sha256()
for t in (out if isinstance(out, (tuple, list)) else [out]):
    h.update(t.contiguous().numpy().tobytes())
print(h.hexdigest())
"""


_MKL_PATH = r"""
import torch
torch.set_num_threads(1)
torch.nn.Conv2d(8, 16, 1)(torch.ones(2, 8, 4, 4))
"""


def mkl_code_path(setting: dict) -> str | None:
    """oneMKL's own account of the code path it takes under ``setting`` (the version line
    ``MKL_VERBOSE=1`` prints at its first call: the ISA it dispatches to) and whether its
    conditional numerical reproducibility is on (``CNR:``), from one 1x1 convolution."""
    env = {**_env(setting), "MKL_VERBOSE": "1"}
    out = subprocess.run([sys.executable, "-c", _MKL_PATH], env=env, cwd=ROOT, capture_output=True,
                         text=True).stdout.splitlines()
    head = next((line for line in out if line.startswith("MKL_VERBOSE oneMKL")), None)
    cnr = next((w for line in out for w in line.split() if w.startswith("CNR:")), None)
    return None if head is None else f"{head[len('MKL_VERBOSE '):]} | {cnr}"


#: ``python -m rdnet.train.run ARGS`` after the prelude
_TRAIN = _PRELUDE + r"""
import runpy, sys
sys.argv = ["rdnet.train.run"] + sys.argv[1:]
runpy.run_module("rdnet.train.run", run_name="__main__", alter_sys=True)
"""


#: ``python -m rdnet.train.run ARGS`` under a dispatch mode that records every ATen op the run
#: calls (forward, backward, optimizer, in order): its name and a sha256 of its inputs (before
#: the call, so in-place ops count) and of its outputs; written as JSON to ``sys.argv[1]``
_TRACE = _PRELUDE + r"""
import hashlib, json, runpy, sys
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_flatten

def digest(obj):
    h = hashlib.sha256()
    for t in tree_flatten(obj)[0]:
        if isinstance(t, torch.Tensor):
            t = t.detach().cpu().contiguous()
            if t.dtype in (torch.bfloat16, torch.float16):
                t = t.view(torch.int16)
            h.update(f"{tuple(t.shape)}{t.dtype}".encode())
            h.update(t.numpy().tobytes())
        else:
            h.update(repr(t).encode())
    return h.hexdigest()[:12]

rows = []
class Trace(TorchDispatchMode):
    # inputs: the arguments the op only reads (a written one's old content is an earlier
    # op's output, or uninitialised memory); outputs: not for the empty family (uninitialised)
    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        if str(func).startswith("profiler."):     # record_function markers: object ids
            return func(*args, **kwargs)
        schema = func._schema.arguments
        written = {a.name for a in schema if a.alias_info is not None and a.alias_info.is_write}
        read_args = [x for a, x in zip(schema, args) if a.name not in written]
        read_kwargs = {k: v for k, v in kwargs.items() if k not in written}
        before = digest((read_args, read_kwargs))
        out = func(*args, **kwargs)
        name = str(func)
        rows.append([name, before, "-" if name.startswith(("aten.empty", "aten.new_empty")) else digest(out)])
        return out

out_path = sys.argv[1]
sys.argv = ["rdnet.train.run"] + sys.argv[2:]
torch.manual_seed(0)    # the DataLoader's base seed (unused with no workers) comes from here
try:
    with Trace():
        runpy.run_module("rdnet.train.run", run_name="__main__", alter_sys=True)
except SystemExit as e:
    if e.code:
        raise
finally:
    with open(out_path, "w") as f:
        json.dump(rows, f)
"""

#: where ``--trace`` writes each host's op traces (one gzipped JSON per host and setting)
TRACES = ROOT / "benchmarks" / "results" / "cross_host_traces"


def _env(setting: dict) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in KERNEL_ENV}
    env.update(setting)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _threads(setting: dict) -> int:
    return int(setting.get("TORCH_THREADS", 1))


def train_subprocess(name: str, setting: dict, pairs: Path, iterations: int, out: Path,
                     script: str = _TRAIN, *script_args: str) -> None:
    """Train the image-guided stage 1 (seed 0, ``iterations`` steps) into ``out`` under
    ``setting`` in a child process running ``script`` (``_TRAIN``, or ``_TRACE`` with its
    trace path first); exits with the child's stderr when it fails."""
    cmd = [sys.executable, "-c", script, *script_args, "--task", "restore", "--params", str(ROOT / "params.yaml"),
           "--train", str(pairs), "--out", str(out), "--no-progress", "--no-resume",
           "--set", "train.seed=0", "--set", f"train.threads={_threads(setting)}",
           "--set", f"train.iterations={iterations}", "--set", "train.dvclive=false"]
    done = subprocess.run(cmd, env=_env(setting), cwd=ROOT, capture_output=True, text=True)
    if done.returncode:
        sys.exit(f"{name}: training failed:\n{done.stderr[-3000:]}")


def run_setting(name: str, setting: dict, pairs: Path, iterations: int, tmp: Path) -> dict:
    out = tmp / name
    threads = _threads(setting)
    t0 = time.perf_counter()
    train_subprocess(name, setting, pairs, iterations, out)
    wall = time.perf_counter() - t0
    infer = subprocess.run([sys.executable, "-c", _INFER, str(PACKAGED), str(threads)], env=_env(setting), check=True, cwd=ROOT,
                           capture_output=True, text=True).stdout.strip()
    rec = {"env": setting, "train_weights_sha256": weights_hash(out / "model.pt"), "train_wall_s": round(wall, 2),
           "inference_sha256": infer, "mkl_code_path": mkl_code_path(setting)}
    if iterations == 800:
        rec["max_abs_diff_to_packaged_amd_seed0"] = max_weight_diff(out / "model.pt", PACKAGED)
    return rec


def _trace_file(setting: str) -> Path:
    """``TRACES/<host>__<setting>.json.gz``: the host key shortened to a readable prefix plus
    8 hex digits of its sha1, so two CPUs whose keys share the prefix get their own files."""
    key = host_key()
    readable = "".join(c if c.isalnum() else "_" for c in key).strip("_")[:40]
    return TRACES / f"{readable}_{hashlib.sha1(key.encode()).hexdigest()[:8]}__{setting}.json.gz"


def trace_setting(name: str, setting: dict, pairs: Path, iterations: int, tmp: Path) -> Path:
    """Train ``iterations`` steps under ``setting`` with every ATen op recorded (``_TRACE``)
    and write the trace, gzipped, to ``TRACES/<host>__<setting>.json.gz``."""
    import gzip
    raw = tmp / f"{name}.trace.json"
    train_subprocess(name, setting, pairs, iterations, tmp / name, _TRACE, str(raw))
    rows = json.loads(raw.read_text())
    TRACES.mkdir(parents=True, exist_ok=True)
    dest = _trace_file(name)
    tmp_dest = dest.with_suffix(".tmp")
    with gzip.GzipFile(tmp_dest, "wb", mtime=0) as f:     # mtime 0: the same trace, the same bytes
        f.write(json.dumps({"host": host_key(), "setting": name, "env": setting, "iterations": iterations,
                            "ops": rows}).encode())
    tmp_dest.replace(dest)
    print(f"{name}: {len(rows)} ops traced -> {dest.relative_to(ROOT)}")
    return dest


def compare_traces() -> None:
    """Per setting traced on two or more hosts: the first ATen op whose outputs differ
    between the hosts while its inputs are the same (the op whose kernel parts the bits),
    and the first op whose inputs differ (where the difference entered from outside)."""
    import gzip
    by_setting: dict[str, list[dict]] = {}
    for f in sorted(TRACES.glob("*.json.gz")):
        with gzip.open(f, "rt") as fh:
            t = json.load(fh)
        by_setting.setdefault(t["setting"], []).append(t)
    for name, traces in by_setting.items():
        print(f"\n{name}: {len(traces)} host(s)")
        if len(traces) < 2:
            continue
        a, b = traces[0], traces[1]
        ops_a, ops_b = a["ops"], b["ops"]
        print(f"  [{a['host']}] {len(ops_a)} ops, [{b['host']}] {len(ops_b)} ops")
        same_ops = next((i for i, (ra, rb) in enumerate(zip(ops_a, ops_b)) if ra[0] != rb[0]),
                        min(len(ops_a), len(ops_b)))
        if same_ops < min(len(ops_a), len(ops_b)):
            print(f"  op sequences part at #{same_ops}: {ops_a[same_ops][0]} against {ops_b[same_ops][0]}")
        pairs = list(zip(ops_a[:same_ops], ops_b[:same_ops]))
        # kernels that part the bits: the same inputs read, other outputs
        parting = [i for i, (ra, rb) in enumerate(pairs) if ra[1] == rb[1] and ra[2] != rb[2]]
        first_in = next((i for i, (ra, rb) in enumerate(pairs) if ra[1] != rb[1]), None)
        first_out = parting[0] if parting else None
        if first_out is None and first_in is None:
            print("  every op the same on both hosts")
            continue
        if first_in is not None and (first_out is None or first_in < first_out):
            print(f"  first op with different inputs: #{first_in} {ops_a[first_in][0]}")
        if first_out is not None:
            lo = max(0, first_out - 3)
            print(f"  first op with the same inputs and different outputs: #{first_out} {ops_a[first_out][0]}")
            for j in range(lo, min(len(ops_a), first_out + 4)):
                print(f"    #{j} {ops_a[j][0]:50s} in {ops_a[j][1]} / {ops_b[j][1]}  out {ops_a[j][2]} / {ops_b[j][2]}")
        print(f"  ops with the same inputs and different outputs: {len(parting)}, "
              f"of kinds {sorted({ops_a[i][0] for i in parting})}")


def host_key() -> str:
    m = machine()
    return f"{cpu_info('vendor_id') or 'unknown'} | {m['cpu']} | {','.join(cpu_flags())}"


def compare(results: dict) -> None:
    """Per step count and setting, each host's training and inference hashes (8 hex digits)
    and whether every host agrees (needs two hosts)."""
    hosts = list(results.get("hosts", {}))
    print(f"{len(hosts)} host(s):\n" + "\n".join(f"  [{i}] {h}" for i, h in enumerate(hosts)))
    for it in sorted({k for h in hosts for k in results["hosts"][h] if not k.startswith("_")}):
        print(f"\n{it}: setting, then training / inference hash per host")
        for name in SETTINGS:
            recs = {i: results["hosts"][h].get(it, {}).get(name) for i, h in enumerate(hosts)}
            recs = {i: r for i, r in recs.items() if r}
            if not recs:
                continue
            cells = "  ".join(f"[{i}] {r['train_weights_sha256'][:8]} / {r['inference_sha256'][:8]}"
                              for i, r in recs.items())
            if len(recs) < 2:
                verdict = "one host"
            else:
                same_t = len({r["train_weights_sha256"] for r in recs.values()}) == 1
                same_i = len({r["inference_sha256"] for r in recs.values()}) == 1
                verdict = ("SAME on every host" if same_t and same_i else
                           f"training {'same' if same_t else 'differs'}, inference {'same' if same_i else 'differs'}")
            print(f"  {name:42s} {cells}  {verdict}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=Path, default=ROOT / "data" / "pairs" / "train.h5")
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--settings", nargs="*", default=list(SETTINGS), choices=list(SETTINGS))
    ap.add_argument("--compare", action="store_true", help="only print the comparison of the recorded hosts")
    ap.add_argument("--trace", action="store_true",
                    help="record every ATen op of an --iterations-step training per setting (to "
                         "benchmarks/results/cross_host_traces/) instead of hashing weights")
    ap.add_argument("--compare-traces", action="store_true",
                    help="only print, per traced setting, the first op whose outputs differ between hosts")
    args = ap.parse_args()
    results = json.loads(RESULTS.read_text()) if RESULTS.exists() else {"hosts": {}}
    if args.compare:
        compare(results)
        return
    if args.compare_traces:
        compare_traces()
        return
    if not args.pairs.exists():
        sys.exit(f"{args.pairs}: no such file (run `dvc repro blur` first)")
    if args.trace:
        with tempfile.TemporaryDirectory() as tmp:
            for name in args.settings:
                trace_setting(name, SETTINGS[name], args.pairs, args.iterations, Path(tmp))
        compare_traces()
        return
    key = host_key()
    entry = results["hosts"].setdefault(key, {})
    import torch
    entry["_versions"] = {"torch": torch.__version__, "machine": machine(),
                          "pairs_md5": hashlib.md5(args.pairs.read_bytes()).hexdigest()}
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.settings:
            rec = run_setting(name, SETTINGS[name], args.pairs, args.iterations, Path(tmp))
            entry.setdefault(f"iterations_{args.iterations}", {})[name] = rec
            print(name, json.dumps(rec))
    RESULTS.write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")
    compare(results)


if __name__ == "__main__":
    main()
