"""Stage `train_ednccn`: the EDnCNN-style per-event keep/drop classifier baseline
(rdnet.restore.ednccn) on the study's training pairs and event streams, its keep
threshold fitted on the held-out training sequences (params: ednccn). Writes OUT/model.pt;
the wall time goes to --timing, outside OUT, so OUT depends only on the settings and data."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.config import section
    from rdnet.restore.ednccn import train_ednccn
    res = train_ednccn(section(params, "ednccn"), args.train, args.events_dir, args.out, progress=not args.no_progress)
    _common.write_json(args.timing, {"wall_s": res["wall_s"], "device": res["device"], "steps": res["steps"],
                                     "parameters": res["parameters"]})
    d = res["decision"]
    print(f"trained {res['checkpoint']} ({res['parameters']:,} parameters, {res['wall_s']:.0f} s): threshold "
          f"{d['threshold']:.4f}, held-out F1 {d['val_metrics']['f1']:.4f} (raw {d['val_metrics_raw']['f1']:.4f}), "
          f"count ratio {d['val_metrics']['count_ratio']:.3f}")


p = _common.parser(__doc__)
p.add_argument("--train", type=Path, default=Path("data/pairs/train.h5"))
p.add_argument("--events-dir", type=Path, default=Path("data/events/train"))
p.add_argument("--out", type=Path, default=Path("models/ednccn"))
p.add_argument("--timing", type=Path, default=Path("metrics/train/ednccn.json"))
p.add_argument("--no-progress", action="store_true")
_common.run(main, p)
