/* The loss curve of `penumbra optimize`: loss.svg and loss.png, one layout drawn as SVG text
 * and as pixels (output.c writes them with the other outputs). */
#include "core/internal.h"
#include "optim/optim_internal.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---- The loss curve: loss.svg and loss.png --------------------------------------------------- */

/* Appends printf output to a growing buffer; returns 0 on exhaustion. */
typedef struct text_buf {
    char *data;
    size_t len, cap;
} text_buf;

static int put(text_buf *b, const char *fmt, ...) PEN_PRINTF(2, 3);
static int put(text_buf *b, const char *fmt, ...) {
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        int n =
            vsnprintf(b->data ? b->data + b->len : NULL, b->data ? b->cap - b->len : 0, fmt, ap);
        va_end(ap);
        if (n < 0) return 0;
        if (b->data && b->len + (size_t)n < b->cap) {
            b->len += (size_t)n;
            return 1;
        }
        size_t cap = (b->cap ? 2 * b->cap : 4096) + (size_t)n;
        char *d = realloc(b->data, cap);
        if (!d) return 0;
        b->data = d;
        b->cap = cap;
    }
}

/* One layout, drawn as SVG text and as pixels, so that the two files show the same plot: log10
 * of the loss (the run's objective, losses[]) against the run's course, whole decades on the y
 * axis. The course is the stages' (pen_optim_stage): each stage before the descent is one step
 * of STAGE_WIDTH pixels (less when several would crowd the descent out), from its loss before
 * to its loss after; the descent's iterations share the rest of the width. With several stages a
 * dashed line marks where each begins and its name heads it. A loss of 0 (or one not finite)
 * sits on the bottom line. */
enum {
    PLOT_W = 640, PLOT_H = 400, PLOT_LEFT = 70, PLOT_RIGHT = 20, PLOT_TOP = 30, PLOT_BOTTOM = 50,
    STAGE_WIDTH = 90, /* fits the longest name, "least squares", at 6 pixels a character */
    LABEL_GAP = 14    /* the least room between decade labels, in pixels */
};

typedef struct loss_plot {
    int n;         /* points */
    double *x, *y; /* their pixel coordinates */
    double lo, hi; /* the log10 range: whole decades */
    int label_step; /* decades from one label to the next */
    int regions;   /* stages drawn: boundaries and names only when there are several */
    double region_x[PEN_OPTIM_MAX_STAGES];
    char region_name[PEN_OPTIM_MAX_STAGES][24];
    double descent_x; /* where iteration 0 is; NAN without a descent */
    int iterations;
    char title[192];
} loss_plot;

static void plot_free(loss_plot *p) {
    free(p->x);
    free(p->y);
    p->x = p->y = NULL;
}

/* A stage's name as the plot prints it (and the command's summary): "least_squares" as "least
 * squares". */
static void stage_label(const char *name, char *out, size_t size) {
    snprintf(out, size, "%s", name ? name : "?");
    for (char *c = out; *c; ++c)
        if (*c == '_') *c = ' ';
}

static pen_status plot_layout(pen_context *ctx, const pen_optim_result *r, int shadows,
                              loss_plot *p) {
    memset(p, 0, sizeof *p);
    /* the stages before the descent: all but a last "adam" (a result made by hand, without
     * stages, is the descent alone) */
    int pre = r->stage_count < 0                      ? 0
              : r->stage_count > PEN_OPTIM_MAX_STAGES ? PEN_OPTIM_MAX_STAGES
                                                      : r->stage_count;
    int descent = 1;
    if (pre > 0 && r->stages[pre - 1].name && strcmp(r->stages[pre - 1].name, "adam") == 0) --pre;
    else if (pre > 0) descent = 0;
    const int it = descent ? r->iterations : 0;
    p->n = pre + it + 1;
    p->iterations = it;
    p->x = pen__malloc(ctx, (size_t)p->n, sizeof *p->x, "loss curve");
    p->y = pen__malloc(ctx, (size_t)p->n, sizeof *p->y, "loss curve");
    if (!p->x || !p->y) {
        plot_free(p);
        return PEN_ERROR_MEMORY;
    }
    for (int k = 0; k < p->n; ++k)
        p->y[k] = k < pre ? r->stages[k].loss_before : r->losses[k - pre];
    double lo = INFINITY, hi = -INFINITY;
    for (int k = 0; k < p->n; ++k)
        if (p->y[k] > 0.0 && isfinite(p->y[k])) {
            lo = fmin(lo, log10(p->y[k]));
            hi = fmax(hi, log10(p->y[k]));
        }
    if (!(lo <= hi)) lo = -1.0, hi = 0.0; /* all zero */
    lo = floor(lo), hi = ceil(hi);
    if (hi <= lo) hi = lo + 1.0;
    p->lo = lo, p->hi = hi;
    const double pw = PLOT_W - PLOT_LEFT - PLOT_RIGHT, ph = PLOT_H - PLOT_TOP - PLOT_BOTTOM;
    p->label_step = (int)fmax(1.0, ceil(LABEL_GAP * (hi - lo) / ph));
    const double sw = descent ? fmin(STAGE_WIDTH, pw / (pre + 1)) : pw / pre;
    const double x0 = PLOT_LEFT + pre * sw; /* the descent's start, or the end */
    for (int k = 0; k < p->n; ++k) {
        p->x[k] = k < pre ? PLOT_LEFT + k * sw
                          : x0 + (pw - pre * sw) * (it > 0 ? (double)(k - pre) / it : 0.0);
        const double v = p->y[k] > 0.0 && isfinite(p->y[k]) ? log10(p->y[k]) : lo;
        p->y[k] = PLOT_TOP + ph * (hi - v) / (hi - lo);
    }
    p->descent_x = descent ? x0 : (double)NAN;
    p->regions = pre + descent;
    size_t len = (size_t)snprintf(p->title, sizeof p->title, "loss (%s)",
                                  shadows ? "shadows" : "no shadows");
    for (int j = 0; j < p->regions; ++j) {
        p->region_x[j] = j < pre ? PLOT_LEFT + j * sw : x0;
        stage_label(j < pre ? r->stages[j].name : "adam", p->region_name[j],
                    sizeof p->region_name[j]);
        if (r->stage_count > 0 && len < sizeof p->title)
            len += (size_t)snprintf(p->title + len, sizeof p->title - len, "%s%s",
                                    j ? " + " : ": ", p->region_name[j]);
    }
    if (descent && len < sizeof p->title)
        snprintf(p->title + len, sizeof p->title - len, ", %d iterations", it);
    return PEN_OK;
}

/* The decade d (lo <= d <= hi) carries a label. */
static int plot_labelled(const loss_plot *p, double d) {
    return (long)(d - p->lo + 0.5) % p->label_step == 0;
}

static double plot_decade_y(const loss_plot *p, double d) {
    const double ph = PLOT_H - PLOT_TOP - PLOT_BOTTOM;
    return PLOT_TOP + ph * (p->hi - d) / (p->hi - p->lo);
}

/* loss.svg */
static pen_status loss_svg(pen_context *ctx, const loss_plot *p, char **out) {
    const double pw = PLOT_W - PLOT_LEFT - PLOT_RIGHT, ph = PLOT_H - PLOT_TOP - PLOT_BOTTOM;
    text_buf b = {NULL, 0, 0};
    int ok = put(&b,
                 "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%d\" height=\"%d\" "
                 "viewBox=\"0 0 %d %d\" font-family=\"sans-serif\" font-size=\"12\">\n"
                 "<rect width=\"%d\" height=\"%d\" fill=\"white\"/>\n"
                 "<text x=\"%d\" y=\"18\">%s</text>\n"
                 "<rect x=\"%d\" y=\"%d\" width=\"%g\" height=\"%g\" fill=\"none\" "
                 "stroke=\"#888\"/>\n",
                 PLOT_W, PLOT_H, PLOT_W, PLOT_H, PLOT_W, PLOT_H, PLOT_LEFT, p->title, PLOT_LEFT,
                 PLOT_TOP, pw, ph);
    for (double d = p->lo; ok && d <= p->hi + 1e-9; d += 1.0) {
        const double y = plot_decade_y(p, d);
        ok = put(&b, "<line x1=\"%d\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#ddd\"/>",
                 PLOT_LEFT, y, PLOT_LEFT + pw, y);
        if (ok && plot_labelled(p, d))
            ok = put(&b, "<text x=\"%d\" y=\"%.1f\" text-anchor=\"end\">1e%d</text>", PLOT_LEFT - 6,
                     y + 4, (int)d);
        ok = ok && put(&b, "\n");
    }
    for (int j = 0; ok && p->regions > 1 && j < p->regions; ++j) {
        if (j > 0)
            ok = put(&b,
                     "<line x1=\"%.1f\" y1=\"%d\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#999\" "
                     "stroke-dasharray=\"4 3\"/>",
                     p->region_x[j], PLOT_TOP, p->region_x[j], PLOT_TOP + ph);
        ok = ok && put(&b, "<text x=\"%.1f\" y=\"%d\" font-size=\"11\" fill=\"#555\">%s</text>\n",
                       p->region_x[j] + 4, PLOT_TOP + 14, p->region_name[j]);
    }
    if (ok && isfinite(p->descent_x))
        ok = put(&b,
                 "<text x=\"%.1f\" y=\"%d\" text-anchor=\"%s\">0</text>"
                 "<text x=\"%.1f\" y=\"%d\" text-anchor=\"end\">%d</text>"
                 "<text x=\"%.1f\" y=\"%d\" text-anchor=\"middle\">iteration</text>\n",
                 p->descent_x, PLOT_H - PLOT_BOTTOM + 16,
                 p->descent_x > PLOT_LEFT ? "middle" : "start", PLOT_LEFT + pw,
                 PLOT_H - PLOT_BOTTOM + 16, p->iterations, (p->descent_x + PLOT_LEFT + pw) / 2,
                 PLOT_H - 12);
    ok = ok && put(&b, "<polyline fill=\"none\" stroke=\"#c33\" stroke-width=\"1.5\" points=\"");
    for (int k = 0; ok && k < p->n; ++k)
        ok = put(&b, "%.1f,%.1f ", p->x[k], p->y[k]);
    ok = ok && put(&b, "\"/>\n</svg>\n");
    if (!ok) {
        free(b.data);
        return pen__error(ctx, PEN_ERROR_MEMORY, "loss curve: out of memory");
    }
    *out = b.data;
    return PEN_OK;
}

/* loss.png: the same plot in pixels, its text in a 5x7 bitmap font (the characters the plot
 * writes; any other is left blank). Each glyph is 7 rows of 5 bits, the leftmost column the
 * highest bit. */
typedef struct glyph {
    char c;
    unsigned char rows[7];
} glyph;

static const glyph FONT[] = {
    {'0', {0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E}},
    {'1', {0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E}},
    {'2', {0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F}},
    {'3', {0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E}},
    {'4', {0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02}},
    {'5', {0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E}},
    {'6', {0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E}},
    {'7', {0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08}},
    {'8', {0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E}},
    {'9', {0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C}},
    {'a', {0x00, 0x00, 0x0E, 0x01, 0x0F, 0x11, 0x0F}},
    {'b', {0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x1E}},
    {'c', {0x00, 0x00, 0x0E, 0x10, 0x10, 0x11, 0x0E}},
    {'d', {0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F}},
    {'e', {0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E}},
    {'f', {0x06, 0x09, 0x08, 0x1C, 0x08, 0x08, 0x08}},
    {'g', {0x00, 0x00, 0x0F, 0x11, 0x0F, 0x01, 0x0E}},
    {'h', {0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x11}},
    {'i', {0x04, 0x00, 0x0C, 0x04, 0x04, 0x04, 0x0E}},
    {'j', {0x02, 0x00, 0x06, 0x02, 0x02, 0x12, 0x0C}},
    {'k', {0x10, 0x10, 0x12, 0x14, 0x18, 0x14, 0x12}},
    {'l', {0x0C, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E}},
    {'m', {0x00, 0x00, 0x1A, 0x15, 0x15, 0x11, 0x11}},
    {'n', {0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11}},
    {'o', {0x00, 0x00, 0x0E, 0x11, 0x11, 0x11, 0x0E}},
    {'p', {0x00, 0x00, 0x1E, 0x11, 0x11, 0x1E, 0x10}},
    {'q', {0x00, 0x00, 0x0F, 0x11, 0x11, 0x0F, 0x01}},
    {'r', {0x00, 0x00, 0x16, 0x19, 0x10, 0x10, 0x10}},
    {'s', {0x00, 0x00, 0x0E, 0x10, 0x0E, 0x01, 0x1E}},
    {'t', {0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06}},
    {'u', {0x00, 0x00, 0x11, 0x11, 0x11, 0x13, 0x0D}},
    {'v', {0x00, 0x00, 0x11, 0x11, 0x11, 0x0A, 0x04}},
    {'w', {0x00, 0x00, 0x11, 0x11, 0x15, 0x15, 0x0A}},
    {'x', {0x00, 0x00, 0x11, 0x0A, 0x04, 0x0A, 0x11}},
    {'y', {0x00, 0x00, 0x11, 0x11, 0x0F, 0x01, 0x0E}},
    {'z', {0x00, 0x00, 0x1F, 0x02, 0x04, 0x08, 0x1F}},
    {'(', {0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02}},
    {')', {0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08}},
    {',', {0x00, 0x00, 0x00, 0x00, 0x04, 0x04, 0x08}},
    {'.', {0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C}},
    {'-', {0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00}},
    {'+', {0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00}},
    {':', {0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00}},
    {'/', {0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00}},
};
enum { GLYPH_ADVANCE = 6, GLYPH_HEIGHT = 7 };

/* sRGB codes of the plot's colours (as in loss.svg) */
enum { INK_BLACK, INK_TEXT, INK_FRAME, INK_GRID, INK_BOUNDARY, INK_CURVE, INKS };
static const unsigned char INK_SRGB[INKS][3] = {
    {0, 0, 0}, {0x55, 0x55, 0x55}, {0x88, 0x88, 0x88}, {0xdd, 0xdd, 0xdd}, {0x99, 0x99, 0x99},
    {0xcc, 0x33, 0x33}};

typedef struct canvas {
    pen_image *im;
    float ink[INKS][3]; /* linear: pen_image_save encodes sRGB, giving back the codes above */
} canvas;

static void dot(canvas *c, int x, int y, int ink) {
    if (x < 0 || y < 0 || x >= c->im->width || y >= c->im->height) return;
    float *d = c->im->data + 3 * ((size_t)y * (size_t)c->im->width + (size_t)x);
    memcpy(d, c->ink[ink], sizeof c->ink[ink]);
}

static void hline(canvas *c, int x0, int x1, int y, int ink) {
    for (int x = x0; x <= x1; ++x)
        dot(c, x, y, ink);
}

/* A vertical line, dashed (4 on, 3 off) or not. */
static void vline(canvas *c, int x, int y0, int y1, int ink, int dashed) {
    for (int y = y0; y <= y1; ++y)
        if (!dashed || (y - y0) % 7 < 4) dot(c, x, y, ink);
}

/* The text's top left corner at (x, y); align: 0 left, 1 centre, 2 right of x. */
static void text(canvas *c, int x, int y, const char *s, int align, int ink) {
    const int w = (int)strlen(s) * GLYPH_ADVANCE - 1;
    x -= align == 1 ? w / 2 : align == 2 ? w : 0;
    for (; *s; ++s, x += GLYPH_ADVANCE)
        for (size_t g = 0; g < sizeof FONT / sizeof FONT[0]; ++g)
            if (FONT[g].c == *s) {
                for (int row = 0; row < GLYPH_HEIGHT; ++row)
                    for (int col = 0; col < 5; ++col)
                        if (FONT[g].rows[row] & (0x10 >> col)) dot(c, x + col, y + row, ink);
                break;
            }
}

/* A segment 2 pixels wide: 2x2 stamps every half pixel along it. */
static void segment(canvas *c, double x0, double y0, double x1, double y1, int ink) {
    const int steps = (int)ceil(2.0 * fmax(fabs(x1 - x0), fabs(y1 - y0))) + 1;
    for (int k = 0; k <= steps; ++k) {
        const double t = (double)k / steps;
        const int x = (int)floor(x0 + t * (x1 - x0) - 0.5);
        const int y = (int)floor(y0 + t * (y1 - y0) - 0.5);
        dot(c, x, y, ink), dot(c, x + 1, y, ink), dot(c, x, y + 1, ink), dot(c, x + 1, y + 1, ink);
    }
}

static pen_status loss_png(pen_context *ctx, const loss_plot *p, pen_image *im) {
    pen_status s = pen_image_create(ctx, PLOT_W, PLOT_H, 3, im);
    if (s) return s;
    canvas c = {im, {{0}}};
    float code[256];
    pen__image_code_table(0, code);
    for (int k = 0; k < INKS; ++k)
        for (int ch = 0; ch < 3; ++ch)
            c.ink[k][ch] = code[INK_SRGB[k][ch]];
    for (size_t i = 0; i < (size_t)PLOT_W * PLOT_H * 3; ++i)
        im->data[i] = 1.0f; /* white */
    const int right = PLOT_W - PLOT_RIGHT, bottom = PLOT_H - PLOT_BOTTOM;
    for (double d = p->lo; d <= p->hi + 1e-9; d += 1.0) {
        const int y = (int)lround(plot_decade_y(p, d));
        hline(&c, PLOT_LEFT, right, y, INK_GRID);
        char label[32];
        snprintf(label, sizeof label, "1e%d", (int)d);
        if (plot_labelled(p, d)) text(&c, PLOT_LEFT - 6, y - 3, label, 2, INK_BLACK);
    }
    hline(&c, PLOT_LEFT, right, PLOT_TOP, INK_FRAME);
    hline(&c, PLOT_LEFT, right, bottom, INK_FRAME);
    vline(&c, PLOT_LEFT, PLOT_TOP, bottom, INK_FRAME, 0);
    vline(&c, right, PLOT_TOP, bottom, INK_FRAME, 0);
    for (int j = 1; p->regions > 1 && j < p->regions; ++j)
        vline(&c, (int)lround(p->region_x[j]), PLOT_TOP + 1, bottom - 1, INK_BOUNDARY, 1);
    for (int k = 0; k + 1 < p->n; ++k)
        segment(&c, p->x[k], p->y[k], p->x[k + 1], p->y[k + 1], INK_CURVE);
    if (p->n == 1) segment(&c, p->x[0], p->y[0], p->x[0], p->y[0], INK_CURVE);
    for (int j = 0; p->regions > 1 && j < p->regions; ++j)
        text(&c, (int)lround(p->region_x[j]) + 4, PLOT_TOP + 5, p->region_name[j], 0, INK_TEXT);
    text(&c, PLOT_LEFT, 10, p->title, 0, INK_BLACK);
    if (isfinite(p->descent_x)) {
        char n[32];
        snprintf(n, sizeof n, "%d", p->iterations);
        const int x0 = (int)lround(p->descent_x);
        text(&c, x0, bottom + 8, "0", x0 > PLOT_LEFT ? 1 : 0, INK_BLACK);
        text(&c, right, bottom + 8, n, 2, INK_BLACK);
        text(&c, (int)lround((p->descent_x + right) / 2), PLOT_H - 18, "iteration", 1, INK_BLACK);
    }
    return PEN_OK;
}

pen_status pen__optim_loss_plots(pen_context *ctx, const pen_optim_result *r, int shadows,
                                 char **svg, pen_image *png) {
    loss_plot plot;
    pen_status s = plot_layout(ctx, r, shadows, &plot);
    if (!s) s = loss_svg(ctx, &plot, svg);
    if (!s) s = loss_png(ctx, &plot, png);
    plot_free(&plot);
    return s;
}
