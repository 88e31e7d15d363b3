// The LCD distance of a point-symmetric set and its gradient, compiled (ssmobs.design.lcd_native).
//
// The same formulas as the NumPy reference ssmobs.design.lcd_distance._symmetric_distance_numpy
// (docs/lcd-design-disturbances.md, Sections 2.4 and 4), fused into one pass over the pairs
// of the half-set: Gram entry, E1 and psi of T- and T+, the psi sum, and the gradient terms
// ((E- - E+) S)_i and ((E- + E+) 1)_i, so that no N x N array is ever written.
//
// Same bits on any x86-64 CPU and with any compiler that follows IEEE 754 (no fast-math, no
// contraction of a*b+c into a fused multiply-add: -ffp-contract=off; the flags are fixed in
// ssmobs/design/lcd_native.py and are part of the cache key of the design sets):
// - every sum runs in one fixed order, written out below (no reduction is left to the
//   compiler, which may not reorder floating-point sums without -ffast-math);
// - log, exp and expm1 are our own (range reduction and Taylor polynomials, below): neither
//   the C library's nor NumPy's, whose last bits differ between versions and CPU kernels;
// - one thread.
// A vectorising compiler may run the element-wise loops on several lanes at once, and some
// loops are written on vectors (Lanes, below): each lane does the same IEEE operations in
// the same order, so the bits do not change (the tests build the kernel also without
// optimisation, and ssmobs/design/lcd_native.py builds it three times, for the x86-64 baseline,
// with -mavx2 and with -mavx512f, and the tests compare the bits of all).

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
const double HALF_LN2 = 0x1.62e42fefa39efp-2;
// rounds a double of magnitude < 2^51 to the nearest integer (ties to even) when added and
// subtracted again
const double ROUND_MAGIC = 0x1.8p52;
// E1 power series for c <= SERIES_MAX, continued fraction above (as the reference)
const double SERIES_MAX = 1.0;
const int MAX_TERMS = 30;
// rows (and columns) of one tile of the pair grid
const std::ptrdiff_t TILE = 32;
// a row's arguments are padded to a multiple of LANES (2 * TILE is one)
const int LANES = 8;
// VECTOR_LANES doubles, the target's vector width (wider vectors the compiler splits,
// slowly; LANES is a multiple of it), with element-wise IEEE arithmetic (the vector
// extension of GCC, which Clang also has: each operation, compare and select on each
// element, the same bits on any width; checked with GCC)
#if defined(__AVX512F__)
const int VECTOR_LANES = 8;
#elif defined(__AVX__)
const int VECTOR_LANES = 4;
#else
const int VECTOR_LANES = 2;
#endif
typedef double Lanes __attribute__((vector_size(VECTOR_LANES * sizeof(double))));
// rows of at most this many coordinates take the gradient's other loop order
const std::ptrdiff_t SHORT_ROWS = 32;

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

// Tables of ln: for t = 0..127 (the first 7 bits of the mantissa m in [1, 2)) and the centre
// c_t = 1 + t/128 (t < 64), 1 + (t+1)/128 (t >= 64) (made from its bits in ln), 1/c_t
// rounded, and ln c_t (t < 64) or ln(c_t / 2) (t >= 64), correctly rounded (computed with 50
// decimal digits).
const double LOG_INVERSE[128] = {
    0x1.0000000000000p+0, 0x1.fc07f01fc07f0p-1, 0x1.f81f81f81f820p-1, 0x1.f44659e4a4271p-1,
    0x1.f07c1f07c1f08p-1, 0x1.ecc07b301ecc0p-1, 0x1.e9131abf0b767p-1, 0x1.e573ac901e574p-1,
    0x1.e1e1e1e1e1e1ep-1, 0x1.de5d6e3f8868ap-1, 0x1.dae6076b981dbp-1, 0x1.d77b654b82c34p-1,
    0x1.d41d41d41d41dp-1, 0x1.d0cb58f6ec074p-1, 0x1.cd85689039b0bp-1, 0x1.ca4b3055ee191p-1,
    0x1.c71c71c71c71cp-1, 0x1.c3f8f01c3f8f0p-1, 0x1.c0e070381c0e0p-1, 0x1.bdd2b899406f7p-1,
    0x1.bacf914c1bad0p-1, 0x1.b7d6c3dda338bp-1, 0x1.b4e81b4e81b4fp-1, 0x1.b2036406c80d9p-1,
    0x1.af286bca1af28p-1, 0x1.ac5701ac5701bp-1, 0x1.a98ef606a63bep-1, 0x1.a6d01a6d01a6dp-1,
    0x1.a41a41a41a41ap-1, 0x1.a16d3f97a4b02p-1, 0x1.9ec8e951033d9p-1, 0x1.9c2d14ee4a102p-1,
    0x1.999999999999ap-1, 0x1.970e4f80cb872p-1, 0x1.948b0fcd6e9e0p-1, 0x1.920fb49d0e229p-1,
    0x1.8f9c18f9c18fap-1, 0x1.8d3018d3018d3p-1, 0x1.8acb90f6bf3aap-1, 0x1.886e5f0abb04ap-1,
    0x1.8618618618618p-1, 0x1.83c977ab2beddp-1, 0x1.8181818181818p-1, 0x1.7f405fd017f40p-1,
    0x1.7d05f417d05f4p-1, 0x1.7ad2208e0ecc3p-1, 0x1.78a4c8178a4c8p-1, 0x1.767dce434a9b1p-1,
    0x1.745d1745d1746p-1, 0x1.724287f46debcp-1, 0x1.702e05c0b8170p-1, 0x1.6e1f76b4337c7p-1,
    0x1.6c16c16c16c17p-1, 0x1.6a13cd1537290p-1, 0x1.6816816816817p-1, 0x1.661ec6a5122f9p-1,
    0x1.642c8590b2164p-1, 0x1.623fa77016240p-1, 0x1.6058160581606p-1, 0x1.5e75bb8d015e7p-1,
    0x1.5c9882b931057p-1, 0x1.5ac056b015ac0p-1, 0x1.58ed2308158edp-1, 0x1.571ed3c506b3ap-1,
    0x1.5390948f40febp-1, 0x1.51d07eae2f815p-1, 0x1.5015015015015p-1, 0x1.4e5e0a72f0539p-1,
    0x1.4cab88725af6ep-1, 0x1.4afd6a052bf5bp-1, 0x1.49539e3b2d067p-1, 0x1.47ae147ae147bp-1,
    0x1.460cbc7f5cf9ap-1, 0x1.446f86562d9fbp-1, 0x1.42d6625d51f87p-1, 0x1.4141414141414p-1,
    0x1.3fb013fb013fbp-1, 0x1.3e22cbce4a902p-1, 0x1.3c995a47babe7p-1, 0x1.3b13b13b13b14p-1,
    0x1.3991c2c187f63p-1, 0x1.3813813813814p-1, 0x1.3698df3de0748p-1, 0x1.3521cfb2b78c1p-1,
    0x1.33ae45b57bcb2p-1, 0x1.323e34a2b10bfp-1, 0x1.30d190130d190p-1, 0x1.2f684bda12f68p-1,
    0x1.2e025c04b8097p-1, 0x1.2c9fb4d812ca0p-1, 0x1.2b404ad012b40p-1, 0x1.29e4129e4129ep-1,
    0x1.288b01288b013p-1, 0x1.27350b8812735p-1, 0x1.25e22708092f1p-1, 0x1.2492492492492p-1,
    0x1.23456789abcdfp-1, 0x1.21fb78121fb78p-1, 0x1.20b470c67c0d9p-1, 0x1.1f7047dc11f70p-1,
    0x1.1e2ef3b3fb874p-1, 0x1.1cf06ada2811dp-1, 0x1.1bb4a4046ed29p-1, 0x1.1a7b9611a7b96p-1,
    0x1.19453808ca29cp-1, 0x1.1811811811812p-1, 0x1.16e0689427379p-1, 0x1.15b1e5f75270dp-1,
    0x1.1485f0e0acd3bp-1, 0x1.135c81135c811p-1, 0x1.12358e75d3033p-1, 0x1.1111111111111p-1,
    0x1.0fef010fef011p-1, 0x1.0ecf56be69c90p-1, 0x1.0db20a88f4696p-1, 0x1.0c9714fbcda3bp-1,
    0x1.0b7e6ec259dc8p-1, 0x1.0a6810a6810a7p-1, 0x1.0953f39010954p-1, 0x1.0842108421084p-1,
    0x1.073260a47f7c6p-1, 0x1.0624dd2f1a9fcp-1, 0x1.05197f7d73404p-1, 0x1.0410410410410p-1,
    0x1.03091b51f5e1ap-1, 0x1.0204081020408p-1, 0x1.0101010101010p-1, 0x1.0000000000000p-1,
};

const double LOG_TABLE[128] = {
    0x0.0p+0, 0x1.fe02a6b106789p-8, 0x1.fc0a8b0fc03e4p-7, 0x1.7b91b07d5b11bp-6,
    0x1.f829b0e783300p-6, 0x1.39e87b9febd60p-5, 0x1.77458f632dcfcp-5, 0x1.b42dd711971bfp-5,
    0x1.f0a30c01162a6p-5, 0x1.16536eea37ae1p-4, 0x1.341d7961bd1d1p-4, 0x1.51b073f06183fp-4,
    0x1.6f0d28ae56b4cp-4, 0x1.8c345d6319b21p-4, 0x1.a926d3a4ad563p-4, 0x1.c5e548f5bc743p-4,
    0x1.e27076e2af2e6p-4, 0x1.fec9131dbeabbp-4, 0x1.0d77e7cd08e59p-3, 0x1.1b72ad52f67a0p-3,
    0x1.29552f81ff523p-3, 0x1.371fc201e8f74p-3, 0x1.44d2b6ccb7d1ep-3, 0x1.526e5e3a1b438p-3,
    0x1.5ff3070a793d4p-3, 0x1.6d60fe719d21dp-3, 0x1.7ab890210d909p-3, 0x1.87fa06520c911p-3,
    0x1.9525a9cf456b4p-3, 0x1.a23bc1fe2b563p-3, 0x1.af3c94e80bff3p-3, 0x1.bc286742d8cd6p-3,
    0x1.c8ff7c79a9a22p-3, 0x1.d5c216b4fbb91p-3, 0x1.e27076e2af2e6p-3, 0x1.ef0adcbdc5936p-3,
    0x1.fb9186d5e3e2bp-3, 0x1.0402594b4d041p-2, 0x1.0a324e27390e3p-2, 0x1.1058bf9ae4ad5p-2,
    0x1.1675cababa60ep-2, 0x1.1c898c16999fbp-2, 0x1.22941fbcf7966p-2, 0x1.2895a13de86a3p-2,
    0x1.2e8e2bae11d31p-2, 0x1.347dd9a987d55p-2, 0x1.3a64c556945eap-2, 0x1.404308686a7e4p-2,
    0x1.4618bc21c5ec2p-2, 0x1.4be5f957778a1p-2, 0x1.51aad872df82dp-2, 0x1.5767717455a6cp-2,
    0x1.5d1bdbf5809cap-2, 0x1.62c82f2b9c795p-2, 0x1.686c81e9b14afp-2, 0x1.6e08eaa2ba1e4p-2,
    0x1.739d7f6bbd007p-2, 0x1.792a55fdd47a2p-2, 0x1.7eaf83b82afc3p-2, 0x1.842d1da1e8b17p-2,
    0x1.89a3386c1425bp-2, 0x1.8f11e873662c7p-2, 0x1.947941c2116fbp-2, 0x1.99d958117e08bp-2,
    -0x1.214456d0eb8d4p-2, -0x1.1bf99635a6b95p-2, -0x1.16b5ccbacfb73p-2, -0x1.1178e8227e47cp-2,
    -0x1.0c42d676162e3p-2, -0x1.07138604d5862p-2, -0x1.01eae5626c691p-2, -0x1.f991c6cb3b379p-3,
    -0x1.ef5ade4dcffe6p-3, -0x1.e530effe71012p-3, -0x1.db13db0d48940p-3, -0x1.d1037f2655e7bp-3,
    -0x1.c6ffbc6f00f71p-3, -0x1.bd087383bd8adp-3, -0x1.b31d8575bce3dp-3, -0x1.a93ed3c8ad9e3p-3,
    -0x1.9f6c407089664p-3, -0x1.95a5adcf7017fp-3, -0x1.8beafeb38fe8cp-3, -0x1.823c16551a3c2p-3,
    -0x1.7898d85444c73p-3, -0x1.6f0128b756abcp-3, -0x1.6574ebe8c133ap-3, -0x1.5bf406b543db2p-3,
    -0x1.527e5e4a1b58dp-3, -0x1.4913d8333b561p-3, -0x1.3fb45a59928ccp-3, -0x1.365fcb0159016p-3,
    -0x1.2d1610c86813ap-3, -0x1.23d712a49c202p-3, -0x1.1aa2b7e23f72ap-3, -0x1.1178e8227e47cp-3,
    -0x1.08598b59e3a07p-3, -0x1.fe89139dbd566p-4, -0x1.ec739830a1120p-4, -0x1.da727638446a2p-4,
    -0x1.c885801bc4b23p-4, -0x1.b6ac88dad5b1cp-4, -0x1.a4e7640b1bc38p-4, -0x1.9335e5d594989p-4,
    -0x1.8197e2f40e3f0p-4, -0x1.700d30aeac0e1p-4, -0x1.5e95a4d9791cbp-4, -0x1.4d3115d207eacp-4,
    -0x1.3bdf5a7d1ee64p-4, -0x1.2aa04a44717a5p-4, -0x1.1973bd1465567p-4, -0x1.08598b59e3a07p-4,
    -0x1.eea31c006b87cp-5, -0x1.ccb73cdddb2ccp-5, -0x1.aaef2d0fb10fcp-5, -0x1.894aa149fb343p-5,
    -0x1.67c94f2d4bb58p-5, -0x1.466aed42de3eap-5, -0x1.252f32f8d183fp-5, -0x1.0415d89e74444p-5,
    -0x1.c63d2ec14aaf2p-6, -0x1.8492528c8cabfp-6, -0x1.432a925980cc1p-6, -0x1.0205658935847p-6,
    -0x1.82448a388a2aap-7, -0x1.010157588de71p-7, -0x1.0080559588b35p-8, 0x0.0p+0,
};

// Natural logarithm of a finite x > 0: x = 2^e m, m in [1, 2), t = the first 7 bits of m;
// r = (m - c_t) / c_t with m - c_t exact and |r| < 1/128, and
// ln x = e ln 2 + ln c_t + ln(1 + r)  (t < 64),  (e + 1) ln 2 + ln(c_t / 2) + ln(1 + r)
// (t >= 64: then x just below a power of 2 has a small result without cancellation).
// ln(1 + r) by its Taylor polynomial to r^8 (remainder below 2e-18 r).  No division and no
// branch (selects only), so that a compiler may run it on vector lanes.
inline double ln(double x) {
    const bool sub = x < 0x1p-1022;  // subnormal: scale into the normal range first
    const double scaled = x * 0x1p54;
    x = sub ? scaled : x;
    const std::uint64_t b = to_bits(x);
    const std::uint64_t t = (b >> 45) & 127;
    // the biased exponent as a double, exactly: 2^52 + field - 2^52
    const double field = from_bits((b >> 52) | 0x4330000000000000ULL) - 0x1p52;
    const double m = from_bits((b & 0x000fffffffffffffULL) | 0x3ff0000000000000ULL);
    const double e = (field - 1023.0) + ((sub ? -54.0 : 0.0) + (t >= 64 ? 1.0 : 0.0));
    // c_t from its bits (the entry of LOG_CENTRE, exactly: 1 + (t + [t >= 64]) / 128), not
    // loaded: one table lookup less per lane
    const double centre = from_bits(0x3ff0000000000000ULL + ((t + (t >> 6)) << 45));
    const double r = (m - centre) * LOG_INVERSE[t];
    double p = -1.0 / 8.0;
    p = p * r + 1.0 / 7.0;
    p = p * r - 1.0 / 6.0;
    p = p * r + 1.0 / 5.0;
    p = p * r - 1.0 / 4.0;
    p = p * r + 1.0 / 3.0;
    p = p * r - 0.5;
    const double log1p_r = r + (r * r) * p;
    return e * LN2_HEAD + (LOG_TABLE[t] + (log1p_r + e * LN2_TAIL));
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

// exp_of without a branch (selects only, so that a compiler may run it on vector lanes):
// the same operations on every a in [-745.2, 709.79], hence the same bits as exp_of; 0 below
// and +inf above, as exp_of.  Also expm1 as in ssmobs_lcd_quadrature: expm1_reduced(a) for
// |a| < HALF_LN2, where k = 0 and r = a exactly (fl(a / ln 2) rounds to at most 1/2 in
// magnitude there, checked at the largest such a), so it is the polynomial already made
// for exp; exp(a) - 1 elsewhere
inline double exp_lanes(double a, double* expm1_out) {
    const bool low = a < -745.2;
    const bool high = a > 709.79;
    const double ac = (low || high) ? 0.0 : a;
    const double kd = (ac * INV_LN2 + ROUND_MAGIC) - ROUND_MAGIC;
    const double r = (ac - kd * LN2_HEAD) - kd * LN2_TAIL;
    const double em = expm1_reduced(r);
    const double y = 1.0 + em;
    // 2^k (k >= -1022) or 2^(k + 600) then 2^-600 (a subnormal result), as exp_of
    const bool sub = kd < -1022.0;
    const double ke = (sub ? kd + 600.0 : kd) + 1023.0;  // the biased exponent, 1..2047
    // its bits: ke (an integer in [0, 2^52)) added to 2^52 has it in its low bits
    const std::uint64_t field = to_bits(ke + 0x1p52) & 0x000fffffffffffffULL;
    const double scale = from_bits(field << 52);
    const double out = (y * scale) * (sub ? 0x1p-600 : 1.0);
    const double ea = low ? 0.0 : (high ? from_bits(0x7ff0000000000000ULL) : out);
    *expm1_out = (a > -HALF_LN2 && a < HALF_LN2) ? em : ea - 1.0;
    return ea;
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

// terms_for by thresholds: the predicate of terms_for for m, "fl(c^(m+1)) <= fl(1e-17 (m+1)
// (m+1)!)", holds for c up to a largest double thr[m] and not above it (fl(c^(m+1)), a
// product of roundings, does not decrease as c grows), so terms_for(c) is the first m with
// c <= thr[m]: the same numbers without the products (thr[m] found once, by bisection on
// the bits of the non-negative doubles, whose order is that of their values)
struct Terms {
    double thr[MAX_TERMS];  // thr[m] for m = 1..MAX_TERMS-1
    static bool holds(double c, int m) {  // the predicate of terms_for, as terms_for
        double power = c;
        double fact = 1.0;
        for (int k = 1; k <= m; ++k) {
            power *= c;
            fact *= static_cast<double>(k + 1);
        }
        return power <= 1e-17 * (static_cast<double>(m + 1) * fact);
    }
    Terms() {
        thr[0] = 0.0;
        for (int m = 1; m < MAX_TERMS; ++m) {
            std::uint64_t lo = 0, hi = to_bits(1.0);  // holds(lo); holds(hi) or hi = 1
            if (holds(1.0, m)) {
                thr[m] = 1.0;
                continue;
            }
            while (hi - lo > 1) {
                const std::uint64_t mid = lo + (hi - lo) / 2;
                if (holds(from_bits(mid), m)) lo = mid;
                else hi = mid;
            }
            thr[m] = from_bits(lo);
        }
    }
    int of(double c) const {  // terms_for(c) for 0 <= c <= 1
        for (int m = 1; m < MAX_TERMS; ++m) {
            if (c <= thr[m]) return m;
        }
        return MAX_TERMS;
    }
};

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

// The gradient terms of one tile of pairs (ssmobs_lcd_pairs): for the rows i of the tile
// gpair_i += sum_j dif_ij s_j and rsum_i += sum_j sum_ij (columns j ascending), then for the
// columns j (pairs j > i only) gpair_j += sum_i dif_ij s_i and rsum_j += sum_i sum_ij (rows
// i ascending).  Two loop orders with the same sums in the same order, hence the same bits:
// for long rows (large q) a row at a time, the q coordinates on vector lanes; for short
// rows (q <= SHORT_ROWS) the other index outermost, so that consecutive updates go to other
// rows and do not wait for each other.
void gradient_tile_long(const double* s, std::ptrdiff_t q, std::ptrdiff_t i0,
                        std::ptrdiff_t ni, std::ptrdiff_t j0, std::ptrdiff_t nj, bool diag,
                        const double* dif, const double* sum, double* gpair, double* rsum) {
    for (std::ptrdiff_t ii = 0; ii < ni; ++ii) {
        double* __restrict gi = &gpair[(i0 + ii) * q];
        double r = rsum[i0 + ii];
        for (std::ptrdiff_t jj = diag ? ii : 0; jj < nj; ++jj) {
            const double d = dif[ii * TILE + jj];
            const double* __restrict sj = &s[(j0 + jj) * q];
            for (std::ptrdiff_t k = 0; k < q; ++k) gi[k] = gi[k] + d * sj[k];
            r = r + sum[ii * TILE + jj];
        }
        rsum[i0 + ii] = r;
    }
    for (std::ptrdiff_t jj = 0; jj < nj; ++jj) {
        double* __restrict gj = &gpair[(j0 + jj) * q];
        double r = rsum[j0 + jj];
        const std::ptrdiff_t iend = diag ? jj : ni;
        for (std::ptrdiff_t ii = 0; ii < iend; ++ii) {
            const double d = dif[ii * TILE + jj];
            const double* __restrict si = &s[(i0 + ii) * q];
            for (std::ptrdiff_t k = 0; k < q; ++k) gj[k] = gj[k] + d * si[k];
            r = r + sum[ii * TILE + jj];
        }
        rsum[j0 + jj] = r;
    }
}

// g_k = g_k + d x_k for k < q: Q > 0 (a multiple of VECTOR_LANES): q = Q, on vectors of
// the target's width; Q = 0: a loop (which the compiler may vectorise)
template <int Q>
inline void add_scaled(double* __restrict g, double d, const double* __restrict x,
                       std::ptrdiff_t q) {
    if (Q > 0) {
        for (int k = 0; k < Q; k += VECTOR_LANES) {
            Lanes gv, xv;
            std::memcpy(&gv, &g[k], sizeof gv);
            std::memcpy(&xv, &x[k], sizeof xv);
            gv = gv + d * xv;
            std::memcpy(&g[k], &gv, sizeof gv);
        }
    } else {
        for (std::ptrdiff_t k = 0; k < q; ++k) g[k] = g[k] + d * x[k];
    }
}

// (Q > 0: q = Q known to the compiler)
template <int Q>
void gradient_tile_short(const double* s, std::ptrdiff_t q_run, std::ptrdiff_t i0,
                         std::ptrdiff_t ni, std::ptrdiff_t j0, std::ptrdiff_t nj, bool diag,
                         const double* dif, const double* sum, double* gpair, double* rsum) {
    const std::ptrdiff_t q = Q > 0 ? Q : q_run;
    double r[TILE];
    // rows: column jj outermost, the rows ii <= jj (diagonal tile) or all rows inside
    for (std::ptrdiff_t ii = 0; ii < ni; ++ii) r[ii] = rsum[i0 + ii];
    for (std::ptrdiff_t jj = 0; jj < nj; ++jj) {
        const double* __restrict sj = &s[(j0 + jj) * q];
        const std::ptrdiff_t iend = diag ? jj + 1 : ni;
        for (std::ptrdiff_t ii = 0; ii < iend; ++ii) {
            const double d = dif[ii * TILE + jj];
            double* __restrict gi = &gpair[(i0 + ii) * q];
            add_scaled<Q>(gi, d, sj, q);
            r[ii] = r[ii] + sum[ii * TILE + jj];
        }
    }
    for (std::ptrdiff_t ii = 0; ii < ni; ++ii) rsum[i0 + ii] = r[ii];
    // columns: row ii outermost, the columns jj > ii (diagonal tile) or all columns inside
    for (std::ptrdiff_t jj = 0; jj < nj; ++jj) r[jj] = rsum[j0 + jj];
    for (std::ptrdiff_t ii = 0; ii < ni; ++ii) {
        const double* __restrict si = &s[(i0 + ii) * q];
        for (std::ptrdiff_t jj = diag ? ii + 1 : 0; jj < nj; ++jj) {
            const double d = dif[ii * TILE + jj];
            double* __restrict gj = &gpair[(j0 + jj) * q];
            add_scaled<Q>(gj, d, si, q);
            r[jj] = r[jj] + sum[ii * TILE + jj];
        }
    }
    for (std::ptrdiff_t jj = 0; jj < nj; ++jj) rsum[j0 + jj] = r[jj];
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
    std::vector<double> ex(static_cast<std::size_t>(n_nodes));
    std::vector<double> exm1(static_cast<std::size_t>(n_nodes));
    for (std::ptrdiff_t i = 0; i < n; ++i) {
        const double* si = &s[i * q];
        double nrm = si[0] * si[0];
        for (std::ptrdiff_t k = 1; k < q; ++k) nrm = nrm + si[k] * si[k];
        norms[i] = nrm;
        const double half_n = 0.5 * nrm;
        // exp and expm1 of every node's argument on vector lanes, then the sums in order
        for (std::ptrdiff_t l = 0; l < n_nodes; ++l) {
            const double a = lam[l] - half_n * sig[l];
            double em1;
            ex[l] = exp_lanes(a, &em1);
            exm1[l] = em1;
        }
        double sj = 0.0;
        double sm = 0.0;
        for (std::ptrdiff_t l = 0; l < n_nodes; ++l) {
            sj = sj + exm1[l] * alpha[l];
            sm = sm + ex[l] * beta[l];
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
    static const Terms terms;
    const double two_inv4b2 = 2.0 * inv4b2;
    const std::size_t tt = static_cast<std::size_t>(TILE * TILE);
    std::vector<double> gram(tt), dif(tt), sum(tt);
    std::vector<double> st(static_cast<std::size_t>(TILE * q));  // column tile, transposed
    // one row of a tile: arguments c- (first nj) and c+ (next nj), and their terms
    std::vector<double> c(2 * TILE), base(2 * TILE), e1(2 * TILE), psi(2 * TILE);
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
                // the largest argument, on VECTOR_LANES partial maxima (a maximum is exact
                // in any order; the arguments are >= +0, none NaN), over c padded with +0
                const std::ptrdiff_t ncp = (nc + LANES - 1) / LANES * LANES;
                for (std::ptrdiff_t t = nc; t < ncp; ++t) c[t] = 0.0;
                Lanes part = {};
                for (std::ptrdiff_t t = 0; t < ncp; t += VECTOR_LANES) {
                    Lanes cl;
                    std::memcpy(&cl, &c[t], sizeof cl);
                    part = cl > part ? cl : part;
                }
                double cbig = part[0];
                for (int l = 1; l < VECTOR_LANES; ++l) cbig = part[l] > cbig ? part[l] : cbig;
                const int m = terms.of(cbig < SERIES_MAX ? cbig : SERIES_MAX);
                // the series on every argument (1 stands in for c <= 0), LANES arguments at
                // a time in a vector of LANES doubles (the partial sums stay in registers);
                // 0 at c <= 0; the continued fraction replaces c > SERIES_MAX below
                for (std::ptrdiff_t t = 0; t < ncp; ++t) {
                    const double ct = c[t];
                    base[t] = -EULER_GAMMA - ln(ct > 0.0 ? ct : 1.0);
                }
                const double s_top = ser.s[m];
                const double q_top = ser.q[m];
                for (std::ptrdiff_t t = 0; t < ncp; t += VECTOR_LANES) {
                    Lanes cl, bl;
                    std::memcpy(&cl, &c[t], sizeof cl);
                    std::memcpy(&bl, &base[t], sizeof bl);
                    Lanes ps = Lanes{} + s_top;  // +0 + s_top: s_top exactly
                    Lanes pq = Lanes{} + q_top;
                    for (int k = m - 1; k >= 1; --k) {
                        ps = ps * cl + ser.s[k];
                        pq = pq * cl + ser.q[k];
                    }
                    const Lanes e = bl + ps * cl;
                    const Lanes p = cl * (bl + (pq * cl + 1.0));
                    const Lanes zero = {};
                    const Lanes e_out = cl > zero ? e : zero;
                    const Lanes p_out = cl > zero ? p : zero;
                    std::memcpy(&e1[t], &e_out, sizeof e_out);
                    std::memcpy(&psi[t], &p_out, sizeof p_out);
                }
                if (cbig > SERIES_MAX) {
                    for (std::ptrdiff_t t = 0; t < nc; ++t) {
                        if (c[t] > SERIES_MAX) {
                            const Pair p = e1_psi(c[t], m, ser);
                            e1[t] = p.e1;
                            psi[t] = p.psi;
                        }
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
            if (q == 8) {  // the dimension of the choice of K in the default profile
                gradient_tile_short<8>(s, q, i0, ni, j0, nj, diag, dif.data(), sum.data(),
                                       gpair, rsum);
            } else if (q <= SHORT_ROWS) {
                gradient_tile_short<0>(s, q, i0, ni, j0, nj, diag, dif.data(), sum.data(), gpair,
                                    rsum);
            } else {
                gradient_tile_long(s, q, i0, ni, j0, nj, diag, dif.data(), sum.data(), gpair,
                                   rsum);
            }
        }
    }
    psi_out[0] = psi_total;
}

// The distance of the point-symmetric set {s_i} U {-s_i} (U {0} for odd K) and, with
// ``want_grad``, its gradient w.r.t. the half-set (n x q), as the reference
// ssmobs.design.lcd_distance._symmetric_distance_numpy: D = D1' - 2 D2' + D3' (doc 2.4), gradient
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

// The number of series terms of each argument in [0, 1] by terms_for (``reference``) and by
// the thresholds the pair loop uses (``fast``), for the test that they agree
void ssmobs_lcd_terms(const double* c, std::ptrdiff_t n, int* reference, int* fast) {
    static const Terms terms;
    for (std::ptrdiff_t i = 0; i < n; ++i) {
        reference[i] = terms_for(c[i]);
        fast[i] = terms.of(c[i]);
    }
}

}  // extern "C"
