"""The compiled LCD kernel (ssmobs.design.lcd_native, lcd_kernel/lcd_kernel.cpp) against the NumPy
reference of ssmobs.design.lcd_distance: the same distance and gradient to ~1e-12, its own log, exp
and expm1 against NumPy's, and bits that the compiler's optimisation does not change (that
NumPy's and OpenBLAS's kernels and thread counts do not: tests/workflow/
test_same_bytes_on_any_kernels.py)."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from scipy import special
from ssmobs.design import lcd_native
from ssmobs.design.lcd_distance import _quadrature, b_max_rule, symmetric_distance

pytestmark = pytest.mark.unit


def _half(q: int, K: int, seed: int, zero_rows: int = 0) -> np.ndarray:
    s = np.random.default_rng(seed).standard_normal((K // 2, q))
    s[:zero_rows] = 0.0  # points at the origin: T- = T+ = 0 against each other
    return s


CASES = [
    # (q, K, b_max): even and odd K, K = 1 (empty half-set), K = 3 (one row), a width so
    # small that arguments exceed 1 (E1 by its continued fraction), q = 1
    (8, 1000, None),
    (8, 7, None),
    (3, 1, None),
    (2, 3, None),
    (2, 33, 0.7),
    (1, 10, None),
    (40, 301, None),
    (40, 301, 0.7),
    (200, 120, None),
]


@pytest.mark.parametrize(("q", "K", "b_max"), CASES)
@pytest.mark.parametrize("zero_rows", [0, 2])
def test_compiled_matches_the_numpy_reference(q, K, b_max, zero_rows):
    b = b_max_rule(q) if b_max is None else b_max
    s = _half(q, K, seed=q * 1000 + K, zero_rows=min(zero_rows, K // 2))
    v_ref, g_ref = symmetric_distance(s, K, b, gradient=True, kernel="numpy")
    v, g = symmetric_distance(s, K, b, gradient=True, kernel="compiled")
    v_only, none = symmetric_distance(s, K, b, gradient=False, kernel="compiled")
    assert none is None and v_only == v
    # the value is a difference of terms of size ~|D1'|: its round-off is relative to them
    scale = max(abs(v_ref), abs(_quadrature(q, b, 80).d1p))
    assert abs(v - v_ref) <= 1e-12 * scale, (v, v_ref)
    assert g.shape == g_ref.shape
    if g.size:
        assert np.max(np.abs(g - g_ref)) <= 1e-11 * np.max(np.abs(g_ref)), np.max(np.abs(g - g_ref))


def test_gradient_matches_finite_differences():
    q, K, b = 3, 9, 2.0
    s = _half(q, K, 5)
    _, g = symmetric_distance(s, K, b, gradient=True)
    h = 1e-6
    for i, k in [(0, 0), (2, 1), (3, 2)]:
        up, down = s.copy(), s.copy()
        up[i, k] += h
        down[i, k] -= h
        fd = (symmetric_distance(up, K, b, gradient=False)[0]
              - symmetric_distance(down, K, b, gradient=False)[0]) / (2 * h)  # fmt: skip
        assert abs(fd - g[i, k]) <= 1e-7 * max(1.0, abs(g[i, k])), (i, k, fd, g[i, k])


def test_own_log_exp_expm1_agree_with_numpy():
    x = np.concatenate(
        [
            np.logspace(-307, 307, 20001),
            1.0 + np.linspace(-1e-3, 1e-3, 2001),
            [5e-324, 1e-310, 2.2250738585072014e-308, 0.5, 2.0, np.sqrt(2.0)],
        ]
    )
    got = lcd_native.elementwise(x, "log")
    want = np.log(x)
    # relative, and absolute near x = 1 where log x -> 0 (as the log of a rounded x is)
    assert np.all(np.abs(got - want) <= 1e-15 * np.maximum(np.abs(want), 1e-3)), np.max(
        np.abs(got - want) / np.maximum(np.abs(want), 1e-3)
    )
    a = np.concatenate([np.linspace(-745.0, 709.0, 20001), np.linspace(-1.0, 1.0, 2001)])
    for name, ref in (("exp", np.exp), ("expm1", np.expm1)):
        got = lcd_native.elementwise(a, name)
        want = ref(a)
        normal = np.abs(want) > 1e-300
        rel = np.abs(got[normal] - want[normal]) / np.abs(want[normal])
        assert np.max(rel) <= 1e-15, (name, np.max(rel))
        assert np.all(np.abs(got[~normal] - want[~normal]) <= 1e-310), name
    assert lcd_native.elementwise(np.array([-800.0]), "exp")[0] == 0.0


def test_e1_and_psi_agree_with_scipy():
    c = np.concatenate([np.logspace(-14, 1.5, 3001), [1.0, np.nextafter(1.0, 2.0)]])
    e1, psi = lcd_native.e1_psi(c)
    want = special.exp1(c)
    assert np.max(np.abs(e1 - want) / want) <= 1e-13
    psi_want = c * want - np.expm1(-c)
    assert np.max(np.abs(psi - psi_want) / np.abs(psi_want)) <= 1e-12
    e1_0, psi_0 = lcd_native.e1_psi(np.array([0.0]))
    assert e1_0[0] == 0.0 and psi_0[0] == 0.0  # the convention E1(0) := 0 (doc Section 4)


def _digest(lib=None) -> str:
    h = hashlib.sha256()
    for q, K, b in [(8, 301, 10.0), (40, 120, 50.0), (2, 33, 0.7)]:
        s = _half(q, K, 7)
        quad = _quadrature(q, b, 80)
        rule = (quad.lam, quad.sig, quad.alpha, quad.beta, quad.d1p, quad.j0p)
        v, g = lcd_native.symmetric_distance(s, K, b, rule, True, lib=lib)
        h.update(np.float64(v).tobytes() + g.tobytes())
    return h.hexdigest()


def test_same_bits_without_optimisation(tmp_path):
    """Built with -O0 (no vectorisation, no scheduling): the same bits as the cached -O3
    build, so the compiler's optimisation does not change a result."""
    flags = tuple("-O0" if f.startswith("-O") else f for f in lcd_native.CXXFLAGS)
    assert flags != lcd_native.CXXFLAGS
    path, _ = lcd_native.build(tmp_path, flags)
    assert _digest(lcd_native.load(path)) == _digest()


def test_auto_runs_the_compiled_kernel_up_to_its_dimension(monkeypatch):
    from ssmobs.design import lcd_distance

    calls = []
    monkeypatch.setattr(lcd_native, "symmetric_distance", lambda *a: calls.append(a) or (0.0, None))
    q = lcd_distance.COMPILED_MAX_Q
    symmetric_distance(_half(q, 4, 1), 4, 2.0, gradient=False)
    assert len(calls) == 1
    symmetric_distance(_half(q + 1, 4, 1), 4, 2.0, gradient=False)  # NumPy above
    assert len(calls) == 1
    with pytest.raises(ValueError, match="kernel must be one of"):
        symmetric_distance(_half(2, 4, 1), 4, 2.0, gradient=False, kernel="fast")


def test_missing_compiler_is_one_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("CXX", str(tmp_path / "no-such-compiler"))
    with pytest.raises(lcd_native.LcdKernelUnavailable, match="needs a C\\+\\+ compiler"):
        lcd_native.build(tmp_path)


def test_the_kernel_source_and_flags_key_the_design_sets():
    from ssmobs.stage_code import code_digest

    code = code_digest("design")
    assert "design/lcd_kernel/lcd_kernel.cpp" in code and "design/lcd_native.py" in code
    assert lcd_native.build_key() != lcd_native.build_key(lcd_native.CXXFLAGS + ("-g",))
    # each build its own cache entry; both flag sets sit in lcd_native.py, part of the key
    keys = {lcd_native.build_key(flags) for flags in lcd_native.BUILDS.values()}
    assert len(keys) == len(lcd_native.BUILDS) == 3


def _bytes_of(lib, q: int, K: int, b: float, seed: int, zero_rows: int) -> bytes:
    s = _half(q, K, seed, zero_rows=min(zero_rows, K // 2))
    quad = _quadrature(q, b, 80)
    rule = (quad.lam, quad.sig, quad.alpha, quad.beta, quad.d1p, quad.j0p)
    v, g = lcd_native.symmetric_distance(s, K, b, rule, True, lib=lib)
    v_only, _ = lcd_native.symmetric_distance(s, K, b, rule, False, lib=lib)
    return np.float64(v).tobytes() + g.tobytes() + np.float64(v_only).tobytes()


@pytest.mark.parametrize(
    "name",
    [
        pytest.param(
            name,
            marks=pytest.mark.skipif(
                not lcd_native.runs(name),
                reason=f"this CPU has no {lcd_native.BUILD_CPU_FLAG[name]}",
            ),
        )
        for name in lcd_native.BUILDS
        if name != "x86-64"
    ],
)
def test_each_vector_build_gives_the_bits_of_the_baseline_build(name):
    """Each vector build (-mavx2: four lanes; -mavx512f: eight; no FMA) against the
    baseline (SSE2, two lanes) on random sets, q = 1..48 (q = 8 takes its own gradient
    loop, q <= 32 and q > 32 two loop orders), odd and even K, widths with arguments above 1
    (continued fraction) and points at the origin: the same bytes of value and gradient,
    and of log, exp, expm1, E1 and psi on arguments over the whole range."""
    base = lcd_native.kernel_of("x86-64")
    vec = lcd_native.kernel_of(name)
    assert lcd_native.BUILDS[name] != lcd_native.BUILDS["x86-64"]
    assert not any("fma" in f or "march" in f for f in lcd_native.BUILDS[name])
    rng = np.random.default_rng(48)
    cases = 0
    for q in range(1, 49):
        K = int(rng.integers(2, 90)) if q > 8 else int(rng.integers(2, 300))
        b = b_max_rule(q) * float(rng.choice([1.0, 0.3, 0.05]))  # small widths: c > 1
        zero_rows = int(rng.integers(0, 3))
        got = _bytes_of(vec, q, K, b, seed=q, zero_rows=zero_rows)
        assert got == _bytes_of(base, q, K, b, seed=q, zero_rows=zero_rows), (q, K, b)
        cases += 1
    for q, K, b in [(8, 1000, b_max_rule(8)), (8, 999, 2.0), (40, 301, 0.7), (48, 257, None),
                    (200, 101, None)]:  # fmt: skip
        bb = b_max_rule(q) if b is None else b
        assert _bytes_of(vec, q, K, bb, 1, 0) == _bytes_of(base, q, K, bb, 1, 0), (q, K)
        cases += 1
    assert cases == 53
    x = np.concatenate([np.exp(rng.uniform(-745, 709, 4000)), [5e-324, 1e-310, 1.0, 2.0]])
    for function, arg in [("log", x), ("exp", rng.uniform(-760, 720, 4000)),
                          ("expm1", rng.uniform(-40, 40, 4000))]:  # fmt: skip
        a = lcd_native.elementwise(arg, function, lib=vec)
        assert a.tobytes() == lcd_native.elementwise(arg, function, lib=base).tobytes(), function
    c = np.concatenate([rng.uniform(0, 2, 4000), rng.exponential(20, 1000), [0.0, 1.0]])
    e_a, p_a = lcd_native.e1_psi(c, lib=vec)
    e_b, p_b = lcd_native.e1_psi(c, lib=base)
    assert e_a.tobytes() == e_b.tobytes() and p_a.tobytes() == p_b.tobytes()


def test_the_series_terms_by_thresholds_are_those_of_the_rule():
    """The pair loop picks a row's number of E1 series terms by thresholds found once; they
    give the number of the rule (first omitted term <= 1e-17, by products) on every
    argument, also at each change of the number and one double either side of it."""
    rng = np.random.default_rng(17)
    c = np.concatenate([rng.uniform(0, 1, 20000), np.exp(rng.uniform(-40, 0, 20000)),
                        [0.0, 5e-324, 1e-300, 0.5, 1.0]])  # fmt: skip
    reference, fast = lcd_native.series_terms(c)
    assert set(reference) >= {1, 5, 10, 15}  # the arguments span many numbers of terms
    # where the number changes: bisect each change on the sorted grid down to adjacent doubles
    order = np.sort(c)
    ref_sorted, _ = lcd_native.series_terms(order)
    edges = []
    for k in np.flatnonzero(np.diff(ref_sorted)):
        lo, hi = order[k], order[k + 1]
        for _ in range(80):
            mid = lo + (hi - lo) / 2
            if mid in (lo, hi):
                break
            r_mid, _ = lcd_native.series_terms(np.array([mid]))
            lo, hi = (mid, hi) if r_mid[0] == ref_sorted[k] else (lo, mid)
        edges += [np.nextafter(lo, 0.0), lo, hi, np.nextafter(hi, 2.0)]
    assert len(edges) >= 4 * 10
    ref_e, fast_e = lcd_native.series_terms(np.array(edges))
    assert np.array_equal(reference, fast) and np.array_equal(ref_e, fast_e)
    assert len(set(ref_e)) > 10


def test_the_build_follows_the_cpu_unless_forced(monkeypatch):
    monkeypatch.delenv(lcd_native.BUILD_ENV, raising=False)
    flags = lcd_native.cpu_flags()
    auto = (
        "x86-64-avx512" if "avx512f" in flags else ("x86-64-avx2" if "avx2" in flags else "x86-64")
    )
    assert lcd_native.chosen_build() == auto
    monkeypatch.setenv(lcd_native.BUILD_ENV, "auto")
    assert lcd_native.chosen_build() == auto
    monkeypatch.setenv(lcd_native.BUILD_ENV, "x86-64")
    assert lcd_native.chosen_build() == "x86-64"
    monkeypatch.setenv(lcd_native.BUILD_ENV, "avx512")
    with pytest.raises(ValueError, match="SSMOBS_LCD_BUILD must be auto or one of"):
        lcd_native.chosen_build()
    # a CPU without AVX-512 (or AVX2): auto falls back, forcing the build is a clear error
    monkeypatch.setattr(lcd_native, "cpu_flags", lambda: frozenset({"sse2", "avx2"}))
    monkeypatch.setenv(lcd_native.BUILD_ENV, "auto")
    assert lcd_native.chosen_build() == "x86-64-avx2"
    monkeypatch.setenv(lcd_native.BUILD_ENV, "x86-64-avx512")
    with pytest.raises(ValueError, match="this CPU has no avx512f"):
        lcd_native.chosen_build()
    monkeypatch.setattr(lcd_native, "cpu_flags", lambda: frozenset())
    monkeypatch.setenv(lcd_native.BUILD_ENV, "auto")
    assert lcd_native.chosen_build() == "x86-64"
