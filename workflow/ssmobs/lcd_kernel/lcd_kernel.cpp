// The LCD distance of a point-symmetric set and its gradient, compiled (ssmobs.lcd_native).
//
// The same formulas as the NumPy reference ssmobs.lcd_distance._symmetric_distance_numpy
// (docs/lcd-design-disturbances.md, Sections 2.4 and 4), fused into one pass over the pairs
// of the half-set: Gram entry, E1 and psi of T- and T+, the psi sum, and the gradient terms
// ((E- - E+) S)_i and ((E- + E+) 1)_i, so that no N x N array is ever written.
//
// Same bits on any x86-64 CPU and with any compiler that follows IEEE 754 (no fast-math, no
// contraction of a*b+c into a fused multiply-add: -ffp-contract=off; the flags are fixed in
// ssmobs/lcd_native.py and are part of the cache key of the design sets):
// - every sum runs in one fixed order, written out below (no reduction is left to the
//   compiler, which may not reorder floating-point sums without -ffast-math);
// - log, exp and expm1 are our own (range reduction and Taylor polynomials, below): neither
//   the C library's nor NumPy's, whose last bits differ between versions and CPU kernels;
// - one thread.
// A vectorising compiler may run the element-wise loops on several lanes at once: each lane
// does the same IEEE operations in the same order, so the bits do not change (the test
// builds the kernel also without optimisation and compares the bits).

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

namespace {

const double EULER_GAMMA = 0.57721566490153286061;
// ln 2 split into a head with 24 significant bits (k * LN2_HEAD is exact for |k| < 2^29)
// and the rest, for the range reductions of log and exp
const double LN2_HEAD = 0x1.62e42fp-1;
const double LN2_TAIL = 0x1.df473de6af279p-26;
const double INV_LN2 = 0x1.71547652b82fep+0;
const double SQRT2 = 0x1.6a09e667f3bcdp+0;
const double HALF_LN2 = 0x1.62e42fefa39efp-2;
// rounds a double of magnitude < 2^51 to the nearest integer (ties to even) when added and
// subtracted again
const double ROUND_MAGIC = 0x1.8p52;
// E1 power series for c <= SERIES_MAX, continued fraction above (as the reference)
const double SERIES_MAX = 1.0;
const int MAX_TERMS = 30;
// rows (and columns) of one tile of the pair grid
const std::ptrdiff_t TILE = 32;

double from_bits(std::uint64_t b) {
    double x;
    std::memcpy(&x, &b, sizeof x);
    return x;
}

std::uint64_t to_bits(double x) {
    std::uint64_t b;
    std::memcpy(&b, &x, sizeof b);
    return b;
}

// 2^k for -1074 <= k <= 1023 (exact)
double pow2(int k) {
    if (k >= -1022) {
        return from_bits(static_cast<std::uint64_t>(k + 1023) << 52);
    }
    return from_bits(static_cast<std::uint64_t>(k + 1023 + 200) << 52) * 0x1p-200;
}

// Natural logarithm of a finite x > 0.  x = 2^e m with m in [sqrt(1/2), sqrt(2)); with
// f = m - 1 (exact) and s = f / (2 + f), log m = 2 atanh s = 2 (s + s^3/3 + s^5/5 + ...),
// |s| <= 0.1716, s^2 <= 0.0295: ten terms after s leave a relative remainder below 1e-18.
// Written without branches (selects only), so that a compiler may run it on vector lanes.
inline double ln(double x) {
    const bool sub = x < 0x1p-1022;  // subnormal: scale into the normal range first
    const double scaled = x * 0x1p54;
    x = sub ? scaled : x;
    const std::uint64_t b = to_bits(x);
    // the biased exponent as a double, exactly: 2^52 + field - 2^52
    const double field = from_bits((b >> 52) | 0x4330000000000000ULL) - 0x1p52;
    double m = from_bits((b & 0x000fffffffffffffULL) | 0x3ff0000000000000ULL);
    const bool big = m > SQRT2;
    const double halved = m * 0.5;
    m = big ? halved : m;
    const double e = (field - 1023.0) + ((sub ? -54.0 : 0.0) + (big ? 1.0 : 0.0));
    const double f = m - 1.0;
    const double s = f / (2.0 + f);
    const double z = s * s;
    double p = 1.0 / 21.0;
    p = p * z + 1.0 / 19.0;
    p = p * z + 1.0 / 17.0;
    p = p * z + 1.0 / 15.0;
    p = p * z + 1.0 / 13.0;
    p = p * z + 1.0 / 11.0;
    p = p * z + 1.0 / 9.0;
    p = p * z + 1.0 / 7.0;
    p = p * z + 1.0 / 5.0;
    p = p * z + 1.0 / 3.0;
    const double two_s = s + s;
    const double log_m = two_s + two_s * (z * p);
    return e * LN2_HEAD + (log_m + e * LN2_TAIL);
}

// exp(r) - 1 for |r| <= ln(2)/2 by its Taylor polynomial (degree 14: remainder < 1e-18 r)
double expm1_reduced(double r) {
    double p = 1.0 / 87178291200.0;  // 1/14!
    p = p * r + 1.0 / 6227020800.0;
    p = p * r + 1.0 / 479001600.0;
    p = p * r + 1.0 / 39916800.0;
    p = p * r + 1.0 / 3628800.0;
    p = p * r + 1.0 / 362880.0;
    p = p * r + 1.0 / 40320.0;
    p = p * r + 1.0 / 5040.0;
    p = p * r + 1.0 / 720.0;
    p = p * r + 1.0 / 120.0;
    p = p * r + 1.0 / 24.0;
    p = p * r + 1.0 / 6.0;
    p = p * r + 0.5;
    return r + (r * r) * p;
}

// exp(a): a = k ln 2 + r with |r| <= ln(2)/2, exp(a) = 2^k (1 + expm1(r))
double exp_of(double a) {
    if (a < -745.2) return 0.0;
    if (a > 709.79) return from_bits(0x7ff0000000000000ULL);  // +inf
    double kd = (a * INV_LN2 + ROUND_MAGIC) - ROUND_MAGIC;
    double r = (a - kd * LN2_HEAD) - kd * LN2_TAIL;
    double y = 1.0 + expm1_reduced(r);
    int k = static_cast<int>(kd);
    if (k < -1022) {  // the result is subnormal: scale in two steps
        return (y * pow2(k + 600)) * 0x1p-600;
    }
    return y * pow2(k);
}

// exp(a) - 1, accurate also near a = 0
double expm1_of(double a) {
    if (a > -HALF_LN2 && a < HALF_LN2) return expm1_reduced(a);
    return exp_of(a) - 1.0;
}

// E1(c) for c > SERIES_MAX: exp(-c) times the continued fraction
// 1/(c+1- 1^2/(c+3- 2^2/(c+5- ...))), evaluated forwards (modified Lentz method)
double e1_continued_fraction(double c) {
    const double tiny = 1e-300;
    double b = c + 1.0;
    double num = 1.0 / tiny;
    double den = 1.0 / b;
    double h = den;
    for (int i = 1; i <= 1000; ++i) {
        double a = -static_cast<double>(i) * static_cast<double>(i);
        b += 2.0;
        den = a * den + b;
        if (den == 0.0) den = tiny;
        num = b + a / num;
        if (num == 0.0) num = tiny;
        den = 1.0 / den;
        double step = num * den;
        h *= step;
        double dev = step - 1.0;
        if (dev < 0.0) dev = -dev;
        if (dev < 1e-16) break;
    }
    return h * exp_of(-c);
}

// Series coefficients: E1(c) = -gamma - ln c + S(c), S(c) = sum_i (-1)^(i+1) c^i / (i i!),
// and psi(c) / (4 B^2) = c E1(c) + 1 - exp(-c) = c (-gamma - ln c + Q(c)) with
// Q(c) = 1 + sum_i (-1)^(i+1) c^i / (i (i+1)!)  (the c^i terms of c S(c) + 1 - exp(-c)).
struct Series {
    double s[MAX_TERMS + 1];  // s[i] for i = 1..MAX_TERMS
    double q[MAX_TERMS + 1];
    Series() {
        double fact = 1.0;  // i!
        for (int i = 1; i <= MAX_TERMS; ++i) {
            fact *= static_cast<double>(i);
            double sign = (i % 2 == 1) ? 1.0 : -1.0;
            s[i] = sign / (static_cast<double>(i) * fact);
            q[i] = sign / (static_cast<double>(i) * (fact * static_cast<double>(i + 1)));
        }
        s[0] = 0.0;
        q[0] = 0.0;
    }
};

// The number of terms for an argument c <= 1: the first m whose first omitted term
// c^(m+1) / ((m+1) (m+1)!) is at most 1e-17 (the reference's rule), by products only
int terms_for(double c) {
    double power = c;  // c^(m+1) below
    double bound = 1e-17;  // 1e-17 (m+1) (m+1)! below
    double fact = 1.0;
    for (int m = 1; m < MAX_TERMS; ++m) {
        power *= c;
        fact *= static_cast<double>(m + 1);
        if (power <= bound * (static_cast<double>(m + 1) * fact)) return m;
    }
    return MAX_TERMS;
}

struct Pair {
    double e1;   // E1(c) (0 at c <= 0)
    double psi;  // psi(T) / (4 B^2) (0 at c <= 0)
};

// E1 and psi of one argument by the series with m terms (c <= SERIES_MAX) or the
// continued fraction
Pair e1_psi(double c, int m, const Series& ser) {
    Pair out;
    if (!(c > 0.0)) {
        out.e1 = 0.0;
        out.psi = 0.0;
        return out;
    }
    if (c > SERIES_MAX) {
        double e = e1_continued_fraction(c);
        out.e1 = e;
        out.psi = c * e - expm1_of(-c);
        return out;
    }
    double ps = ser.s[m];
    double pq = ser.q[m];
    for (int i = m - 1; i >= 1; --i) {
        ps = ps * c + ser.s[i];
        pq = pq * c + ser.q[i];
    }
    ps *= c;
    pq = pq * c + 1.0;
    double base = -EULER_GAMMA - ln(c);
    out.e1 = base + ps;
    out.psi = c * (base + pq);
    return out;
}

}  // namespace

extern "C" {

// Squared norms n_i = |s_i|^2 (coordinates ascending) and the quadrature sums of J' and M
// (doc 2.4, 4): for each i and node l, a = lam_l - (0.5 n_i) sig_l,
// jp_i = sum_l expm1(a) alpha_l,  m_i = sum_l exp(a) beta_l  (l ascending).
void ssmobs_lcd_quadrature(const double* s, std::ptrdiff_t n, std::ptrdiff_t q,
                           const double* lam, const double* sig, const double* alpha,
                           const double* beta, std::ptrdiff_t n_nodes, double* norms,
                           double* jp, double* mm) {
    for (std::ptrdiff_t i = 0; i < n; ++i) {
        const double* si = &s[i * q];
        double nrm = si[0] * si[0];
        for (std::ptrdiff_t k = 1; k < q; ++k) nrm = nrm + si[k] * si[k];
        norms[i] = nrm;
        const double half_n = 0.5 * nrm;
        double sj = 0.0;
        double sm = 0.0;
        for (std::ptrdiff_t l = 0; l < n_nodes; ++l) {
            const double a = lam[l] - half_n * sig[l];
            const double ea = exp_of(a);
            const double em1 = (a > -HALF_LN2 && a < HALF_LN2) ? expm1_reduced(a) : ea - 1.0;
            sj = sj + em1 * alpha[l];
            sm = sm + ea * beta[l];
        }
        jp[i] = sj;
        mm[i] = sm;
    }
}

// The pair terms of the point-symmetric set {s_i} U {-s_i} (doc 2.4, 4).  Inputs: the
// half-set ``s`` (n x q, rows), ``cn`` = |s_i|^2 / (4 B^2), ``inv4b2`` = 1 / (4 B^2).
// Outputs:
// - ``psi_out[0]``: sum over ordered pairs (i, j) of [psi(T-_ij) + psi(T+_ij)] / (4 B^2),
//   with T-_ii := 0;
// - with ``want_grad``: ``gpair`` (n x q) = ((E- - E+) S) and ``rsum`` (n) = ((E- + E+) 1)
//   (overwritten), E-_ii := 0.
// Order: tiles of TILE x TILE pairs, row tiles ascending, column tiles from the diagonal on
// ascending; within a tile rows, then columns ascending; the Gram entry sums over the
// coordinates in ascending order; the psi sum of a tile row by row, added to the total tile
// by tile; gpair_i and rsum_i over the columns j ascending, then (pairs j > i) gpair_j and
// rsum_j over the rows i ascending.  The series of a row of a tile has the terms its own
// largest argument needs (terms_for).
void ssmobs_lcd_pairs(const double* s, std::ptrdiff_t n, std::ptrdiff_t q, const double* cn,
                      double inv4b2, int want_grad, double* psi_out, double* gpair,
                      double* rsum) {
    static const Series ser;
    const double two_inv4b2 = 2.0 * inv4b2;
    const std::size_t tt = static_cast<std::size_t>(TILE * TILE);
    std::vector<double> gram(tt), dif(tt), sum(tt);
    std::vector<double> st(static_cast<std::size_t>(TILE * q));  // column tile, transposed
    // one row of a tile: arguments c- (first nj) and c+ (next nj), and their terms
    std::vector<double> c(2 * TILE), base(2 * TILE), ps(2 * TILE), pq(2 * TILE);
    std::vector<double> e1(2 * TILE), psi(2 * TILE);
    if (want_grad) {
        for (std::ptrdiff_t i = 0; i < n * q; ++i) gpair[i] = 0.0;
        for (std::ptrdiff_t i = 0; i < n; ++i) rsum[i] = 0.0;
    }
    double psi_total = 0.0;
    for (std::ptrdiff_t i0 = 0; i0 < n; i0 += TILE) {
        const std::ptrdiff_t ni = (n - i0 < TILE) ? n - i0 : TILE;
        for (std::ptrdiff_t j0 = i0; j0 < n; j0 += TILE) {
            const std::ptrdiff_t nj = (n - j0 < TILE) ? n - j0 : TILE;
            const bool diag = (i0 == j0);
            for (std::ptrdiff_t jj = 0; jj < nj; ++jj) {
                for (std::ptrdiff_t k = 0; k < q; ++k) st[k * TILE + jj] = s[(j0 + jj) * q + k];
            }
            // Gram tile: gram[ii][jj] = s_i . s_j, coordinates ascending
            for (std::ptrdiff_t ii = 0; ii < ni; ++ii) {
                double* g = &gram[ii * TILE];
                const double* si = &s[(i0 + ii) * q];
                for (std::ptrdiff_t jj = 0; jj < nj; ++jj) g[jj] = si[0] * st[jj];
                for (std::ptrdiff_t k = 1; k < q; ++k) {
                    const double sik = si[k];
                    const double* sk = &st[k * TILE];
                    for (std::ptrdiff_t jj = 0; jj < nj; ++jj) g[jj] = g[jj] + sik * sk[jj];
                }
            }
            double psi_tile = 0.0;
            for (std::ptrdiff_t ii = 0; ii < ni; ++ii) {
                const std::ptrdiff_t jb = diag ? ii : 0;  // first column of this row
                const std::ptrdiff_t len = nj - jb;
                const double ci = cn[i0 + ii];
                const double* g = &gram[ii * TILE + jb];
                const double* cj = &cn[j0 + jb];
                // arguments (as the reference: (cn_i + cn_j) -+ 2 s_i.s_j / (4 B^2)), >= 0
                for (std::ptrdiff_t t = 0; t < len; ++t) {
                    const double g2 = g[t] * two_inv4b2;
                    const double a = ci + cj[t];
                    const double vm = a - g2;
                    const double vp = a + g2;
                    c[t] = vm > 0.0 ? vm : 0.0;
                    c[len + t] = vp > 0.0 ? vp : 0.0;
                }
                if (diag) c[0] = 0.0;  // T-_ii := 0
                const std::ptrdiff_t nc = 2 * len;
                double cbig = 0.0;
                for (std::ptrdiff_t t = 0; t < nc; ++t) cbig = c[t] > cbig ? c[t] : cbig;
                const int m = terms_for(cbig < SERIES_MAX ? cbig : SERIES_MAX);
                // the series on every argument (1 stands in for c <= 0), fixed up below
                const double s_top = ser.s[m];
                const double q_top = ser.q[m];
                for (std::ptrdiff_t t = 0; t < nc; ++t) {
                    const double ct = c[t];
                    base[t] = -EULER_GAMMA - ln(ct > 0.0 ? ct : 1.0);
                    ps[t] = s_top;
                    pq[t] = q_top;
                }
                for (int k = m - 1; k >= 1; --k) {
                    const double sk = ser.s[k];
                    const double qk = ser.q[k];
                    for (std::ptrdiff_t t = 0; t < nc; ++t) {
                        ps[t] = ps[t] * c[t] + sk;
                        pq[t] = pq[t] * c[t] + qk;
                    }
                }
                for (std::ptrdiff_t t = 0; t < nc; ++t) {
                    e1[t] = base[t] + ps[t] * c[t];
                    psi[t] = c[t] * (base[t] + (pq[t] * c[t] + 1.0));
                }
                for (std::ptrdiff_t t = 0; t < nc; ++t) {
                    if (!(c[t] > 0.0)) {
                        e1[t] = 0.0;
                        psi[t] = 0.0;
                    } else if (c[t] > SERIES_MAX) {
                        const Pair p = e1_psi(c[t], m, ser);
                        e1[t] = p.e1;
                        psi[t] = p.psi;
                    }
                }
                double psi_row = 0.0;
                for (std::ptrdiff_t t = 0; t < len; ++t) {
                    const double w = (diag && t == 0) ? 1.0 : 2.0;
                    psi_row = psi_row + w * (psi[t] + psi[len + t]);
                    dif[ii * TILE + jb + t] = e1[t] - e1[len + t];
                    sum[ii * TILE + jb + t] = e1[t] + e1[len + t];
                }
                psi_tile = psi_tile + psi_row;
            }
            psi_total = psi_total + psi_tile;
            if (!want_grad) continue;
            // rows of the tile: gpair_i += sum_j dif_ij s_j, rsum_i += sum_j sum_ij (j ascending)
            for (std::ptrdiff_t ii = 0; ii < ni; ++ii) {
                double* gi = &gpair[(i0 + ii) * q];
                double r = rsum[i0 + ii];
                for (std::ptrdiff_t jj = diag ? ii : 0; jj < nj; ++jj) {
                    const double d = dif[ii * TILE + jj];
                    const double* sj = &s[(j0 + jj) * q];
                    for (std::ptrdiff_t k = 0; k < q; ++k) gi[k] = gi[k] + d * sj[k];
                    r = r + sum[ii * TILE + jj];
                }
                rsum[i0 + ii] = r;
            }
            // columns (pairs j > i only): gpair_j += sum_i dif_ij s_i (i ascending)
            for (std::ptrdiff_t jj = 0; jj < nj; ++jj) {
                double* gj = &gpair[(j0 + jj) * q];
                double r = rsum[j0 + jj];
                const std::ptrdiff_t iend = diag ? jj : ni;
                for (std::ptrdiff_t ii = 0; ii < iend; ++ii) {
                    const double d = dif[ii * TILE + jj];
                    const double* si = &s[(i0 + ii) * q];
                    for (std::ptrdiff_t k = 0; k < q; ++k) gj[k] = gj[k] + d * si[k];
                    r = r + sum[ii * TILE + jj];
                }
                rsum[j0 + jj] = r;
            }
        }
    }
    psi_out[0] = psi_total;
}

// The distance of the point-symmetric set {s_i} U {-s_i} (U {0} for odd K) and, with
// ``want_grad``, its gradient w.r.t. the half-set (n x q), as the reference
// ssmobs.lcd_distance._symmetric_distance_numpy: D = D1' - 2 D2' + D3' (doc 2.4), gradient
// doc Section 4.  ``lam`` .. ``beta``, ``d1p``, ``j0p``: the quadrature rule of (q, B).
void ssmobs_lcd_symmetric(const double* s, std::ptrdiff_t n, std::ptrdiff_t q,
                          std::ptrdiff_t K, double b_max, const double* lam, const double* sig,
                          const double* alpha, const double* beta, std::ptrdiff_t n_nodes,
                          double d1p, double j0p, int want_grad, double* value,
                          double* grad) {
    static const Series ser;
    const double w = 1.0 / static_cast<double>(K);
    const std::ptrdiff_t eps = K - 2 * n;
    const double inv4b2 = 1.0 / (4.0 * b_max * b_max);
    std::vector<double> norms(static_cast<std::size_t>(n));
    std::vector<double> jp(static_cast<std::size_t>(n));
    std::vector<double> mm(static_cast<std::size_t>(n));
    std::vector<double> cn(static_cast<std::size_t>(n));
    std::vector<double> rsum(static_cast<std::size_t>(n));
    ssmobs_lcd_quadrature(s, n, q, lam, sig, alpha, beta, n_nodes, norms.data(), jp.data(),
                          mm.data());
    double jp_sum = 0.0;
    for (std::ptrdiff_t i = 0; i < n; ++i) {
        jp_sum = jp_sum + jp[i];
        cn[i] = norms[i] * inv4b2;
    }
    const double d2p = 2.0 * w * jp_sum + static_cast<double>(eps) * w * j0p;
    double psi = 0.0;
    ssmobs_lcd_pairs(s, n, q, cn.data(), inv4b2, want_grad, &psi, grad, rsum.data());
    // the origin of an odd set: T = |s_i|^2 against 0
    double psi0 = 0.0;
    std::vector<double> e0(static_cast<std::size_t>(n), 0.0);
    if (eps != 0) {
        for (std::ptrdiff_t i = 0; i < n; ++i) {
            const double c = cn[i];
            const Pair p = e1_psi(c, terms_for(c < SERIES_MAX ? c : SERIES_MAX), ser);
            e0[i] = p.e1;
            psi0 = psi0 + p.psi;
        }
    }
    const double d3p = -(w * w / 8.0) * 4.0 * b_max * b_max *
                       (2.0 * psi + 4.0 * static_cast<double>(eps) * psi0);
    value[0] = d1p - 2.0 * d2p + d3p;
    if (!want_grad) return;
    // grad_i = 4 w m_i s_i + w^2 (gpair_i - rsum_i s_i) - w^2 e0_i s_i  (gpair in ``grad``)
    const double ww = w * w;
    const double w4 = 4.0 * w;
    for (std::ptrdiff_t i = 0; i < n; ++i) {
        const double a = w4 * mm[i];
        const double r = rsum[i];
        const double e = e0[i];
        for (std::ptrdiff_t k = 0; k < q; ++k) {
            const double sik = s[i * q + k];
            double g = a * sik + ww * (grad[i * q + k] - r * sik);
            if (eps != 0) g = g - ww * e * sik;
            grad[i * q + k] = g;
        }
    }
}

// The element-wise functions, for the test against NumPy
void ssmobs_lcd_elementwise(const double* x, std::ptrdiff_t n, int which, double* out) {
    for (std::ptrdiff_t i = 0; i < n; ++i) {
        if (which == 0) out[i] = ln(x[i]);
        else if (which == 1) out[i] = exp_of(x[i]);
        else out[i] = expm1_of(x[i]);
    }
}

// E1 and psi / (4 B^2) of each argument (the series with the terms for its own value), for
// the test against the reference
void ssmobs_lcd_e1_psi(const double* c, std::ptrdiff_t n, double* e1, double* psi) {
    static const Series ser;
    for (std::ptrdiff_t i = 0; i < n; ++i) {
        const int m = terms_for(c[i] < SERIES_MAX ? c[i] : SERIES_MAX);
        const Pair p = e1_psi(c[i], m, ser);
        e1[i] = p.e1;
        psi[i] = p.psi;
    }
}

}  // extern "C"
