"""Stage `restoration`: restoration metrics against the undegraded events of the test set
(metrics/restoration.json) for the raw degraded events, the event filters (STCF, GEF, BAF on
each sample's window; GEF on the voxels as in the ablation rows), the EDnCNN-style per-event
classifier (models/ednccn, rdnet.restore.ednccn) and every stage-1 network
of the study (rdnet.study.rows.LEARNED_RESTORERS: the count output image-guided and
events-only, the paper's signed output, and RDNet's fine-tuned stage 1 of both): voxel L1 of
the networks' responses and the event-level precision / recall / F1 / count ratio / voxel L1,
overall and per dominant degradation."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.config import section
    from rdnet.study.rows import LEARNED_RESTORERS, restoration_table
    restore = section(params, "restore")
    learned = dict(LEARNED_RESTORERS)
    for item in args.learned or []:
        name, _, path = item.partition("=")
        learned[name] = path
    res = restoration_table(section(params, "ablation"), args.pairs, args.events_dir,
                            {k: Path(v) for k, v in learned.items()}, seeds=section(params, "study").seeds,
                            baf_dt_us=restore.baf_dt_us, gef_bins=restore.gef_bins,
                            ednccn=args.ednccn if args.ednccn.exists() else None)
    _common.write_json(args.out, res)


p = _common.parser(__doc__)
p.add_argument("--pairs", type=Path, default=Path("data/pairs/test.h5"))
p.add_argument("--events-dir", type=Path, default=Path("data/events/test"))
p.add_argument("--learned", action="append", metavar="NAME=DIR",
               help="a stage-1 network to score besides (or instead of) the study's defaults")
p.add_argument("--ednccn", type=Path, default=Path("models/ednccn"),
               help="the EDnCNN-style classifier baseline (scored when the path exists)")
p.add_argument("--out", type=Path, default=Path("metrics/restoration.json"))
_common.run(main, p)
