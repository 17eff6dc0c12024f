"""jaxrt.rendering.program_cache: compiled render passes on disk (what a second ``jaxrt render``
reads).

A hit must render the image of a fresh compile bit for bit; any change to what the traced
program depends on must miss; a damaged or hostile file must be ignored with a warning."""

import pickle
import shutil

import jax
import numpy as np
import pytest

from jaxrt.integrators.config import make_estimator, prepare_scene
from jaxrt.rendering import program_cache
from jaxrt.rendering.driver import render
from jaxrt.rendering.passes import RenderPass
from jaxrt.scene import builtin as scenes
from jaxrt.scene.container import with_triangle_sampling

SIZE = 8


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    """The program cache in a fresh directory, its counters at zero; off again afterwards.
    No program is kept in memory meanwhile, so that every render asks the directory."""
    monkeypatch.setattr(program_cache, "MAX_PROGRAMS", 0)
    monkeypatch.setattr(program_cache, "DIRECTORY", str(tmp_path / "programs"))
    monkeypatch.setattr(program_cache, "STATS", dict.fromkeys(program_cache.STATS, 0))
    return tmp_path / "programs"


def _key(scene, estimator="mis", count=2, spp=2):
    est = make_estimator(estimator)
    run = RenderPass(prepare_scene(scene, est), 0, jax.local_devices()[:1], 256, est=est,
                     sampler="independent", spp_total=spp, batch_size=64)
    return program_cache.program_key(*run.job(count))


def _files(directory):
    return sorted(directory.glob("*.jaxrt-program"))


def test_off_by_default():
    assert program_cache.DIRECTORY is None


def test_hit_renders_the_fresh_compile_bit_for_bit(cache_dir, monkeypatch):
    box = scenes.cornell_box(SIZE, SIZE)
    first = render(box, "mis", spp=2, seed=5, progress=False)
    assert program_cache.STATS == {"hits": 0, "misses": 1, "stores": 1, "unreadable": 0}
    assert len(_files(cache_dir)) == 1
    # the second render reads the program: no trace, lower or compile (only misses do those)
    hit = render(box, "mis", spp=2, seed=5, progress=False)
    assert program_cache.STATS == {"hits": 1, "misses": 1, "stores": 1, "unreadable": 0}
    # and the image equals a fresh compile's with the cache off
    monkeypatch.setattr(program_cache, "DIRECTORY", None)
    fresh = render(box, "mis", spp=2, seed=5, progress=False)
    assert np.array_equal(hit.image, fresh.image) and np.array_equal(hit.stderr, fresh.stderr)
    assert np.array_equal(first.image, fresh.image)
    assert _files(cache_dir)[0].name.startswith(_key(box))


def test_a_hit_compiles_nothing_not_even_the_option_probe(tmp_path, compiles_in_fresh_process):
    """A fresh process that reads its pass from the cache compiles no program at all: the key
    names the options jaxrt asks for, not those the probe finds XLA accepts (a function of
    them and the jaxlib version, both in the key), so the probe runs only on a miss."""
    body = """
        from jaxrt.rendering import program_cache
        from jaxrt.scene import builtin as scenes
        from jaxrt.rendering.driver import render
        program_cache.set_directory(sys.argv[1])
        render(scenes.cornell_box(8, 8), "mis", spp=2, seed=3, progress=False)
        print(json.dumps([len(COMPILES), program_cache.STATS]))
    """
    directory = str(tmp_path / "programs")
    compiles, stats = compiles_in_fresh_process(body, directory)
    assert compiles >= 2 and stats["misses"] == 1 and stats["stores"] == 1  # probe and pass
    compiles, stats = compiles_in_fresh_process(body, directory)
    assert stats["hits"] == 1 and stats["misses"] == 0
    assert compiles == 0


def test_two_devices_compile_one_program_and_a_hit_reads_it(tmp_path,
                                                          compiles_in_fresh_process):
    """Two CPU devices run the pass as one SPMD program: one compile for both (a program per
    device compiled twice), stored once and read back by a second process, bit for bit."""
    body = """
        jax.config.update("jax_num_cpu_devices", 2)
        from jaxrt.rendering import program_cache
        from jaxrt.scene import builtin as scenes
        from jaxrt.rendering.driver import render
        program_cache.set_directory(sys.argv[1])
        r = render(scenes.cornell_box(20, 16), "mis", spp=2, seed=3, devices=2,
                   progress=False)
        print(json.dumps([len(COMPILES), program_cache.STATS, r.image.tolist()]))
    """
    directory = str(tmp_path / "programs")
    compiles, stats, first = compiles_in_fresh_process(body, directory)
    assert compiles == 2 and stats["misses"] == 1 and stats["stores"] == 1  # probe and pass
    compiles, stats, again = compiles_in_fresh_process(body, directory)
    assert stats["hits"] == 1 and stats["misses"] == 0 and compiles == 0
    assert again == first
    one = render(scenes.cornell_box(20, 16), "mis", spp=2, seed=3, devices=1, progress=False)
    assert np.array_equal(np.asarray(first, np.float32), one.image)


def test_every_static_change_misses(monkeypatch):
    box = scenes.cornell_box(SIZE, SIZE)
    base = _key(box)
    assert _key(box) == base  # deterministic
    variants = {
        "estimator": _key(box, "light_area"),
        "spp per pass": _key(box, count=1),
        "spp (strata)": _key(box, spp=4),
        "image size": _key(scenes.cornell_box(SIZE, 2 * SIZE)),
        "static scene field": _key(box.replace(
            lights=with_triangle_sampling(box.lights, "solid_angle"))),
        "accelerator": _key(scenes.cornell_box(SIZE, SIZE, accel="bvh")),
        "light selection": _key(scenes.cornell_box(SIZE, SIZE, light_selection="uniform")),
    }
    with jax.enable_x64(True):
        variants["x64"] = _key(scenes.cornell_box(SIZE, SIZE))
    monkeypatch.setattr(program_cache, "source_digest", lambda root=None: "edited")
    variants["jaxrt source"] = _key(box)
    monkeypatch.undo()
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_enable_fast_math=true")
    variants["XLA_FLAGS"] = _key(box)
    keys = variants
    for what, key in keys.items():
        assert key != base, f"changing the {what} does not change the key"
    assert len(set(keys.values())) == len(keys)


def test_source_digest_follows_every_file(tmp_path):
    import jaxrt

    src = tmp_path / "jaxrt"
    shutil.copytree(jaxrt.__path__[0], src, ignore=shutil.ignore_patterns("__pycache__"))
    before = program_cache.source_digest.__wrapped__(str(src))
    target = src / "scene" / "lights" / "area.py"
    target.write_text(target.read_text() + "\n# a comment\n")
    assert program_cache.source_digest.__wrapped__(str(src)) != before


def _damage(path, how):
    data = path.read_bytes()
    header, _, payload = data.partition(b"\n\n")
    if how == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif how == "bit flip":
        i = len(header) + 2 + len(payload) // 2
        path.write_bytes(data[:i] + bytes([data[i] ^ 0x10]) + data[i + 1:])
    elif how == "garbage":
        path.write_bytes(b"not a program at all")
    elif how == "hostile pickle":  # a valid checksum over a pickle that would run a command
        import hashlib

        class Evil:
            def __reduce__(self):
                import os

                return (os.system, ("echo pwned > /dev/null",))

        payload = pickle.dumps(Evil())
        magic, key, _ = header.split(b"\n")
        path.write_bytes(magic + b"\n" + key + b"\n"
                         + hashlib.sha256(payload).hexdigest().encode() + b"\n\n" + payload)


@pytest.mark.parametrize("how", ["truncated", "bit flip", "garbage", "hostile pickle"])
def test_unreadable_file_is_ignored_with_a_warning(cache_dir, how, monkeypatch):
    box = scenes.cornell_box(SIZE, SIZE)
    good = render(box, "mis", spp=2, seed=1, progress=False)
    (path,) = _files(cache_dir)
    _damage(path, how)
    if how == "hostile pickle":
        import os

        monkeypatch.setattr(os, "system", lambda *a: pytest.fail("unpickled os.system"))
    with pytest.warns(UserWarning, match="ignoring unreadable compiled-program cache file"):
        again = render(box, "mis", spp=2, seed=1, progress=False)
    assert np.array_equal(good.image, again.image)
    assert program_cache.STATS["unreadable"] == 1 and program_cache.STATS["hits"] == 0
    # the damaged file was replaced by a good one: the next render hits
    render(box, "mis", spp=2, seed=1, progress=False)
    assert program_cache.STATS["hits"] == 1


def test_least_recently_used_programs_are_evicted(cache_dir, monkeypatch):
    monkeypatch.setattr(program_cache, "MAX_FILES", 1)
    box = scenes.cornell_box(SIZE, SIZE)
    render(box, "mis", spp=2, progress=False)
    render(box, "mis", spp=1, progress=False)
    files = _files(cache_dir)
    assert len(files) == 1 and files[0].name.startswith(_key(box, count=1, spp=1))


# ---------------------------------------------------------------- programs kept in memory


@pytest.fixture
def compiles(monkeypatch):
    """The keys of the programs compiled (not found in memory) from here on, in order."""
    seen = []
    real = program_cache._compile_or_load
    monkeypatch.setattr(program_cache, "_compile_or_load",
                        lambda key, *a: seen.append(key) or real(key, *a))
    program_cache.release_programs()
    yield seen
    program_cache.release_programs()


def test_a_scene_of_a_structure_in_memory_compiles_nothing(compiles):
    box = scenes.cornell_box(SIZE, SIZE)
    first = render(box, "mis", spp=2, seed=1, progress=False)
    # new numbers (another seed, another albedo), same structure: the same program
    brighter = box.replace(materials=box.materials._replace(kd=box.materials.kd * 0.5))
    again = render(brighter, "mis", spp=2, seed=2, progress=False)
    assert len(compiles) == 1
    assert not np.array_equal(first.image, again.image)


def test_only_the_last_programs_are_kept(compiles, monkeypatch):
    monkeypatch.setattr(program_cache, "MAX_PROGRAMS", 2)
    sizes = [(SIZE, SIZE), (SIZE, SIZE + 1), (SIZE, SIZE + 2)]
    for w, h in sizes:
        render(scenes.cornell_box(w, h), "light_area", spp=1, progress=False)
    assert len(compiles) == 3 and len(program_cache._IN_MEMORY) == 2
    # the most recent two are in memory; the first was released and compiles again
    render(scenes.cornell_box(*sizes[2]), "light_area", spp=1, progress=False)
    assert len(compiles) == 3
    render(scenes.cornell_box(*sizes[0]), "light_area", spp=1, progress=False)
    assert len(compiles) == 4 and compiles[3] == compiles[0]
    assert program_cache.release_programs() == 2 and not program_cache._IN_MEMORY
