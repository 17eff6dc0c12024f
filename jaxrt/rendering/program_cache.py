"""Compiled render passes kept on disk, so that a second ``jaxrt render`` traces nothing.

JAX's persistent compilation cache skips XLA on a second run, but not tracing and lowering
(1.2–1.5 s of the 256² Cornell box's pass on this 2-core machine): its key is a hash of the
lowered program, which exists only after both. This cache is keyed instead by everything the
traced program is a function of, known before tracing:

- jaxrt's own source (every ``.py`` file of the package), the versions of jax, jaxlib and
  numpy, JAX's tracing configuration (x64, promotion rules, …) and ``XLA_FLAGS``;
- the compiled function, its static arguments (estimator, sampler, spp, samples per pass,
  tiles) and the XLA compiler options;
- the arguments' pytree structure, which carries the scene's static fields (BSDF and light
  kinds, light counts, sampling modes, accelerator, image size), and every array's shape,
  dtype and device;
- the backend (platform and version, the kind and id of each device the program runs on,
  process) and the host CPU (model and instruction-set flags: the executable is machine code
  for this CPU).

A hit deserialises the XLA executable (~0.3 s) and runs it: the same machine code as a fresh
compile, hence bit-identical images. A file that cannot be read (truncated, corrupt, from
another jax) is ignored with a warning and replaced. Payloads are checked against a SHA-256
before they are unpickled, and the unpickler resolves only classes and functions of jax,
jaxlib, numpy's ``dtype`` and arrays, and jaxrt (never a module) (the executable format of
``jax.experimental.serialize_executable``); like JAX's own cache, the directory must be
writable only by you.

The cache is off unless a directory is set: the ``jaxrt`` command sets
``$XDG_CACHE_HOME/jaxrt/programs`` (else ``~/.cache/jaxrt/programs``) and turns it off with
the XLA cache (``--no-compile-cache``, ``JAXRT_NO_COMPILE_CACHE=1``); importing the library
never does. At most :data:`MAX_FILES` programs are kept (least recently used go first).

In memory, whether or not a directory is set, a process keeps the last :data:`MAX_PROGRAMS`
programs it compiled or loaded, under the same key, so that rendering a scene of a structure
seen recently compiles nothing. Beyond that the least recently used is released, with what
XLA:CPU holds for it (its machine code is mapped in ~150–400 memory maps and ~25 MB per
program): each program is traced through a ``jax.jit`` of its own, so JAX's tracing,
lowering and compilation caches, which key on the function weakly, let go of it too. Without
this bound a process that renders many scene structures (a sweep, a notebook, a test worker)
would keep every program JAX compiled for it, and at the kernel's ``vm.max_map_count``
(65 530) LLVM would fail to map a new program and the process die. :func:`release_programs`
drops them all.
"""

from __future__ import annotations

import collections
import concurrent.futures
import functools
import hashlib
import io
import os
import pickle
import platform
import tempfile
import threading
import types
import warnings
from pathlib import Path

import jax
import numpy as np

#: Where compiled programs are kept; None (the default) turns the cache off.
DIRECTORY: str | None = None
#: Programs kept at most; the least recently used are deleted beyond this.
MAX_FILES = 64
#: Programs kept in this process's memory at most; the least recently used are released.
MAX_PROGRAMS = 16
#: What this process did: programs loaded, compiled and stored, files ignored as unreadable.
STATS = {"hits": 0, "misses": 0, "stores": 0, "unreadable": 0}

_IN_MEMORY: collections.OrderedDict = collections.OrderedDict()  # key -> Compiled, LRU first

_MAGIC = b"jaxrt-program-v1\n"
_SUFFIX = ".jaxrt-program"


def set_directory(path: str | os.PathLike | None) -> None:
    """Keep compiled programs in ``path`` (created on first store); None turns the cache off."""
    global DIRECTORY
    DIRECTORY = None if path is None else os.fspath(path)


@functools.cache
def source_digest(root: str | None = None) -> str:
    """SHA-256 of jaxrt's source: every ``.py`` file under the package, path and contents."""
    base = Path(root) if root is not None else Path(__file__).resolve().parent
    h = hashlib.sha256()
    for p in sorted(base.rglob("*.py")):
        h.update(p.relative_to(base).as_posix().encode() + b"\0")
        h.update(p.read_bytes() + b"\0")
    return h.hexdigest()


@functools.cache
def _host_cpu() -> str:
    """The CPU model and its instruction-set flags (machine code is compiled for them)."""
    try:
        with open("/proc/cpuinfo") as f:
            lines = f.read().split("\n\n")[0].splitlines()
        keep = ("vendor_id", "model name", "flags", "cpu family", "model")
        return "\n".join(ln for ln in lines if ln.split(":")[0].strip() in keep)
    except OSError:
        return f"{platform.machine()} {platform.processor()}"


def _trace_config() -> str:
    """JAX's configuration that affects tracing (what ``jax.jit`` keys its own cache on)."""
    try:
        from jax._src import config

        ctx = config.trace_context()
    except Exception:  # pragma: no cover - other jax versions
        ctx = (jax.config.jax_enable_x64, jax.config.jax_numpy_dtype_promotion)
    # drop members without a stable text form (objects printed with their address)
    return repr(tuple(x for x in ctx if " at 0x" not in repr(x)))


def program_key(fn, args: tuple, static: dict, options: dict, devices) -> str:
    """The cache key of ``fn`` compiled for ``args`` (arrays), ``static`` and ``options`` on
    ``devices`` (one device or a list)."""
    import jaxlib

    devices = _device_list(devices)
    leaves, treedef = jax.tree.flatten(args)
    parts = [
        _MAGIC.decode(), source_digest(), f"jax {jax.__version__} jaxlib {jaxlib.__version__} "
        f"numpy {np.__version__}", _trace_config(), os.environ.get("XLA_FLAGS", ""),
        f"{fn.__module__}.{getattr(fn, '__qualname__', fn.__name__)}",
        repr(sorted(static.items())), repr(sorted(options.items())), str(treedef),
        *(f"{jax.typeof(x)} {getattr(x, 'sharding', None)}" for x in leaves),
        *(f"{d.platform} {d.client.platform_version} {d.device_kind} {d.id}" for d in devices),
        f"{jax.process_index()}/{jax.process_count()}", _host_cpu()]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def compile_cached(fn, args: tuple, static: dict, options: dict, devices, resolve=None):
    """``fn.lower(*args, **static).compile(options)``, read from the cache when it holds it.

    ``fn`` is a ``jax.jit`` function with ``static`` as its static arguments; ``args`` are
    committed to ``devices`` (a device, or the list of devices one SPMD program runs on).
    ``options`` are the compiler options the key names; ``resolve``, when given, is called
    only when the program must be compiled, before it is traced, and gives the options to
    compile with, a dict or a ``concurrent.futures.Future`` of one (waited for after
    lowering, so that it can be found beside the trace). jaxrt's passes
    name the options they ask for and resolve them to the ones this XLA accepts
    (:func:`jaxrt.core.xla.compiler_options_soon`): the accepted set is a function of the
    asked set and the jaxlib version, both in the key, so a hit needs no probe.
    Returns a ``jax.stages.Compiled``, kept in memory among the last :data:`MAX_PROGRAMS`
    (the key costs ~0.4 ms for the 256² Cornell box's pass, once per pass size of a render).
    """
    key = program_key(fn, args, static, options, devices)
    compiled = _IN_MEMORY.get(key)
    if compiled is None:
        compiled = _compile_or_load(key, fn, args, static, options, devices, resolve)
    _IN_MEMORY[key] = compiled
    _IN_MEMORY.move_to_end(key)
    while len(_IN_MEMORY) > MAX_PROGRAMS:
        _IN_MEMORY.popitem(last=False)
    return compiled


def release_programs() -> int:
    """Release every compiled program this process keeps in memory; returns how many.

    What XLA holds for them (machine code, memory maps) goes with the last reference: a
    :class:`jaxrt.RenderResult` holds none, so after this a later render of any scene compiles
    (or reads from the directory) again. Programs a user compiled through their own
    ``jax.jit`` (of :func:`jaxrt.estimate_image`, say) live in JAX's caches instead:
    ``jax.clear_caches()`` releases those.
    """
    count = len(_IN_MEMORY)
    _IN_MEMORY.clear()
    return count


def _compile_or_load(key: str, fn, args: tuple, static: dict, options: dict, devices,
                     resolve):
    """The program of ``key``: from the directory when it holds it, else compiled (and stored)."""
    if DIRECTORY is None:
        return _compile(fn, args, static, options, resolve)
    path = Path(DIRECTORY) / (key + _SUFFIX)
    in_tree = jax.tree.structure((args, {}))
    if path.exists():
        compiled = _load(path, key, in_tree, devices)
        if compiled is not None:
            STATS["hits"] += 1
            return compiled
    STATS["misses"] += 1
    _watch_xla_cache()
    before = getattr(_XLA_CACHE_HITS, "n", 0)
    compiled = _compile(fn, args, static, options, resolve)
    # an executable read from JAX's persistent cache is not kept: XLA:CPU (jaxlib 0.10.2)
    # serialises a deserialised executable without some of its kernels, and running it
    # fails ("Function ... not found"); only freshly compiled programs are stored
    if getattr(_XLA_CACHE_HITS, "n", 0) == before:
        _store(path, key, compiled)
    return compiled


def _compile(fn, args: tuple, static: dict, options: dict, resolve):
    pending = options if resolve is None else resolve()
    lowered = _own_jit(fn, tuple(static)).lower(*args, **static)
    if isinstance(pending, concurrent.futures.Future):
        pending = pending.result()
    return lowered.compile(pending)


def _own_jit(fn, static_argnames: tuple):
    """``jax.jit`` of the function ``fn`` jits, through a wrapper of this call's own.

    JAX's caches key on the Python function weakly and hold what they computed for it
    strongly (the jaxpr, the lowered module, the executable): traced through a wrapper that
    only the compiled program's caller keeps alive, all of it is released with the program.
    Only the static argument names are carried over: ``fn`` must be a ``jax.jit`` with no
    other options (donation, shardings), as jaxrt's passes are.
    """
    inner = getattr(fn, "__wrapped__", fn)

    @functools.wraps(inner)
    def program(*args, **kwargs):
        return inner(*args, **kwargs)

    return jax.jit(program, static_argnames=static_argnames)


#: JAX persistent-cache hits in this thread (see :func:`compile_cached`).
_XLA_CACHE_HITS = threading.local()
_WATCHING: list = []


def _count_xla_cache_hit(event: str, **kwargs) -> None:
    if event == "/jax/compilation_cache/cache_hits":
        _XLA_CACHE_HITS.n = getattr(_XLA_CACHE_HITS, "n", 0) + 1


def _watch_xla_cache() -> None:
    if not _WATCHING:
        _WATCHING.append(True)
        jax.monitoring.register_event_listener(_count_xla_cache_hit)


#: numpy names a program file may hold: dtypes, and arrays (a several-device program's mesh
#: holds its devices as an object array, whose elements go through the same checks)
_NUMPY = {("numpy", "dtype"), ("numpy", "ndarray"), ("numpy._core.multiarray", "_reconstruct"),
          ("numpy.core.multiarray", "_reconstruct")}


class _Unpickler(pickle.Unpickler):
    """``serialize_executable``'s unpickler, resolving only jax/jaxlib/jaxrt names."""

    def __init__(self, file, backend, devices):
        super().__init__(file)
        self.backend, self.devices = backend, devices

    def find_class(self, module, name):
        top = module.split(".")[0]
        if "." in name or not (top in ("jax", "jaxlib", "jaxrt") or (module, name) in _NUMPY):
            raise pickle.UnpicklingError(f"{module}.{name} is not allowed in a program file")
        obj = super().find_class(module, name)
        if isinstance(obj, types.ModuleType):  # e.g. jax._src.x.os: never a way out
            raise pickle.UnpicklingError(f"{module}.{name} is a module")
        return obj

    def persistent_load(self, pid):
        from jax._src.lib import xla_client as xc

        if pid[0] == "exec":
            return self.backend.deserialize_executable(
                pid[1], executable_devices=xc.DeviceList(tuple(self.devices)))
        if pid[0] == "device":
            return {d.id: d for d in self.devices}[pid[1]]
        if pid[0] == "client":
            return self.backend
        raise pickle.UnpicklingError(f"unknown persistent id {pid[0]!r}")


def _device_list(devices) -> list:
    return list(devices) if isinstance(devices, (list, tuple)) else [devices]


def _load(path: Path, key: str, in_tree, devices):
    """The compiled program in ``path``, or None (with a warning) if it cannot be used."""
    devices = _device_list(devices)
    try:
        data = path.read_bytes()
        header, _, payload = data.partition(b"\n\n")
        magic, file_key, digest = header.split(b"\n")
        if magic + b"\n" != _MAGIC or file_key.decode() != key:
            raise ValueError("not a program of this key")
        if hashlib.sha256(payload).hexdigest() != digest.decode():
            raise ValueError("checksum mismatch (truncated or corrupt)")
        unloaded, args_flat, no_kwargs, file_in_tree, out_tree = _Unpickler(
            io.BytesIO(payload), devices[0].client, devices).load()
        if file_in_tree != in_tree:
            raise ValueError("argument structure differs")
        compiled = jax.stages.Compiled(unloaded.load(), [], in_tree.unflatten(args_flat),
                                       out_tree, no_kwargs=no_kwargs)
        os.utime(path)  # recently used
        return compiled
    except Exception as e:  # any failure is a miss: never a crash, never a wrong program
        STATS["unreadable"] += 1
        warnings.warn(f"ignoring unreadable compiled-program cache file {path} ({e}); "
                      "compiling instead", stacklevel=3)
        return None


def _store(path: Path, key: str, compiled) -> None:
    """Write ``compiled`` to ``path`` atomically; failures only warn (the render goes on)."""
    try:
        from jax.experimental.serialize_executable import _JaxPjrtPickler

        unloaded = getattr(compiled._executable, "_unloaded_executable", None)
        if unloaded is None or compiled._params.const_args:
            return  # not serialisable (JAX says so); nothing to keep
        args_flat, in_tree = jax.tree.flatten(compiled.args_info)
        buf = io.BytesIO()
        _JaxPjrtPickler(buf).dump((unloaded, args_flat, compiled._no_kwargs, in_tree,
                                   compiled.out_tree))
        payload = buf.getvalue()
        header = _MAGIC + key.encode() + b"\n" + hashlib.sha256(payload).hexdigest().encode()
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=_SUFFIX)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(header + b"\n\n" + payload)
            os.replace(tmp, path)
        except BaseException:
            os.unlink(tmp)
            raise
        STATS["stores"] += 1
        _evict(path.parent)
    except Exception as e:
        warnings.warn(f"could not keep the compiled program in {path.parent} ({e})",
                      stacklevel=3)


def _evict(directory: Path) -> None:
    """Delete the least recently used programs beyond :data:`MAX_FILES`."""
    files = sorted(directory.glob("*" + _SUFFIX), key=lambda p: p.stat().st_mtime)
    for p in files[:max(0, len(files) - MAX_FILES)]:
        try:
            p.unlink()
        except OSError:
            pass
