/* The fixture of tests/cli_own_mesh.sh, a user's own asset that the repository does not ship, and
 * the image checks of that test. Compiled by the test with the system's C compiler, libjpeg and
 * libpng (the build's own dependencies).
 *
 *   own_mesh_fixture write DIR
 *       DIR/chair.obj   a chair of boxes in centimetres (45 x 95 x 45), each box closed, placed
 *                       off the origin (its feet at y = 30) as modelling tools often leave it;
 *                       UVs, one material through mtllib
 *       DIR/chair.mtl   material 'wood': map_Kd wood.jpg
 *       DIR/wood.jpg    a 64 x 64 red-brown striped texture (JPEG, written with libjpeg)
 *       DIR/sky.hdr     a 512 x 256 equirectangular sky (Radiance RGBE, flat scanlines): a blue
 *                       gradient over a dark ground and a sun of 2 degrees' radius at elevation
 *                       45 degrees, azimuth 60 degrees (from +Z towards +X)
 *   own_mesh_fixture mask MASK.png RENDER.png
 *       prints "objects F centre C border B red R": F the fraction of the image the object
 *       covers (mask > 0.5), C the fraction of the central 10 % x 10 % window it covers, B its
 *       pixels on the image's outermost rows and columns, R the mean red over the mean green of
 *       its pixels in the render (the texture's colour, where a lost material gives grey, 1). */
#include <stddef.h>
#include <stdio.h> /* before jpeglib.h, which uses size_t and FILE */

#include <jpeglib.h>
#include <math.h>
#include <png.h>
#include <stdlib.h>
#include <string.h>

#define PI 3.14159265358979323846

static FILE *open_out(const char *dir, const char *name) {
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "wb");
    if (!f) {
        perror(path);
        exit(1);
    }
    return f;
}

/* A closed box [x0, x1] x [y0, y1] x [z0, z1]: 8 vertices, 6 quads with UVs 0..1, outward. */
static void box(FILE *f, int *base, double x0, double y0, double z0, double x1, double y1,
                double z1) {
    for (int i = 0; i < 8; ++i)
        fprintf(f, "v %g %g %g\n", i & 1 ? x1 : x0, i & 2 ? y1 : y0, i & 4 ? z1 : z0);
    static const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                                    {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
    for (int q = 0; q < 6; ++q) {
        fputc('f', f);
        for (int k = 0; k < 4; ++k)
            fprintf(f, " %d/%d", *base + quads[q][k], k + 1);
        fputc('\n', f);
    }
    *base += 8;
}

static void write_chair(const char *dir) {
    FILE *f = open_out(dir, "chair.obj");
    fprintf(f, "# a chair in centimetres, feet at y = 30\nmtllib chair.mtl\n"
               "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl wood\n");
    int base = 1;
    const double y = 30.0, x = 10.0;                                /* off the origin */
    box(f, &base, x - 22.5, y + 45, -22.5, x + 22.5, y + 50, 22.5); /* seat */
    for (int i = 0; i < 4; ++i) {                                   /* legs, into the seat */
        const double lx = x + (i & 1 ? 17.5 : -21.5), lz = i & 2 ? 17.5 : -21.5;
        box(f, &base, lx, y, lz, lx + 4, y + 46, lz + 4);
    }
    box(f, &base, x - 22.5, y + 49, -22.5, x + 22.5, y + 95, -18.5); /* back, into the seat */
    fclose(f);
    f = open_out(dir, "chair.mtl");
    fprintf(f, "newmtl wood\nKd 1 1 1\nmap_Kd wood.jpg\n");
    fclose(f);
}

static void write_texture(const char *dir) {
    FILE *f = open_out(dir, "wood.jpg");
    struct jpeg_compress_struct c;
    struct jpeg_error_mgr err;
    c.err = jpeg_std_error(&err);
    jpeg_create_compress(&c);
    jpeg_stdio_dest(&c, f);
    c.image_width = 64, c.image_height = 64, c.input_components = 3, c.in_color_space = JCS_RGB;
    jpeg_set_defaults(&c);
    jpeg_set_quality(&c, 95, TRUE);
    jpeg_start_compress(&c, TRUE);
    unsigned char row[64 * 3];
    for (int yy = 0; yy < 64; ++yy) {
        for (int xx = 0; xx < 64; ++xx) {
            const double stripe = 0.8 + 0.2 * sin(xx * 0.6 + 0.3 * sin(yy * 0.2));
            row[3 * xx] = (unsigned char)(210 * stripe);
            row[3 * xx + 1] = (unsigned char)(70 * stripe);
            row[3 * xx + 2] = (unsigned char)(45 * stripe);
        }
        JSAMPROW r = row;
        jpeg_write_scanlines(&c, &r, 1);
    }
    jpeg_finish_compress(&c);
    jpeg_destroy_compress(&c);
    fclose(f);
}

static void rgbe(const double rgb[3], unsigned char out[4]) {
    const double v = fmax(rgb[0], fmax(rgb[1], rgb[2]));
    if (v < 1e-32) {
        memset(out, 0, 4);
        return;
    }
    int e;
    const double scale = frexp(v, &e) * 256.0 / v;
    for (int k = 0; k < 3; ++k)
        out[k] = (unsigned char)(rgb[k] * scale);
    out[3] = (unsigned char)(e + 128);
}

static void write_sky(const char *dir) {
    const int w = 512, h = 256;
    const double el = 45.0 * PI / 180.0, az = 60.0 * PI / 180.0, radius = 2.0 * PI / 180.0;
    const double sun[3] = {cos(el) * sin(az), sin(el), cos(el) * cos(az)};
    /* Irradiance 3 from the disk: radiance E / (pi sin^2 b). */
    const double sun_radiance = 3.0 / (PI * sin(radius) * sin(radius));
    FILE *f = open_out(dir, "sky.hdr");
    fprintf(f, "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n", h, w);
    for (int yy = 0; yy < h; ++yy)
        for (int xx = 0; xx < w; ++xx) {
            /* penumbra/envmap.h: dir(u, v) = (-sin t sin p, cos t, sin t cos p). */
            const double t = PI * (yy + 0.5) / h, p = 2.0 * PI * (xx + 0.5) / w;
            const double d[3] = {-sin(t) * sin(p), cos(t), sin(t) * cos(p)};
            double c[3];
            if (d[1] > 0.0) {
                c[0] = 0.25 + 0.15 * (1.0 - d[1]), c[1] = 0.4 + 0.1 * (1.0 - d[1]), c[2] = 0.7;
            } else {
                c[0] = 0.12, c[1] = 0.11, c[2] = 0.1;
            }
            if (acos(fmin(1.0, d[0] * sun[0] + d[1] * sun[1] + d[2] * sun[2])) < radius)
                c[0] = c[1] = c[2] = sun_radiance;
            unsigned char px[4];
            rgbe(c, px);
            fwrite(px, 1, 4, f);
        }
    fclose(f);
}

static unsigned char *read_png(const char *path, png_uint_32 format, int *w, int *h) {
    png_image img;
    memset(&img, 0, sizeof img);
    img.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_file(&img, path)) {
        fprintf(stderr, "%s: %s\n", path, img.message);
        exit(1);
    }
    img.format = format;
    unsigned char *px = malloc(PNG_IMAGE_SIZE(img));
    if (!px || !png_image_finish_read(&img, NULL, px, 0, NULL)) {
        fprintf(stderr, "%s: %s\n", path, img.message);
        exit(1);
    }
    *w = (int)img.width, *h = (int)img.height;
    return px;
}

static int mask_stats(const char *mask_path, const char *render_path) {
    int w, h, rw, rh;
    unsigned char *m = read_png(mask_path, PNG_FORMAT_GRAY, &w, &h);
    unsigned char *r = read_png(render_path, PNG_FORMAT_RGB, &rw, &rh);
    if (rw != w || rh != h) {
        fprintf(stderr, "%s and %s differ in size\n", mask_path, render_path);
        return 1;
    }
    long in = 0, centre = 0, centre_all = 0, border = 0;
    double red = 0.0, green = 0.0;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const int on = m[(size_t)y * w + x] > 127;
            const int c = fabs(x + 0.5 - 0.5 * w) < 0.05 * w && fabs(y + 0.5 - 0.5 * h) < 0.05 * h;
            centre_all += c;
            if (!on) continue;
            ++in, centre += c;
            border += x == 0 || y == 0 || x == w - 1 || y == h - 1;
            red += r[3 * ((size_t)y * w + x)], green += r[3 * ((size_t)y * w + x) + 1];
        }
    printf("objects %.4f centre %.4f border %ld red %.3f\n", (double)in / ((double)w * h),
           centre_all ? (double)centre / centre_all : 0.0, border, green > 0 ? red / green : 0.0);
    free(m), free(r);
    return 0;
}

int main(int argc, char **argv) {
    if (argc == 3 && !strcmp(argv[1], "write")) {
        write_chair(argv[2]);
        write_texture(argv[2]);
        write_sky(argv[2]);
        return 0;
    }
    if (argc == 4 && !strcmp(argv[1], "mask")) return mask_stats(argv[2], argv[3]);
    fprintf(stderr, "usage: own_mesh_fixture write DIR | mask MASK.png RENDER.png\n");
    return 2;
}
