#!/usr/bin/env python3
"""Generates src/sh/sh_fast_product_L.inc: straight-line SH code over lane vectors for the fast
shading kernel (src/shade/shade_fast.c, via shade_fast_ops.inc), one set per band count 3..6: the
SH products, and the real SH basis and Legendre polynomials evaluated as polynomials (below).

The product c = a * b, c_k = sum_ij Gamma_ijk a_i b_j, is sparse (353 ordered non-zero entries of
16^3 at 4 bands). A loop over a table of entries spends most of its instructions on indices and
loads; written out with the values as constants, each entry is one fused multiply-add on a lane
vector, and the compiler keeps the partial sums in registers. Terms are grouped by output k, then
by the index i of `a`: c_k = sum_i a_i (sum_j Gamma_ijk b_j), one multiply per (k, i) group and one
FMA per entry.

Variants (the fast kernel needs each):
  fp_prod_L(a, b, c)    full product (the exponential's backward through a squaring); up to 4
                        bands written by pairs: Gamma is symmetric in i, j, so
                        c_k = sum_{i <= j} Gamma_ijk (a_i b_j + a_j b_i) forms each pair's sum once
                        and adds it into every output it reaches
  fp_prod_h_L(a, h, c)  h is the clamped cosine rotated to the normal: its bands 3, 5 are exactly
                        zero (the clamped cosine has no odd bands above 1), so they are skipped
  fp_prod_oh_L(a, b, c) only the outputs in the clamped cosine's bands (the d_H of V * H; the other
                        outputs are left unwritten)
  fp_square_L(a, c)     c = a * a: Gamma is symmetric in i, j, so the pairs i < j are summed once
                        with weight 2 (the squarings of the exponential)

Besides the products, the basis and the cap, written out per band count (no loops over l, m, and
the Legendre recurrences folded into polynomial coefficients, Horner in z^2 or c^2):
  fp_basis_L(x, y, z, Y)           Y_k at the unit direction (x, y, z), all L^2 of them (for the
                                   clamped cosine rotated to the normal)
  fp_basis_acc_L(x, y, z, su, F)   F_k += su_l Y_k(x, y, z), su one factor per band (a sphere's
                                   log-visibility added into the sum)
  fp_basis_contract_L(x, y, z, w, u, A, g)
                                   A_l = sum over band l of w_k Y_k, and g the gradient in
                                   (x, y, z) of sum_k u_l w_k Y_k (the backwards of the two above,
                                   in one pass over the basis)
  fp_cap_L(c, ce, u)               u_l = ce_l (P_{l-1}(c) - P_{l+1}(c)), P_{-1} = 1: a cap's
                                   per-band log-visibility factor at cos(half-angle) c
  fp_legendre_L(c, P)              P_l(c) for l < L (the cap's backward: du_l/dc is
                                   proportional to P_l(c))

The Gaunt values come from scripts/sh_common.py, the one definition of the product tensor (the
library's table in src/sh/tables.c is generated from it too), and are written as float literals;
the basis uses the same real SH (Condon-Shortley phase, index l^2 + l + m).
The includer defines FP_VF (the lane vector type), FP_MUL(a, b), FP_FMA(a, b, c) = a * b + c and
FP_K(x) (a float constant broadcast to a lane vector).

Usage: python3 scripts/gen_sh_fast.py L > src/sh/sh_fast_product_L.inc   (L = 3, 4, 5 or 6)

One file per band count keeps each generated file readable (the 4-band product alone is some
500 lines); src/shade/shade_fast.c includes all four.
"""
import math
import sys
from fractions import Fraction

sys.dont_write_bytecode = True  # no __pycache__ in the source tree
from sh_common import band, gaunt, sh_K  # noqa: E402

BANDS = range(3, 7)


def h_band(l):
    """Bands in which the clamped cosine is non-zero: 0, 1 and the even ones."""
    return l <= 1 or l % 2 == 0


def lit(v):
    return "FP_K(%sf)" % ("%.9g" % v if "e" in "%.9g" % v or "." in "%.9g" % v else "%.9g.0" % v)


def emit_groups(name, groups, n, out_ok, stats):
    """groups[k] = list of (i, [(j, value)]) -> c[k] = sum_i a_i sum_j value b_j."""
    lines = []
    entries = 0
    ops = 0
    for k in range(n):
        if not out_ok(k):
            continue
        gs = groups.get(k, [])
        if not gs:
            lines.append("    c[%d] = FP_K(0.0f);" % k)
            continue
        acc = None
        for i, terms in gs:
            s = None
            for j, v in terms:
                s = "FP_MUL(%s, %s)" % (j, lit(v)) if s is None else "FP_FMA(%s, %s, %s)" % (j, lit(v), s)
                entries += 1
                ops += 1
            acc = "FP_MUL(%s, %s)" % (i, s) if acc is None else "FP_FMA(%s, %s, %s)" % (i, s, acc)
            ops += 1
        lines.append("    c[%d] = %s;" % (k, acc))
    stats[name] = (entries, ops)
    return lines


def emit_pairs(name, G, n, square, stats):
    """c_k = sum over unordered pairs i <= j of Gamma_ijk s_ij, s_ij = a_i b_j + a_j b_i (a_i b_i on
    the diagonal; for a square 2 a_i a_j): Gamma is symmetric in i, j, so each pair's product is
    formed once and added into every output it reaches (the accumulators stay in registers)."""
    by_pair = {}
    for (i, j, k), v in sorted(G.items()):
        if i <= j:
            by_pair.setdefault((i, j), []).append((k, v if (i == j or not square) else 2 * v))
    lines = []
    started = set()
    entries = ops = 0
    for k in range(n):
        lines.append("    FP_VF c%d;" % k)
    for (i, j), terms in sorted(by_pair.items()):
        if i == j:
            pe = "FP_MUL(a[%d], %s[%d])" % (i, "a" if square else "b", i)
            ops += 1
        elif square:
            pe = "FP_MUL(a[%d], a[%d])" % (i, j)
            ops += 1
        else:
            pe = "FP_FMA(a[%d], b[%d], FP_MUL(a[%d], b[%d]))" % (i, j, j, i)
            ops += 2
        lines.append("    { const FP_VF s = %s;" % pe)
        for k, v in terms:
            if k in started:
                lines.append("      c%d = FP_FMA(s, %s, c%d);" % (k, lit(v), k))
            else:
                lines.append("      c%d = FP_MUL(s, %s);" % (k, lit(v)))
                started.add(k)
            entries += 1
            ops += 1
        lines.append("    }")
    for k in range(n):
        lines.append("    c[%d] = %s;" % (k, "c%d" % k if k in started else "FP_K(0.0f)"))
    stats[name] = (entries, ops)
    return lines


def product_groups(G, n, keep):
    groups = {}
    for k in range(n):
        by_i = {}
        for (i, j, kk), v in sorted(G.items()):
            if kk != k or not keep(i, j, k):
                continue
            by_i.setdefault(i, []).append(("b[%d]" % j, v))
        groups[k] = [("a[%d]" % i, t) for i, t in sorted(by_i.items())]
    return groups


def square_groups(G, n):
    groups = {}
    for k in range(n):
        by_i = {}
        for (i, j, kk), v in sorted(G.items()):
            if kk != k or j < i:
                continue
            by_i.setdefault(i, []).append(("a[%d]" % j, v if i == j else 2 * v))
        groups[k] = [("a[%d]" % i, t) for i, t in sorted(by_i.items())]
    return groups


def q_polys(L):
    """Q_l^m(z) as coefficient lists (Fractions, lowest degree first): the associated Legendre
    function without its (1 - z^2)^(m/2) factor, Condon-Shortley phase included (sh_ops.inc)."""
    Q = {}
    for m in range(L):
        qmm = Fraction(1)
        for i in range(1, m + 1):
            qmm *= -(2 * i - 1)
        Q[(m, m)] = [qmm]
        if m + 1 < L:
            Q[(m + 1, m)] = [Fraction(0), (2 * m + 1) * qmm]
        for l in range(m + 2, L):
            a, b = Q[(l - 1, m)], Q[(l - 2, m)]
            c = [Fraction(0)] * (l - m + 1)
            for p, v in enumerate(a):
                c[p + 1] += Fraction(2 * l - 1, l - m) * v
            for p, v in enumerate(b):
                c[p] -= Fraction(l + m - 1, l - m) * v
            Q[(l, m)] = c
    return Q


def horner(coef, scale, z, z2):
    """Expression for scale * sum coef[p] z^p (one parity only), Horner in z^2."""
    nz = [(p, float(v) * scale) for p, v in enumerate(coef) if v != 0]
    if not nz:
        return "FP_K(0.0f)"
    odd = nz[0][0] % 2
    terms = {p // 2: v for p, v in nz}
    top = max(terms)
    e = lit(terms[top])
    for q in range(top - 1, -1, -1):
        e = "FP_FMA(%s, %s, %s)" % (z2, e, lit(terms.get(q, 0.0)))
    return "FP_MUL(%s, %s)" % (z, e) if odd else e


def emit_cs(L, lines):
    """C_m = Re (x + i y)^m, S_m = Im (x + i y)^m for 1 <= m < L."""
    if L > 1:
        lines.append("    const FP_VF C1 = x, S1 = y;")
    for m in range(2, L):
        lines.append("    const FP_VF C%d = FP_FMA(x, C%d, -FP_MUL(y, S%d)), S%d = FP_FMA(x, S%d, FP_MUL(y, C%d));"
                     % (m, m - 1, m - 1, m, m - 1, m - 1))


def emit_basis(L):
    Q = q_polys(L)
    lines = ["    const FP_VF z2 = FP_MUL(z, z);"]
    emit_cs(L, lines)
    for m in range(L):
        for l in range(m, L):
            ks = sh_K(l, m) * (math.sqrt(2.0) if m else 1.0)
            p = horner(Q[(l, m)], ks, "z", "z2")
            if m == 0:
                lines.append("    Y[%d] = %s;" % (l * l + l, p))
            else:
                lines.append("    { const FP_VF p = %s; Y[%d] = FP_MUL(p, C%d); Y[%d] = FP_MUL(p, S%d); }"
                             % (p, l * l + l + m, m, l * l + l - m, m))
    return lines


def emit_accumulate(L):
    """F_k += su_l Y_k(x, y, z): the per-band scale goes into the z-polynomial before the
    azimuthal factor, so a pair (l, +-m) costs one multiply and two FMAs."""
    Q = q_polys(L)
    lines = ["    const FP_VF z2 = FP_MUL(z, z);", "    (void)z2;"]
    emit_cs(L, lines)
    for m in range(L):
        for l in range(m, L):
            ks = sh_K(l, m) * (math.sqrt(2.0) if m else 1.0)
            p = horner(Q[(l, m)], ks, "z", "z2")
            i0 = l * l + l
            if m == 0:
                lines.append("    F[%d] = FP_FMA(su[%d], %s, F[%d]);" % (i0, l, p, i0))
            else:
                lines.append("    { const FP_VF ps = FP_MUL(su[%d], %s);" % (l, p))
                lines.append("      F[%d] = FP_FMA(ps, C%d, F[%d]); F[%d] = FP_FMA(ps, S%d, F[%d]); }"
                             % (i0 + m, m, i0 + m, i0 - m, m, i0 - m))
    return lines


def emit_contract(L):
    """A[l] = sum_{k in band l} w_k Y_k(x, y, z); g = gradient of sum_k u_l w_k Y_k."""
    Q = q_polys(L)
    lines = ["    const FP_VF z2 = FP_MUL(z, z);"]
    emit_cs(L, lines)
    lines.append("    FP_VF gz = FP_K(0.0f);")
    for l in range(L):
        lines.append("    FP_VF A%d = FP_K(0.0f);" % l)
    for m in range(L):
        if m:
            lines.append("    FP_VF al%d = FP_K(0.0f), be%d = FP_K(0.0f);" % (m, m))
            if m + 1 < L:  # Q_m^m is constant: band m alone has no z-derivative
                lines.append("    FP_VF dal%d = FP_K(0.0f), dbe%d = FP_K(0.0f);" % (m, m))
        for l in range(m, L):
            ks = sh_K(l, m) * (math.sqrt(2.0) if m else 1.0)
            q = Q[(l, m)]
            dq = [p * v for p, v in enumerate(q)][1:]
            p = horner(q, ks, "z", "z2")
            dp = horner(dq, ks, "z", "z2") if any(v != 0 for v in dq) else None
            i0 = l * l + l
            if m == 0:
                lines.append("    { const FP_VF p = %s; A%d = FP_FMA(w[%d], p, A%d);" % (p, l, i0, l))
                if dp:
                    lines.append("      gz = FP_FMA(FP_MUL(w[%d], u[%d]), %s, gz); }" % (i0, l, dp))
                else:
                    lines.append("    }")
                continue
            ip, im = i0 + m, i0 - m
            lines.append("    { const FP_VF p = %s;" % p)
            lines.append("      A%d = FP_FMA(p, FP_FMA(w[%d], C%d, FP_MUL(w[%d], S%d)), A%d);"
                         % (l, ip, m, im, m, l))
            lines.append("      const FP_VF pu = FP_MUL(p, u[%d]);" % l)
            lines.append("      al%d = FP_FMA(pu, w[%d], al%d); be%d = FP_FMA(pu, w[%d], be%d);"
                         % (m, ip, m, m, im, m))
            if dp:
                lines.append("      const FP_VF dpu = FP_MUL(%s, u[%d]);" % (dp, l))
                lines.append("      dal%d = FP_FMA(dpu, w[%d], dal%d); dbe%d = FP_FMA(dpu, w[%d], dbe%d);"
                             % (m, ip, m, m, im, m))
            lines.append("    }")
    # dC_m/dx = m C_{m-1}, dC_m/dy = -m S_{m-1}, dS_m/dx = m S_{m-1}, dS_m/dy = m C_{m-1}
    gx, gy = [], []
    for m in range(1, L):
        cm1 = "C%d" % (m - 1) if m > 1 else "FP_K(1.0f)"
        sm1 = "S%d" % (m - 1) if m > 1 else None
        if m == 1:
            gx.append("al1")
            gy.append("be1")
        else:
            gx.append("FP_MUL(FP_K(%d.0f), FP_FMA(al%d, %s, FP_MUL(be%d, %s)))" % (m, m, cm1, m, sm1))
            gy.append("FP_MUL(FP_K(%d.0f), FP_FMA(be%d, %s, -FP_MUL(al%d, %s)))" % (m, m, cm1, m, sm1))
        if m + 1 < L:
            lines.append("    gz = FP_FMA(dal%d, C%d, FP_FMA(dbe%d, S%d, gz));" % (m, m, m, m))
    lines.append("    g[0] = %s;" % (" + ".join(gx) if gx else "FP_K(0.0f)"))
    lines.append("    g[1] = %s;" % (" + ".join(gy) if gy else "FP_K(0.0f)"))
    lines.append("    g[2] = gz;")
    for l in range(L):
        lines.append("    A[%d] = A%d;" % (l, l))
    return lines


def legendre_polys(L):
    """P_0 .. P_L as coefficient lists (Fractions, lowest degree first)."""
    P = [[Fraction(1)], [Fraction(0), Fraction(1)]]
    for l in range(1, L):
        a, b = P[l], P[l - 1]
        c = [Fraction(0)] * (l + 2)
        for p, v in enumerate(a):
            c[p + 1] += Fraction(2 * l + 1, l + 1) * v
        for p, v in enumerate(b):
            c[p] -= Fraction(l, l + 1) * v
        P.append(c)
    return P


def poly_expr(coef, c, c2):
    """Expression of sum coef[p] c^p for a polynomial of one parity (or degree <= 1)."""
    nz = [p for p, v in enumerate(coef) if v != 0]
    if len(nz) == 2 and nz == [0, 1]:  # 1 - c and the like
        return "FP_FMA(%s, %s, %s)" % (c, lit(float(coef[1])), lit(float(coef[0])))
    return horner(coef, 1.0, c, c2)


def emit_cap(L):
    """u[l] = ce[l] (P_{l-1}(c) - P_{l+1}(c)), P_{-1} = 1: the cap's log-visibility per band
    before its weight (ce[l] = -eps 2 pi / (2l+1) from the frame), written out per band."""
    P = legendre_polys(L)
    lines = ["    const FP_VF c2 = FP_MUL(c, c);", "    (void)c2;"]
    for l in range(L):
        prev = [Fraction(1)] if l == 0 else P[l - 1]
        d = [Fraction(0)] * (l + 2)
        for p, v in enumerate(prev):
            d[p] += v
        for p, v in enumerate(P[l + 1]):
            d[p] -= v
        lines.append("    u[%d] = FP_MUL(ce[%d], %s);" % (l, l, poly_expr(d, "c", "c2")))
    return lines


def emit_legendre(L):
    """P[l] = P_l(c) for l < L."""
    P = legendre_polys(L)
    lines = ["    const FP_VF c2 = FP_MUL(c, c);", "    (void)c2;", "    P[0] = FP_K(1.0f);"]
    for l in range(1, L):
        lines.append("    P[%d] = %s;" % (l, "c" if l == 1 else poly_expr(P[l], "c", "c2")))
    return lines


def main():
    if len(sys.argv) != 2 or not sys.argv[1].isdigit() or int(sys.argv[1]) not in BANDS:
        sys.exit("usage: gen_sh_fast.py L   (L in %d..%d: the band count to generate)"
                 % (BANDS[0], BANDS[-1]))
    L = int(sys.argv[1])
    out = sys.stdout
    out.write("/* Generated by scripts/gen_sh_fast.py %d; do not edit. Straight-line SH code for %d bands\n"
              " * over lane vectors for src/shade/shade_fast.c (see the script for the variants and the\n"
              " * grouping). Gaunt values from scripts/sh_common.py (as src/sh/tables.c), as float\n"
              " * literals. */\n\n" % (L, L))
    n = L * L
    G = gaunt(L)
    stats = {}
    hk = lambda idx: h_band(band(idx))
    prod_g = emit_groups("prod_groups", product_groups(G, n, lambda i, j, k: True), n,
                         lambda k: True, stats)
    prod_p = emit_pairs("prod_pairs", G, n, False, stats)
    sq_g = emit_groups("square_groups", square_groups(G, n), n, lambda k: True, stats)
    sq_p = emit_pairs("square_pairs", G, n, True, stats)
    bodies = [
        # By pairs while the n outputs fit in the 32 vector registers (4 bands): 27% fewer
        # operations; at 5 and 6 bands the pairs' scattered updates spill (measured slower).
        ("fp_prod_%d" % L, "const FP_VF *a, const FP_VF *b, FP_VF *c", prod_p if n <= 16 else prod_g),
        ("fp_prod_h_%d" % L, "const FP_VF *a, const FP_VF *b, FP_VF *c",
         emit_groups("prod_h", product_groups(G, n, lambda i, j, k: hk(j)), n, lambda k: True, stats)),
        ("fp_prod_oh_%d" % L, "const FP_VF *a, const FP_VF *b, FP_VF *c",
         emit_groups("prod_oh", product_groups(G, n, lambda i, j, k: True), n, hk, stats)),
        # By groups although pairs take ~9% fewer operations: measured slower (bench/NOTES.md).
        ("fp_square_%d" % L, "const FP_VF *a, FP_VF *c", sq_g),
    ]
    bodies += [
        ("fp_basis_%d" % L, "FP_VF x, FP_VF y, FP_VF z, FP_VF *Y", emit_basis(L)),
        ("fp_basis_acc_%d" % L, "FP_VF x, FP_VF y, FP_VF z, const FP_VF *su, FP_VF *F",
         emit_accumulate(L)),
        ("fp_basis_contract_%d" % L,
         "FP_VF x, FP_VF y, FP_VF z, const FP_VF *w, const FP_VF *u, FP_VF *A, FP_VF *g",
         emit_contract(L)),
        ("fp_cap_%d" % L, "FP_VF c, const FP_VF *ce, FP_VF *u", emit_cap(L)),
        ("fp_legendre_%d" % L, "FP_VF c, FP_VF *P", emit_legendre(L)),
    ]
    out.write("/* ---- %d bands: %d ordered Gaunt entries ---- */\n\n" % (L, len(G)))
    for name, args, lines in bodies:
        out.write("static inline void %s(%s) {\n" % (name, args))
        out.write("\n".join(lines) + "\n}\n\n")
    out.write("/* Vector operations per product (entries / multiply-adds incl. one per (k, i) group):\n")
    out.write(" *   %d bands (%d entries): %s\n" % (
        L, len(G), ", ".join("%s %d/%d" % (k, v[0], v[1]) for k, v in stats.items())))
    out.write(" */\n")


if __name__ == "__main__":
    main()
