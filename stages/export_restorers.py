"""Stage `export_restorers`: copy the trained restorers of the study (seed 0, the lowest
seed) into the package (rdnet/restore/models/restore_image.pt / restore_frames.pt /
restore_events.pt, each
with its card .json: model arguments, training config, fitted decision and its
validation metrics), so that `rdnet restore --method rdnet` works in a fresh install
without `dvc repro` (rdnet.restore.learned.load_restorer falls back to them)."""
from pathlib import Path

import _common


def main(args, params):
    from rdnet.restore.learned import export_restorer
    for ck, kind in ((args.image, "frame"), (args.frames, "frame_pair"), (args.events, "events")):
        out = export_restorer(ck, args.out, kind=kind)
        print(f"exported {ck} -> {out} ({out.stat().st_size / 1e6:.2f} MB)")


p = _common.parser(__doc__)
p.add_argument("--image", type=Path, default=Path("models/restore_image"))
p.add_argument("--frames", type=Path, default=Path("models/restore_frames"))
p.add_argument("--events", type=Path, default=Path("models/restore_events"))
p.add_argument("--out", type=Path, default=Path("rdnet/restore/models"))
_common.run(main, p)
