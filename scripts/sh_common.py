"""The SH definitions the code generators share (imported by gen_sh_tables.py and gen_sh_fast.py;
not a script). Standard library only, so that Debian's /usr/bin/python3 runs it as is.

This module is the one source of truth for the SH product tensor Gamma_ijk = integral over the
sphere of Y_i Y_j Y_k (real SH, Condon-Shortley phase, index l^2 + l + m; the recurrence of
src/sh/sh_ops.inc). gen_sh_tables.py writes it into src/sh/tables.c, which is what the library
uses at run time (src/sh/gaunt.c only expands and sorts it); gen_sh_fast.py writes the same values
as float literals into src/sh/sh_fast_product_L.inc. tests/test_sh.c checks the table against an
independent quadrature in C.

Gamma does not depend on the band count: the table for L bands is the part of the PEN_SH_MAX_BANDS
table with i, j, k < L^2. It is integrated once, at MAX_BANDS, in double by a quadrature that is
exact for the integrand (a polynomial of degree <= 3(L-1) in x, y, z): Gauss-Legendre in
cos(theta) with 2L nodes x a uniform phi grid of 4L points. Triples that the selection rules make
zero are skipped without integrating (they would integrate to rounding noise), and values below
1e-12 in magnitude are dropped.
"""
import math

MAX_BANDS = 8  # PEN_SH_MAX_BANDS


def sh_K(l, m):
    """K_lm = sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!)."""
    return math.sqrt((2 * l + 1) / (4 * math.pi) * math.factorial(l - m) / math.factorial(l + m))


def sh_eval(L, d):
    """Real SH of direction d (unit), all L^2 of them, by the recurrence of src/sh/sh_ops.inc."""
    x, y, z = d
    C = [1.0] + [0.0] * L
    S = [0.0] * (L + 1)
    for m in range(1, L):
        C[m] = x * C[m - 1] - y * S[m - 1]
        S[m] = x * S[m - 1] + y * C[m - 1]
    out = [0.0] * (L * L)
    qmm = 1.0
    for m in range(L):
        if m > 0:
            qmm *= -(2 * m - 1)
        q_prev, q = 0.0, qmm
        for l in range(m, L):
            if l == m + 1:
                q_prev, q = q, (2 * m + 1) * z * qmm
            elif l > m + 1:
                q_prev, q = q, ((2 * l - 1) * z * q - (l + m - 1) * q_prev) / (l - m)
            k = sh_K(l, m)
            if m == 0:
                out[l * l + l] = k * q
            else:
                ks = k * math.sqrt(2.0)
                out[l * l + l + m] = ks * q * C[m]
                out[l * l + l - m] = ks * q * S[m]
    return out


def gauss_legendre(n):
    """Nodes and weights of n-point Gauss-Legendre on [-1, 1] (Newton's method on P_n)."""
    xs, ws = [], []
    for i in range(n):
        t = math.cos(math.pi * (i + 0.75) / (n + 0.5))
        for _ in range(100):
            p0, p1 = 1.0, t
            for l in range(1, n):
                p0, p1 = p1, ((2 * l + 1) * t * p1 - l * p0) / (l + 1)
            dp = n * (t * p1 - p0) / (t * t - 1)
            dt = p1 / dp
            t -= dt
            if abs(dt) < 1e-16:
                break
        p0, p1 = 1.0, t
        for l in range(1, n):
            p0, p1 = p1, ((2 * l + 1) * t * p1 - l * p0) / (l + 1)
        dp = n * (t * p1 - p0) / (t * t - 1)
        xs.append(t)
        ws.append(2 / ((1 - t * t) * dp * dp))
    return xs, ws


def band(i):
    return math.isqrt(i)


def _l_m(i):
    l = math.isqrt(i)
    return l, i - l * l - l


def _may_be_nonzero(i, j, k):
    """Selection rules of real Gaunt coefficients (necessary conditions): l_i + l_j + l_k even and
    the triangle inequality; one |m| the sum of the other two; an even number of negative m (the
    negative ones are sin(|m| phi), and an odd count integrates to zero over phi)."""
    (a, ma), (b, mb), (c, mc) = _l_m(i), _l_m(j), _l_m(k)
    if (a + b + c) % 2 or c > a + b or c < abs(a - b):
        return False
    lo, mid, hi = sorted((abs(ma), abs(mb), abs(mc)))
    if hi != lo + mid:
        return False
    return sum(m < 0 for m in (ma, mb, mc)) % 2 == 0


_triples = None


def gaunt_triples():
    """[(i, j, k, Gamma_ijk)] for i <= j <= k < MAX_BANDS^2, the non-zero ones, sorted."""
    global _triples
    if _triples is None:
        L = MAX_BANDS
        n, nt, nph = L * L, 2 * L, 4 * L
        xs, ws = gauss_legendre(nt)
        pts = []
        for a in range(nt):
            z = xs[a]
            s = math.sqrt(max(0.0, 1 - z * z))
            for b in range(nph):
                phi = 2 * math.pi * (b + 0.5) / nph
                pts.append((ws[a] * 2 * math.pi / nph,
                            sh_eval(L, (s * math.cos(phi), s * math.sin(phi), z))))
        out = []
        for i in range(n):
            for j in range(i, n):
                for k in range(j, n):
                    if not _may_be_nonzero(i, j, k):
                        continue
                    v = sum(w * y[i] * y[j] * y[k] for w, y in pts)
                    if abs(v) >= 1e-12:
                        out.append((i, j, k, v))
        _triples = out
    return _triples


def gaunt(L):
    """{(i, j, k): Gamma_ijk} for all ordered non-zero entries at L bands."""
    n = L * L
    G = {}
    for i, j, k, v in gaunt_triples():
        if k >= n:
            continue
        for p in {(i, j, k), (i, k, j), (j, i, k), (j, k, i), (k, i, j), (k, j, i)}:
            G[p] = v
    return G
