"""The ``jaxrt`` command: render a scene to an HDR EXR (and a PNG preview), list the built-in
scenes, draw the sampling-warp gallery.

Everything that can be checked without JAX (arguments, output paths) is checked first, so a
mistyped path fails in a fraction of a second instead of after the render. The caches of
compiled programs are switched on here, for the command only (``--no-compile-cache`` or
``JAXRT_NO_COMPILE_CACHE=1`` turn them off): ``render`` keeps its compiled passes in
:mod:`jaxrt.rendering.program_cache`, ``gallery`` uses JAX's persistent compilation cache; importing
the library never touches either.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import threading
import warnings
from pathlib import Path

from jaxrt.cli.ctrl_c import EXIT_INTERRUPTED, CtrlC
from jaxrt.cli.processes import launch

#: The choices of --estimator and --sampler, spelled out so that ``jaxrt --help`` and the
#: argument checks need no JAX (tests/cli/test_cli.py checks they equal the library's).
ESTIMATOR_NAMES = ("uniform_hemisphere", "cosine_hemisphere", "bsdf", "light_area",
                   "light_solid_angle", "mis", "mis_one_sample", "ris", "path")
SAMPLER_NAMES = ("independent", "stratified", "sobol")
MESH_SUFFIXES = (".obj", ".ply", ".gltf", ".glb")
DEFAULT_SPP = 64
EXIT_USAGE = 2

EXAMPLES = """\
examples:
  jaxrt scenes                                          list the built-in scenes
  jaxrt render cornell_box --spp 256 -o box.exr --png box.png
  jaxrt render veach_mis --estimator light_area --width 512 --height 256
  jaxrt render cornell_box --estimator path --spp 256 -o gi.exr   # global illumination
  jaxrt render my_scene.json --time-budget 30 --sampler sobol -o out.exr
  jaxrt render my_scene.json --target-error 0.01 -o out.exr   # until 1 % relative error
  jaxrt gallery -o warps.png                            every warp: samples against its pdf

Ctrl-C stops a render after the pass running (about a second) and writes the image so far
(its spp is in the EXR header); exit status 130. A scene file is JSON: see docs/scenes.md
or the docstring of jaxrt/scene/file.py.
"""


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Every option's default in its help (unless the help states it, or there is none to
    state: a flag, an unset option), examples kept as written."""

    def _get_help_string(self, action):
        text = action.help or ""
        if ("default" in text or action.default in (None, False, argparse.SUPPRESS)
                or not action.option_strings):
            return text
        return text + " (default: %(default)s)"


class CLIError(Exception):
    """A usage error found by the command: printed as one line, exit status 2."""


def _positive(kind):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
        return value

    parse.__name__ = f"positive {kind.__name__}"
    return parse


def _depth(text: str) -> int:
    """``--max-depth``: an integer ≥ 1, or −1 for unbounded paths."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v == -1 or v >= 1:
        return v
    raise argparse.ArgumentTypeError(f"must be -1 (unbounded) or >= 1, got {v}")


def _check_output(path: str, suffix: str, option: str, force: bool) -> Path:
    """Fail now, not after the render, if ``path`` cannot take the file ``option`` writes."""
    p = Path(path)
    if p.suffix.lower() != suffix:
        raise CLIError(f"{path}: {option} writes {suffix[1:].upper()}, so its file name must "
                       f"end in {suffix} (got {p.suffix or 'no extension'})")
    if p.is_dir():
        raise CLIError(f"{path}: is a directory; give a file name for {option}")
    parent = p.parent
    if not parent.exists():
        raise CLIError(f"{path}: directory {str(parent)!r} does not exist")
    if not parent.is_dir():
        raise CLIError(f"{path}: {str(parent)!r} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise CLIError(f"{path}: directory {str(parent)!r} is not writable")
    if p.exists() and not force:
        # like rm and cp -i: a write-protected file is replaced only when asked (even as root)
        if not p.stat().st_mode & 0o222 or not os.access(p, os.W_OK):
            raise CLIError(f"{path}: exists and is read-only; use --force to replace it")
    return p


def _cache_base(args) -> str | None:
    """The user's cache directory for jaxrt, or None when the caches are turned off."""
    if getattr(args, "no_compile_cache", False) or os.environ.get("JAXRT_NO_COMPILE_CACHE",
                                                                  "") not in ("", "0"):
        return None
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "jaxrt")


def _enable_program_cache(args) -> str | None:
    """jaxrt's cache of compiled render passes (:mod:`jaxrt.rendering.program_cache`), unless
    disabled.

    ``jaxrt render`` uses it *instead of* JAX's persistent compilation cache: a hit skips
    tracing as well as XLA, and a program is stored only when freshly compiled (one read
    back from JAX's cache cannot be serialised again with this jaxlib)."""
    base = _cache_base(args)
    if base is None:
        return None
    from jaxrt.rendering import program_cache
    program_cache.set_directory(os.path.join(base, "programs"))
    return program_cache.DIRECTORY


def _enable_compile_cache(args) -> str | None:
    """JAX's persistent compilation cache in the user's cache directory, unless disabled."""
    base = _cache_base(args)
    if base is None:
        return None
    path = os.path.join(base, "jax")
    import jax

    jax.config.update("jax_compilation_cache_dir", path)
    # the gallery's programs compile in a fraction of a second each
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    return path


def _load(args):
    """The scene named on the command line (a built-in name or a scene file)."""
    from jaxrt.scene import builtin as scenes
    size = {k: getattr(args, k) for k in ("width", "height") if getattr(args, k) is not None}
    if args.scene is None or args.scene in scenes.BUILTIN:
        scene = scenes.by_name(args.scene or "cornell_box", accel=args.accel or "auto", **size)
        return _with_options(scene, args)
    path = Path(args.scene)
    if path.suffix.lower() in MESH_SUFFIXES:
        raise CLIError(
            f"{path}: a mesh file, not a scene: a scene file (.json) places meshes, lights and "
            f"a camera, e.g. {{\"camera\": {{\"eye\": [0, 1, 4], \"target\": [0, 0, 0]}}, "
            f"\"meshes\": [{{\"file\": \"{path.name}\"}}], \"lights\": [{{\"type\": \"point\", "
            f"\"position\": [0, 2, 0], \"intensity\": 10}}]}} (docs/scenes.md)")
    if not path.exists():
        raise CLIError(f"no such scene file or built-in scene: {args.scene!r} (built-ins: "
                       f"{', '.join(sorted(scenes.BUILTIN))})")
    from jaxrt.scene.file import load_scene

    return _with_options(load_scene(path, accel=args.accel, **size), args)


def _with_options(scene, args):
    """The scene with the command line's ``--triangle-sampling`` (if given) in force."""
    if args.triangle_sampling is None:
        return scene
    from jaxrt.scene.container import with_triangle_sampling

    return scene.replace(lights=with_triangle_sampling(scene.lights, args.triangle_sampling),
                         occluders=scene.occluders)


def _write(args, result, interrupted: bool = False) -> None:
    from jaxrt.scene import images as io
    attributes = {"spp": int(result.spp), "jaxrt.stopped_by": result.stopped_by,
                  "jaxrt.estimator": args.estimator, "jaxrt.sampler": args.sampler,
                  "jaxrt.seed": int(args.seed)}
    for name in ("light_samples", "bsdf_samples", "heuristic", "max_depth", "rr_depth",
                 "ris_candidates", "nee"):
        if getattr(args, name) is not None:  # what the user chose (defaults: the README's)
            value = getattr(args, name)
            attributes[f"jaxrt.{name}"] = value if isinstance(value, str) else int(value)
    io.write_exr(args.output, result.image, extra_channels={"stderr": result.stderr},
                 attributes=attributes)
    if args.png:
        io.write_png(args.png, result.image, exposure=args.exposure)
    if not interrupted:
        print(f"wrote {args.output}" + (f" and {args.png}" if args.png else ""))


def _render(args) -> int:
    if args.process_id == 0:  # the process that writes (other hosts may lack the directory)
        _check_output(args.output, ".exr", "-o/--output", args.force)
        if args.png:
            _check_output(args.png, ".png", "--png", args.force)
    if args.processes > 1:
        return launch(_without_option(args.argv, "--processes"), args.processes)
    adaptive = args.time_budget is not None or args.target_error is not None
    spp = args.spp if args.spp is not None else (None if adaptive else DEFAULT_SPP)
    if args.num_processes > 1:
        _join_processes(args)
    _enable_program_cache(args)
    scene = _load(args)
    if args.process_id == 0:
        print(scene.summary(), flush=True)
    params = {k: getattr(args, k) for k in ("light_samples", "bsdf_samples", "heuristic",
                                            "max_depth", "rr_depth", "ris_candidates", "nee")
              if getattr(args, k) is not None}
    return _render_interruptibly(args, scene, spp, params)


def _render_interruptibly(args, scene, spp, params) -> int:
    """Render in a worker thread so that Ctrl-C reaches this (main) thread's handler at once
    (:mod:`jaxrt.cli.ctrl_c`): the first stops the render after its pass and this thread writes
    what it has; during compilation (nothing to save) or a second time, it exits at once."""
    from jaxrt.rendering.driver import RenderInterrupted, render

    ctrl_c, finished = args.ctrl_c, threading.Event()
    box: dict = {}

    def work():
        try:
            box["result"] = render(scene, args.estimator, spp=spp, seed=args.seed,
                                   sampler=args.sampler, time_budget=args.time_budget,
                                   target_error=args.target_error, progress=not args.quiet,
                                   spp_per_pass=args.spp_per_pass, stop=ctrl_c.stop,
                                   on_pass=ctrl_c.passes_done.append, **params)
        except BaseException as e:  # handed to the main thread
            box["error"] = e
        finally:
            finished.set()

    ctrl_c.stage = "rendering"
    # a daemon thread: quit_now must not wait for a compilation it cannot interrupt
    threading.Thread(target=work, name="jaxrt-render", daemon=True).start()
    # a timed wait: the kernel may deliver SIGINT to any of the process's threads, and
    # Python runs the handler only when the main thread next runs bytecode (an untimed wait
    # would run it after the render, as if the image were complete)
    while not finished.wait(0.1):
        pass
    ctrl_c.stage = "finishing"
    if args.process_id != 0:  # process 0 reports and writes
        e = box.get("error")
        if e is not None and not isinstance(e, RenderInterrupted):
            raise e
        return EXIT_INTERRUPTED if e is not None else 0
    if "error" in box:
        e = box["error"]
        if isinstance(e, RenderInterrupted):
            if e.result is None:
                print("jaxrt: interrupted before the first pass; nothing written",
                      file=sys.stderr)
                return EXIT_INTERRUPTED
            _write(args, e.result, interrupted=True)
            print(f"jaxrt: interrupted: wrote {e.result.spp} spp to {args.output}"
                  + (f" and {args.png}" if args.png else ""), file=sys.stderr)
            return EXIT_INTERRUPTED
        raise e
    result = box["result"]
    t = result.timings
    from jaxrt.rendering import program_cache
    hits = program_cache.STATS["hits"]
    cached = f", {hits} program(s) read from the program cache" if hits else ""
    print(f"{result.spp} spp in {t['render']:.2f} s (+{t['compile']:.2f} s compile{cached}): "
          f"{t['samples_per_s'] / 1e6:.2f} M samples/s, mean relative error "
          f"{result.relative_error:.4f}, stopped by {result.stopped_by}"
          + (f", {result.nonfinite} non-finite samples dropped" if result.nonfinite else ""))
    _write(args, result)
    return 0


def _join_processes(args) -> None:
    """Join a multi-process render (``--num-processes``/``--process-id``/``--coordinator``)."""
    if not 0 <= args.process_id < args.num_processes or not args.coordinator:
        raise CLIError(f"--process-id must lie in [0, {args.num_processes}) and --coordinator "
                       "HOST:PORT must be given with --num-processes")
    import jax

    if args.process_id != 0:
        # process 0 decides when to stop (Ctrl-C there stops everyone after the pass); a
        # process quitting alone would leave the others waiting in a collective
        import signal

        signal.signal(signal.SIGINT, signal.SIG_IGN)
    jax.distributed.initialize(coordinator_address=args.coordinator,
                               num_processes=args.num_processes, process_id=args.process_id)


def _without_option(argv: list, name: str) -> list:
    """``argv`` without option ``name`` and its value (``--name v`` or ``--name=v``)."""
    out, skip = [], False
    for token in argv:
        if skip:
            skip = False
        elif token == name:
            skip = True
        elif not token.startswith(name + "="):
            out.append(token)
    return out


def plain_text(rst: str) -> str:
    """A docstring line without reStructuredText markup (``x``, :func:`x`, *x*)."""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"\1", rst)
    text = re.sub(r"``([^`]+)``", r"\1", text)
    return re.sub(r"(?<!\w)\*([^*]+)\*(?!\w)", r"\1", text)


def _scenes(args) -> int:
    from jaxrt.scene import builtin as scenes
    for name, fn in sorted(scenes.BUILTIN.items()):
        doc = (fn.__doc__ or "").strip().split("\n\n")[0]
        print(f"{name:20s} {plain_text(' '.join(doc.split()))}")
    return 0


def _gallery(args) -> int:
    _check_output(args.output, ".png", "-o/--output", args.force)
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise CLIError("jaxrt gallery draws with matplotlib, which is not installed: "
                       "pip install 'jaxrt[plot]' (or pip install matplotlib)") from None
    _enable_compile_cache(args)
    from jaxrt.validation.gallery import make_gallery

    make_gallery(args.output, num_samples=args.samples, progress=not args.quiet)
    print(f"wrote {args.output}")
    return 0


def _version() -> str:
    from jaxrt import __version__

    return f"jaxrt {__version__}"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="jaxrt", formatter_class=_Formatter, epilog=EXAMPLES,
        description="Monte Carlo direct illumination in JAX: render a built-in scene or a "
                    "JSON scene file with any estimator of the reflection equation (or "
                    "global illumination with the path tracer), to an HDR EXR with a "
                    "per-pixel standard-error layer and an sRGB PNG preview.")
    p.add_argument("--version", action="version", version=_version())
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    r = sub.add_parser("render", formatter_class=_Formatter, epilog=EXAMPLES,
                       help="render a scene to an EXR (and a PNG preview)",
                       description="Render a scene to an HDR EXR (RGB + a stderr layer) and "
                                   "optionally an sRGB PNG preview.")
    r.add_argument("scene", nargs="?", default=None,
                   help="a scene file (.json) or a built-in scene name (see 'jaxrt scenes'); "
                        "default: cornell_box")
    r.add_argument("--estimator", default="mis", choices=ESTIMATOR_NAMES,
                   help="direct-illumination estimator, or 'path' for global illumination "
                        "(docs/estimators.md and docs/path_tracing.md)")
    r.add_argument("--spp", type=_positive(int), default=None,
                   help=f"samples per pixel (default: {DEFAULT_SPP}; no limit with "
                        "--time-budget or --target-error, where it is a maximum)")
    r.add_argument("--seed", type=int, default=0, help="random seed (same seed, same image)")
    r.add_argument("--sampler", default="independent", choices=SAMPLER_NAMES,
                   help="sample stream (sobol converges fastest on smooth pixels)")
    r.add_argument("--light-samples", type=_positive(int), default=None,
                   help="MIS light samples (default: the estimator's, 1)")
    r.add_argument("--bsdf-samples", type=_positive(int), default=None,
                   help="MIS BSDF samples (default: the estimator's, 1)")
    r.add_argument("--heuristic", choices=("balance", "power"), default=None,
                   help="MIS heuristic (default: the estimator's, power)")
    r.add_argument("--max-depth", type=_depth, default=None,
                   help="path: longest path in segments, camera ray included (2 = direct "
                        "light, as Mitsuba 3 counts; default: -1, unbounded)")
    r.add_argument("--rr-depth", type=_positive(int), default=None,
                   help="path: Russian roulette from this many bounces on (default: 5)")
    r.add_argument("--ris-candidates", type=_positive(int), default=None,
                   help="ris, and path with --nee ris: light samples resampled per shading "
                        "point (default: 8)")
    r.add_argument("--nee", choices=("light", "ris"), default=None,
                   help="path: next-event estimation by one light sample or by RIS "
                        "(default: light)")
    r.add_argument("--time-budget", type=_positive(float), default=None, metavar="SECONDS",
                   help="stop after this many seconds of rendering (compilation excluded)")
    r.add_argument("--target-error", type=_positive(float), default=None, metavar="E",
                   help="stop at this mean relative standard error (e.g. 0.01)")
    r.add_argument("--width", type=_positive(int), default=None,
                   help="image width in pixels (default: the scene's)")
    r.add_argument("--height", type=_positive(int), default=None,
                   help="image height in pixels (default: the scene's)")
    r.add_argument("--accel", default=None, choices=("auto", "brute", "bvh"),
                   help="ray acceleration (default: the scene file's, else auto, which picks "
                        "brute force below 96 triangles)")
    r.add_argument("--triangle-sampling", default=None, choices=("area", "solid_angle"),
                   help="how MIS and one-sample MIS sample triangle lights (default: the "
                        "scene's, area unless its file says otherwise; light_area and "
                        "light_solid_angle use their own)")
    r.add_argument("-o", "--output", default="out.exr", help="EXR output (RGB + stderr)")
    r.add_argument("--png", default=None, help="also write an sRGB PNG preview here")
    r.add_argument("--exposure", type=float, default=0.0, help="PNG exposure in stops")
    r.add_argument("-f", "--force", action="store_true",
                   help="replace read-only output files")
    r.add_argument("--no-compile-cache", action="store_true",
                   help="do not keep or read compiled render passes (also: "
                        "JAXRT_NO_COMPILE_CACHE=1); they live in $XDG_CACHE_HOME/jaxrt/"
                        "programs or ~/.cache/jaxrt/programs")
    r.add_argument("--spp-per-pass", type=_positive(int), default=None, metavar="N",
                   help="samples per pixel per pass (default: about 2^21 samples per pass, a "
                        "divisor of --spp; a different value changes the last bits)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    m = r.add_argument_group(
        "several processes", "Render with N processes (JAX's multi-process runtime): the "
        "image is bit for bit that of one process. On one machine: --processes N. On N "
        "hosts: the same command on each, with --coordinator HOST0:PORT --num-processes N "
        "--process-id I (process 0 writes the files).")
    m.add_argument("--processes", type=_positive(int), default=1, metavar="N",
                   help="start N local processes that render together")
    m.add_argument("--num-processes", type=_positive(int), default=1, metavar="N",
                   help="the number of processes of a multi-host render")
    m.add_argument("--process-id", type=int, default=0, metavar="I",
                   help="this process's index, 0 … N-1")
    m.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                   help="address of process 0's coordinator (any free port on host 0)")
    r.set_defaults(func=_render)

    s = sub.add_parser("scenes", help="list the built-in scenes", formatter_class=_Formatter)
    s.set_defaults(func=_scenes)

    g = sub.add_parser("gallery", formatter_class=_Formatter,
                       help="draw every sampling warp into one PNG (needs jaxrt[plot])",
                       description="Draw every sampling warp: its points, a histogram of its "
                                   "samples and its integrated pdf, with the chi-square p.")
    g.add_argument("-o", "--output", default="warp_gallery.png", help="PNG output")
    g.add_argument("--samples", type=_positive(int), default=200_000,
                   help="samples per histogram")
    g.add_argument("-f", "--force", action="store_true", help="replace a read-only output")
    g.add_argument("--no-compile-cache", action="store_true",
                   help="do not use JAX's persistent compilation cache")
    g.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    g.set_defaults(func=_gallery)
    return p


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """A warning as one line, without the source line Python's default format adds."""
    print(f"jaxrt: warning: {message}", file=sys.stderr if file is None else file)


def main(argv=None) -> int:
    """Entry point of the ``jaxrt`` console script."""
    # Ctrl-C quits at once until the command has something to save (jaxrt.cli.ctrl_c)
    with CtrlC() as ctrl_c:
        argv = list(sys.argv[1:] if argv is None else argv)
        args = build_parser().parse_args(argv)
        args.argv, args.ctrl_c = argv, ctrl_c
        return _run_command(args)


def _run_command(args) -> int:
    """``args.func(args)``, with its errors as one line and an exit status."""
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return args.func(args)
    except CLIError as e:
        print(f"jaxrt: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except (ValueError, OSError) as e:  # file errors name the file and the entry
        print(f"jaxrt: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:  # not from SIGINT (jaxrt.cli.ctrl_c handles that): still one line
        print("\njaxrt: interrupted; nothing written", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
