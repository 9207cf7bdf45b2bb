// flopcount: the floating-point operations the per-pixel shading kernel executes, counted from
// the code itself, on a real frame (bench/NOTES.md).
//
// The kernel is written once in src/shade/shade_ops.inc and src/sh/sh_ops.inc over a type REAL;
// the library compiles it with float and double. This tool compiles the same text a third time,
// as C++ with REAL = R, a float that counts every +, -, *, /, sqrt, exp and comparison it takes
// part in. Values the kernel derives only from per-frame constants (the Gaunt values, SH
// normalisation constants, epsilon, the clamped cosine, casts of loop indices) are marked
// constant, and an operation between two constants is tallied apart ("hoistable"): a tuned kernel
// computes those once per frame. The calls from shade_ops.inc into the SH engine are redirected
// through wrappers (macro rescanning of the SUF() names) that attribute the counts to a stage.
//
// The frame is set up as src/render/forward.c does through the public API: scene, fitted spheres,
// posed mesh, G-buffer, interpolated points and normals; every shaded pixel (object or ground)
// runs the forward and the backward the bench times (all gradient groups but vertices: d_x and
// d_n on object pixels, d_rho, d_sh, d_spheres). Not counted: texture lookups, the background,
// rasterization, antialiasing, and the double-precision accumulations (d_sh, d_spheres).
//
// Build (from the repository root, after building the library into build/):
//   g++ -O2 -std=c++17 -Iinclude -Isrc bench/flopcount.cpp build/libpenumbra.a
//     $(pkg-config --libs libcjson OpenEXR stb) -lembree3 -fopenmp -o build/flopcount
// Run: build/flopcount [SCENE.json] [--size N] [--spheres N] [--bands N] [--stride K]
//   (--stride K counts every K-th pixel in x and y and scales up; default 1: every pixel)
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

extern "C" {
#include "penumbra/penumbra.h"
#include "penumbra/fit.h"
#include "core/internal.h"
#include "sh/sh_internal.h"
#include "render/render_internal.h"
}

// ---- The counting float -------------------------------------------------------------------------

// OP_DIVC: a division by a per-frame constant (a multiplication by a precomputed reciprocal in a
// tuned kernel); OP_DIV: by a value.
enum Op { OP_ADD, OP_MUL, OP_DIV, OP_DIVC, OP_SQRT, OP_EXP, OP_CMP, OP_CONST, OP_COUNT };
static const char *const op_names[OP_COUNT] = {"add",  "mul", "div",  "div/k",
                                               "sqrt", "exp", "cmp", "hoist"};

enum Stage {
    ST_GLUE,        // the kernel's own loops: weights, sums over spheres, shading dot products
    ST_ROTATE,      // pen_sh_rotate_zonal outside logvis: the clamped cosine H_n
    ST_LOGVIS,      // per-sphere log-visibility (cap geometry, zonal cap, zonal rotation)
    ST_EXP,         // the SH exponential
    ST_PRODUCT,     // V * H
    ST_ROTATE_BWD,  // backward of H_n
    ST_LOGVIS_BWD,  // backward of the log-visibility
    ST_EXP_BWD,     // backward of the exponential (it recomputes its forward)
    ST_PRODUCT_BWD, // backward of V * H
    ST_COUNT
};
static const char *const stage_names[ST_COUNT] = {"glue",       "rotate H",   "logvis",
                                                  "exp",        "product",    "rotate H bwd",
                                                  "logvis bwd", "exp bwd",    "product bwd"};

static int g_stage = ST_GLUE;
static int g_pass = 0; // 0 forward, 1 backward
static double g_count[2][ST_COUNT][OP_COUNT];

static inline void tally(Op op, bool both_const) {
    g_count[g_pass][g_stage][both_const ? OP_CONST : op] += 1.0;
}

struct R {
    float v;
    bool k; // a per-frame constant
    R() : v(0.0f), k(true) {}
    R(double x) : v((float)x), k(true) {}
    static R data(float x) {
        R r;
        r.v = x, r.k = false;
        return r;
    }
    explicit operator double() const { return (double)v; }
};

static inline R mk(float v, bool k) {
    R r;
    r.v = v, r.k = k;
    return r;
}
#define BINOP(sym, op)                                                                            \
    static inline R operator sym(R a, R b) {                                                      \
        tally(op, a.k && b.k);                                                                    \
        return mk(a.v sym b.v, a.k && b.k);                                                       \
    }                                                                                             \
    static inline R &operator sym##=(R & a, R b) {                                                \
        a = a sym b;                                                                              \
        return a;                                                                                 \
    }
BINOP(+, OP_ADD)
BINOP(-, OP_ADD)
BINOP(*, OP_MUL)
static inline R operator/(R a, R b) {
    tally(b.k ? OP_DIVC : OP_DIV, a.k && b.k);
    return mk(a.v / b.v, a.k && b.k);
}
static inline R &operator/=(R &a, R b) {
    a = a / b;
    return a;
}
static inline R operator-(R a) { return mk(-a.v, a.k); } // a sign flip, not an operation
#define CMPOP(sym)                                                                                \
    static inline bool operator sym(R a, R b) {                                                   \
        tally(OP_CMP, a.k && b.k);                                                                \
        return a.v sym b.v;                                                                       \
    }
CMPOP(<)
CMPOP(<=)
CMPOP(>)
CMPOP(>=)
CMPOP(==)
CMPOP(!=)
static inline R sqrt(R a) {
    tally(OP_SQRT, a.k);
    return mk(std::sqrt(a.v), a.k);
}
static inline R exp(R a) {
    tally(OP_EXP, a.k);
    return mk(std::exp(a.v), a.k);
}
static inline R ldexp(R a, int e) { return mk(std::ldexp(a.v, e), a.k); } // exponent shift

// ---- The kernel, compiled over R ----------------------------------------------------------------

#define REAL R
#define SUF(name) name##_cnt
#define PEN_SH_REAL_IS_FLOAT 1
#include "sh/sh_ops.inc"

// Stage wrappers: the outermost wrapped call names the stage (logvis's own zonal rotation stays
// logvis).
struct Scope {
    int prev;
    explicit Scope(int s) : prev(g_stage) {
        if (g_stage == ST_GLUE) g_stage = s;
    }
    ~Scope() { g_stage = prev; }
};
static void w_rotate(int b, const R *z, const R d[3], R *o) {
    Scope s(ST_ROTATE);
    pen_sh_rotate_zonal_cnt(b, z, d, o);
}
static void w_rotate_bwd(int b, const R *z, const R d[3], const R *d_o, R *d_z, R d_d[3]) {
    Scope s(ST_ROTATE_BWD);
    pen_sh_rotate_zonal_bwd_cnt(b, z, d, d_o, d_z, d_d);
}
static void w_logvis(int b, const R x[3], const R c[3], R r, R eps, R *f) {
    Scope s(g_pass ? ST_LOGVIS_BWD : ST_LOGVIS);
    pen_sh_logvis_cnt(b, x, c, r, eps, f);
}
static void w_logvis_bwd(int b, const R x[3], const R c[3], R r, R eps, const R *d_f, R d_x[3],
                         R d_c[3], R *d_r, R *d_eps) {
    Scope s(ST_LOGVIS_BWD);
    pen_sh_logvis_bwd_cnt(b, x, c, r, eps, d_f, d_x, d_c, d_r, d_eps);
}
static void w_exp(const pen_sh_exp_model *m, const pen_sh_gaunt *g, const R *F, R *V) {
    Scope s(ST_EXP);
    pen_sh_exp_cnt(m, g, F, V);
}
static void w_exp_bwd(const pen_sh_exp_model *m, const pen_sh_gaunt *g, const R *F, const R *d_V,
                      R *d_F) {
    Scope s(ST_EXP_BWD);
    pen_sh_exp_bwd_cnt(m, g, F, d_V, d_F);
}
static void w_product(const pen_sh_gaunt *g, const R *a, const R *b, R *c) {
    Scope s(g_pass ? ST_PRODUCT_BWD : ST_PRODUCT);
    pen_sh_product_cnt(g, a, b, c);
}
static void w_product_bwd(const pen_sh_gaunt *g, const R *a, const R *b, const R *d_c, R *d_a,
                          R *d_b) {
    Scope s(ST_PRODUCT_BWD);
    pen_sh_product_bwd_cnt(g, a, b, d_c, d_a, d_b);
}
#define pen_sh_rotate_zonal_cnt w_rotate
#define pen_sh_rotate_zonal_bwd_cnt w_rotate_bwd
#define pen_sh_logvis_cnt w_logvis
#define pen_sh_logvis_bwd_cnt w_logvis_bwd
#define pen_sh_exp_cnt w_exp
#define pen_sh_exp_bwd_cnt w_exp_bwd
#define pen_sh_product_cnt w_product
#define pen_sh_product_bwd_cnt w_product_bwd
#include "shade/shade_ops.inc"

// ---- The frame ----------------------------------------------------------------------------------

static void die(pen_context *ctx, const char *what) {
    std::fprintf(stderr, "flopcount: %s: %s\n", what, pen_context_error(ctx));
    std::exit(1);
}

int main(int argc, char **argv) {
    const char *path = "examples/scenes/spot_city.json";
    int size = 512, spheres = 32, bands = 4, stride = 1;
    for (int i = 1; i < argc; ++i) {
        if (!std::strcmp(argv[i], "--size") && i + 1 < argc) size = std::atoi(argv[++i]);
        else if (!std::strcmp(argv[i], "--spheres") && i + 1 < argc) spheres = std::atoi(argv[++i]);
        else if (!std::strcmp(argv[i], "--bands") && i + 1 < argc) bands = std::atoi(argv[++i]);
        else if (!std::strcmp(argv[i], "--stride") && i + 1 < argc) stride = std::atoi(argv[++i]);
        else path = argv[i];
    }
    if (size < 1 || spheres < 1 || bands < 1 || bands > PEN_SH_MAX_BANDS || stride < 1) {
        std::fprintf(stderr, "flopcount: bad arguments\n");
        return 2;
    }
    pen_context *ctx = pen_context_create();
    pen_scene sc;
    if (pen_scene_load(ctx, path, &sc)) die(ctx, path);
    // The bench's case set-up: size, bands (lighting re-projected), fitted spheres.
    sc.camera.width = sc.camera.height = size;
    if (bands != sc.sh_bands && sc.lighting.envmap.data &&
        pen_envmap_to_sh(ctx, &sc.lighting.envmap, bands, sc.lighting.rotation_y_deg,
                         sc.lighting.scale, sc.lighting.sh))
        die(ctx, "lighting");
    if (bands != sc.sh_bands)
        sc.shadow.epsilon = (float)pen_sh_exp_model_default(sc.shadow.exp, bands).epsilon;
    sc.sh_bands = bands;
    for (int o = 0; o < sc.object_count; ++o) {
        pen_spheres_free(&sc.objects[o].spheres);
        sc.objects[o].fit_spheres = spheres;
    }
    if (pen_scene_fit_spheres(ctx, &sc)) die(ctx, "fit");

    // Posed geometry, G-buffer and per-pixel attributes, as forward.c's prepare().
    const int O = sc.object_count;
    std::vector<std::vector<float>> world(O), vnormal(O);
    std::vector<pen_raster_mesh> meshes(O);
    std::vector<float> sph;   // world-space spheres of all objects
    std::vector<float> kappa; // their overlap weights, as the renderer computes them
    for (int o = 0; o < O; ++o) {
        const pen_object *ob = &sc.objects[o];
        const int V = ob->mesh.vertex_count, T = ob->mesh.triangle_count;
        world[o].resize(3 * (size_t)V), vnormal[o].resize(3 * (size_t)V);
        pen_pose_points_fwd(&ob->pose, V, ob->mesh.positions, world[o].data());
        if (pen_vertex_normals_fwd(ctx, V, world[o].data(), T, ob->mesh.indices,
                                   vnormal[o].data()))
            die(ctx, "normals");
        meshes[o].vertex_count = V, meshes[o].triangle_count = T;
        meshes[o].positions = world[o].data(), meshes[o].indices = ob->mesh.indices;
        meshes[o].adjacency = nullptr;
        std::vector<float> k((size_t)ob->spheres.count);
        if (ob->spheres.count > 0 && pen_spheres_overlap_weights(ctx, &ob->spheres, k.data()))
            die(ctx, "overlap weights");
        kappa.insert(kappa.end(), k.begin(), k.end());
        for (int i = 0; i < ob->spheres.count; ++i) {
            float c[3];
            pen_pose_apply(&ob->pose, ob->spheres.data + 4 * (size_t)i, c);
            sph.insert(sph.end(), {c[0], c[1], c[2], ob->spheres.data[4 * i + 3] * ob->pose.scale});
        }
    }
    pen_view view;
    pen_gbuffer gb;
    if (pen_view_init(ctx, &sc.camera, &view) || pen_gbuffer_create(ctx, size, size, &gb) ||
        pen_raster_gbuffer(ctx, &view, meshes.data(), O, &sc.ground, &gb))
        die(ctx, "raster");
    const size_t np = (size_t)size * (size_t)size;
    std::vector<float> X(3 * np), NR(3 * np);
    pen_gbuffer_points(&view, &gb, X.data());
    for (int o = 0; o < O; ++o) {
        pen_interpolate_fwd(&gb, o, sc.objects[o].mesh.indices, world[o].data(), 3, X.data());
        pen_interpolate_fwd(&gb, o, sc.objects[o].mesh.indices, vnormal[o].data(), 3, NR.data());
    }
    const pen_sh_exp_model model = pen_sh_exp_model_default(sc.shadow.exp, bands);
    pen__shade_params p;
    pen__shade_params_init(&p, bands, &model, (double)sc.shadow.epsilon, 1);

    const int S = (int)(sph.size() / 4), nc = bands * bands;
    std::vector<R> rs(sph.size());
    for (size_t i = 0; i < sph.size(); ++i) rs[i] = R::data(sph[i]);
    std::vector<R> rk(kappa.size());
    for (size_t i = 0; i < kappa.size(); ++i) rk[i] = R::data(kappa[i]);
    R sh[PEN_SH_MAX_COEFFS][3];
    for (int k = 0; k < nc; ++k)
        for (int ch = 0; ch < 3; ++ch) sh[k][ch] = R(sc.lighting.sh[k][ch]); // per-frame constant
    std::vector<double> d_sph(4 * (size_t)S);
    double px_obj = 0, px_ground = 0, px_bg = 0, active = 0, ramp = 0;
    for (int y = 0; y < size; y += stride)
        for (int xx = 0; xx < size; xx += stride) {
            const size_t i = (size_t)y * (size_t)size + (size_t)xx;
            const int surf = gb.surface[i];
            if (surf == PEN_SURFACE_BACKGROUND) {
                px_bg += 1;
                continue;
            }
            const bool obj = surf >= 0;
            (obj ? px_obj : px_ground) += 1;
            float n[3] = {0.0f, 1.0f, 0.0f};
            if (obj) pen_normalize_fwd(1, &NR[3 * i], n); // facing sign +1: a closed mesh
            R x[3], nn[3], rho[3], rgb[3], fv[2 * PEN_SH_MAX_COEFFS];
            for (int a = 0; a < 3; ++a)
                x[a] = R::data(X[3 * i + a]), nn[a] = R::data(n[a]), rho[a] = R::data(0.5f);
            // Census of the spheres' weights (uncounted: plain floats).
            for (int s = 0; s < S; ++s) {
                const float *c = &sph[4 * (size_t)s];
                const float h = (n[0] * (c[0] - X[3 * i]) + n[1] * (c[1] - X[3 * i + 1]) +
                                 n[2] * (c[2] - X[3 * i + 2])) / c[3];
                active += h > PEN_RENDER_SELF_H0;
                ramp += h > PEN_RENDER_SELF_H0 && h < PEN_RENDER_SELF_H1;
            }
            g_pass = 0;
            pen__shade_fwd_cnt(&p, sh, S, rs.data(), rk.data(), x, nn, rho, rgb, fv);
            g_pass = 1;
            R d_rgb[3] = {R::data(0.01f), R::data(-0.02f), R::data(0.015f)};
            R d_x[3], d_n[3], d_rho[3];
            double d_sh[PEN_SH_MAX_COEFFS][3];
            pen__shade_bwd_cnt(&p, sh, S, rs.data(), rk.data(), x, nn, rho, d_rgb, fv, d_sh, d_sph.data(),
                               obj ? d_x : nullptr, obj ? d_n : nullptr, d_rho);
        }
    const double scale = (double)stride * (double)stride, shaded = px_obj + px_ground;
    std::printf("scene %s: %dx%d, %d spheres, %d bands, Gaunt entries %d, squarings %d, "
                "stride %d\n",
                path, size, size, S, bands, p.gaunt->count, model.squarings, stride);
    std::printf("pixels: %.0f object, %.0f ground, %.0f background; spheres with w > 0 per shaded "
                "pixel %.2f, in the smoothstep ramp %.2f\n",
                px_obj * scale, px_ground * scale, px_bg * scale, active / shaded, ramp / shaded);
    std::printf("Gaunt entries by bands:");
    for (int b = 1; b <= PEN_SH_MAX_BANDS; ++b) std::printf(" %d:%d", b, pen_sh_gaunt_table(b)->count);
    std::printf("\n\nper shaded pixel (flops = add + mul + div + div/k + sqrt; exp and cmp "
                "apart; hoist = operations between per-frame constants)\n");
    std::printf("%-6s %-13s %9s", "pass", "stage", "flops");
    for (int op = 0; op < OP_COUNT; ++op) std::printf(" %8s", op_names[op]);
    std::printf("\n");
    for (int pass = 0; pass < 2; ++pass) {
        double tot[OP_COUNT] = {0};
        for (int st = 0; st < ST_COUNT; ++st) {
            const double *c = g_count[pass][st];
            const double fl = c[OP_ADD] + c[OP_MUL] + c[OP_DIV] + c[OP_DIVC] + c[OP_SQRT];
            if (fl == 0 && c[OP_CONST] == 0 && c[OP_CMP] == 0) continue;
            std::printf("%-6s %-13s %9.1f", pass ? "bwd" : "fwd", stage_names[st], fl / shaded);
            for (int op = 0; op < OP_COUNT; ++op) {
                std::printf(" %8.1f", c[op] / shaded);
                tot[op] += c[op];
            }
            std::printf("\n");
        }
        const double fl = tot[OP_ADD] + tot[OP_MUL] + tot[OP_DIV] + tot[OP_DIVC] + tot[OP_SQRT];
        std::printf("%-6s %-13s %9.1f", pass ? "bwd" : "fwd", "TOTAL", fl / shaded);
        for (int op = 0; op < OP_COUNT; ++op) std::printf(" %8.1f", tot[op] / shaded);
        std::printf("   -> %.3f GFLOP per frame\n", fl * scale * 1e-9);
    }
    pen_gbuffer_free(&gb);
    pen_scene_free(&sc);
    pen_context_destroy(ctx);
    return 0;
}
