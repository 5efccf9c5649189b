"""The on-disk cache of compiled loops: a folder, a manifest that vouches for its files, numba's cache guarded by it.

A generated module (:mod:`blocks.engines.compiled.codegen`) is written once to the
cache folder as ``dobkit_loop_<key>.py``; numba's machine code for its
functions goes beside it, in ``__pycache__``, as an index (``.nbi``) and
data files (``.nbc``) per function.  Files on disk can be cut short (a full
disk, a killed copy), overwritten with anything, or become unwritable, and
numba reads them as they are: a truncated pickle crashes every later run, a
changed one may load wrong machine code.  So:

* every ``.nbi``/``.nbc`` file is recorded, with its size and SHA-256, in the
  module's manifest ``dobkit_loop_<key>.manifest`` right after numba wrote it
  (the manifest is replaced atomically, under a lock);
* before a module is used its files are checked against the manifest; a file
  that differs, or that the manifest does not list, is deleted and its code
  compiled again (and cached again); numba reads only files that check out,
  and anything it fails to read counts as a miss, not an error;
* a folder that cannot be written (read-only, full disk, not a folder) does
  not stop a run: what cannot be saved stays compiled in memory for the
  process.

Each of these is reported once per folder and process as a
:class:`CompiledCacheWarning` (the command line shows it as one note line)
that names the folder; none changes a number of a run.

The folder is ``$DOBKIT_CACHE_DIR/compiled``, else
``$XDG_CACHE_HOME/dobkit/compiled`` (``~/.cache/dobkit/compiled``).
"""
from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import sys
import time
import uuid
import warnings
from pathlib import Path

try:                                # POSIX: a lock serialises the manifest's read-change-write between processes
    import fcntl
except ImportError:                 # pragma: no cover - Windows: last writer wins (a lost entry is compiled again)
    fcntl = None

__all__ = ["CompiledCacheWarning", "cache_dir", "ModuleCache", "guard_dispatcher"]

_MANIFEST_FORMAT = 1


class CompiledCacheWarning(UserWarning):
    """The compiled-code cache could not be used as it is (corrupt or unwritable files); the message names the
    folder and what was done instead.  The run's numbers are not affected."""


def cache_dir() -> Path:
    """Where generated modules and numba's machine code for them are kept (see the module docstring)."""
    root = os.environ.get("DOBKIT_CACHE_DIR")
    if root:
        return Path(root) / "compiled"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "dobkit" / "compiled"


_noted: set[tuple[str, str]] = set()


def _note(folder: Path, kind: str, text: str) -> None:
    """One :class:`CompiledCacheWarning` per folder, kind (``corrupt``, ``unwritable``) and process."""
    if (str(folder), kind) in _noted:
        return
    _noted.add((str(folder), kind))
    warnings.warn(f"compiled-code cache {folder}: {text}", CompiledCacheWarning, stacklevel=2)


def _sha256(path: Path) -> tuple[int, str] | None:
    """Size (bytes) and SHA-256 of a file, or None when it cannot be read."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError:
        return None
    return len(data), hashlib.sha256(data).hexdigest()


def _write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all (a temporary file, then a rename)."""
    tmp = path.with_name(f"{path.name}.tmp.{uuid.uuid4().hex[:12]}")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _remove(path: Path) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path)


class ModuleCache:
    """The cached files of one generated module: its source, numba's files for it, and their manifest.

    Parameters
    ----------
    stem : str
        The module's name, ``dobkit_loop_<key>``; every file of the module starts with it.
    text : str
        The module's source text.
    folder : pathlib.Path, optional
        The cache folder (default :func:`cache_dir`).

    Attributes
    ----------
    folder : pathlib.Path
    source_path : pathlib.Path
        Where the module's text is (or would be) kept.
    stamp : str
        SHA-256 of the text: numba's index is valid for this text only.
    complete : bool
        The manifest says a full compile of the module was cached, and every file checked out.
    writable : bool
        Whether new machine code is still saved (False once a write failed).
    """

    def __init__(self, stem: str, text: str, folder: Path | None = None) -> None:
        self.stem, self.folder = stem, cache_dir() if folder is None else Path(folder)
        self.numba_dir = self.folder / "__pycache__"
        self.source_path = self.folder / f"{stem}.py"
        self.manifest_path = self.folder / f"{stem}.manifest"
        data = text.encode("utf-8")
        self.stamp = hashlib.sha256(data).hexdigest()
        self.writable = True
        self._verified: dict[str, tuple[int, int]] = {}         # name -> (size, mtime_ns) that checked out
        self._write_source(data)
        self.complete = self._check_files()

    # -- notes ---------------------------------------------------------------------------------------------------
    def corrupt(self, what: str, done: str = "deleted and compiled again") -> None:
        """Report (once) that cached files were corrupt, and what was done about them."""
        _note(self.folder, "corrupt", f"{what}; {done} (the run is not affected)")

    def unwritable(self, err: OSError) -> None:
        """Stop saving, and report (once) that the compiled code stays in memory for this process."""
        self.writable = False
        reason = f"[Errno {err.errno}] {err.strerror}" if err.errno else str(err)
        _note(self.folder, "unwritable",
              f"cannot write to it ({reason}); the loop is compiled in memory for this process only "
              f"(free space or permissions there, or set DOBKIT_CACHE_DIR to a writable folder)")

    # -- the source text -----------------------------------------------------------------------------------------
    def _write_source(self, data: bytes) -> None:
        try:
            with open(self.source_path, "rb") as f:
                found = f.read()
        except FileNotFoundError:
            found = None
        except OSError:
            found = b""
        if found == data:
            return
        if found is not None:
            self.corrupt(f"the module {self.source_path.name} differed from its text", "written again")
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            _write_atomic(self.source_path, data)
        except OSError as err:
            self.unwritable(err)

    # -- the manifest --------------------------------------------------------------------------------------------
    def _read_manifest(self) -> dict | None:
        """The manifest's content ({"files": ..., "compiled": ...}); None when it is missing; {} when unreadable."""
        try:
            with open(self.manifest_path, "rb") as f:
                raw = f.read()
        except FileNotFoundError:
            return None
        except OSError:
            return {}
        try:
            data = json.loads(raw.decode("utf-8"))
            files = data["files"]
            ok = (data.get("format") == _MANIFEST_FORMAT and data.get("stamp") == self.stamp
                  and isinstance(files, dict)
                  and all(isinstance(v, dict) and isinstance(v.get("size"), int) and isinstance(v.get("sha256"), str)
                          for v in files.values()))
        except (ValueError, KeyError, TypeError, AttributeError):
            ok = False
        return data if ok else {}

    @contextlib.contextmanager
    def _locked(self):
        """The manifest's lock (held while it is read, changed and replaced)."""
        if fcntl is None:
            yield
            return
        with open(self.folder / f"{self.stem}.lock", "ab") as lock:
            fcntl.flock(lock.fileno(), fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(lock.fileno(), fcntl.LOCK_UN)

    def _update_manifest(self, change) -> None:
        """Apply ``change(manifest)`` to the manifest and replace it atomically; a failed write stops saving."""
        if not self.writable:
            return
        try:
            with self._locked():
                data = self._read_manifest() or {}
                data = {"format": _MANIFEST_FORMAT, "stamp": self.stamp, "files": dict(data.get("files", {})),
                        "compiled": data.get("compiled")}
                change(data)
                _write_atomic(self.manifest_path, json.dumps(data, indent=1, sort_keys=True).encode("utf-8"))
        except OSError as err:
            self.unwritable(err)

    def _check_files(self) -> bool:
        """Check every numba file of the module against the manifest; delete those that fail.  Whether the module
        is complete (a full compile recorded, nothing deleted)."""
        manifest = self._read_manifest()
        try:
            present = sorted(p.name for p in self.numba_dir.iterdir()
                             if p.name.startswith(self.stem + ".") and p.suffix in (".nbi", ".nbc"))
        except OSError:
            present = []
        if manifest == {}:
            self.corrupt(f"its manifest {self.manifest_path.name} was unreadable")
        listed = (manifest or {}).get("files", {})
        bad = [name for name in present if not self._matches(name, listed.get(name))]
        for name in bad:
            _remove(self.numba_dir / name)
        if bad:
            self.corrupt(f"{len(bad)} file(s) were not as its manifest records them ({', '.join(bad[:3])}"
                         f"{', ...' if len(bad) > 3 else ''})")
            self._update_manifest(lambda m: [m["files"].pop(name, None) for name in bad])
        return bool(manifest) and bool(manifest.get("compiled")) and not bad

    def _matches(self, name: str, entry: dict | None) -> bool:
        if entry is None:
            return False
        path = self.numba_dir / name
        try:
            st = os.stat(path)
        except OSError:
            return False
        if st.st_size != entry["size"]:
            return False
        if self._verified.get(name) == (st.st_size, st.st_mtime_ns):
            return True
        found = _sha256(path)
        if found is None or found != (entry["size"], entry["sha256"]):
            return False
        self._verified[name] = (st.st_size, st.st_mtime_ns)
        return True

    # -- what the guarded numba cache asks -----------------------------------------------------------------------
    def trusted(self, name: str) -> bool:
        """Whether numba's file ``name`` is exactly as recorded; a file that is not is deleted (and reported)."""
        path = self.numba_dir / name
        if not path.exists():
            return False
        if self._matches(name, (self._read_manifest() or {}).get("files", {}).get(name)):
            return True
        self.reject(name, "did not match its manifest")
        return False

    def reject(self, name: str, why: str) -> None:
        """Delete numba's file ``name`` (it is compiled and saved again), reporting why once."""
        _remove(self.numba_dir / name)
        self._verified.pop(name, None)
        self.corrupt(f"{name} {why}")

    def record(self, names) -> None:
        """Record numba's files ``names`` (just written) in the manifest with their size and hash."""
        def change(m):
            for name in names:
                found = _sha256(self.numba_dir / name)
                if found is not None:
                    m["files"][name] = {"size": found[0], "sha256": found[1]}
        self._update_manifest(change)

    def mark_compiled(self) -> None:
        """Record that a full compile of the module is cached (the next process says nothing about compiling)."""
        self._update_manifest(lambda m: m.__setitem__("compiled", time.strftime("%Y-%m-%d %H:%M:%S")))


def _filename_base(py_func, stem: str) -> str:
    """The file name numba's files of ``py_func`` start with (numba's own pattern: module.function-line.pyXY)."""
    return (f"{stem}.{py_func.__qualname__}-{py_func.__code__.co_firstlineno}"
            f".py{sys.version_info[0]}{sys.version_info[1]}{getattr(sys, 'abiflags', '')}")


def _guarded_cache_class():
    """The numba cache class whose files are checked against the module's manifest (built on first use)."""
    from numba.core import caching, compiler

    class GuardedCache(caching._Cache):
        """numba's index and data files of one function, read only when the manifest vouches for them."""

        def __init__(self, py_func, store: ModuleCache) -> None:
            self._py_func, self._store = py_func, store
            self._file = caching.IndexDataCacheFile(cache_path=str(store.numba_dir),
                                                    filename_base=_filename_base(py_func, store.stem),
                                                    source_stamp=store.stamp)
            self._enabled = True

        # numba's key of an overload (signature, target, bytecode): its own function, on this cache
        _index_key = caching.Cache._index_key

        @property
        def cache_path(self):
            return str(self._store.numba_dir)

        def enable(self):
            self._enabled = True

        def disable(self):
            self._enabled = False

        def flush(self):
            pass

        def load_overload(self, sig, target_context):
            target_context.refresh()
            store, index = self._store, self._file._index_name
            if not self._enabled or not store.trusted(index):
                return None
            reading = index
            try:
                overloads = self._file._load_index()
                reading = overloads.get(self._index_key(sig, target_context.codegen()))
                if reading is None or not store.trusted(reading):
                    return None
                return compiler.CompileResult._rebuild(target_context, *self._file._load_data(reading))
            except Exception as err:          # anything numba cannot read is a miss: compile again
                store.reject(str(reading), f"could not be read ({type(err).__name__}: {err})")
                return None

        def save_overload(self, sig, cres):
            store = self._store
            if not self._enabled or not store.writable:       # a failed write was reported once already
                return
            if any(not x.can_cache for x in cres.lifted) or cres.library.has_dynamic_globals:
                return
            index = self._file._index_name
            if (store.numba_dir / index).exists():
                store.trusted(index)            # deletes an index that does not check out: numba starts anew
            try:
                store.numba_dir.mkdir(parents=True, exist_ok=True)
                key = self._index_key(sig, cres.codegen)
                self._file.save(key, cres._reduce())
                name = self._file._load_index().get(key)
            except OSError as err:
                store.unwritable(err)
                return
            except Exception as err:            # a file changed under us: leave it to the next run to rebuild
                store.reject(index, f"could not be updated ({type(err).__name__}: {err})")
                return
            store.record([index] + ([name] if name else []))

    return GuardedCache


_cache_class = None


def guard_dispatcher(dispatcher, store: ModuleCache | None) -> None:
    """Give a numba dispatcher (made without ``cache=True``) the manifest-checked cache of ``store``.

    With ``store`` None, or when this numba's cache internals are not those
    expected, the dispatcher keeps numba's default: compile in memory, no cache.
    """
    global _cache_class
    if store is None:
        return
    try:
        if _cache_class is None:
            _cache_class = _guarded_cache_class()
        dispatcher._cache = _cache_class(dispatcher.py_func, store)
    except (ImportError, AttributeError, TypeError) as err:
        store.unwritable(OSError(errno.ENOTSUP, f"numba's cache cannot be guarded here ({err})"))
