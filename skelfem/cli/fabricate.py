"""``skelfem fabricate``: plan (every check before the folder is touched), then build and publish the parts.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path
from .common import EXIT_INPUT, EXIT_INTERNAL, EXIT_OK, InputError, error, reserve_output

log = logging.getLogger("skelfem")


def fabricate(args) -> int:
    """Plan (every check before the folder is touched), then build and publish the parts whole."""
    from mpi4py import MPI

    from .. import fabricate as fab
    from ..design.spec import DesignError
    from ..design.parse import load_design
    from ..io.outdir import publish

    t0 = time.perf_counter()
    if MPI.COMM_WORLD.size > 1:
        raise InputError("fabricate runs on one process; start it without mpirun")
    try:
        design = load_design(args.design, args.overrides)
        designs = fab.split_bodies(design)                  # one design per soft body, each cast on its own
        plans = [fab.plan(d) for d in designs]
        if args.format == "3mf":
            for plan in plans:
                fab.check_print(plan)
    except DesignError as exc:
        raise InputError(str(exc)) from None
    except fab.FabricationError as exc:
        raise InputError(f"{design.source}: {exc.key}: {exc.message}") from None
    args.out = reserve_output(args, design, "fabricate")
    printed = args.format == "3mf"
    several = len(designs) > 1
    log.info("%s: building %d bone(s) and %s", design.name, len(design.bones),
             ("the bodies" if several else "the body") + " for multi-material printing" if printed
             else "a mould per body" if several else "the mould")
    with publish(args.out, MPI.COMM_WORLD, "fabricate") as stage:
        try:
            write = fab.write_print if printed else fab.write
            reports = []
            for d, plan in zip(designs, plans):
                folder = stage.path / d.body.name if several else stage.path
                folder.mkdir(exist_ok=True)
                reports.append(write(plan, folder, picture_file=not args.no_picture))
            if several:
                from ..io.files import write_json
                write_json(stage.path / "fabrication.json",
                           {"design": design.name, "output": args.format,
                            "bodies": {d.body.name: f"{d.body.name}/fabrication.json" for d in designs},
                            "checks": {"passed": all(r["checks"]["passed"] for r in reports)}})
        except OSError as exc:
            stage.errors.append(f"cannot write {Path(exc.filename).name if exc.filename else 'the parts'}: "
                                f"{exc.strerror or exc}")
            reports = None
    if reports is None:
        return EXIT_INPUT
    code = EXIT_OK
    for d, report in zip(designs, reports):
        out = args.out / d.body.name if several else args.out
        for note in report["notes"]:
            log.warning("%s: warning: %s", d.name, note)
        code = max(code, (_printed if printed else _cast)(args, d, report, out, t0))
    return code


def _cast(args, design, report: dict, out: Path, t0: float) -> int:
    """The bones' and mould's checks and summary."""
    if _failed(design, report, out, ("stl_closed_and_oriented", "bone_volumes", "cavity_is_body", "routes_held")):
        return EXIT_INTERNAL
    if not args.quiet:
        print(f"{design.name}: {len(design.bones)} bone(s) and a two-part mould in {out}/, "
              f"{time.perf_counter() - t0:.1f} s")
        for name, part in report["parts"].items():
            print(f"  {part['stl']:24s} {part['volume']:10.1f} mm^3  {part['triangles']:6d} triangles")
        m = report["mould"]
        print(f"  mould cavity {m['cavity_volume']:.1f} mm^3 against the body's {m['body_volume']:.1f} mm^3 "
              f"({100 * m['relative_error']:+.2f} %; {100 * m['closed_relative_error']:+.3f} % without the pour "
              "hole, vents, exits, clamp holes, pins and pegs); every STL closed and oriented")
    return EXIT_OK


def _failed(design, report: dict, out: Path, keys: tuple) -> bool:
    """Report the failed checks of fabrication.json (an internal error: the plan checked the input)."""
    checks = report["checks"]
    if checks["passed"]:
        return False
    failed = [k for k in keys if not checks[k]]
    error(f"internal error: {design.name}: fabrication check(s) failed: {', '.join(failed)}; "
          f"see {out / 'fabrication.json'}")
    return True


def _printed(args, design, report: dict, out: Path, t0: float) -> int:
    """The 3MF's checks and summary."""
    checks = report["checks"]
    if _failed(design, report, out, ("parts_closed_and_oriented", "part_volumes", "complement_exact")):
        return EXIT_INTERNAL
    if not args.quiet:
        print(f"{design.name}: one multi-material print, {report['file']} in {out}/, "
              f"{time.perf_counter() - t0:.1f} s")
        for name, part in report["parts"].items():
            print(f"  {name:24s} {part['volume']:10.1f} mm^3  extruder {part['extruder']}  ({part['material']})")
        c = checks["complement"]
        fill = "body and bones fill" if len(report["parts"]) > 1 else "the printed body fills"
        print(f"  {fill} the body with its channels open to {abs(c['relative_error']):.1g} "
              f"(channels {c['channels_volume']:.1f} mm^3); lying on its {report['print']['down']} face")
    return EXIT_OK
