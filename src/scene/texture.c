/* Bilinear texture sampling with its backward: the one lookup of an object's albedo texture, used
 * by the renderer's shading (point or filtered over the pixel's footprint) and, at points, by the
 * reference renderer, whose samples filter it over the pixel, so that both see the same albedo.
 *
 * Texture lookup: bilinear between the four nearest texel centres, repeat wrap in both
 * directions (the OpenGL default and what OBJ texture coordinates outside [0,1] expect). Texel
 * (i, j), row j counted from the top of the image, has its centre at u = (i + 0.5) / W,
 * v = 1 - (j + 0.5) / H. The lookup is continuous in uv and piecewise linear; its uv gradient
 * jumps at texel centres, which the optimiser tolerates like any kink.
 *
 * Footprint filter (the renderer's lookup, docs/design.md sec. 1.4): the mean of the bilinear
 * lookup at a fixed PEN__TEXTURE_GRID x PEN__TEXTURE_GRID grid of points uv + J o over the
 * pixel, o the grid's cell centres in [-1/2, 1/2]^2 and J = d(uv)/d(pixel x, y) at the pixel
 * centre, i.e. a box filter of the texture over the pixel's parallelogram footprint, as a
 * supersampled reference sees it. The grid is fixed (no adaptive switch), so the lookup stays
 * continuous in uv and J. Its backward is exact: in the texels each sample's bilinear weights /
 * K, in uv the mean of the samples' uv gradients, and in J their sum weighted by the offsets
 * (the renderer carries it on to the geometry: src/render/footprint.c).
 */
#include "scene/texture.h"

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

/* The lookup's pieces are inlined into the footprint's loops, which keeps a sample's texel
 * offsets in registers instead of a returned struct. */
#define INLINE static inline __attribute__((always_inline))

typedef struct bilinear {
    size_t idx[4]; /* texel offsets (in texels) of (i0,j0), (i1,j0), (i0,j1), (i1,j1) */
    long row[2];   /* j0 and j1: the rows of idx[0..1] and idx[2..3] */
    float a, b;    /* fractions along u (columns) and down the rows */
} bilinear;

static int wrap(long i, int n) {
    if (i >= 0 && i < n) return (int)i; /* the common case, without a division */
    if (i == n) return 0;
    long r = i % n;
    return (int)(r < 0 ? r + n : r);
}

/* The lookup at texel coordinates (fx, fy) inside the texture and short of its last column and
 * row (bilinear_from's common case): floor() is the truncation and nothing wraps. */
INLINE bilinear bilinear_inside(const pen_image *tex, double fx, double fy) {
    bilinear s;
    const long i0 = (long)fx, j0 = (long)fy;
    s.a = (float)(fx - (double)i0);
    s.b = (float)(fy - (double)j0);
    const size_t w = (size_t)tex->width, at = (size_t)j0 * w + (size_t)i0;
    s.idx[0] = at, s.idx[1] = at + 1, s.idx[2] = at + w, s.idx[3] = at + w + 1;
    s.row[0] = j0, s.row[1] = j0 + 1;
    return s;
}

/* The lookup at texel coordinates (fx, fy) = (u W - 1/2, (1 - v) H - 1/2). The common case
 * (bilinear_inside) gives the general branch's result bit for bit, without its tests and
 * divisions. */
INLINE bilinear bilinear_from(const pen_image *tex, double fx, double fy) {
    if (fx >= 0.0 && fx < (double)(tex->width - 1) && fy >= 0.0 && fy < (double)(tex->height - 1))
        return bilinear_inside(tex, fx, fy);
    bilinear s;
    double x0 = floor(fx), y0 = floor(fy);
    if (!isfinite(x0) || fabs(x0) > 1e9) x0 = 0.0; /* garbage uv: a defined texel */
    if (!isfinite(y0) || fabs(y0) > 1e9) y0 = 0.0;
    s.a = (float)(isfinite(fx) ? fx - x0 : 0.0);
    s.b = (float)(isfinite(fy) ? fy - y0 : 0.0);
    if (!(s.a >= 0.0f && s.a <= 1.0f)) s.a = 0.0f;
    if (!(s.b >= 0.0f && s.b <= 1.0f)) s.b = 0.0f;
    const long i0 = wrap((long)x0, tex->width), i1 = wrap((long)x0 + 1, tex->width);
    const long j0 = wrap((long)y0, tex->height), j1 = wrap((long)y0 + 1, tex->height);
    const size_t w = (size_t)tex->width;
    s.row[0] = j0, s.row[1] = j1;
    s.idx[0] = (size_t)j0 * w + (size_t)i0;
    s.idx[1] = (size_t)j0 * w + (size_t)i1;
    s.idx[2] = (size_t)j1 * w + (size_t)i0;
    s.idx[3] = (size_t)j1 * w + (size_t)i1;
    return s;
}

/* Double for the texel coordinate: u * W loses the fraction in float for large u. */
INLINE bilinear bilinear_at(const pen_image *tex, double u, double v) {
    return bilinear_from(tex, u * tex->width - 0.5, (1.0 - v) * tex->height - 0.5);
}

/* The lerps take the channel count as an argument (tex->channels, or a constant where the
 * footprint's loops are specialised for 3 or 4: the channel clamp and the offsets' products
 * fold away). */

/* Adds the texel part of the bilinear lookup's backward at s, for the texels of rows [r0, r1)
 * only. */
INLINE void lerp_bwd_rows(const pen_image *tex, int nch, const bilinear *s, const float d_rgb[3],
                          float *d_texels, long r0, long r1) {
    const float wt[4] = {(1 - s->a) * (1 - s->b), s->a * (1 - s->b), (1 - s->a) * s->b,
                         s->a * s->b};
    for (int q = 0; q < 4; ++q) {
        const long row = s->row[q >> 1];
        if (row < r0 || row >= r1) continue;
        for (int ch = 0; ch < 3 && ch < nch; ++ch)
            d_texels[s->idx[q] * (size_t)nch + (size_t)ch] += wt[q] * d_rgb[ch];
    }
}

/* rgb = the bilinear lookup at s. */
INLINE void lerp_fwd(const pen_image *tex, int nch, const bilinear *s, float rgb[3]) {
    const float wt[4] = {(1 - s->a) * (1 - s->b), s->a * (1 - s->b), (1 - s->a) * s->b,
                         s->a * s->b};
    for (int ch = 0; ch < 3; ++ch) {
        const int c = ch < nch ? ch : nch - 1;
        float v = 0.0f;
        for (int q = 0; q < 4; ++q)
            v += wt[q] * tex->data[s->idx[q] * (size_t)nch + (size_t)c];
        rgb[ch] = v;
    }
}

/* Adds the uv part of the bilinear lookup's backward at s into d_uv. */
INLINE void lerp_bwd_uv(const pen_image *tex, int nch, const bilinear *s, const float d_rgb[3],
                        float d_uv[2]) {
    /* rgb = (1-b)((1-a) t00 + a t10) + b((1-a) t01 + a t11); a grows with u (x W), b grows
     * downwards, i.e. with -v (x H). */
    float da = 0.0f, db = 0.0f;
    for (int ch = 0; ch < 3; ++ch) {
        const int c = ch < nch ? ch : nch - 1;
        const float *t = tex->data;
        const float t00 = t[s->idx[0] * (size_t)nch + (size_t)c];
        const float t10 = t[s->idx[1] * (size_t)nch + (size_t)c];
        const float t01 = t[s->idx[2] * (size_t)nch + (size_t)c];
        const float t11 = t[s->idx[3] * (size_t)nch + (size_t)c];
        da += d_rgb[ch] * ((1 - s->b) * (t10 - t00) + s->b * (t11 - t01));
        db += d_rgb[ch] * ((1 - s->a) * (t01 - t00) + s->a * (t11 - t10));
    }
    d_uv[0] += da * (float)tex->width;
    d_uv[1] -= db * (float)tex->height;
}

void pen__texture_fwd(const pen_image *tex, const float uv[2], float rgb[3]) {
    const bilinear s = bilinear_at(tex, (double)uv[0], (double)uv[1]);
    lerp_fwd(tex, tex->channels, &s, rgb);
}

void pen__texture_bwd(const pen_image *tex, const float uv[2], const float d_rgb[3],
                      float *d_texels, float d_uv[2]) {
    const bilinear s = bilinear_at(tex, (double)uv[0], (double)uv[1]);
    if (d_texels) lerp_bwd_rows(tex, tex->channels, &s, d_rgb, d_texels, 0, tex->height);
    if (d_uv) lerp_bwd_uv(tex, tex->channels, &s, d_rgb, d_uv);
}

/* ---- Footprint ----
 * The three footprint calls (forward, backward, texel scatter) each set up their samples' texel
 * coordinates together first (footprint_setup, two doubles at a time in SSE2), which also
 * decides once for all of them whether the vector loops apply (nearly always); otherwise one
 * scalar loop over the samples runs, specialised for bilinear_from's common case and for 3 and
 * 4 channels (BY_CASE). Every value a sample contributes is computed with the operations, and
 * summed in the order, of a lookup at a time, so the results are its bit for bit. */

#define K PEN__TEXTURE_SAMPLES

/* The grid's cell centres o_i = (i + 1/2) / n - 1/2, i < n, in double for the sample points and
 * in float for the backward's d_J: constants, where each sample used to divide for them (the
 * same values: the compiler rounds the constant expressions as the divisions did). */
_Static_assert(PEN__TEXTURE_GRID == 3, "grid_o and grid_of are written out for a 3 x 3 grid");
static const double grid_o[3] = {(0 + 0.5) / 3 - 0.5, (1 + 0.5) / 3 - 0.5, (2 + 0.5) / 3 - 0.5};
#define GRID_OF(i) (((float)(i) + 0.5f) / 3 - 0.5f)
static const float grid_of[3] = {GRID_OF(0), GRID_OF(1), GRID_OF(2)};

/* A footprint's samples, sample k at the grid's cell (k % n, k / n): their texel coordinates
 * (bilinear_from's fx, fy), and whether the vector loops below apply (vec: all in
 * bilinear_from's common case and a row short of the last row, so that a sample's 4-float loads
 * stay inside the texture, 3 channels, and the texture's sides under 2^15). */
typedef struct footprint_set {
    double f[K][2];
    int vec;
} footprint_set;

/* The corner tests: all nine samples fall in a range when the four corner samples do (rounding is
 * monotone, so each coordinate of a sample lies between those of the corner samples of its row
 * and column, or a corner's is not finite and the test fails). */
static const int corners[4] = {0, PEN__TEXTURE_GRID - 1, K - PEN__TEXTURE_GRID, K - 1};

/* Whether all nine samples fall in bilinear_from's common case (the scalar loops' test; the
 * vector case's is footprint_setup's). */
static int footprint_inside(const pen_image *tex, const footprint_set *fs) {
    const double x_end = (double)(tex->width - 1), y_end = (double)(tex->height - 1);
    int inside = 1;
    for (int c = 0; c < 4; ++c) {
        const double x = fs->f[corners[c]][0], y = fs->f[corners[c]][1];
        inside &= (x >= 0.0) & (x < x_end) & (y >= 0.0) & (y < y_end);
    }
    return inside;
}

#if defined(__SSE2__)
/* Sample k's point is (u + J0 o_x + J1 o_y, v + J2 o_x + J3 o_y), evaluated left to right: its
 * first two terms depend only on the column, its last only on the row, so each is computed once
 * per grid line, with the roundings it has sample by sample. The set-up runs two doubles at a
 * time, lane 0 the column coordinate and lane 1 the row's, with v's terms negated: -(v + J2 o)
 * is (-v) + (-J2) o and 1 - x is (-x) + 1 in IEEE arithmetic, whose rounding is symmetric; the
 * two differ only in the sign of a zero sum, which the added 1 drops (and lane 0 adds -0, which
 * changes nothing). So every f is bilinear_at's, bit for bit. */
INLINE void footprint_setup(const pen_image *tex, const float uv[2], const float J[4],
                            footprint_set *fs) {
    const int n = PEN__TEXTURE_GRID;
    const __m128 neg13 = _mm_setr_ps(0.0f, -0.0f, 0.0f, -0.0f);
    const __m128 uvf = _mm_loadl_pi(_mm_setzero_ps(), (const __m64 *)uv);
    const __m128 Jf = _mm_loadu_ps(J);
    const __m128d p = _mm_cvtps_pd(_mm_xor_ps(uvf, neg13)); /* {u, -v} */
    /* {J0, -J2, J1, -J3}: the column's and the row's factors */
    const __m128 Jx = _mm_xor_ps(_mm_shuffle_ps(Jf, Jf, _MM_SHUFFLE(3, 1, 2, 0)), neg13);
    const __m128d Jc = _mm_cvtps_pd(Jx), Jr = _mm_cvtps_pd(_mm_movehl_ps(Jx, Jx));
    __m128d col[PEN__TEXTURE_GRID], row[PEN__TEXTURE_GRID];
    for (int i = 0; i < n; ++i) {
        const __m128d o = _mm_set1_pd(grid_o[i]);
        col[i] = _mm_add_pd(p, _mm_mul_pd(Jc, o));
        row[i] = _mm_mul_pd(Jr, o);
    }
    /* the texel coordinates of bilinear_at: {x W - 0.5, (1 - y) H - 0.5} */
    const __m128d one = _mm_setr_pd(-0.0, 1.0), half = _mm_set1_pd(0.5);
    const __m128d WH = _mm_setr_pd((double)tex->width, (double)tex->height);
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            const __m128d x = _mm_add_pd(_mm_add_pd(col[i], row[j]), one);
            _mm_storeu_pd(fs->f[n * j + i], _mm_sub_pd(_mm_mul_pd(x, WH), half));
        }
    /* vec: 0 <= x < W - 1 and 0 <= y < H - 2 at the corners */
    const __m128d end = _mm_sub_pd(WH, _mm_setr_pd(1.0, 2.0));
    __m128d in = _mm_castsi128_pd(_mm_set1_epi32(-1));
    for (int c = 0; c < 4; ++c) {
        const __m128d f = _mm_loadu_pd(fs->f[corners[c]]);
        in = _mm_and_pd(in, _mm_and_pd(_mm_cmpge_pd(f, _mm_setzero_pd()), _mm_cmplt_pd(f, end)));
    }
    fs->vec = (_mm_movemask_pd(in) == 3) & (tex->channels == 3) &
              ((unsigned)(tex->width | tex->height) < 32768u);
}
#else
INLINE void footprint_setup(const pen_image *tex, const float uv[2], const float J[4],
                            footprint_set *fs) {
    const int n = PEN__TEXTURE_GRID;
    /* Sample k's point is (u + J0 o_x + J1 o_y, v + J2 o_x + J3 o_y), evaluated left to right:
     * its first two terms depend only on the column, its last only on the row, so each is
     * computed once per grid line, with the roundings it has sample by sample. */
    double col_u[PEN__TEXTURE_GRID], col_v[PEN__TEXTURE_GRID];
    double row_u[PEN__TEXTURE_GRID], row_v[PEN__TEXTURE_GRID];
    for (int i = 0; i < n; ++i) {
        col_u[i] = (double)uv[0] + (double)J[0] * grid_o[i];
        col_v[i] = (double)uv[1] + (double)J[2] * grid_o[i];
        row_u[i] = (double)J[1] * grid_o[i];
        row_v[i] = (double)J[3] * grid_o[i];
    }
    /* the texel coordinates of bilinear_at */
    const double W = (double)tex->width, H = (double)tex->height;
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            fs->f[n * j + i][0] = (col_u[i] + row_u[j]) * W - 0.5;
            fs->f[n * j + i][1] = (1.0 - (col_v[i] + row_v[j])) * H - 0.5;
        }
    fs->vec = 0; /* (no vector loops) */
}
#endif

/* Sample k: bilinear_from, its test made once for all the samples (inside, a constant in the
 * loops below). */
INLINE bilinear footprint_sample(const pen_image *tex, const footprint_set *fs, int inside, int k) {
    return inside ? bilinear_inside(tex, fs->f[k][0], fs->f[k][1])
                  : bilinear_from(tex, fs->f[k][0], fs->f[k][1]);
}

/* The footprint's loops, for a texture of nch channels, over samples all in bilinear_from's
 * common case or not (inside). */
INLINE void footprint_fwd_n(const pen_image *tex, int nch, int inside, const footprint_set *fs,
                            float rgb[3]) {
    double acc[3] = {0.0, 0.0, 0.0};
    for (int k = 0; k < K; ++k) {
        const bilinear s = footprint_sample(tex, fs, inside, k);
        float c[3];
        lerp_fwd(tex, nch, &s, c);
        for (int ch = 0; ch < 3; ++ch)
            acc[ch] += (double)c[ch];
    }
    for (int ch = 0; ch < 3; ++ch)
        rgb[ch] = (float)(acc[ch] / K);
}

INLINE void footprint_bwd_n(const pen_image *tex, int nch, int inside, const footprint_set *fs,
                            const float d_rgb[3], float *d_texels, float d_uv[2], float d_J[4]) {
    const int n = PEN__TEXTURE_GRID;
    const float inv = 1.0f / K;
    const float d_k[3] = {d_rgb[0] * inv, d_rgb[1] * inv, d_rgb[2] * inv};
    /* d_uv and d_J summed in locals, stored once: the same additions in the same order, as
     * neither is part of the texture, d_texels or the other */
    float uv_sum[2] = {0.0f, 0.0f}, J_sum[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    if (d_uv) uv_sum[0] = d_uv[0], uv_sum[1] = d_uv[1];
    if (d_J) J_sum[0] = d_J[0], J_sum[1] = d_J[1], J_sum[2] = d_J[2], J_sum[3] = d_J[3];
    const int want_uv = d_uv || d_J;
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            const bilinear s = footprint_sample(tex, fs, inside, n * j + i);
            if (d_texels) lerp_bwd_rows(tex, nch, &s, d_k, d_texels, 0, tex->height);
            if (!want_uv) continue;
            float g[2] = {0.0f, 0.0f};
            lerp_bwd_uv(tex, nch, &s, d_k, g);
            uv_sum[0] += g[0], uv_sum[1] += g[1];
            const float ox = grid_of[i], oy = grid_of[j];
            J_sum[0] += g[0] * ox, J_sum[1] += g[0] * oy, J_sum[2] += g[1] * ox;
            J_sum[3] += g[1] * oy;
        }
    if (d_uv) d_uv[0] = uv_sum[0], d_uv[1] = uv_sum[1];
    if (d_J) d_J[0] = J_sum[0], d_J[1] = J_sum[1], d_J[2] = J_sum[2], d_J[3] = J_sum[3];
}

INLINE void footprint_scatter_n(const pen_image *tex, int nch, int inside, const footprint_set *fs,
                                const float d_rgb[3], float *d_texels, long r0, long r1) {
    const float inv = 1.0f / K;
    const float d_k[3] = {d_rgb[0] * inv, d_rgb[1] * inv, d_rgb[2] * inv};
    for (int k = 0; k < K; ++k) {
        const bilinear s = footprint_sample(tex, fs, inside, k);
        lerp_bwd_rows(tex, nch, &s, d_k, d_texels, r0, r1);
    }
}

/* ---- The footprint's loops in SSE2, for 3-channel textures (fs->vec) ----
 * A texel's three channels lie in lanes 0-2 of one vector, loaded 4 floats at a time from its
 * first channel (lane 3, the next texel's first channel, is ignored; the scatter stores exactly
 * the floats of the texels it adds to). Each lane does the scalar loops' operations on its
 * channel in their order, and SSE arithmetic is the scalar code's IEEE single and double (the
 * default flags have no FMA to contract either), so the results are the scalar loops' bit for
 * bit; they save the per-channel loads, index arithmetic and loops (about 40% of the footprint's
 * texture instructions). */
#if defined(__SSE2__)

/* Lanes of one vector, by the integer shuffle: one instruction where shufps needs a copy. */
#define SHUF(v, q3, q2, q1, q0)                                                                    \
    _mm_castsi128_ps(_mm_shuffle_epi32(_mm_castps_si128(v), _MM_SHUFFLE(q3, q2, q1, q0)))
#define LANE(v, q) SHUF(v, q, q, q, q)

/* Sample k: the offset of its texel (i0, j0), its row j0, and its bilinear weights
 * {(1-a)(1-b), a(1-b), (1-a)b, ab} (lerp_fwd's wt), with x = {1-a, a, 1-b, b}, from
 * bilinear_inside's truncation. wi is {1, W} in 16-bit lanes: i0 and j0 lie in [0, 2^15)
 * (fs->vec), so j0 W + i0 is one multiply-add of their 16-bit halves. */
INLINE __m128 vec_sample(const footprint_set *fs, int k, __m128i wi, size_t *at, long *j0,
                         __m128 *x) {
    const __m128d f = _mm_loadu_pd(fs->f[k]);
    const __m128i ij = _mm_cvttpd_epi32(f);                             /* (long)fx, (long)fy */
    const __m128 ab = _mm_cvtpd_ps(_mm_sub_pd(f, _mm_cvtepi32_pd(ij))); /* {a, b, 0, 0} */
    const __m128i ij16 = _mm_packs_epi32(ij, ij);
    *at = (size_t)(uint32_t)_mm_cvtsi128_si32(_mm_madd_epi16(ij16, wi));
    *j0 = _mm_extract_epi16(ij16, 1);
    *x = _mm_unpacklo_ps(_mm_sub_ps(_mm_set1_ps(1.0f), ab), ab);
    return _mm_mul_ps(SHUF(*x, 1, 0, 1, 0), SHUF(*x, 3, 3, 2, 2));
}

/* wi of vec_sample */
INLINE __m128i vec_wi(const pen_image *tex) {
    return _mm_setr_epi16(1, (short)tex->width, 0, 0, 0, 0, 0, 0);
}

INLINE void footprint_fwd_vec(const pen_image *tex, const footprint_set *fs, float rgb[3]) {
    const size_t w3 = 3 * (size_t)tex->width;
    const __m128i wi = vec_wi(tex);
    const float *data = tex->data;
    __m128d acc01 = _mm_setzero_pd(), acc2 = _mm_setzero_pd();
    for (int k = 0; k < K; ++k) {
        size_t at;
        long j0;
        __m128 x;
        const __m128 wt = vec_sample(fs, k, wi, &at, &j0, &x);
        const float *t = data + 3 * at;
        /* (lerp_fwd's v starts at 0, and 0 + x is x but for a zero's sign, which the sum in
         * acc, never -0, drops) */
        __m128 v = _mm_mul_ps(LANE(wt, 0), _mm_loadu_ps(t));
        v = _mm_add_ps(v, _mm_mul_ps(LANE(wt, 1), _mm_loadu_ps(t + 3)));
        v = _mm_add_ps(v, _mm_mul_ps(LANE(wt, 2), _mm_loadu_ps(t + w3)));
        v = _mm_add_ps(v, _mm_mul_ps(LANE(wt, 3), _mm_loadu_ps(t + w3 + 3)));
        acc01 = _mm_add_pd(acc01, _mm_cvtps_pd(v));
        acc2 = _mm_add_pd(acc2, _mm_cvtps_pd(_mm_movehl_ps(v, v)));
    }
    double acc[4];
    _mm_storeu_pd(acc, acc01), _mm_storeu_pd(acc + 2, acc2);
    for (int ch = 0; ch < 3; ++ch)
        rgb[ch] = (float)(acc[ch] / K);
}

/* lerp_bwd_rows for one row of a sample, its texels q0 and q0 + 1 (adjacent: 6 floats at p),
 * given wa = {w_q0, w_q0, w_q0, w_q0+1} and wb = {w_q0+1, w_q0+1, ...}, dka = {dk0, dk1, dk2,
 * dk0} and dkb = {dk1, dk2, ...}: every float gets its one product, stored back by a 4-float and
 * a 2-float store that touch only the two texels. */
INLINE void vec_scatter_row(float *p, __m128 wa, __m128 wb, __m128 dka, __m128 dkb) {
    _mm_storeu_ps(p, _mm_add_ps(_mm_loadu_ps(p), _mm_mul_ps(wa, dka)));
    const __m128 lo = _mm_loadl_pi(_mm_setzero_ps(), (const __m64 *)(p + 4));
    _mm_storel_pi((__m64 *)(p + 4), _mm_add_ps(lo, _mm_mul_ps(wb, dkb)));
}

/* The texel part of sample (at, j0, wt) for rows [r0, r1) (lerp_bwd_rows), dk as in
 * vec_scatter_row, w3 = 3 W; band 0 (a constant) when the band holds both rows. */
INLINE void vec_scatter(size_t w3, size_t at, long j0, __m128 wt, __m128 dka, __m128 dkb,
                        float *d_texels, int band, long r0, long r1) {
    float *p = d_texels + 3 * at;
    if (!band || (j0 >= r0 && j0 < r1))
        vec_scatter_row(p, SHUF(wt, 1, 0, 0, 0), LANE(wt, 1), dka, dkb);
    if (!band || (j0 + 1 >= r0 && j0 + 1 < r1))
        vec_scatter_row(p + w3, SHUF(wt, 3, 2, 2, 2), LANE(wt, 3), dka, dkb);
}

/* {d_rgb[ch] / K} as dka and dkb of vec_scatter_row, and in lanes 0-2 of the result. */
INLINE __m128 vec_d_k(const float d_rgb[3], __m128 *dka, __m128 *dkb) {
    const float inv = 1.0f / K;
    const __m128 d =
        _mm_mul_ps(_mm_setr_ps(d_rgb[0], d_rgb[1], d_rgb[2], d_rgb[0]), _mm_set1_ps(inv));
    *dka = d, *dkb = SHUF(d, 2, 1, 2, 1);
    return d;
}

/* The grid's offsets {o_x, o_y, o_x, o_y} of sample k, the factors of its d_J terms. */
static _Alignas(16) const float grid_oxy[K][4] = {{GRID_OF(0), GRID_OF(0), GRID_OF(0), GRID_OF(0)},
                                                  {GRID_OF(1), GRID_OF(0), GRID_OF(1), GRID_OF(0)},
                                                  {GRID_OF(2), GRID_OF(0), GRID_OF(2), GRID_OF(0)},
                                                  {GRID_OF(0), GRID_OF(1), GRID_OF(0), GRID_OF(1)},
                                                  {GRID_OF(1), GRID_OF(1), GRID_OF(1), GRID_OF(1)},
                                                  {GRID_OF(2), GRID_OF(1), GRID_OF(2), GRID_OF(1)},
                                                  {GRID_OF(0), GRID_OF(2), GRID_OF(0), GRID_OF(2)},
                                                  {GRID_OF(1), GRID_OF(2), GRID_OF(1), GRID_OF(2)},
                                                  {GRID_OF(2), GRID_OF(2), GRID_OF(2), GRID_OF(2)}};

/* footprint_bwd_n for the vector case, with texels (d_texels) and uvj (d_uv or d_J) constants. */
INLINE void footprint_bwd_vec(const pen_image *tex, const footprint_set *fs, const float d_rgb[3],
                              float *d_texels, float d_uv[2], float d_J[4], int texels, int uvj) {
    const size_t w3 = 3 * (size_t)tex->width;
    const float *data = tex->data;
    __m128 dka, dkb;
    const __m128 dk = vec_d_k(d_rgb, &dka, &dkb);
    /* {uv_sum} and {J_sum} of footprint_bwd_n; g = {da W, -(db H)} */
    __m128 uv_sum = _mm_setzero_ps(), J_sum = _mm_setzero_ps();
    if (d_uv) uv_sum = _mm_setr_ps(d_uv[0], d_uv[1], 0.0f, 0.0f);
    if (d_J) J_sum = _mm_loadu_ps(d_J);
    const __m128 scale = _mm_setr_ps((float)tex->width, (float)tex->height, 0.0f, 0.0f);
    const __m128 flip = _mm_setr_ps(0.0f, -0.0f, 0.0f, 0.0f);
    const __m128i wi = vec_wi(tex);
    for (int k = 0; k < K; ++k) {
        size_t at;
        long j0;
        __m128 x;
        const __m128 wt = vec_sample(fs, k, wi, &at, &j0, &x);
        /* (every row: both of the sample's are in the texture) */
        if (texels) vec_scatter(w3, at, j0, wt, dka, dkb, d_texels, 0, 0, 0);
        if (!uvj) continue;
        const float *t = data + 3 * at;
        const __m128 t00 = _mm_loadu_ps(t), t10 = _mm_loadu_ps(t + 3);
        const __m128 t01 = _mm_loadu_ps(t + w3), t11 = _mm_loadu_ps(t + w3 + 3);
        /* lerp_bwd_uv's per-channel terms of da (x) and db (y); x's lanes are 1-a, a, 1-b, b */
        const __m128 da = _mm_mul_ps(dk, _mm_add_ps(_mm_mul_ps(LANE(x, 2), _mm_sub_ps(t10, t00)),
                                                    _mm_mul_ps(LANE(x, 3), _mm_sub_ps(t11, t01))));
        const __m128 db = _mm_mul_ps(dk, _mm_add_ps(_mm_mul_ps(LANE(x, 0), _mm_sub_ps(t01, t00)),
                                                    _mm_mul_ps(LANE(x, 1), _mm_sub_ps(t11, t10))));
        /* {da, db}: the channels summed in order, lanes 0 and 1 (lerp_bwd_uv's sums start at 0,
         * but 0 + x differs from x only in a zero's sign, which g's 0 + drops) */
        const __m128 lo = _mm_unpacklo_ps(da, db), hi = _mm_unpackhi_ps(da, db);
        const __m128 s = _mm_add_ps(_mm_add_ps(lo, _mm_movehl_ps(lo, lo)), hi);
        /* g = {0 + da W, 0 - db H}; x - y is x + (-y) in IEEE arithmetic (here with the sign
         * of a NaN flipped, as the vector loop has always had it) */
        const __m128 g = _mm_add_ps(_mm_setzero_ps(), _mm_xor_ps(_mm_mul_ps(s, scale), flip));
        uv_sum = _mm_add_ps(uv_sum, g);
        J_sum = _mm_add_ps(J_sum, _mm_mul_ps(SHUF(g, 1, 1, 0, 0), _mm_load_ps(grid_oxy[k])));
    }
    if (d_uv) _mm_storel_pi((__m64 *)d_uv, uv_sum);
    if (d_J) _mm_storeu_ps(d_J, J_sum);
}

INLINE void footprint_scatter_band(const pen_image *tex, const footprint_set *fs,
                                   const float d_rgb[3], float *d_texels, int band, long r0,
                                   long r1) {
    __m128 dka, dkb;
    vec_d_k(d_rgb, &dka, &dkb);
    const __m128i wi = vec_wi(tex);
    const size_t w3 = 3 * (size_t)tex->width;
    for (int k = 0; k < K; ++k) {
        size_t at;
        long j0;
        __m128 x;
        const __m128 wt = vec_sample(fs, k, wi, &at, &j0, &x);
        vec_scatter(w3, at, j0, wt, dka, dkb, d_texels, band, r0, r1);
    }
}

/* A band of every row (one thread's scatter) needs no row tests: the samples' rows are in the
 * texture (fs->vec). */
INLINE void footprint_scatter_vec(const pen_image *tex, const footprint_set *fs,
                                  const float d_rgb[3], float *d_texels, long r0, long r1) {
    if (r0 <= 0 && r1 >= tex->height)
        footprint_scatter_band(tex, fs, d_rgb, d_texels, 0, 0, 0);
    else
        footprint_scatter_band(tex, fs, d_rgb, d_texels, 1, r0, r1);
}

#undef LANE
#undef SHUF
#define VEC_CASE(fs, CALL)                                                                         \
    if ((fs).vec) {                                                                                \
        CALL;                                                                                      \
        return;                                                                                    \
    }
#else
#define VEC_CASE(fs, CALL)
#endif

/* Runs CALL, which names nch and inside, with both constants: the common case (footprint_inside)
 * for 3 and 4 channels and for any, and the general one. */
#define BY_CASE(tex, fs, CALL)                                                                     \
    do {                                                                                           \
        const int in_ = footprint_inside(tex, fs);                                                 \
        if (in_ && (tex)->channels == 3) {                                                         \
            const int nch = 3, inside = 1;                                                         \
            CALL;                                                                                  \
        } else if (in_ && (tex)->channels == 4) {                                                  \
            const int nch = 4, inside = 1;                                                         \
            CALL;                                                                                  \
        } else if (in_) {                                                                          \
            const int nch = (tex)->channels, inside = 1;                                           \
            CALL;                                                                                  \
        } else {                                                                                   \
            const int nch = (tex)->channels, inside = 0;                                           \
            CALL;                                                                                  \
        }                                                                                          \
    } while (0)

/* The scalar loops, out of line: inlined, their registers and spills would weigh on every call,
 * the vector case's (nearly all) too. */
#define NOINLINE static __attribute__((noinline))

NOINLINE void footprint_fwd_any(const pen_image *tex, const footprint_set *fs, float rgb[3]) {
    BY_CASE(tex, fs, footprint_fwd_n(tex, nch, inside, fs, rgb));
}

NOINLINE void footprint_bwd_any(const pen_image *tex, const footprint_set *fs, const float d_rgb[3],
                                float *d_texels, float d_uv[2], float d_J[4]) {
    BY_CASE(tex, fs, footprint_bwd_n(tex, nch, inside, fs, d_rgb, d_texels, d_uv, d_J));
}

NOINLINE void footprint_scatter_any(const pen_image *tex, const footprint_set *fs,
                                    const float d_rgb[3], float *d_texels, long r0, long r1) {
    BY_CASE(tex, fs, footprint_scatter_n(tex, nch, inside, fs, d_rgb, d_texels, r0, r1));
}

void pen__texture_footprint_fwd(const pen_image *tex, const float uv[2], const float J[4],
                                float rgb[3]) {
    footprint_set fs;
    footprint_setup(tex, uv, J, &fs);
    VEC_CASE(fs, footprint_fwd_vec(tex, &fs, rgb));
    footprint_fwd_any(tex, &fs, rgb);
}

void pen__texture_footprint_bwd(const pen_image *tex, const float uv[2], const float J[4],
                                const float d_rgb[3], float *d_texels, float d_uv[2],
                                float d_J[4]) {
    footprint_set fs;
    footprint_setup(tex, uv, J, &fs);
#if defined(__SSE2__)
    if (fs.vec) { /* (with constants for the loop's two parts) */
        if (d_texels && (d_uv || d_J))
            footprint_bwd_vec(tex, &fs, d_rgb, d_texels, d_uv, d_J, 1, 1);
        else if (d_texels)
            footprint_bwd_vec(tex, &fs, d_rgb, d_texels, d_uv, d_J, 1, 0);
        else if (d_uv || d_J)
            footprint_bwd_vec(tex, &fs, d_rgb, d_texels, d_uv, d_J, 0, 1);
        return;
    }
#endif
    footprint_bwd_any(tex, &fs, d_rgb, d_texels, d_uv, d_J);
}

int pen__texture_rows(const pen_image *tex, const float uv[2], const float J[4], long *first,
                      long *last) {
    const double reach = J ? 0.5 * (fabs((double)J[2]) + fabs((double)J[3])) : 0.0;
    const double H = (double)tex->height;
    const double lo = (1.0 - ((double)uv[1] + reach)) * H - 0.5;
    const double hi = (1.0 - ((double)uv[1] - reach)) * H - 0.5;
    if (!(lo >= -1e9 && hi <= 1e9) || hi - lo >= H - 4.0) return 0;
    /* rows a .. b, unwrapped, a row more on each side than the samples' floor() can reach */
    const long a = (long)floor(lo) - 1, b = (long)floor(hi) + 2;
    const long h = tex->height;
    *first = ((a % h) + h) % h, *last = ((b % h) + h) % h;
    return 1;
}

/* Whether the lookup may read a texel of rows [r0, r1) (pen__texture_rows). */
static int lookup_may_read_rows(const pen_image *tex, const float uv[2], const float J[4], long r0,
                                long r1) {
    long wa, wb;
    if (!pen__texture_rows(tex, uv, J, &wa, &wb)) return 1;
    if (wa <= wb) return wa < r1 && wb >= r0;
    return wa < r1 || wb >= r0; /* across the last row: [wa, h) and [0, wb] */
}

void pen__texture_scatter_rows(const pen_image *tex, const float uv[2], const float J[4],
                               const float d_rgb[3], float *d_texels, long r0, long r1) {
    /* (a band of every row needs no test: the lookup reads some of them) */
    if ((r0 > 0 || r1 < tex->height) && !lookup_may_read_rows(tex, uv, J, r0, r1)) return;
    if (!J) {
        const bilinear s = bilinear_at(tex, (double)uv[0], (double)uv[1]);
        lerp_bwd_rows(tex, tex->channels, &s, d_rgb, d_texels, r0, r1);
        return;
    }
    footprint_set fs;
    footprint_setup(tex, uv, J, &fs);
    VEC_CASE(fs, footprint_scatter_vec(tex, &fs, d_rgb, d_texels, r0, r1));
    footprint_scatter_any(tex, &fs, d_rgb, d_texels, r0, r1);
}
