"""Command line: ``jgi render`` (one image) and ``jgi run`` (an experiment from a config file).

    jgi render cornell_box --estimator pt --spp 64 --seed 0 --out out/cb.exr --strategy mis
    jgi render scenes/my_scene.toml -e pt --spp 16 -p heuristic=power -p power=2
    jgi render cornell_box -e bdpt --spp 4096 --checkpoint ref/ --chunk-spp 256 [--workers 2]
                                           # seeded chunks kept in ref/: resumable, spreadable
    jgi render --list                      # every estimator with its parameters and defaults
    jgi run configs/quickstart.toml [--dry-run]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from . import estimators  # noqa: F401  (registers the estimators)
from .api import render
from .core.errors import CheckpointError, ParameterError
from .core.imageio import write_exr, write_png
from .estimators.registry import REGISTRY, get
from .scene.builder import SceneError
from .scene.files import load_scene


def _convert(param, text: str):
    if param.type is bool:
        if text.lower() in ("1", "true", "yes", "on"):
            return True
        if text.lower() in ("0", "false", "no", "off"):
            return False
        raise SystemExit(f"jgi: parameter '{param.name}' expects true/false, got '{text}'")
    if param.type in (int, float):
        try:
            v = float(text)
        except ValueError:
            raise SystemExit(f"jgi: parameter '{param.name}' expects a number, "
                             f"got '{text}'") from None
        return int(v) if param.type is int and v.is_integer() else v
    return text


def _render(argv) -> int:
    ap = argparse.ArgumentParser(prog="jgi render", description="Render one image.")
    ap.add_argument("scene", nargs="?", help="built-in scene name or scene file (.toml)")
    ap.add_argument("-e", "--estimator", default="pt")
    ap.add_argument("--spp", type=int, default=16, help="samples per pixel")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="out/image.exr",
                    help="EXR path; a tone-mapped PNG is written beside it")
    ap.add_argument("--width", type=int, default=None)
    ap.add_argument("--height", type=int, default=None)
    ap.add_argument("--exposure", type=float, default=0.0, help="PNG exposure in stops")
    ap.add_argument("-p", "--param", action="append", default=[], metavar="KEY=VALUE",
                    help="estimator parameter (repeatable); '--KEY VALUE' works too")
    ap.add_argument("--list", action="store_true", help="list estimators and their parameters")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    ap.add_argument("--checkpoint", metavar="DIR", default=None,
                    help="render in seeded chunks, each saved in DIR: an interrupted render "
                         "resumes from them (with --chunk-spp)")
    ap.add_argument("--chunk-spp", type=int, default=None, metavar="N",
                    help="samples per chunk of a checkpointed render (at least two chunks); "
                         "the chunks' spread gives a variance image, written as *_variance.exr")
    ap.add_argument("--workers", type=int, default=None,
                    help="render a checkpointed render's chunks on N local Dask workers")
    ap.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="render a checkpointed render's chunks on this Dask cluster")
    args, rest = ap.parse_known_args(argv)

    if args.list:
        for name in sorted(REGISTRY):
            print(REGISTRY[name].describe())
        return 0
    if not args.scene:
        ap.error("a scene is required (a built-in name or a .toml file); see --help")
    try:
        est = get(args.estimator)
    except ParameterError as e:
        raise SystemExit(f"jgi: {e}") from None
    params = {}
    pairs = [p.split("=", 1) for p in args.param]
    it = iter(rest)
    for tok in it:
        if not tok.startswith("--"):
            raise SystemExit(f"jgi: unexpected argument '{tok}'")
        key = tok[2:].replace("-", "_")
        if "=" in key:
            key, val = key.split("=", 1)
        else:
            val = next(it, None)
            if val is None:
                raise SystemExit(f"jgi: option '{tok}' needs a value")
        pairs.append([key, val])
    for pair in pairs:
        if len(pair) != 2:
            raise SystemExit(f"jgi: parameters are KEY=VALUE, got '{'='.join(pair)}'")
        key, val = pair
        try:
            param = est.lookup(key)   # unknown and former names are refused, naming what to use
        except ParameterError as e:
            raise SystemExit(f"jgi: {e}") from None
        params[key] = _convert(param, val)


    chunked = args.checkpoint is not None or args.chunk_spp is not None
    if chunked and (args.checkpoint is None or args.chunk_spp is None):
        raise SystemExit("jgi: --checkpoint DIR and --chunk-spp N go together")
    if (args.workers or args.scheduler) and not chunked:
        raise SystemExit("jgi: --workers / --scheduler spread a checkpointed render's chunks; "
                         "add --checkpoint DIR --chunk-spp N")
    if chunked and not 1 <= args.chunk_spp <= args.spp // 2:
        raise SystemExit(f"jgi: --chunk-spp must be from 1 to spp / 2 = {args.spp // 2} (at "
                         f"least two chunks), got {args.chunk_spp}")
    variance = None
    try:
        scene = load_scene(args.scene)
        size = None
        if args.width or args.height:
            size = (args.width or scene.camera.width, args.height or scene.camera.height)
            scene = scene.with_resolution(*size)
        t0 = time.perf_counter()
        if chunked:
            # the studies' modules (Dask, plots, statistics) load only for a checkpointed render
            from .experiment.checkpoint import render_checkpointed

            est.resolve(params)   # a bad parameter is refused here, not on a worker
            image, variance = render_checkpointed(
                args.scene, args.estimator, spp=args.spp, seed=args.seed,
                folder=args.checkpoint, chunk_spp=args.chunk_spp, params=params,
                resolution=size, workers=args.workers, scheduler=args.scheduler,
                progress=not args.quiet)
        else:
            image = render(scene, args.estimator, spp=args.spp, seed=args.seed,
                           progress=not args.quiet, **params)
    except (SceneError, ParameterError, CheckpointError) as e:
        raise SystemExit(f"jgi: {e}") from None
    dt = time.perf_counter() - t0
    out = Path(args.out)
    if out.suffix.lower() != ".exr":
        out = out.with_suffix(".exr")
    write_exr(out, image)
    if variance is not None:
        write_exr(out.with_name(out.stem + "_variance.exr"), variance)
    write_png(out.with_suffix(".png"), image, args.exposure)
    h, w, _ = image.shape
    print(f"wrote {out} and {out.with_suffix('.png')} ({w}x{h}, {args.spp} spp, {dt:.1f} s)")
    return 0


def _run(argv) -> int:
    from .experiment import main_run

    return main_run(argv) or 0


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0
    cmd, rest = argv[0], argv[1:]
    if cmd == "render":
        return _render(rest)
    if cmd == "run":
        return _run(rest)
    raise SystemExit(f"jgi: unknown command '{cmd}'; use 'render' or 'run'")


if __name__ == "__main__":
    sys.exit(main())
