/* Edge antialiasing: vertex-position gradients against central finite differences of the
 * antialiased image (a triangle over a background, and a full rasterize-shade-antialias chain
 * with occlusion and a ground plane), the colour backward as the exact transpose of the forward,
 * silhouette detection on a closed mesh, the gradient of the image sum against the exact
 * derivative of the covered area, thread-count independence and robustness. */
#include "raster_util.h"
#include "raster/raster_internal.h" /* the ground border blend */

/* ---- Helpers ------------------------------------------------------------------------------- */

static pen_status aa_fwd(const pen_gbuffer *gb, const pen_view *view, const pen_raster_mesh *m,
                         int n, const float *color, int channels, float *out, int threads) {
    pen_context *ctx = pen_context_create();
    pen_context_set_threads(ctx, threads);
    pen_status st = pen_antialias_fwd(ctx, gb, view, m, n, color, channels, out);
    pen_context_destroy(ctx);
    return st;
}

static pen_status aa_bwd(const pen_gbuffer *gb, const pen_view *view, const pen_raster_mesh *m,
                         int n, const float *color, int channels, const float *d_out,
                         float *d_color, float *const *d_pos, int threads) {
    pen_context *ctx = pen_context_create();
    pen_context_set_threads(ctx, threads);
    pen_status st = pen_antialias_bwd(ctx, gb, view, m, n, color, channels, d_out, d_color, d_pos);
    pen_context_destroy(ctx);
    return st;
}

static double dot_d(const float *a, const float *b, size_t n) {
    double s = 0;
    for (size_t i = 0; i < n; ++i)
        s += (double)a[i] * (double)b[i];
    return s;
}

/* Central difference of a scene loss in one coordinate *x, at step h. The loss is smooth only
 * while no pixel changes coverage and no edge switches between the horizontal and the vertical
 * pair scheme (a vertex crossing a row or column of pixel centres; see docs/rasterizer.md), so
 * the difference is used only if both G-buffers match gb and both one-sided differences agree;
 * returns 0 otherwise. */
typedef double (*loss_fn)(const void *scene, const float *W, pen_gbuffer *gb);

static int fd_smooth(loss_fn loss, const void *scene, const float *W, float *x, float h, double l0,
                     const pen_gbuffer *gb, pen_gbuffer *gp, pen_gbuffer *gm, double *fd) {
    float save = *x;
    *x = save + h;
    double lp = loss(scene, W, gp);
    *x = save - h;
    double lm = loss(scene, W, gm);
    *x = save;
    if (!ru_same_coverage(gp, gb) || !ru_same_coverage(gm, gb)) return 0;
    double up = (lp - l0) / (double)h, down = (l0 - lm) / (double)h;
    if (fabs(up - down) > 0.05 * fmax(fmax(fabs(up), fabs(down)), 1.0)) return 0;
    *fd = (lp - lm) / (2.0 * (double)h);
    return 1;
}

/* Flat colours: object k gets flat[k], background and ground their own. */
static void flat_colors(const pen_gbuffer *gb, float *color) {
    static const float obj[3][3] = {{1.0f, 0.5f, 0.25f}, {0.2f, 0.9f, 0.4f}, {0.6f, 0.1f, 0.7f}};
    static const float bg[3] = {0.1f, 0.2f, 0.3f}, ground[3] = {0.5f, 0.5f, 0.45f};
    for (size_t i = 0; i < (size_t)gb->width * gb->height; ++i) {
        int s = gb->surface[i];
        const float *c = s >= 0 ? obj[s % 3] : s == PEN_SURFACE_GROUND ? ground : bg;
        memcpy(color + 3 * i, c, 3 * sizeof(float));
    }
}

/* One mesh (and optionally the ground) in flat colours: the loss W . antialias(colours) then
 * depends on the vertices only through the silhouette blending. */
typedef struct flat_scene {
    pen_view view;
    pen_raster_mesh mesh;
    const pen_ground *ground;
} flat_scene;

static double flat_loss(const void *scene, const float *W, pen_gbuffer *gb) {
    const flat_scene *s = scene;
    size_t n = (size_t)s->view.width * s->view.height;
    float *color = malloc(3 * n * sizeof(float)), *out = malloc(3 * n * sizeof(float));
    CHECK(ru_raster(&s->view, &s->mesh, 1, s->ground, gb, 0) == PEN_OK);
    flat_colors(gb, color);
    CHECK(aa_fwd(gb, &s->view, &s->mesh, 1, color, 3, out, 0) == PEN_OK);
    double l = dot_d(W, out, 3 * n);
    free(color), free(out);
    return l;
}

/* ---- A triangle over a background ---------------------------------------------------------- */

typedef struct tri_scene {
    flat_scene fs;
    float pos[9];
    uint32_t idx[3];
    int32_t adj[3];
} tri_scene;

static void tri_scene_init(tri_scene *s, unsigned long long *seed) {
    pen_camera cam = ru_camera(32, 32, 45.0f, 0.1f, 0.2f, 3.0f, 0, 0, 0);
    s->fs.view = ru_view(&cam);
    s->fs.ground = NULL;
    for (int k = 0; k < 3; ++k) {
        double a = 2.1 * k + 0.5 * check_rand_(seed), r = 0.6 + 0.3 * check_rand_(seed);
        s->pos[3 * k] = (float)(r * cos(a));
        s->pos[3 * k + 1] = (float)(r * sin(a));
        s->pos[3 * k + 2] = (float)(0.4 * (2 * check_rand_(seed) - 1));
        s->idx[k] = (uint32_t)k;
    }
    CHECK(pen_raster_adjacency(NULL, 3, 1, s->idx, s->adj) == PEN_OK);
    s->fs.mesh = ru_mesh(3, s->pos, 1, s->idx, s->adj);
}

static void test_triangle_over_background_fd(void) {
    unsigned long long seed = 61;
    size_t n = 32 * 32;
    float *W = malloc(3 * n * sizeof(float)), *color = malloc(3 * n * sizeof(float));
    for (size_t i = 0; i < 3 * n; ++i)
        W[i] = (float)(2 * check_rand_(&seed) - 1);
    pen_gbuffer gb = ru_gbuffer(32, 32), gp = ru_gbuffer(32, 32), gm = ru_gbuffer(32, 32);
    int tested = 0, total = 0;
    const float h = 1.0f / 4096; /* ~3e-3 pixel */
    for (int rep = 0; rep < 8; ++rep) {
        tri_scene s;
        tri_scene_init(&s, &seed);
        double l0 = flat_loss(&s.fs, W, &gb);
        flat_colors(&gb, color);
        float d_pos[9] = {0}, *d_positions[1] = {d_pos};
        CHECK(aa_bwd(&gb, &s.fs.view, &s.fs.mesh, 1, color, 3, W, NULL, d_positions, 0) == PEN_OK);
        for (int j = 0; j < 9; ++j) {
            double fd;
            ++total;
            if (!fd_smooth(flat_loss, &s.fs, W, s.pos + j, h, l0, &gb, &gp, &gm, &fd)) continue;
            ++tested;
            /* Tolerance: 1% relative, floor 0.5. The image is float: rounding of the ~60
             * blended pixels puts ~1e-3 of noise on these differences at this step. */
            CHECK_REL(d_pos[j], fd, 1e-2, 0.5);
        }
    }
    CHECK(tested >= total * 3 / 4);
    free(W), free(color);
    pen_gbuffer_free(&gb), pen_gbuffer_free(&gp), pen_gbuffer_free(&gm);
}

/* ---- Full chain: rasterize, interpolate, shade, antialias ---------------------------------- */

/* A smooth colour of a world point, and its Jacobian dC/dx (row c: d colour_c / d x). */
static void shade(const float *x, float *c, double J[9]) {
    double X = x[0], Y = x[1], Z = x[2];
    c[0] = (float)(0.5 + 0.4 * sin(2 * X + Y));
    c[1] = (float)(0.5 + 0.4 * cos(X - 3 * Z));
    c[2] = (float)(0.3 + 0.2 * Y);
    if (!J) return;
    double a = 0.4 * cos(2 * X + Y), b = -0.4 * sin(X - 3 * Z);
    double M[9] = {2 * a, a, 0, b, 0, -3 * b, 0, 0.2, 0};
    memcpy(J, M, sizeof M);
}

/* Per-pixel colours: shaded mesh and ground points, a constant background. `pos` receives the
 * interpolated mesh positions. */
static void chain_colors(const ru_scene *s, const pen_gbuffer *gb, float *pos, float *color) {
    size_t n = (size_t)gb->width * gb->height;
    pen_gbuffer_points(&s->view, gb, pos);
    pen_interpolate_fwd(gb, 0, s->idx0, s->pos0, 3, pos);
    pen_interpolate_fwd(gb, 1, s->idx1, s->pos1, 3, pos);
    for (size_t i = 0; i < n; ++i) {
        if (gb->surface[i] == PEN_SURFACE_BACKGROUND) {
            color[3 * i] = 0.1f, color[3 * i + 1] = 0.2f, color[3 * i + 2] = 0.9f;
            continue;
        }
        shade(pos + 3 * i, color + 3 * i, NULL);
    }
}

static double chain_loss(const void *scene, const float *W, pen_gbuffer *gb) {
    const ru_scene *s = scene;
    size_t n = (size_t)s->cam.width * s->cam.height;
    float *pos = malloc(3 * n * sizeof(float)), *color = malloc(3 * n * sizeof(float));
    float *out = malloc(3 * n * sizeof(float));
    CHECK(ru_raster(&s->view, s->meshes, 2, &s->ground, gb, 0) == PEN_OK);
    chain_colors(s, gb, pos, color);
    CHECK(aa_fwd(gb, &s->view, s->meshes, 2, color, 3, out, 0) == PEN_OK);
    double l = dot_d(W, out, 3 * n);
    free(pos), free(color), free(out);
    return l;
}

static void test_full_chain_fd(void) {
    ru_scene s;
    ru_scene_init(&s);
    size_t n = (size_t)s.cam.width * s.cam.height;
    unsigned long long seed = 62;
    float *W = malloc(3 * n * sizeof(float));
    for (size_t i = 0; i < 3 * n; ++i)
        W[i] = (float)(2 * check_rand_(&seed) - 1);
    pen_gbuffer gb = ru_gbuffer(32, 28), gp = ru_gbuffer(32, 28), gm = ru_gbuffer(32, 28);
    double l0 = chain_loss(&s, W, &gb);
    float *pos = malloc(3 * n * sizeof(float)), *color = malloc(3 * n * sizeof(float));
    float *d_color = calloc(3 * n, sizeof(float)), *d_x = calloc(3 * n, sizeof(float));
    float *d_bary = calloc(2 * n, sizeof(float));
    chain_colors(&s, &gb, pos, color);
    /* Backward: antialias -> shading -> interpolation -> barycentrics. */
    float d_pos0[12] = {0}, d_pos1[9] = {0}, *d_positions[2] = {d_pos0, d_pos1};
    CHECK(aa_bwd(&gb, &s.view, s.meshes, 2, color, 3, W, d_color, d_positions, 0) == PEN_OK);
    float aa_only = fabsf(d_pos0[0]) + fabsf(d_pos1[4]) + fabsf(d_pos0[7]);
    CHECK(aa_only > 0);
    for (size_t i = 0; i < n; ++i) {
        if (gb.surface[i] < 0) continue;
        double J[9];
        float c[3];
        shade(pos + 3 * i, c, J);
        for (int k = 0; k < 3; ++k)
            for (int r = 0; r < 3; ++r)
                d_x[3 * i + k] += (float)(J[3 * r + k] * (double)d_color[3 * i + r]);
    }
    pen_interpolate_bwd(&gb, 0, s.idx0, s.pos0, 3, d_x, d_pos0, d_bary);
    pen_interpolate_bwd(&gb, 1, s.idx1, s.pos1, 3, d_x, d_pos1, d_bary);
    CHECK(pen_raster_bary_bwd(NULL, &s.view, s.meshes, 2, &gb, d_bary, d_positions) == PEN_OK);
    const float h = 1.0f / 4096;
    int tested = 0;
    for (int m = 0; m < 2; ++m) {
        float *p = m ? s.pos1 : s.pos0;
        for (int j = 0; j < (m ? 9 : 12); ++j) {
            double fd;
            if (!fd_smooth(chain_loss, &s, W, p + j, h, l0, &gb, &gp, &gm, &fd)) continue;
            ++tested;
            CHECK_REL(d_positions[m][j], fd, 1e-2, 0.5);
        }
    }
    CHECK(tested >= 15);
    free(W), free(pos), free(color), free(d_color), free(d_x), free(d_bary);
    pen_gbuffer_free(&gb), pen_gbuffer_free(&gp), pen_gbuffer_free(&gm);
}

/* ---- Colour backward is the transpose of the forward -------------------------------------- */

static void test_color_adjoint(void) {
    ru_scene s;
    ru_scene_init(&s);
    size_t n = (size_t)s.cam.width * s.cam.height;
    pen_gbuffer gb = ru_scene_gbuffer(&s);
    unsigned long long seed = 63;
    float *c = malloc(3 * n * sizeof(float)), *g = malloc(3 * n * sizeof(float));
    float *out = malloc(3 * n * sizeof(float)), *dc = calloc(3 * n, sizeof(float));
    for (size_t i = 0; i < 3 * n; ++i) {
        c[i] = (float)check_rand_(&seed);
        g[i] = (float)(2 * check_rand_(&seed) - 1);
    }
    CHECK(aa_fwd(&gb, &s.view, s.meshes, 2, c, 3, out, 0) == PEN_OK);
    CHECK(aa_bwd(&gb, &s.view, s.meshes, 2, c, 3, g, dc, NULL, 0) == PEN_OK);
    /* <g, A c> = <A^T g, c>; and A moves some pixels. */
    CHECK_REL(dot_d(g, out, 3 * n), dot_d(dc, c, 3 * n), 1e-5, 1);
    int changed = 0;
    for (size_t i = 0; i < 3 * n; ++i)
        changed += out[i] != c[i];
    CHECK(changed > 20);
    free(c), free(g), free(out), free(dc);
    pen_gbuffer_free(&gb);
}

/* ---- The ground square's border ------------------------------------------------------------ */

/* The border blend (pen__ground_border_fwd/bwd) with the square shrunk until its far side is in
 * view: the backward is the forward's transpose (<g, A c> = <A^T g, c>, in double), A moves only
 * pixels on the border (a ground pixel beside a background one, or the reverse), each row of A is
 * a convex blend (a constant image stays constant), and without a ground nothing blends. */
static void test_ground_border_adjoint(void) {
    ru_scene s;
    ru_scene_init(&s);
    s.ground.half_size = 1.6f;
    const int W = s.cam.width, H = s.cam.height;
    const size_t n = (size_t)W * (size_t)H;
    pen_gbuffer gb = ru_scene_gbuffer(&s);
    unsigned long long seed = 64;
    float *c = malloc(3 * n * sizeof(float)), *g = malloc(3 * n * sizeof(float));
    float *out = malloc(3 * n * sizeof(float)), *dc = calloc(3 * n, sizeof(float));
    for (size_t i = 0; i < 3 * n; ++i) {
        c[i] = (float)check_rand_(&seed);
        g[i] = (float)(2 * check_rand_(&seed) - 1);
    }
    pen_context *ctx = pen_context_create();
    memcpy(out, c, 3 * n * sizeof(float)); /* (the forward blends in place) */
    CHECK(pen__ground_border_fwd(ctx, &gb, &s.view, &s.ground, out, 3) == PEN_OK);
    CHECK(pen__ground_border_bwd(ctx, &gb, &s.view, &s.ground, 3, g, dc) == PEN_OK);
    CHECK_REL(dot_d(g, out, 3 * n), dot_d(dc, c, 3 * n), 1e-6, 1);
    int changed = 0, off_border = 0;
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            const size_t i = (size_t)y * (size_t)W + (size_t)x;
            if (out[3 * i] == c[3 * i]) continue;
            ++changed;
            int beside = 0; /* a neighbour on the other side of the border */
            const int d[4][2] = {{-1, 0}, {1, 0}, {0, -1}, {0, 1}};
            for (int k = 0; k < 4; ++k) {
                const int xx = x + d[k][0], yy = y + d[k][1];
                if (xx < 0 || xx >= W || yy < 0 || yy >= H) continue;
                const int a = gb.surface[i], b = gb.surface[(size_t)yy * (size_t)W + (size_t)xx];
                beside |= (a == PEN_SURFACE_GROUND && b == PEN_SURFACE_BACKGROUND) ||
                          (a == PEN_SURFACE_BACKGROUND && b == PEN_SURFACE_GROUND);
            }
            off_border += !beside;
        }
    CHECK_MSG(changed > 10, "%d pixels blended", changed);
    CHECK_MSG(off_border == 0, "%d pixels blended off the border", off_border);
    for (size_t i = 0; i < 3 * n; ++i)
        out[i] = 0.75f;
    CHECK(pen__ground_border_fwd(ctx, &gb, &s.view, &s.ground, out, 3) == PEN_OK);
    for (size_t i = 0; i < 3 * n; ++i)
        CHECK_MSG(fabsf(out[i] - 0.75f) < 1e-6f, "pixel %zu: %g", i / 3, (double)out[i]);
    /* without a ground nothing blends */
    s.ground.enabled = 0;
    pen_gbuffer_free(&gb);
    gb = ru_scene_gbuffer(&s);
    memcpy(out, g, 3 * n * sizeof(float));
    CHECK(pen__ground_border_fwd(ctx, &gb, &s.view, &s.ground, out, 3) == PEN_OK);
    CHECK(memcmp(out, g, 3 * n * sizeof(float)) == 0);
    pen_context_destroy(ctx);
    free(c), free(g), free(out), free(dc);
    pen_gbuffer_free(&gb);
}

/* ---- Silhouettes of a closed mesh ---------------------------------------------------------- */

static void test_closed_mesh_silhouettes_only(void) {
    /* A rotated cube with a different colour per triangle: blending across its interior edges
     * would change pixels inside the silhouette; only pixels next to the outside may change. */
    float pos[24];
    for (int v = 0; v < 8; ++v) {
        double p[3] = {v & 1 ? 0.5 : -0.5, v & 2 ? 0.5 : -0.5, v & 4 ? 0.5 : -0.5};
        double a = 0.6, b = 0.4; /* rotate about y, then x */
        double x = cos(a) * p[0] + sin(a) * p[2], z = -sin(a) * p[0] + cos(a) * p[2];
        double y = cos(b) * p[1] - sin(b) * z;
        z = sin(b) * p[1] + cos(b) * z;
        pos[3 * v] = (float)x, pos[3 * v + 1] = (float)y, pos[3 * v + 2] = (float)z;
    }
    const uint32_t idx[36] = {0, 2, 3, 0, 3, 1, 4, 5, 7, 4, 7, 6, 0, 1, 5, 0, 5, 4,
                              2, 6, 7, 2, 7, 3, 0, 4, 6, 0, 6, 2, 1, 3, 7, 1, 7, 5};
    int32_t adj[36];
    CHECK(pen_raster_adjacency(NULL, 8, 12, idx, adj) == PEN_OK);
    for (int i = 0; i < 36; ++i)
        CHECK(adj[i] >= 0);
    pen_camera cam = ru_camera(40, 40, 40.0f, 0.2f, 0.3f, 3.5f, 0, 0, 0);
    pen_view view = ru_view(&cam);
    pen_raster_mesh mesh = ru_mesh(8, pos, 12, idx, adj);
    pen_gbuffer gb = ru_gbuffer(40, 40);
    CHECK(ru_raster(&view, &mesh, 1, NULL, &gb, 0) == PEN_OK);
    size_t n = 40 * 40;
    float *c = malloc(3 * n * sizeof(float)), *out = malloc(3 * n * sizeof(float));
    for (size_t i = 0; i < n; ++i)
        for (int k = 0; k < 3; ++k)
            c[3 * i + k] =
                gb.surface[i] < 0 ? 0.0f : (float)(0.1 + 0.07 * gb.triangle[i] + 0.2 * k);
    CHECK(aa_fwd(&gb, &view, &mesh, 1, c, 3, out, 0) == PEN_OK);
    int inner = 0, rim_changed = 0, tri_pairs = 0;
    for (int y = 1; y < 39; ++y)
        for (int x = 1; x < 39; ++x) {
            size_t i = (size_t)y * 40 + x;
            int nb[4] = {gb.surface[i - 1], gb.surface[i + 1], gb.surface[i - 40],
                         gb.surface[i + 40]};
            int rim = gb.surface[i] < 0 || nb[0] < 0 || nb[1] < 0 || nb[2] < 0 || nb[3] < 0;
            int diff = out[3 * i] != c[3 * i];
            if (rim) {
                rim_changed += diff;
                continue;
            }
            ++inner;
            tri_pairs += gb.triangle[i] != gb.triangle[i + 1];
            CHECK(!diff);
        }
    CHECK(inner > 300 && tri_pairs > 10 && rim_changed > 20);
    free(c), free(out);
    pen_gbuffer_free(&gb);
}

/* ---- The image sum follows the covered area ------------------------------------------------ */

static void test_area_derivative(void) {
    /* A triangle of colour 1 on 0, parallel to the image plane: the box-filtered image sum is
     * its screen area. Scaling it about its centroid by (1 + e) grows the area at 2 A per unit
     * e; translating it keeps the area. The antialiasing gradient must follow both. */
    pen_camera cam = ru_camera(48, 48, 45.0f, 0, 0, 3, 0, 0, 0);
    pen_view view = ru_view(&cam);
    const double S[3][2] = {{9.3, 7.7}, {41.2, 15.4}, {17.6, 40.1}};
    float pos[9];
    for (int k = 0; k < 3; ++k)
        ru_unproject(&view, S[k][0], S[k][1], 3.0, pos + 3 * k);
    uint32_t idx[3] = {0, 1, 2};
    int32_t adj[3];
    CHECK(pen_raster_adjacency(NULL, 3, 1, idx, adj) == PEN_OK);
    pen_raster_mesh mesh = ru_mesh(3, pos, 1, idx, adj);
    pen_gbuffer gb = ru_gbuffer(48, 48);
    CHECK(ru_raster(&view, &mesh, 1, NULL, &gb, 0) == PEN_OK);
    size_t n = 48 * 48;
    float *c = malloc(n * sizeof(float)), *ones = malloc(n * sizeof(float));
    for (size_t i = 0; i < n; ++i)
        c[i] = gb.surface[i] == 0 ? 1.0f : 0.0f, ones[i] = 1.0f;
    float d_pos[9] = {0}, *d_positions[1] = {d_pos};
    CHECK(aa_bwd(&gb, &view, &mesh, 1, c, 1, ones, NULL, d_positions, 0) == PEN_OK);
    double cen[3] = {0, 0, 0}, d_scale = 0, d_tx = 0, d_ty = 0;
    for (int k = 0; k < 3; ++k)
        for (int i = 0; i < 3; ++i)
            cen[i] += (double)pos[3 * k + i] / 3.0;
    for (int k = 0; k < 3; ++k) {
        for (int i = 0; i < 3; ++i)
            d_scale += (double)d_pos[3 * k + i] * ((double)pos[3 * k + i] - cen[i]);
        d_tx += (double)d_pos[3 * k], d_ty += (double)d_pos[3 * k + 1];
    }
    double area = 0.5 * fabs((S[1][0] - S[0][0]) * (S[2][1] - S[0][1]) -
                             (S[2][0] - S[0][0]) * (S[1][1] - S[0][1]));
    double px_per_unit = view.focal[1] / 3.0;
    /* Per edge, the scheme sums one term per pixel row (column) that the edge crosses instead
     * of integrating over its projected length; the two differ by less than one row, and each
     * term is at most one pixel of motion per pixel of translation (|slope| <= 1). So the
     * translation derivative, 0 for the true area, is bounded by one pixel per edge: 3. For
     * the scaling the terms are weighted by the distance to the centroid; this triangle
     * measures about 1% off 2A, checked at 5%. */
    CHECK_REL(d_scale, 2 * area, 0.05, 0);
    CHECK_NEAR(d_tx / px_per_unit, 0, 3.0);
    CHECK_NEAR(d_ty / px_per_unit, 0, 3.0);
    free(c), free(ones);
    pen_gbuffer_free(&gb);
}

/* ---- A real closed mesh ------------------------------------------------------------------- */

/* The bundled Spot mesh and its adjacency (NULL, with the failure recorded, if it cannot load). */
static int32_t *load_spot(pen_mesh *mesh) {
    pen_context *ctx = pen_context_create();
    pen_status st = pen_mesh_load(ctx, PEN_SOURCE_DIR "/data/meshes/spot_triangulated.obj", mesh);
    CHECK_MSG(st == PEN_OK, "%s", pen_context_error(ctx));
    pen_context_destroy(ctx);
    if (st) return NULL;
    int32_t *adj = malloc(sizeof(int32_t) * 3 * (size_t)mesh->triangle_count);
    CHECK(pen_raster_adjacency(NULL, mesh->vertex_count, mesh->triangle_count, mesh->indices,
                               adj) == PEN_OK);
    return adj;
}

static void test_spot_silhouette_fd(void) {
    /* Spot over the ground: self-occlusion (ears, legs) and silhouettes against the ground and
     * the background. The vertices with the largest gradients are checked. */
    pen_mesh mesh;
    int32_t *adj = load_spot(&mesh);
    if (!adj) return;
    flat_scene s;
    int size = check_quick_() ? 24 : 48;
    pen_camera cam = ru_camera(size, size, 35.0f, 0.9f, 1.0f, 2.5f, 0, 0.0f, 0);
    s.view = ru_view(&cam);
    s.mesh = ru_mesh(mesh.vertex_count, mesh.positions, mesh.triangle_count, mesh.indices, adj);
    pen_ground g = {1, -0.75f, {1, 1, 1}, 3};
    s.ground = &g;
    size_t n = (size_t)size * size, nv = 3 * (size_t)mesh.vertex_count;
    unsigned long long seed = 64;
    float *W = malloc(3 * n * sizeof(float)), *color = malloc(3 * n * sizeof(float));
    float *d_pos = calloc(nv, sizeof(float)), *d_positions[1] = {d_pos};
    for (size_t i = 0; i < 3 * n; ++i)
        W[i] = (float)(2 * check_rand_(&seed) - 1);
    pen_gbuffer gb = ru_gbuffer(size, size), gp = ru_gbuffer(size, size);
    pen_gbuffer gm = ru_gbuffer(size, size);
    double l0 = flat_loss(&s, W, &gb);
    flat_colors(&gb, color);
    CHECK(aa_bwd(&gb, &s.view, &s.mesh, 1, color, 3, W, NULL, d_positions, 0) == PEN_OK);
    CHECK(ru_all_finite(d_pos, nv));
    int tested = 0, nonzero = 0;
    for (int round = 0; round < 12; ++round) {
        size_t best = 0; /* the largest remaining gradient */
        for (size_t j = 0; j < nv; ++j)
            if (fabsf(d_pos[j]) > fabsf(d_pos[best])) best = j;
        if (d_pos[best] == 0) break;
        ++nonzero;
        double fd;
        if (fd_smooth(flat_loss, &s, W, mesh.positions + best, 1.0f / 4096, l0, &gb, &gp, &gm,
                      &fd)) {
            ++tested;
            CHECK_REL(d_pos[best], fd, 1e-2, 0.5);
        }
        d_pos[best] = 0;
    }
    CHECK(nonzero == 12 && tested >= 8);
    free(W), free(color), free(d_pos), free(adj);
    pen_gbuffer_free(&gb), pen_gbuffer_free(&gp), pen_gbuffer_free(&gm);
    pen_mesh_free(&mesh);
}

/* Spot from afar, its triangles about a pixel or smaller: the segment between an outline pair's
 * centres usually leaves the covering triangle through an edge the surface continues across,
 * and the silhouette it crosses is an edge of a neighbour. Every outline pair (Spot against the
 * background) must still blend (before the walk over neighbours 31% did at this size). */
static void test_small_triangles_blend(void) {
    pen_mesh mesh;
    int32_t *adj = load_spot(&mesh);
    if (!adj) return;
    const int size = check_quick_() ? 96 : 192;
    pen_camera cam = ru_camera(size, size, 35.0f, 1.8f, 2.0f, 5.0f, 0, 0.0f, 0);
    pen_view view = ru_view(&cam);
    pen_raster_mesh rm =
        ru_mesh(mesh.vertex_count, mesh.positions, mesh.triangle_count, mesh.indices, adj);
    pen_gbuffer gb = ru_gbuffer(size, size);
    CHECK(ru_raster(&view, &rm, 1, NULL, &gb, 0) == PEN_OK);
    size_t n = (size_t)size * (size_t)size;
    float *color = malloc(3 * n * sizeof(float)), *out = malloc(3 * n * sizeof(float));
    flat_colors(&gb, color);
    CHECK(aa_fwd(&gb, &view, &rm, 1, color, 3, out, 0) == PEN_OK);
    int outline = 0, blended = 0, covered = 0;
    for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x) {
            size_t i = (size_t)y * (size_t)size + (size_t)x;
            covered += gb.surface[i] == 0;
            for (int axis = 0; axis < 2; ++axis) {
                if (axis ? y + 1 == size : x + 1 == size) continue;
                size_t j = axis ? i + (size_t)size : i + 1;
                if ((gb.surface[i] == 0) == (gb.surface[j] == 0)) continue;
                ++outline;
                blended += memcmp(color + 3 * i, out + 3 * i, 3 * sizeof(float)) != 0 ||
                           memcmp(color + 3 * j, out + 3 * j, 3 * sizeof(float)) != 0;
            }
        }
    /* triangles about a pixel: 5856 of them over the covered pixels */
    CHECK_MSG(covered < 2 * mesh.triangle_count, "%d pixels for %d triangles", covered,
              mesh.triangle_count);
    CHECK_MSG(outline > size && blended >= 0.98 * outline, "%d of %d outline pairs blend", blended,
              outline);
    free(color), free(out), free(adj);
    pen_gbuffer_free(&gb);
    pen_mesh_free(&mesh);
}

/* ---- Determinism, robustness, validation --------------------------------------------------- */

static void test_threads_and_identity(void) {
    ru_scene s;
    ru_scene_init_size(&s, RU_PARALLEL_W, RU_PARALLEL_H);
    size_t n = (size_t)s.cam.width * s.cam.height;
    pen_gbuffer gb = ru_scene_gbuffer(&s);
    float *c = malloc(3 * n * sizeof(float)), *o1 = malloc(3 * n * sizeof(float));
    float *o3 = malloc(3 * n * sizeof(float)), *dc1 = calloc(3 * n, sizeof(float));
    float *dc3 = calloc(3 * n, sizeof(float));
    float *pos = malloc(3 * n * sizeof(float));
    chain_colors(&s, &gb, pos, c);
    float a0[12] = {0}, a1[9] = {0}, b0[12] = {0}, b1[9] = {0};
    float *da[2] = {a0, a1}, *db[2] = {b0, b1};
    CHECK(aa_fwd(&gb, &s.view, s.meshes, 2, c, 3, o1, 1) == PEN_OK);
    CHECK(aa_fwd(&gb, &s.view, s.meshes, 2, c, 3, o3, 3) == PEN_OK);
    CHECK(memcmp(o1, o3, 3 * n * sizeof(float)) == 0);
    CHECK(aa_bwd(&gb, &s.view, s.meshes, 2, c, 3, c, dc1, da, 1) == PEN_OK);
    CHECK(aa_bwd(&gb, &s.view, s.meshes, 2, c, 3, c, dc3, db, 3) == PEN_OK);
    CHECK(memcmp(dc1, dc3, 3 * n * sizeof(float)) == 0);
    CHECK(memcmp(a0, b0, sizeof a0) == 0 && memcmp(a1, b1, sizeof a1) == 0);
    /* Without discontinuities (a plane filling the view) the op is the identity. */
    float big[12] = {-50, -50, -1, 50, -50, -1, 50, 50, -1, -50, 50, -1};
    uint32_t qi[6] = {0, 1, 2, 0, 2, 3};
    int32_t qa[6];
    CHECK(pen_raster_adjacency(NULL, 4, 2, qi, qa) == PEN_OK);
    pen_raster_mesh plane = ru_mesh(4, big, 2, qi, qa);
    CHECK(ru_raster(&s.view, &plane, 1, NULL, &gb, 0) == PEN_OK);
    CHECK(aa_fwd(&gb, &s.view, &plane, 1, c, 3, o1, 0) == PEN_OK);
    CHECK(memcmp(o1, c, 3 * n * sizeof(float)) == 0);
    free(c), free(o1), free(o3), free(dc1), free(dc3), free(pos);
    pen_gbuffer_free(&gb);
}

static void test_degenerate_and_errors(void) {
    /* Near-plane crossings, an edge-on triangle, a zero-area one and a grazing ground. */
    pen_camera cam = ru_camera(32, 24, 60.0f, 0, 0.02f, 0.3f, 0, 0.02f, -1);
    pen_view view = ru_view(&cam);
    float pos[] = {-3, -1,   2,  3,    -1,   2,    0,    1.5f, -3,   -1,   2,     -2,
                   1,  -2,   1,  2,    2,    0.2f, 0,    -1,   0.3f, 0,    1,     -1,
                   0,  0.5f, -2, 0.2f, 0.3f, -1,   0.2f, 0.3f, -1,   0.7f, -0.1f, -1};
    uint32_t idx[12];
    for (int i = 0; i < 12; ++i)
        idx[i] = (uint32_t)i;
    int32_t adj[12];
    CHECK(pen_raster_adjacency(NULL, 12, 4, idx, adj) == PEN_OK);
    pen_raster_mesh mesh = ru_mesh(12, pos, 4, idx, adj);
    pen_ground ground = {1, 0, {1, 1, 1}, 100};
    pen_gbuffer gb = ru_gbuffer(32, 24);
    CHECK(ru_raster(&view, &mesh, 1, &ground, &gb, 0) == PEN_OK);
    size_t n = 32 * 24;
    float *c = malloc(3 * n * sizeof(float)), *out = malloc(3 * n * sizeof(float));
    float *dc = calloc(3 * n, sizeof(float)), dp[36] = {0}, *dps[1] = {dp};
    flat_colors(&gb, c);
    CHECK(aa_fwd(&gb, &view, &mesh, 1, c, 3, out, 0) == PEN_OK);
    CHECK(aa_bwd(&gb, &view, &mesh, 1, c, 3, c, dc, dps, 0) == PEN_OK);
    CHECK(ru_all_finite(out, 3 * n) && ru_all_finite(dc, 3 * n) && ru_all_finite(dp, 36));
    /* Errors: no adjacency, an adjacency entry outside the mesh (the walk would follow it), no
     * channels, size mismatch. */
    pen_context *ctx = pen_context_create();
    mesh.adjacency = NULL;
    CHECK(pen_antialias_fwd(ctx, &gb, &view, &mesh, 1, c, 3, out) == PEN_ERROR_ARGUMENT);
    CHECK(strstr(pen_context_error(ctx), "adjacency") != NULL);
    int32_t bad[12];
    memcpy(bad, adj, sizeof bad);
    bad[5] = 12;
    mesh.adjacency = bad;
    CHECK(pen_antialias_fwd(ctx, &gb, &view, &mesh, 1, c, 3, out) == PEN_ERROR_ARGUMENT);
    CHECK(strstr(pen_context_error(ctx), "adjacency[5] = 12") != NULL);
    bad[5] = -2;
    CHECK(pen_antialias_bwd(ctx, &gb, &view, &mesh, 1, c, 3, c, dc, NULL) == PEN_ERROR_ARGUMENT);
    mesh.adjacency = adj;
    CHECK(pen_antialias_bwd(ctx, &gb, &view, &mesh, 1, c, 0, c, dc, NULL) == PEN_ERROR_ARGUMENT);
    view.width = 31;
    CHECK(pen_antialias_fwd(ctx, &gb, &view, &mesh, 1, c, 3, out) == PEN_ERROR_ARGUMENT);
    pen_context_destroy(ctx);
    free(c), free(out), free(dc);
    pen_gbuffer_free(&gb);
}

RUN_TESTS(TEST(test_triangle_over_background_fd), TEST(test_full_chain_fd),
          TEST(test_ground_border_adjoint),
          TEST(test_small_triangles_blend),
          TEST(test_color_adjoint), TEST(test_closed_mesh_silhouettes_only),
          TEST(test_area_derivative), TEST(test_spot_silhouette_fd),
          TEST(test_threads_and_identity), TEST(test_degenerate_and_errors))
