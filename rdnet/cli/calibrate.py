"""``rdnet calibrate RECORDING --out DIR``: sim-to-real calibration.

Simulates events from the recording's frames (upsampled between frames) with the
``sensor`` and ``degrade`` parameters (plus ``--set`` overrides; what is zero there is
what the simulator leaves out; ``--base ideal``: every effect off but those set),
compares them with the recorded events, re-fits the
thresholds and the configured effects, and names the effects the config leaves out that
the recording needs (held-out gain significant against the seed spread). Writes
DIR/report.json, DIR/report.md and PNG figures. Settings: the ``calibrate`` section
(:class:`rdnet.calib.settings.CalibrateConfig`) and ``interpolate``.
"""
from __future__ import annotations

from pathlib import Path

from rdnet.config import add_params_args, load_cli_params, seed_arg


def register(subparsers) -> None:
    p = subparsers.add_parser("calibrate", help="locate and fit the sim-to-real mismatch of a recording",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("recording", type=Path, help="recording with frames and events (.h5 project layout, .aedat4)")
    p.add_argument("--out", type=Path, required=True, help="output folder (report.json, report.md, figures)")
    add_params_args(p)
    p.add_argument("--base", choices=("params", "ideal"), default="params",
                   help="the config the recording is compared with: params (default: the sensor and degrade "
                        "sections, what is zero there is what the simulator leaves out) or ideal (every effect "
                        "of the vocabulary off but those given with --set: which effects the camera has beyond "
                        "an ideal sensor, as the calibrate_real stage asks)")
    p.add_argument("--seed", type=seed_arg, default=0, help="base seed of the simulations (default 0)")
    p.add_argument("--no-interpolate", action="store_true",
                   help="simulate from the frames as given (as interpolate.method=none)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    from rdnet.cli.info import add_progress_arg
    add_progress_arg(p)
    p.set_defaults(func=run)


def base_degrade(degrade, base: str, sets: list[str]):
    """The ``degrade`` config the recording is compared with: as read (``base`` 'params'), or
    with every effect of the vocabulary off but the keys given by ``--set degrade.KEY=...``
    (``base`` 'ideal', :func:`rdnet.calib.effects.ideal`)."""
    if base == "params":
        return degrade
    from rdnet.calib.effects import ideal
    from rdnet.config import parse_set
    given = {path[1] for path, _ in map(parse_set, sets) if len(path) == 2 and path[0] == "degrade"}
    return ideal(degrade, keep=given)


def run(args) -> int:
    from rdnet.calib.calibrate import calibrate, finding
    from rdnet.calib.report import write_report
    from rdnet.cli.simulate import _section
    from rdnet.errors import FormatError
    from rdnet.eval.report import prepare_figures
    from rdnet.events.io import load, open_events
    from rdnet.events.io._common import check_output_folder
    from rdnet.runtime import forked_workers

    params = load_cli_params(args)
    sensor = _section(params, "sensor", "rdnet.sim.settings:SensorConfig")
    degrade = _section(params, "degrade", "rdnet.sim.settings:DegradeConfig")
    cfg = _section(params, "calibrate", "rdnet.calib.settings:CalibrateConfig")
    interp = _section(params, "interpolate", "rdnet.sim.interpolate:InterpolateConfig")
    degrade = base_degrade(degrade, args.base, args.sets)
    if args.no_interpolate:
        import dataclasses
        interp = dataclasses.replace(interp, method="none")
    check_output_folder(args.out, ("report.json", "report.md"))   # before the calibration, not after it
    with open_events(args.recording) as src:     # header only (RAW/DAT/HDF5): fail before decoding
        if not src.has_frames:
            raise FormatError(args.recording, "frames", "recording has no frames (calibrate simulates from them)")
    rec = load(args.recording)
    # two workers, forked before the calibration starts its threads, load matplotlib at the
    # lowest priority (on the CPU time the calibration leaves idle) and draw the figures side
    # by side at the end (rdnet.runtime.ForkedWorker); where fork is missing, the figures
    # are drawn here
    with forked_workers(0 if args.no_plots else 2, prepare_figures, nice=19) as workers:
        cal = calibrate(rec, sensor, degrade, cfg, seed=args.seed, interpolate=interp, source=str(args.recording),
                        progress=args.progress)
        paths = write_report(cal, args.out, plots=not args.no_plots, workers=workers)
    print(finding(cal.report))
    flagged = (["the basic refit"] if cal.report.get("refit_caveats") else []) + [
        e["name"] for e in cal.report["effects"] if e["missing"] and e.get("caveats")]
    if flagged:
        print(f"caveats for {', '.join(flagged)}: see the section 'Caveats' of {args.out / 'report.md'}")
    print(f"wrote {', '.join(str(p) for p in paths[:2])} and {len(paths) - 2} figures "
          f"({cal.runtime_s:.1f} s, {cal.report['setup']['simulations']} simulations)")
    return 0
