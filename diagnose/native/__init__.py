"""Compiled kernels without the numba start-up cost: a native (C) fast path, numba as fallback.

The fitting stage spends its time in a handful of small loops (`diagnose.stiction_model._batch_kernel`,
`diagnose.process_model._lag_filter`, `diagnose.output_error._ham_sse`,
`diagnose.output_error._hp_filter_2d`, `diagnose.output_error._valve_smooth`). They are written once, in
Python, and decorated with `njit` from this module instead of numba's. That decorator is lazy:

* importing a module that defines kernels does not import numba (numba's import and the first
  load of its cached machine code cost about a second, more than a whole identification);
* on the first call a kernel runs its **native twin**, a line-by-line C port in
  ``diagnose/native/kernels.c``, when one exists and a C compiler is (or was once) available;
* otherwise it compiles itself with numba (``numba.njit`` with the decorator's options, cached on
  disk as before) and runs that.

The C source is compiled once per user and machine on first use by the system compiler (``$CC``, or
``cc``/``gcc``/``clang`` on the path) with ``-O3 -march=native -ffp-contract=off`` (no fused
multiply-add, no fast-math; see `CFLAGS`) into ``$STICTION_CACHE`` (default
``$XDG_CACHE_HOME/stiction`` or ``~/.cache/stiction``) as ``native-<hash>.so``; the hash covers the source, the flags and the
CPU, so an edited source builds a new library. The library is written to a temporary file in the
same directory and renamed into place, so processes that build at the same time never see a partial
file. A failed build leaves a ``native-<hash>.failed`` note (with the compiler's message) so later
runs go straight to numba instead of retrying.

The twins perform the same floating-point operations in the same order as the numba kernels, so
they return the same numbers bit for bit (tests/test_native.py checks this on random inputs). Each
twin is tied to a fingerprint of the Python source of the kernels it ports: if a kernel is edited
and the C port is not, the twin is not used (numba runs) and the test suite says which fingerprint
to update.

Environment: ``STICTION_NATIVE=0`` forces numba; ``STICTION_NATIVE=1`` requires the native path
(an error when it cannot be built); unset: native when possible.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import sys
import threading
import types
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import StictionError, StictionWarning

SOURCE = Path(__file__).with_name("kernels.c")
#: Compiler flags. -ffp-contract=off: no fused multiply-add (numba does not contract either), so
#: results equal numba's bit for bit; no -ffast-math for the same reason. -O3 with the host's vector
#: width (-march=native: AVX on x86-64) runs the vector loops of `ham_sse` about twice as fast as
#: numba; -O2 or SSE2 only is slower than numba (still exact). -march=native is dropped if the compiler
#: refuses it; the library name includes the CPU, so a cache shared between machines stays valid.
CFLAGS = ("-O3", "-shared", "-fPIC", "-std=c99", "-ffp-contract=off", "-fno-fast-math")
CFLAGS_TUNED = ("-march=native",)
ABI_VERSION = 1

_LOCK = threading.RLock()
_KERNELS: dict[str, "Kernel"] = {}
_WARNED: set[str] = set()
_state: dict[str, Any] = {"lib": None, "tried": False, "reason": "not loaded yet", "path": None}


class NativeBuildError(StictionError):
    """The native kernels could not be built or loaded (only raised with STICTION_NATIVE=1)."""


# --------------------------------------------------------------------------------------------------
# configuration
# --------------------------------------------------------------------------------------------------

def mode() -> str:
    """``"off"``, ``"require"`` or ``"auto"`` from the environment variable STICTION_NATIVE."""
    v = os.environ.get("STICTION_NATIVE", "").strip().lower()
    if v in ("0", "off", "false", "no", "numba"):
        return "off"
    if v in ("1", "on", "true", "yes", "require", "native"):
        return "require"
    return "auto"


def cache_dir() -> Path:
    """Directory of the compiled library.

    $STICTION_CACHE, else $XDG_CACHE_HOME/stiction, else ~/.cache/stiction.
    """
    env = os.environ.get("STICTION_CACHE")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "stiction"


def _machine() -> str:
    """Platform, architecture and CPU model/features (the library is tuned to the CPU)."""
    parts = [sys.platform]
    try:
        u = os.uname()
        parts += [u.machine, u.nodename if sys.platform != "linux" else ""]
    except AttributeError:  # pragma: no cover - Windows
        pass
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:            # the first processor's block is enough
                if not line.strip():
                    break
                key = line.split(":", 1)[0].strip().lower()
                if key in ("vendor_id", "model name", "flags", "features", "cpu implementer", "cpu part"):
                    parts.append(line.strip())
    except OSError:
        pass
    return "|".join(parts)


def library_path(directory: Path | None = None) -> Path:
    """Where the library for the current source, flags and machine lives (built or not)."""
    h = hashlib.sha256()
    h.update(SOURCE.read_bytes())
    h.update(repr((CFLAGS, CFLAGS_TUNED, ABI_VERSION, _machine())).encode())
    return (directory if directory is not None else cache_dir()) / f"native-{h.hexdigest()[:16]}.so"


def _compiler() -> list[str] | None:
    import shlex
    import shutil
    cc = os.environ.get("CC")
    if cc:
        parts = shlex.split(cc)
        if parts and shutil.which(parts[0]):
            return parts
    for name in ("cc", "gcc", "clang"):
        path = shutil.which(name)
        if path:
            return [path]
    return None


# --------------------------------------------------------------------------------------------------
# build and load
# --------------------------------------------------------------------------------------------------

def build(directory: Path | None = None, *, force: bool = False, retry_failed: bool = False) -> Path:
    """Compile ``kernels.c`` into the cache (atomically) unless it is there; returns the library path.

    ``force`` rebuilds even when the library exists; ``retry_failed`` tries again after an earlier
    failed build. Raises `NativeBuildError` when no compiler is found or the compiler fails (and
    then leaves a ``.failed`` note next to where the library would be).
    """
    target = library_path(directory)
    if target.exists() and not force:
        return target
    import subprocess
    import tempfile

    failed = target.with_suffix(".failed")
    if failed.exists() and not (force or retry_failed):
        raise NativeBuildError(f"an earlier build failed (see {failed}); delete it to retry")
    cc = _compiler()
    if cc is None:
        raise NativeBuildError("no C compiler found (set CC, or install cc/gcc/clang)")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=target.stem + ".", suffix=".tmp", dir=target.parent)
    except OSError as exc:
        raise NativeBuildError(f"cannot write the native library cache {target.parent}: {exc}") from exc
    os.close(fd)
    try:
        for flags in ((*CFLAGS, *CFLAGS_TUNED), CFLAGS):
            proc = subprocess.run([*cc, *flags, "-o", tmp, str(SOURCE)], capture_output=True, text=True,
                                  timeout=300)
            if proc.returncode == 0:
                break
        if proc.returncode != 0:
            msg = (proc.stderr or proc.stdout or "").strip()
            _write_note(failed, f"{' '.join(cc)} failed ({proc.returncode}):\n{msg}\n")
            raise NativeBuildError(f"compiling {SOURCE.name} failed: {msg.splitlines()[-1] if msg else '?'}")
        os.chmod(tmp, 0o755)
        os.replace(tmp, target)         # atomic: readers see the old file, or none, or the whole new one
    except (OSError, subprocess.SubprocessError) as exc:
        raise NativeBuildError(f"building the native kernels failed: {exc}") from exc
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return target


def _write_note(path: Path, text: str) -> None:
    try:
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)
    except OSError:
        pass


_P = ctypes.c_void_p
_I = ctypes.c_int64
_D = ctypes.c_double
_C = ctypes.c_int
_SIGNATURES = {
    "stiction_native_abi": ([], _C),
    "stiction_batch": ([_P, _I, _P, _P, _P, _I, _P, _I], None),
    "valve_smooth": ([_P, _I, _D, _D, _D, _P], None),
    "lag_filter": ([_P, _I, _D, _D, _I, _C, _D, _P], None),
    "hp_filter_2d": ([_P, _I, _I, _I, _D, _P], None),
    "ham_sse": ([_P, _I, _P, _P, _P, _I, _P, _P, _P, _P, _I, _D, _D, _P, _P, _P, _I, _P, _D, _P, _P,
                 _C, _D], _C),
}


def _open(path: Path) -> ctypes.CDLL:
    lib = ctypes.CDLL(str(path))
    for name, (argtypes, restype) in _SIGNATURES.items():
        fn = getattr(lib, name)
        fn.argtypes = argtypes
        fn.restype = restype
    if lib.stiction_native_abi() != ABI_VERSION:
        raise NativeBuildError(f"{path} is not ABI version {ABI_VERSION}")
    return lib


def library() -> ctypes.CDLL | None:
    """The loaded native library, building it on first use; None when disabled or unavailable.

    Raises `NativeBuildError` when STICTION_NATIVE=1 and the library cannot be had.
    """
    if _state["tried"]:
        return _state["lib"]
    with _LOCK:
        if _state["tried"]:
            return _state["lib"]
        md = mode()
        lib = None
        if md == "off":
            _state["reason"] = "disabled by STICTION_NATIVE=0"
        else:
            try:
                path = build(retry_failed=md == "require")
                try:
                    lib = _open(path)
                except (OSError, AttributeError, NativeBuildError):
                    # a damaged or foreign file under our name: build it again, once
                    path = build(force=True)
                    lib = _open(path)
                _state["path"] = str(path)
                _state["reason"] = "native"
            except (NativeBuildError, OSError, AttributeError) as exc:
                _state["reason"] = f"numba fallback: {exc}"
                if md == "require":
                    _state["tried"] = True
                    raise NativeBuildError(f"STICTION_NATIVE=1 but the native kernels are unavailable: "
                                           f"{exc}") from exc
        _state["lib"] = lib
        _state["tried"] = True
        return lib


def status() -> dict[str, Any]:
    """Which path the kernels take: ``{"mode", "native", "reason", "path", "kernels"}``."""
    try:
        library()
    except NativeBuildError:
        pass
    return {"mode": mode(), "native": _state["lib"] is not None, "reason": _state["reason"],
            "path": _state["path"],
            "kernels": {k: ("native" if v.native is not None else "numba") for k, v in _KERNELS.items()
                        if k in _TWINS}}


def reset() -> None:
    """Forget the loaded library and every kernel's choice (re-read STICTION_NATIVE on next call)."""
    with _LOCK:
        _state.update(lib=None, tried=False, reason="not loaded yet", path=None)
        for k in _KERNELS.values():
            k._impl = None


# --------------------------------------------------------------------------------------------------
# the lazy decorator
# --------------------------------------------------------------------------------------------------

class Kernel:
    """A kernel written in numba-compatible Python, run natively or by numba (chosen on first call).

    Attributes
    ----------
    py_func : function
        The Python source (the specification; runs as plain Python, slowly).
    numba : numba dispatcher
        The numba-compiled kernel (compiled, or loaded from numba's cache, on first access).
    native : callable or None
        The native twin, None when unavailable, disabled or out of date.
    """

    def __init__(self, py_func: Callable, options: dict[str, Any]) -> None:
        functools.update_wrapper(self, py_func)
        self.py_func = py_func
        self.options = dict(options)
        self.key = f"{py_func.__module__}.{py_func.__qualname__}"
        self._dispatcher = None
        self._impl = None
        _KERNELS[self.key] = self

    def __call__(self, *args, **kwargs):
        if kwargs:                      # the twins take positional arguments only
            return self.numba(*args, **kwargs)
        impl = self._impl
        if impl is None:
            impl = self._resolve()
        return impl(*args)

    def __repr__(self) -> str:
        return f"<Kernel {self.key}>"

    def __reduce__(self):
        # pickled by reference, like the module-level function it replaces
        return (_kernel_by_name, (self.py_func.__module__, self.py_func.__qualname__))

    def _resolve(self) -> Callable:
        with _LOCK:
            impl = self.native
            if impl is None:
                impl = self.numba
            self._impl = impl
            return impl

    @property
    def native(self) -> Callable | None:
        twin = _TWINS.get(self.key)
        if twin is None:
            return None
        maker, deps = twin
        stale = [d for d, fp in deps.items() if fingerprint(d) not in (fp, "*")]
        if stale:
            if self.key not in _WARNED:
                _WARNED.add(self.key)
                import warnings
                warnings.warn(f"the native twin of {self.key} is out of date ({', '.join(stale)} changed "
                              "since its C port): running numba instead, which is slower; port the "
                              "change to diagnose/native/kernels.c (tests/test_native.py names the "
                              "fingerprints to update)", StictionWarning, stacklevel=3)
            return None
        lib = library()
        return None if lib is None else maker(lib)

    @property
    def numba(self):
        if self._dispatcher is None:
            with _LOCK:
                if self._dispatcher is None:
                    import numba
                    f = self.py_func
                    # Kernels that call kernels: numba must see dispatchers, not `Kernel` objects.
                    # Compile against a copy of the module's namespace so the module keeps its
                    # `Kernel` objects (and with them the native path).
                    g = dict(f.__globals__)
                    for name in _global_names(f.__code__):
                        val = g.get(name)
                        if isinstance(val, Kernel) and val is not self:
                            g[name] = val.numba
                    fn = types.FunctionType(f.__code__, g, f.__name__, f.__defaults__, f.__closure__)
                    fn.__qualname__ = f.__qualname__
                    fn.__module__ = f.__module__
                    fn.__doc__ = f.__doc__
                    self._dispatcher = numba.njit(**self.options)(fn)
        return self._dispatcher


def _kernel_by_name(module: str, qualname: str) -> "Kernel":
    import importlib
    obj: Any = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def _global_names(code: types.CodeType) -> set[str]:
    names = set(code.co_names)
    for c in code.co_consts:
        if isinstance(c, types.CodeType):
            names |= _global_names(c)
    return names


def njit(*args, **options):
    """Drop-in for ``numba.njit`` (``@njit`` or ``@njit(cache=True, ...)``) that defers numba.

    Returns a `Kernel`: the native twin runs when there is one, else numba compiles the function
    with these options on its first call.
    """
    if args and callable(args[0]) and not options:
        return Kernel(args[0], {})

    def deco(fn):
        return Kernel(fn, options)
    return deco


@functools.lru_cache(maxsize=None)
def _source_lines(filename: str) -> tuple[str, ...] | None:
    try:
        with open(filename, encoding="utf-8") as fh:
            return tuple(fh.read().splitlines())
    except OSError:
        return None


def kernel_source(key: str) -> str | None:
    """The source text of kernel ``key`` (decorator to the end of the function), or None."""
    k = _KERNELS.get(key)
    if k is None:
        return None
    code = k.py_func.__code__
    lines = _source_lines(code.co_filename)
    if lines is None:
        return None
    start = code.co_firstlineno - 1
    out = []
    seen_def = False
    for line in lines[start:]:
        if seen_def and line.strip() and not line[0].isspace():
            break
        if line.lstrip().startswith("def "):
            seen_def = True
        out.append(line.rstrip())
    while out and not out[-1]:
        out.pop()
    return "\n".join(out)


def fingerprint(key: str) -> str | None:
    """Short hash of a kernel's Python source: ties a native twin to the code it ports.

    None when the kernel is not defined (its module not imported). When the source file cannot be
    read (an installation without .py files) the twin is trusted: ``"*"`` matches any fingerprint.
    """
    if key not in _KERNELS:
        return None
    src = kernel_source(key)
    if src is None:
        return "*"
    return hashlib.sha256(src.encode()).hexdigest()[:12]


# --------------------------------------------------------------------------------------------------
# native twins (thin wrappers: check shapes, pass pointers)
# --------------------------------------------------------------------------------------------------

_from_buffer = ctypes.c_char.from_buffer
_addressof = ctypes.addressof


def _addr(a: np.ndarray) -> int:
    """Address of an array's data (about 3x faster than ``a.ctypes.data`` for writable arrays)."""
    try:
        return _addressof(_from_buffer(a))
    except (TypeError, ValueError, BufferError):     # read-only or empty
        return a.ctypes.data


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def _out_ok(a, ndim: int) -> bool:
    return (isinstance(a, np.ndarray) and a.ndim == ndim and a.dtype == np.float64 and a.flags.c_contiguous
            and a.flags.writeable)


def _make_batch_kernel(lib):
    fn = lib.stiction_batch

    def batch_kernel(x, S, J, f0, out):
        x, S, J, f0 = _f64(x), _f64(S), _f64(J), _f64(f0)
        m, n = S.shape[0], x.shape[0]
        if x.ndim != 1 or S.ndim != 1 or J.shape[0] < m or f0.shape[0] < m or out.ndim != 2 \
                or out.shape[0] < m or out.shape[1] < n:
            raise IndexError("stiction kernel: inconsistent shapes")
        if m == 0 or n == 0:
            return out
        rows_ok = (out.dtype == np.float64 and out.strides[1] == 8 and out.strides[0] > 0
                   and out.strides[0] % 8 == 0 and out.flags.writeable)
        buf = out if rows_ok else np.empty((m, n))
        fn(_addr(x), n, _addr(S), _addr(J), _addr(f0), m, _addr(buf),
           buf.strides[0] // 8)
        if buf is not out:
            out[:m, :n] = buf
        return out
    return batch_kernel


def _make_valve_smooth(lib):
    fn = lib.valve_smooth

    def valve_smooth(x, s, j, f0, out):
        x = _f64(x)
        n = x.shape[0]
        if out.shape[0] < n:
            raise IndexError("valve_smooth: out is shorter than x")
        if n == 0:
            return out
        buf = out if _out_ok(out, 1) else np.empty(n)
        fn(_addr(x), n, float(s), float(j), float(f0), _addr(buf))
        if buf is not out:
            out[:n] = buf
        return out
    return valve_smooth


def _make_lag_filter(lib):
    fn = lib.lag_filter

    def lag_filter(u, a1, a2, d, integ, ts_s):
        u = _f64(u)
        n = u.shape[0]
        if int(d) < 0:
            raise ValueError("lag_filter: the dead time must be >= 0 samples")
        z = np.empty(n)
        if n:
            fn(_addr(u), n, float(a1), float(a2), int(d), 1 if integ else 0, float(ts_s), _addr(z))
        return z
    return lag_filter


def _make_hp_filter_2d(lib):
    fn = lib.hp_filter_2d

    def hp_filter_2d(v, a):
        v = _f64(v)
        if v.ndim != 2:
            raise TypeError("hp_filter_2d: v must be two-dimensional")
        n, m = v.shape
        out = np.empty((n, m))
        if n and m:
            fn(_addr(v), n, m, m, float(a), _addr(out))
        return out
    return hp_filter_2d


def _make_ham_sse(lib):
    fn = lib.ham_sse

    def ham_sse(x, S, J, F, a1, a2, d, integ, ts, ahp, w, yw, Qw, Qty, yyp, sse, gain, smooth, gfix):
        x, S, J, F = _f64(x), _f64(S), _f64(J), _f64(F)
        a1, a2, w, yw, Qty, Qw = _f64(a1), _f64(a2), _f64(w), _f64(yw), _f64(Qty), _f64(Qw)
        d = np.ascontiguousarray(d, dtype=np.int64)
        ib = np.ascontiguousarray(integ, dtype=np.bool_).view(np.uint8)
        m, P, n = S.shape[0], a1.shape[0], x.shape[0]
        K = Qw.shape[1] if Qw.ndim == 2 else -1
        if (K < 0 or J.shape[0] < m or F.shape[0] < m or a2.shape[0] < P or d.shape[0] < P
                or ib.shape[0] < P or w.shape[0] < n or yw.shape[0] < n or Qw.shape[0] < n
                or Qty.shape[0] < K or sse.shape[0] < m or gain.shape[0] < m or sse.shape[1] < P
                or gain.shape[1] < P):
            raise IndexError("ham_sse: inconsistent shapes")
        if n > 0 and np.any(d[:P] < 0):
            raise ValueError("ham_sse: dead times must be >= 0 samples")
        if m == 0 or P == 0:
            return sse
        so = sse if (_out_ok(sse, 2) and sse.shape[1] == P) else np.empty((m, P))
        go = gain if (_out_ok(gain, 2) and gain.shape[1] == P) else np.empty((m, P))
        rc = fn(_addr(x), n, _addr(S), _addr(J), _addr(F), m, _addr(a1),
                _addr(a2), _addr(d), _addr(ib), P, float(ts), float(ahp), _addr(w),
                _addr(yw), _addr(Qw), K, _addr(Qty), float(yyp), _addr(so),
                _addr(go), 1 if smooth else 0, float(gfix))
        if rc != 0:
            raise MemoryError("ham_sse: out of memory")
        if so is not sse:
            sse[:m, :P] = so
        if go is not gain:
            gain[:m, :P] = go
        return sse
    return ham_sse


#: kernel -> (maker of its native twin, {ported kernel: fingerprint of its Python source}).
#: When a kernel's Python source changes, port the change to kernels.c and update the fingerprint
#: (tests/test_native.py prints the new value).
_TWINS: dict[str, tuple[Callable, dict[str, str]]] = {
    "diagnose.stiction_model._batch_kernel": (_make_batch_kernel, {
        "diagnose.stiction_model._batch_kernel": "9cefad784174"}),
    "diagnose.output_error._valve_smooth": (_make_valve_smooth, {
        "diagnose.output_error._valve_smooth": "3fc687fd5279"}),
    "diagnose.process_model._lag_filter": (_make_lag_filter, {
        "diagnose.process_model._lag_filter": "c1d48f13f90f"}),
    "diagnose.output_error._hp_filter_2d": (_make_hp_filter_2d, {
        "diagnose.output_error._hp_filter_2d": "f398745ca6a3"}),
    "diagnose.output_error._ham_sse": (_make_ham_sse, {
        "diagnose.output_error._ham_sse": "7c86161513b8",
        "diagnose.output_error._one_structure": "5acad93837b7",
        "diagnose.output_error._valve_smooth": "3fc687fd5279",
        "diagnose.stiction_model._batch_kernel": "9cefad784174"}),
}
