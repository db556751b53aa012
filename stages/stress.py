"""Stage `stress`: the rows of `study.stress_rows` on the test sequences re-simulated with
every degradation at exactly each scale of `study.stress_scales` (metrics/stress.json,
results/stress/psnr_vs_strength.png and its `dvc plots` data)."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.config import section
    from rdnet.study.stress import plot_stress, stress_plot_data, stress_test
    res = stress_test(params, args.scenes, args.interp, args.work)
    res["train_scale"] = [list(r) for r in section(params, "randomize").train_ranges]
    res["test_scale"] = list(section(params, "randomize").test_scale)
    _common.write_json(args.out, res)
    plot_stress(args.figures / "psnr_vs_strength.png", res)
    _common.write_json(args.figures / "psnr_vs_strength.json", stress_plot_data(res))


p = _common.parser(__doc__)
p.add_argument("--scenes", type=Path, default=Path("data/scenes"))
p.add_argument("--interp", type=Path, default=Path("data/interp"))
p.add_argument("--work", type=Path, default=Path("data/stress"))
p.add_argument("--out", type=Path, default=Path("metrics/stress.json"))
p.add_argument("--figures", type=Path, default=Path("results/stress"))
_common.run(main, p)
