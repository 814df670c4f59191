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
        plan = fab.plan(design)
        if args.format == "3mf":
            fab.check_print(plan)
    except DesignError as exc:
        raise InputError(str(exc)) from None
    except fab.FabricationError as exc:
        raise InputError(f"{design.source}: {exc.key}: {exc.message}") from None
    args.out = reserve_output(args, design, "fabricate")
    printed = args.format == "3mf"
    log.info("%s: building %d bone(s) and %s", design.name, len(design.bones),
             "the body for one multi-material print" if printed else "the mould")
    with publish(args.out, MPI.COMM_WORLD, "fabricate") as stage:
        try:
            write = fab.write_print if printed else fab.write
            report = write(plan, stage.path, picture_file=not args.no_picture)
        except OSError as exc:
            stage.errors.append(f"cannot write {Path(exc.filename).name if exc.filename else 'the parts'}: "
                                f"{exc.strerror or exc}")
            report = None
    if report is None:
        return EXIT_INPUT
    for note in report["notes"]:
        log.warning("%s: warning: %s", design.name, note)
    if printed:
        return _printed(args, design, report, t0)
    if _failed(args, design, report, ("stl_closed_and_oriented", "bone_volumes", "cavity_is_body", "routes_held")):
        return EXIT_INTERNAL
    if not args.quiet:
        print(f"{design.name}: {len(design.bones)} bone(s) and a two-part mould in {args.out}/, "
              f"{time.perf_counter() - t0:.1f} s")
        for name, part in report["parts"].items():
            print(f"  {part['stl']:24s} {part['volume']:10.1f} mm^3  {part['triangles']:6d} triangles")
        m = report["mould"]
        print(f"  mould cavity {m['cavity_volume']:.1f} mm^3 against the body's {m['body_volume']:.1f} mm^3 "
              f"({100 * m['relative_error']:+.2f} %; {100 * m['closed_relative_error']:+.3f} % without the pour "
              "hole, vents, exits, clamp holes, pins and pegs); every STL closed and oriented")
    return EXIT_OK


def _failed(args, design, report: dict, keys: tuple) -> bool:
    """Report the failed checks of fabrication.json (an internal error: the plan checked the input)."""
    checks = report["checks"]
    if checks["passed"]:
        return False
    failed = [k for k in keys if not checks[k]]
    error(f"internal error: {design.name}: fabrication check(s) failed: {', '.join(failed)}; "
          f"see {args.out / 'fabrication.json'}")
    return True


def _printed(args, design, report: dict, t0: float) -> int:
    """The 3MF's checks and summary."""
    checks = report["checks"]
    if _failed(args, design, report, ("parts_closed_and_oriented", "part_volumes", "complement_exact")):
        return EXIT_INTERNAL
    if not args.quiet:
        print(f"{design.name}: one multi-material print, {report['file']} in {args.out}/, "
              f"{time.perf_counter() - t0:.1f} s")
        for name, part in report["parts"].items():
            print(f"  {name:24s} {part['volume']:10.1f} mm^3  extruder {part['extruder']}  ({part['material']})")
        c = checks["complement"]
        print(f"  body and bones fill the body with its channels open to {abs(c['relative_error']):.1g} "
              f"(channels {c['channels_volume']:.1f} mm^3); lying on its {report['print']['down']} face")
    return EXIT_OK
