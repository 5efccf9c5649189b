"""The compiled-code cache is checked before use: corrupt, read-only or full, it never crashes a run or changes a number.

Every case starts from a copy of one clean cache folder (the clean run compiled
it), damages it as a disk or a user might, runs the same scenario with a fresh
module (as a new process would) and checks that the run's times, states and
outputs equal the clean run's bit for bit, that one note naming the folder
said what happened, and where the folder is writable that the cache is whole
again afterwards (the next load compiles nothing and says nothing).
"""
from __future__ import annotations

import builtins
import errno
import os
import shutil
import warnings
from collections import OrderedDict
from pathlib import Path

import numpy as np
import pytest

import blocks

numba = pytest.importorskip("numba", reason="the compiled engine needs the extra dobkit[fast]")

import blocks.figure2.loop as loop_module  # noqa: E402
from blocks.engines.compiled import cache, codegen  # noqa: E402
from blocks.engines.compiled.cache import CompiledCacheWarning  # noqa: E402

pytestmark = pytest.mark.slow          # each case compiles a loop's functions once or more

SCENARIO = blocks.load_scenario("paper").replace(simulation={"t_final": 0.05, "output_step": 0.005})
# A function a run loads from the cache itself (called from Python), and cheaper to compile than the integrator
LOADED = "grid_outputs"


def _fresh(monkeypatch, root: Path) -> None:
    """Point the cache at ``root`` and forget every compiled module, as a new process would start."""
    monkeypatch.setenv("DOBKIT_CACHE_DIR", str(root))
    monkeypatch.setattr(codegen, "_modules", {})
    monkeypatch.setattr(codegen, "_stores", {})
    monkeypatch.setattr(cache, "_noted", set())
    monkeypatch.setattr(loop_module, "_prepared_runs", OrderedDict())
    monkeypatch.setattr(loop_module, "_last_prepared", [None])


def _run(monkeypatch, root: Path, fresh: bool = True):
    """The scenario run by the compiled engine on the cache ``root``; the run and the cache notes it gave."""
    if fresh:
        _fresh(monkeypatch, root)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = blocks.simulate(SCENARIO, observer=False, engine="compiled")
    notes = [str(w.message) for w in caught if issubclass(w.category, CompiledCacheWarning)]
    return run, notes


def _assert_same(run, clean) -> None:
    np.testing.assert_array_equal(run.time, clean.time)
    np.testing.assert_array_equal(run.states, clean.states)
    np.testing.assert_array_equal(run.outputs, clean.outputs)


def _folder(root: Path) -> Path:
    return root / "compiled"


def _files(root: Path, pattern: str) -> list[Path]:
    found = sorted(_folder(root).glob(pattern)) + sorted((_folder(root) / "__pycache__").glob(pattern))
    assert found, f"no cached file matches {pattern}"
    return found


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])


def _randomise(path: Path) -> None:
    path.write_bytes(np.random.default_rng(7).bytes(max(path.stat().st_size, 64)))


def _assert_whole_again(monkeypatch, root: Path, clean) -> None:
    """The next fresh load finds the cache complete: nothing compiled, nothing noted, the same numbers."""
    run, notes = _run(monkeypatch, root)
    assert notes == []
    _assert_same(run, clean)
    engine = loop_module._prepared(SCENARIO, False).compiled_engine()
    for fn in (engine.module.dopri_run, getattr(engine.module, LOADED)):
        assert sum(fn.stats.cache_misses.values()) == 0 and sum(fn.stats.cache_hits.values()) == 1, fn
    assert not list(_folder(root).rglob("*.tmp.*")), "a temporary file was left behind"


@pytest.fixture(scope="module")
def clean_cache(tmp_path_factory):
    """A cache folder the clean run compiled into, and that run."""
    root = tmp_path_factory.mktemp("clean-cache")
    with pytest.MonkeyPatch.context() as patch:
        run, notes = _run(patch, root)
    assert notes == []
    assert list((_folder(root) / "__pycache__").glob(f"*{LOADED}*.nbc"))
    return root, run


@pytest.fixture
def damaged(clean_cache, tmp_path):
    """A copy of the clean cache to damage, and the clean run."""
    root, clean = clean_cache
    copy = tmp_path / "cache"
    shutil.copytree(root, copy)
    return copy, clean


# -- corrupt files ---------------------------------------------------------------------------------------------------
CORRUPT = {
    "module text": "*.py",
    "numba index": f"*.{LOADED}-*.nbi",
    "numba data": f"*.{LOADED}-*.nbc",
    "manifest": "*.manifest",
}


@pytest.mark.parametrize("damage", [_truncate, _randomise], ids=["truncated", "random bytes"])
@pytest.mark.parametrize("kind", list(CORRUPT))
def test_a_corrupt_cached_file_is_rebuilt_with_one_note_and_the_same_numbers(monkeypatch, damaged, kind, damage):
    root, clean = damaged
    for path in _files(root, CORRUPT[kind]):
        damage(path)
    run, notes = _run(monkeypatch, root)
    _assert_same(run, clean)
    assert len(notes) == 1 and str(_folder(root)) in notes[0] and "again" in notes[0], notes
    _assert_whole_again(monkeypatch, root, clean)


def test_every_numba_file_corrupt_at_once_is_rebuilt(monkeypatch, damaged):
    root, clean = damaged
    for path in _files(root, "*.nbi"):
        _truncate(path)
    for path in _files(root, "*.nbc"):
        _randomise(path)
    run, notes = _run(monkeypatch, root)
    _assert_same(run, clean)
    assert len(notes) == 1 and str(_folder(root)) in notes[0], notes
    _assert_whole_again(monkeypatch, root, clean)


def test_a_file_corrupted_after_the_check_is_not_loaded(monkeypatch, damaged):
    """Damage between the check at load and numba's read (another process, a failing disk): still a miss."""
    root, clean = damaged
    _fresh(monkeypatch, root)
    codegen.load_module(loop_module._prepared(SCENARIO, False).compiled_engine().program)      # checked: all good
    for path in _files(root, CORRUPT["numba data"]):
        _truncate(path)
    run, notes = _run(monkeypatch, root, fresh=False)
    _assert_same(run, clean)
    assert len(notes) == 1 and "did not match its manifest" in notes[0], notes
    _assert_whole_again(monkeypatch, root, clean)


def test_a_file_the_manifest_vouches_for_but_numba_cannot_read_is_a_miss(monkeypatch, damaged):
    """Even a manifest that records a bad file (say, a folder copied from elsewhere) does not crash the run."""
    root, clean = damaged
    _fresh(monkeypatch, root)
    program = loop_module._prepared(SCENARIO, False).compiled_engine().program
    store = cache.ModuleCache(f"dobkit_loop_{program.key}", codegen._module_text(program), _folder(root))
    bad = _files(root, CORRUPT["numba data"])
    for path in bad:
        _randomise(path)
    store.record([p.name for p in bad])                 # the manifest now vouches for the random bytes
    run, notes = _run(monkeypatch, root)
    _assert_same(run, clean)
    assert len(notes) == 1 and "could not be read" in notes[0], notes
    _assert_whole_again(monkeypatch, root, clean)


def test_the_note_is_one_line_of_the_command_line(monkeypatch, damaged, capsys):
    """The command line shows the cache note as one ``dobkit <command>: note:`` line naming the folder."""
    from dobkit.cli import _warnings_as_notes

    root, clean = damaged
    _randomise(_files(root, "*.py")[0])
    _fresh(monkeypatch, root)
    with _warnings_as_notes("simulate"):
        run = blocks.simulate(SCENARIO, observer=False, engine="compiled")
    _assert_same(run, clean)
    lines = [line for line in capsys.readouterr().err.splitlines() if "note:" in line]
    assert lines == [f"dobkit simulate: note: compiled-code cache {_folder(root)}: the module "
                     f"{_files(root, '*.py')[0].name} differed from its text; written again (the run is not "
                     f"affected)"]


# -- folders that cannot be written --------------------------------------------------------------------------------
class _FailingWrites:
    """A file whose writes fail with ``code`` (what a full or read-only disk does), closed on exit."""

    def __init__(self, f, code: int) -> None:
        self._f, self._code = f, code

    def write(self, data):
        raise OSError(self._code, os.strerror(self._code))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()

    def __getattr__(self, name):
        return getattr(self._f, name)


def _fail_writes(monkeypatch, folder: Path, code: int, only=lambda name: True) -> None:
    """Make every write to a file under ``folder`` whose name satisfies ``only`` fail with OSError(code)."""
    real_open = builtins.open

    def open_failing(file, mode="r", *args, **kwargs):
        f = real_open(file, mode, *args, **kwargs)
        path = Path(os.fsdecode(file)) if isinstance(file, (str, bytes, os.PathLike)) else None
        if path is not None and set(mode) & set("wax") and folder in path.parents and only(path.name):
            return _FailingWrites(f, code)
        return f

    monkeypatch.setattr(builtins, "open", open_failing)


def test_a_full_disk_compiles_in_memory_with_one_note_naming_the_cache(monkeypatch, tmp_path, clean_cache):
    """First run on a full disk: nothing can be written; the run completes, the note names the folder and ENOSPC."""
    _, clean = clean_cache
    root = tmp_path / "full"
    _fail_writes(monkeypatch, root, errno.ENOSPC)
    run, notes = _run(monkeypatch, root)
    _assert_same(run, clean)
    assert len(notes) == 1 and str(_folder(root)) in notes[0] and "[Errno 28] No space left on device" in notes[0]
    assert "compiled in memory" in notes[0]
    assert not [p for p in root.rglob("*") if p.is_file() and p.stat().st_size], "a partial file was left behind"


def test_a_disk_that_fills_while_numba_saves_keeps_the_compiled_code_in_memory(monkeypatch, damaged):
    """The module text is there, numba's new files cannot be written: the run completes, nothing half written stays."""
    root, clean = damaged
    for path in _files(root, f"*.{LOADED}-*"):
        path.unlink()                                   # a function compiled now, and saved (or not) now
    _fail_writes(monkeypatch, root, errno.ENOSPC, only=lambda name: ".nb" in name)
    run, notes = _run(monkeypatch, root)
    _assert_same(run, clean)
    assert len(notes) == 1 and "No space left on device" in notes[0] and str(_folder(root)) in notes[0], notes
    assert not list(_folder(root).rglob("*.tmp.*"))
    monkeypatch.undo()
    run, _ = _run(monkeypatch, root)                    # with space again it is compiled once more and saved
    _assert_same(run, clean)
    _assert_whole_again(monkeypatch, root, clean)


def _can_write(folder: Path) -> bool:
    try:
        (folder / ".probe").write_text("x")
    except OSError:
        return False
    (folder / ".probe").unlink()
    return True


@pytest.mark.parametrize("how", ["permissions", "read-only file system"])
def test_a_read_only_cache_is_read_and_what_is_new_stays_in_memory(monkeypatch, damaged, how):
    root, clean = damaged
    for path in _files(root, f"*.{LOADED}-*"):
        path.unlink()                                   # one function to compile and not save
    folders = [_folder(root), _folder(root) / "__pycache__"]
    if how == "permissions":
        for folder in folders:
            folder.chmod(0o555)
        if _can_write(folders[1]):                      # root ignores permissions
            for folder in folders:
                folder.chmod(0o755)
            pytest.skip("this user can write to a folder without write permission (root)")
    else:
        _fail_writes(monkeypatch, root, errno.EROFS)
    try:
        run, notes = _run(monkeypatch, root)
    finally:
        for folder in folders:
            folder.chmod(0o755)
    _assert_same(run, clean)
    assert len(notes) == 1 and str(_folder(root)) in notes[0] and "cannot write" in notes[0], notes
    engine = loop_module._prepared(SCENARIO, False).compiled_engine()
    assert sum(engine.module.dopri_run.stats.cache_hits.values()) == 1     # what was cached was still read


def test_a_remembered_gather_text_is_the_arrays_repr_whatever_shares_its_bytes():
    """The compiled cache key holds each block's input gather as its repr; remembered by dtype, shape and bytes,
    arrays with the same bytes but another dtype or shape keep their own text (a shared text would share code)."""
    from blocks.engines.compiled.codegen import _gather_text
    flat = np.arange(6, dtype=np.int64)
    same_bytes = [flat, flat.reshape(2, 3), flat.view(np.float64), flat.astype(np.int32), flat[::-1].copy()]
    for _ in range(2):                                         # computed, then remembered
        assert [_gather_text(a) for a in same_bytes] == [repr(a) for a in same_bytes]
    assert len({_gather_text(a) for a in same_bytes}) == len(same_bytes)
    assert _gather_text(slice(2, 9)) == "slice(2, 9, None)"
