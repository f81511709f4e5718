"""Native (C) kernels: equal to numba and to the reference, fallback to numba, atomic cached build."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import diagnose.fit as fit
import diagnose.output_error as oe
import diagnose.native as nv
import diagnose.process_model as pm
import diagnose.stiction_model as sm
from diagnose.errors import StictionWarning
from diagnose.stiction_model import stiction_reference

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A private library cache for this module (built once, ~1 s)."""
    d = tmp_path_factory.mktemp("stiction-cache")
    old = {k: os.environ.get(k) for k in ("STICTION_CACHE", "STICTION_NATIVE")}
    os.environ["STICTION_CACHE"] = str(d)
    os.environ.pop("STICTION_NATIVE", None)
    nv.reset()
    assert nv.library() is not None, nv.status()["reason"]
    yield d
    for k, v in old.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
    nv.reset()


def _bits(a):
    """Exact equality including the sign of zero and NaN payloads."""
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def _walk(rng, n, step=0.4, lo=-5.0, hi=105.0):
    """An OP-like random walk with flat stretches, reversals, and excursions past 0 and 100 %."""
    x = 50.0 + np.cumsum(rng.normal(0.0, step, n) * (rng.random(n) < 0.7))
    return np.clip(x, lo, hi)


def test_every_identify_kernel_has_an_up_to_date_native_twin(cache):
    st = nv.status()
    assert st["native"], st["reason"]
    for key in ("diagnose.stiction_model._batch_kernel", "diagnose.process_model._lag_filter",
                "diagnose.output_error._ham_sse", "diagnose.output_error._hp_filter_2d",
                "diagnose.output_error._valve_smooth"):
        deps = nv._TWINS[key][1]
        stale = {d: nv.fingerprint(d) for d, fp in deps.items() if nv.fingerprint(d) != fp}
        assert not stale, (f"{key}: the Python kernel changed; port the change to diagnose/native/kernels.c "
                           f"and set these fingerprints in diagnose/native/__init__.py: {stale}")
        assert st["kernels"][key] == "native"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_stiction_kernel_native_equals_numba_and_reference_bit_for_bit(cache, seed):
    rng = np.random.default_rng(seed)
    n, m = 1500, 12
    x = _walk(rng, n)
    S = rng.uniform(0.0, 6.0, m)
    J = np.where(rng.random(m) < 0.3, 0.0, rng.uniform(0.0, 8.0, m))
    S[0], J[0] = 0.0, 0.0
    f0 = np.where(rng.random(m) < 0.5, 1.0, -1.0)
    out_n = sm._batch_kernel.native(x, S, J, f0, np.empty((m, n)))
    out_b = sm._batch_kernel.numba(x, S, J, f0, np.empty((m, n)))
    np.testing.assert_array_equal(_bits(out_n), _bits(out_b))
    for i in range(m):
        ref = stiction_reference(x, S[i], J[i], int(f0[i]))
        np.testing.assert_array_equal(out_n[i], ref)
    # a strided output (rows of a wider array) and a non-contiguous one are filled in place
    wide = np.full((m, n + 7), -1.0)
    sm._batch_kernel.native(x, S, J, f0, wide)
    np.testing.assert_array_equal(wide[:, :n], out_n)
    assert np.all(wide[:, n:] == -1.0)
    fort = np.asfortranarray(np.zeros((m, n)))
    sm._batch_kernel.native(x, S, J, f0, fort)
    np.testing.assert_array_equal(fort, out_n)


def test_valve_smooth_native_equals_numba_and_python(cache):
    rng = np.random.default_rng(3)
    x = _walk(rng, 800)
    for s, j, f in [(2.0, 0.5, 1.0), (1.0, 3.0, -1.0), (4.0, 0.0, 1.0), (0.0, 0.0, 1.0)]:
        a = oe._valve_smooth.native(x, s, j, f, np.empty(x.size))
        b = oe._valve_smooth.numba(x, s, j, f, np.empty(x.size))
        c = oe._valve_smooth.py_func(x, s, j, f, np.empty(x.size))
        np.testing.assert_array_equal(_bits(a), _bits(b))
        np.testing.assert_array_equal(a, c)


@pytest.mark.parametrize("a1,a2,d,integ", [(0.9, -1.0, 0, False), (0.95, 0.8, 3, False),
                                           (0.5, -1.0, 7, True), (0.0, -1.0, 2, False)])
def test_lag_filter_native_equals_numba_and_python(cache, a1, a2, d, integ):
    u = _walk(np.random.default_rng(4), 600)
    a = pm._lag_filter.native(u, a1, a2, d, integ, 0.5)
    b = pm._lag_filter.numba(u, a1, a2, d, integ, 0.5)
    c = pm._lag_filter.py_func(u, a1, a2, d, integ, 0.5)
    np.testing.assert_array_equal(_bits(a), _bits(b))
    np.testing.assert_array_equal(a, c)


@pytest.mark.parametrize("m", [1, 3])
def test_hp_filter_native_equals_numba_and_python(cache, m):
    v = np.random.default_rng(5).normal(size=(500, m)).cumsum(axis=0)
    a = oe._hp_filter_2d.native(v, 0.9)
    b = oe._hp_filter_2d.numba(v, 0.9)
    c = oe._hp_filter_2d.py_func(v, 0.9)
    np.testing.assert_array_equal(_bits(a), _bits(b))
    np.testing.assert_array_equal(a, c)


def _ham_case(rng, n, m, P, K, hp, gfix, smooth):
    x = _walk(rng, n)
    S = rng.uniform(0.0, 5.0, m)
    J = rng.uniform(0.0, 6.0, m)
    F = np.where(rng.random(m) < 0.5, 1.0, -1.0)
    kinds = rng.choice(["foptd", "soptd", "integrating"], P)
    entries = [(k, float(rng.uniform(0.5, 30.0)), float(rng.uniform(0.5, 10.0)), int(rng.integers(0, 9)))
               for k in kinds]
    cfg = oe._make_configs(entries, 1.0)
    w = (rng.random(n) < 0.8).astype(float)
    w[:20] = 0.0
    y = rng.normal(size=n).cumsum() * 0.1
    Q = np.linalg.qr(rng.normal(size=(n, K)))[0] if K else np.zeros((n, 0))
    Qw = np.ascontiguousarray(Q * w[:, None])
    yw = w * y
    Qty = Qw.T @ y
    yyp = float(yw @ y - Qty @ Qty)
    ahp = 0.8 if hp else -1.0
    args = (x, S, J, F, cfg.a1, cfg.a2, cfg.d, cfg.integ, 1.0, ahp, w, yw, Qw, Qty, yyp)
    return args, smooth, gfix


def _ham_reference(args, smooth, gfix):
    """SSE and gain from numpy sums (independent of the kernels' loop structure)."""
    x, S, J, F, a1, a2, d, integ, ts, ahp, w, yw, Qw, Qty, yyp = args
    m, P = S.shape[0], a1.shape[0]
    sse = np.empty((m, P))
    gain = np.empty((m, P))
    for i in range(m):
        if smooth:
            u = oe._valve_smooth.py_func(x, S[i], J[i], F[i], np.empty(x.size))
        else:
            u = stiction_reference(x, S[i], J[i], int(F[i]))
        for p in range(P):
            z = pm._lag_filter.py_func(u - u[0], a1[p], a2[p] if a2[p] >= 0 else 0.0, int(d[p]),
                                       bool(integ[p]), ts)
            # the kernel starts the lags at rest at 0 with the dead time filled by u0 (0 here)
            v = oe._hp_filter_2d.py_func(z[:, None], ahp)[:, 0] if ahp >= 0 else z
            szz, szy, szq = float(np.sum(w * v * v)), float(yw @ v), Qw.T @ v
            zzp, zyp = szz - szq @ szq, szy - szq @ Qty
            if gfix == gfix:
                sse[i, p], gain[i, p] = yyp - 2 * gfix * zyp + gfix * gfix * max(zzp, 0.0), gfix
            elif zzp > 1e-10 * (szz + 1e-300):
                sse[i, p], gain[i, p] = yyp - zyp * zyp / zzp, zyp / zzp
            else:
                sse[i, p], gain[i, p] = yyp, 0.0
    return sse, gain


@pytest.mark.parametrize("m,P,K,hp,gfix,smooth", [
    (5, 9, 3, True, np.nan, False),     # four-structure groups and leftovers
    (7, 1, 1, False, np.nan, False),    # many candidates at one structure (the simplex path)
    (2, 4, 0, True, 1.0, False),        # fixed gain, no load basis
    (3, 6, 2, False, np.nan, True),     # the smoothed valve
])
def test_ham_sse_native_equals_numba_bit_for_bit_and_reference(cache, m, P, K, hp, gfix, smooth):
    rng = np.random.default_rng(10 * m + P)
    args, smooth, gfix = _ham_case(rng, 700, m, P, K, hp, gfix, smooth)
    outs = {}
    for name in ("native", "numba"):
        k = getattr(oe._ham_sse, name)
        sse, gain = np.empty((m, P)), np.empty((m, P))
        k(*args, sse, gain, smooth, gfix)
        outs[name] = (sse, gain)
    np.testing.assert_array_equal(_bits(outs["native"][0]), _bits(outs["numba"][0]))
    np.testing.assert_array_equal(_bits(outs["native"][1]), _bits(outs["numba"][1]))
    ref_sse, ref_gain = _ham_reference(args, smooth, gfix)
    # the reference sums in another order: equal to rounding (1e-12 of the data's sum of squares)
    scale = float(args[11] @ args[11]) + abs(args[14])
    np.testing.assert_allclose(outs["native"][0], ref_sse, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(outs["native"][1], ref_gain, rtol=1e-9, atol=1e-12)


def test_fit_is_identical_native_and_numba(cache, monkeypatch):
    rng = np.random.default_rng(7)
    n = 600
    op = 50.0 + 5.0 * np.sin(np.arange(n) / 15.0) + rng.normal(0, 0.3, n)
    pv = np.convolve(np.clip(op, 0, 100), np.ones(5) / 5, mode="same") + rng.normal(0, 0.05, n)
    res = {}
    for mode in ("1", "0"):
        monkeypatch.setenv("STICTION_NATIVE", mode)
        nv.reset()
        f = fit.fit_hammerstein(op, pv, 1.0, kinds=("foptd",), n_S=6, n_J=6, surface=False, max_samples=None)
        res[mode] = (f.S_pct, f.J_pct, f.f0, f.rmse, f.process.tau_s, f.process.delay_s)
        assert nv.status()["native"] is (mode == "1")
    assert res["1"] == res["0"]
    nv.reset()


def test_fallback_when_disabled_and_when_no_compiler(tmp_path, monkeypatch):
    monkeypatch.setenv("STICTION_CACHE", str(tmp_path / "c"))
    monkeypatch.setenv("STICTION_NATIVE", "0")
    nv.reset()
    assert nv.library() is None and sm._batch_kernel.native is None
    x = _walk(np.random.default_rng(8), 300)
    y = sm.stiction_batch(x, [2.0], [1.0], [1])[0]
    np.testing.assert_array_equal(y, stiction_reference(x, 2.0, 1.0, 1))
    assert "numba" in type(sm._batch_kernel._impl).__module__
    # no compiler: auto mode falls back to numba, STICTION_NATIVE=1 is an error
    monkeypatch.setattr(nv, "_compiler", lambda: None)
    monkeypatch.delenv("STICTION_NATIVE")
    nv.reset()
    assert nv.library() is None
    assert "numba fallback" in nv.status()["reason"] and "no C compiler" in nv.status()["reason"]
    np.testing.assert_array_equal(sm.stiction_batch(x, [2.0], [1.0], [1])[0], y)
    monkeypatch.setenv("STICTION_NATIVE", "1")
    nv.reset()
    with pytest.raises(nv.NativeBuildError, match="unavailable"):
        nv.library()
    nv.reset()


def test_failed_build_is_remembered(tmp_path, monkeypatch):
    monkeypatch.setenv("STICTION_CACHE", str(tmp_path))
    monkeypatch.setattr(nv, "_compiler", lambda: ["false"])
    with pytest.raises(nv.NativeBuildError, match="failed"):
        nv.build()
    assert nv.library_path().with_suffix(".failed").exists()
    assert not list(tmp_path.glob("*.tmp")) and not nv.library_path().exists()

    def boom():
        raise AssertionError("the compiler must not run again")
    monkeypatch.setattr(nv, "_compiler", boom)
    with pytest.raises(nv.NativeBuildError, match="earlier build failed"):
        nv.build()


def test_concurrent_builds_are_atomic(tmp_path):
    env = dict(os.environ, STICTION_CACHE=str(tmp_path), PYTHONPATH=str(ROOT))
    env.pop("STICTION_NATIVE", None)
    code = "import diagnose.native as nv; p = nv.build(); nv._open(p); print(p)"
    procs = [subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(3)]
    outs = [p.communicate(timeout=120) for p in procs]
    assert all(p.returncode == 0 for p in procs), outs
    paths = {o[0].strip() for o in outs}
    assert len(paths) == 1
    files = sorted(f.name for f in tmp_path.iterdir())
    assert files == [Path(paths.pop()).name], files       # one library, no temporary left over


def test_identify_path_imports_neither_numba_nor_scipy(cache):
    code = textwrap.dedent("""
        import sys
        import numpy as np
        from diagnose.identify import identify
        from diagnose.record import LoopRecord
        import diagnose.native as nv
        rng = np.random.default_rng(0)
        n = 400
        op = 50 + 5 * np.sin(np.arange(n) / 12.0) + rng.normal(0, 0.2, n)
        pv = np.convolve(op, np.ones(4) / 4, mode="same") + rng.normal(0, 0.05, n)
        identify(LoopRecord(name="L", ts_s=1.0, op=op, pv=pv))
        assert nv.status()["native"], nv.status()
        heavy = sorted(m for m in ("numba", "scipy", "llvmlite", "torch") if m in sys.modules)
        print(heavy)
    """)
    env = dict(os.environ, STICTION_CACHE=str(cache), PYTHONPATH=str(ROOT))
    env.pop("STICTION_NATIVE", None)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_stale_twin_is_not_used(cache, monkeypatch):
    maker, deps = nv._TWINS["diagnose.process_model._lag_filter"]
    monkeypatch.setitem(nv._TWINS, "diagnose.process_model._lag_filter",
                        (maker, {k: "000000000000" for k in deps}))
    nv._WARNED.discard("diagnose.process_model._lag_filter")
    with pytest.warns(StictionWarning, match="out of date"):
        assert pm._lag_filter.native is None
    nv.reset()
    u = np.linspace(0.0, 10.0, 50)
    np.testing.assert_array_equal(pm._lag_filter(u, 0.5, -1.0, 1, False, 1.0),
                                  pm._lag_filter.py_func(u, 0.5, -1.0, 1, False, 1.0))
    assert "numba" in type(pm._lag_filter._impl).__module__
    monkeypatch.undo()
    nv.reset()


def test_required_native_reuses_the_cached_library(cache, monkeypatch):
    def boom():
        raise AssertionError("the library is cached: the compiler must not run")
    monkeypatch.setattr(nv, "_compiler", boom)
    monkeypatch.setenv("STICTION_NATIVE", "1")
    nv.reset()
    assert nv.library() is not None and nv.status()["native"]
    monkeypatch.undo()
    nv.reset()


def test_kernels_pickle_by_reference():
    import pickle
    assert pickle.loads(pickle.dumps(sm._batch_kernel)) is sm._batch_kernel
    assert pickle.loads(pickle.dumps(oe._ham_sse)) is oe._ham_sse


def test_a_damaged_library_is_rebuilt(tmp_path, monkeypatch):
    monkeypatch.setenv("STICTION_CACHE", str(tmp_path))
    monkeypatch.delenv("STICTION_NATIVE", raising=False)
    target = nv.library_path()
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_bytes(b"not a shared library")
    nv.reset()
    assert nv.library() is not None, nv.status()["reason"]
    assert target.read_bytes() != b"not a shared library"
    monkeypatch.undo()
    nv.reset()
