/* Sets of calibrated views (pen_camera_set): imported from a COLMAP text model or a NeRF-style
 * transforms.json, and read and written as the "views" JSON (docs/file-formats.md, "Views").
 *
 * COLMAP (cameras.txt, images.txt): the PINHOLE (fx fy cx cy) and SIMPLE_PINHOLE (f cx cy)
 * models, whose principal point already follows penumbra's convention (image corner at 0, pixel
 * centres at +0.5). Models with lens distortion are refused: penumbra renders a pinhole, so those
 * images must be undistorted first (COLMAP's image_undistorter writes PINHOLE cameras). An image
 * line holds IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME; the quaternion (Hamilton, w first)
 * and t are the world-to-camera pose, and the line after it (2-D points, maybe empty) is skipped.
 * Views are sorted by image name, so the set does not depend on COLMAP's id order.
 *
 * transforms.json: "frames" with "file_path" and "transform_matrix", a camera-to-world matrix in
 * OpenGL axes (x right, y up, z backwards); intrinsics "fl_x"/"fl_y" or "camera_angle_x"/
 * "camera_angle_y" (radians, full angles), "cx", "cy", "w", "h", each taken from the frame or
 * else from the top level; missing cx, cy are the image centre, a missing fl_y equals fl_x, and
 * a missing w or h is read from the image itself. A file_path without an extension that names no
 * file gets ".png" (the synthetic NeRF scenes write them so). Views keep the file's order. Lens
 * distortion (nerfstudio's and instant-ngp's k1.., p1, p2, "camera_model", "is_fisheye") is
 * refused as COLMAP's distorted models are, and the matrix's last row must be 0 0 0 1.
 *
 * Every number is checked for range and finiteness where it is read; errors name the file and
 * the line (COLMAP) or the JSON key path. Every image must exist: a views file names the images
 * a task will read.
 */
#include "core/internal.h"
#include "io/io_internal.h"
#include "penumbra/io.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

typedef pen__json_where where;

#define TEXT_MAX_BYTES ((size_t)256 << 20)

void pen_camera_set_free(pen_camera_set *set) {
    if (!set) return;
    for (int i = 0; i < set->count; ++i)
        free(set->images ? set->images[i] : NULL);
    free(set->images);
    free(set->cameras);
    memset(set, 0, sizeof *set);
}

static pen_status set_alloc(pen_context *ctx, int n, pen_camera_set *set) {
    set->cameras = pen__calloc(ctx, (size_t)(n ? n : 1), sizeof *set->cameras, "views");
    set->images = pen__calloc(ctx, (size_t)(n ? n : 1), sizeof *set->images, "view images");
    return set->cameras && set->images ? PEN_OK : PEN_ERROR_MEMORY;
}

/* "dir/name" (name as is when absolute); malloc'd. */
static char *join(pen_context *ctx, const char *dir, const char *name) {
    size_t dn = strlen(dir);
    char *base = pen__malloc(ctx, dn + 3, 1, "path");
    if (!base) return NULL;
    memcpy(base, dir, dn);
    base[dn] = '/', base[dn + 1] = 'x', base[dn + 2] = '\0'; /* a file inside dir */
    char *out = pen__io_path_resolve(ctx, base, name);
    free(base);
    return out;
}

static int file_exists(const char *path) {
    struct stat st;
    return stat(path, &st) == 0 && S_ISREG(st.st_mode);
}

/* ---- COLMAP text models ----------------------------------------------------------------------- */

typedef struct colmap_camera {
    long id;
    int width, height;
    double fx, fy, cx, cy;
} colmap_camera;

/* A COLMAP text file, whole. The line reader below ends lines at NULs like C strings do, so a
 * NUL inside the file would silently end it there and drop every image after it: refused with
 * its line instead. */
static pen_status read_text(pen_context *ctx, const char *path, char **text) {
    size_t size = 0;
    pen_status s = pen__io_read_file(ctx, path, TEXT_MAX_BYTES, text, &size);
    if (s) return s;
    const char *nul = memchr(*text, '\0', size);
    if (!nul) return PEN_OK;
    int line = 1;
    for (const char *p = *text; p < nul; ++p)
        line += *p == '\n';
    free(*text);
    *text = NULL;
    return pen__error(ctx, PEN_ERROR_PARSE, "%s:%d: NUL byte (a binary file, or a damaged one)",
                      path, line);
}

/* The next line of text (NUL-terminated in place); NULL at the end. */
static char *next_line(char **cursor, int *line_no) {
    char *p = *cursor;
    if (!p || !*p) return NULL;
    char *nl = strchr(p, '\n');
    if (nl) {
        *nl = '\0';
        *cursor = nl + 1;
    } else {
        *cursor = p + strlen(p);
    }
    size_t n = strlen(p);
    if (n && p[n - 1] == '\r') p[n - 1] = '\0';
    ++*line_no;
    return p;
}

static int blank_or_comment(const char *s) {
    while (isspace((unsigned char)*s))
        ++s;
    return *s == '\0' || *s == '#';
}

/* Reads `n` numbers from *s (advancing it); 0 if one is missing or not finite. */
static int numbers(char **s, int n, double *out) {
    for (int k = 0; k < n; ++k) {
        char *end;
        errno = 0;
        out[k] = strtod(*s, &end);
        if (end == *s || errno == ERANGE || !isfinite(out[k])) return 0;
        *s = end;
    }
    return 1;
}

static int word(char **s, char *out, size_t size) {
    while (isspace((unsigned char)**s))
        ++*s;
    size_t n = 0;
    while (**s && !isspace((unsigned char)**s)) {
        if (n + 1 < size) out[n++] = **s;
        ++*s;
    }
    out[n] = '\0';
    return n > 0 && n + 1 < size;
}

static pen_status read_colmap_cameras(pen_context *ctx, const char *path, colmap_camera **out,
                                      int *count) {
    char *text = NULL;
    pen_status s = read_text(ctx, path, &text);
    if (s) return s;
    int cap = 0, n = 0, line_no = 0;
    colmap_camera *cams = NULL;
    char *cur = text, *line;
    while (!s && (line = next_line(&cur, &line_no))) {
        if (blank_or_comment(line)) continue;
        char model[32];
        double v[3], p[4];
        char *q = line;
        if (!numbers(&q, 1, v) || !word(&q, model, sizeof model) || !numbers(&q, 2, v + 1)) {
            s = pen__error(ctx, PEN_ERROR_PARSE,
                           "%s:%d: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS...", path, line_no);
            break;
        }
        const int simple = strcmp(model, "SIMPLE_PINHOLE") == 0;
        if (!simple && strcmp(model, "PINHOLE") != 0) {
            s = pen__error(ctx, PEN_ERROR_UNSUPPORTED,
                           "%s:%d: camera model %s has lens distortion or is not a pinhole: "
                           "undistort the images first (COLMAP's image_undistorter writes "
                           "PINHOLE cameras)",
                           path, line_no, model);
            break;
        }
        if (!numbers(&q, simple ? 3 : 4, p) || !blank_or_comment(q)) {
            s = pen__error(ctx, PEN_ERROR_PARSE, "%s:%d: %s takes %d parameters", path, line_no,
                           model, simple ? 3 : 4);
            break;
        }
        if (v[0] != floor(v[0]) || fabs(v[0]) > 2e9 || v[1] != floor(v[1]) || v[1] < 1 ||
            v[1] > PEN_IMAGE_MAX_DIM || v[2] != floor(v[2]) || v[2] < 1 ||
            v[2] > PEN_IMAGE_MAX_DIM) {
            s = pen__error(ctx, PEN_ERROR_PARSE,
                           "%s:%d: camera id, width or height out of range (sizes 1 .. %d)", path,
                           line_no, PEN_IMAGE_MAX_DIM);
            break;
        }
        if (n == cap) {
            cap = cap ? 2 * cap : 16;
            colmap_camera *grown = realloc(cams, (size_t)cap * sizeof *cams);
            if (!grown || cap > PEN_CAMERA_SET_MAX) {
                free(grown ? grown : cams);
                cams = NULL;
                s = grown ? pen__error(ctx, PEN_ERROR_PARSE, "%s: more than %d cameras", path,
                                       PEN_CAMERA_SET_MAX)
                          : pen__error(ctx, PEN_ERROR_MEMORY, "%s: out of memory", path);
                break;
            }
            cams = grown;
        }
        colmap_camera *c = &cams[n++];
        c->id = (long)v[0], c->width = (int)v[1], c->height = (int)v[2];
        c->fx = p[0], c->fy = simple ? p[0] : p[1];
        c->cx = p[simple ? 1 : 2], c->cy = p[simple ? 2 : 3];
        if (!(c->fx > 0 && c->fx <= PEN_CAMERA_MAX_FOCAL && c->fy > 0 &&
              c->fy <= PEN_CAMERA_MAX_FOCAL && fabs(c->cx) <= PEN_CAMERA_MAX_PRINCIPAL &&
              fabs(c->cy) <= PEN_CAMERA_MAX_PRINCIPAL)) {
            s = pen__error(ctx, PEN_ERROR_PARSE, "%s:%d: focal length or principal point out of "
                           "range", path, line_no);
            break;
        }
    }
    free(text);
    if (s) {
        free(cams);
        return s;
    }
    *out = cams;
    *count = n;
    return PEN_OK;
}

/* Row-major rotation of a unit quaternion (w, x, y, z). */
static void quaternion_rotation(const double q[4], double R[9]) {
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    R[0] = 1 - 2 * (y * y + z * z), R[1] = 2 * (x * y - w * z), R[2] = 2 * (x * z + w * y);
    R[3] = 2 * (x * y + w * z), R[4] = 1 - 2 * (x * x + z * z), R[5] = 2 * (y * z - w * x);
    R[6] = 2 * (x * z - w * y), R[7] = 2 * (y * z + w * x), R[8] = 1 - 2 * (x * x + y * y);
}

static int by_image_name(const void *a, const void *b) {
    return strcmp(*(char *const *)a, *(char *const *)b);
}

/* Parses images.txt into set (one view per image line) against the cameras. */
static pen_status read_colmap_images(pen_context *ctx, const char *path, const char *images_dir,
                                     const colmap_camera *cams, int cam_count,
                                     pen_camera_set *set) {
    char *text = NULL;
    pen_status s = read_text(ctx, path, &text);
    if (s) return s;
    /* Count image lines first: every non-comment line after the header comments is an image
     * line followed by its points line. */
    int n = 0, line_no = 0, in_header = 1, expect_points = 0;
    char *cur = text, *line;
    for (char *p = text; *p; ++p)
        n += *p == '\n';
    n = n / 2 + 1;
    if (n > PEN_CAMERA_SET_MAX) n = PEN_CAMERA_SET_MAX;
    s = set_alloc(ctx, n, set);
    int count = 0;
    while (!s && (line = next_line(&cur, &line_no))) {
        if (in_header && blank_or_comment(line)) continue;
        in_header = 0;
        if (expect_points) { /* the 2-D points of the image above, possibly empty */
            expect_points = 0;
            continue;
        }
        if (blank_or_comment(line)) continue; /* trailing blank lines */
        double v[9];
        char *q = line;
        char name[1024];
        if (!numbers(&q, 9, v) || !word(&q, name, sizeof name) || !blank_or_comment(q)) {
            s = pen__error(ctx, PEN_ERROR_PARSE,
                           "%s:%d: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME (a "
                           "name without spaces, under 1024 bytes)",
                           path, line_no);
            break;
        }
        if (count == n) {
            s = pen__error(ctx, PEN_ERROR_PARSE, "%s: more than %d images", path,
                           PEN_CAMERA_SET_MAX);
            break;
        }
        const colmap_camera *c = NULL;
        for (int k = 0; k < cam_count && !c; ++k)
            if ((double)cams[k].id == v[8]) c = &cams[k];
        if (!c) {
            s = pen__error(ctx, PEN_ERROR_PARSE, "%s:%d: camera %.0f is not in cameras.txt", path,
                           line_no, v[8]);
            break;
        }
        double qn = sqrt(v[1] * v[1] + v[2] * v[2] + v[3] * v[3] + v[4] * v[4]);
        if (!(fabs(qn - 1.0) <= 1e-2)) {
            s = pen__error(ctx, PEN_ERROR_PARSE, "%s:%d: quaternion of norm %.4g, not 1", path,
                           line_no, qn);
            break;
        }
        double qv[4] = {v[1] / qn, v[2] / qn, v[3] / qn, v[4] / qn}, R[9];
        quaternion_rotation(qv, R);
        pen_camera *cam = &set->cameras[count];
        cam->width = c->width, cam->height = c->height;
        cam->fx = (float)c->fx, cam->fy = (float)c->fy, cam->cx = (float)c->cx,
        cam->cy = (float)c->cy;
        cam->fov_y_deg = (float)fmin(2.0 * atan(0.5 * c->height / c->fy) * (180.0 / PEN_PI),
                                     179.999);
        char why[160];
        if (!pen__io_camera_pose(R, v + 5, cam, why, sizeof why)) {
            s = pen__error(ctx, PEN_ERROR_PARSE, "%s:%d: %s", path, line_no, why);
            break;
        }
        set->images[count] = join(ctx, images_dir, name);
        if (!set->images[count]) {
            s = PEN_ERROR_MEMORY;
        } else if (!file_exists(set->images[count])) {
            s = pen__error(ctx, PEN_ERROR_IO, "%s:%d: image %s not found (the images folder is %s)",
                           path, line_no, set->images[count], images_dir);
        }
        ++count;
        set->count = count;
        expect_points = 1;
    }
    free(text);
    if (!s && count == 0) s = pen__error(ctx, PEN_ERROR_PARSE, "%s: no images", path);
    if (!s) {
        /* Sort the views by image name: cameras and names move together. */
        typedef struct {
            char *name;
            pen_camera cam;
        } pair;
        pair *p = pen__malloc(ctx, (size_t)count, sizeof *p, "views");
        if (!p) return PEN_ERROR_MEMORY;
        for (int i = 0; i < count; ++i)
            p[i].name = set->images[i], p[i].cam = set->cameras[i];
        qsort(p, (size_t)count, sizeof *p, by_image_name);
        for (int i = 0; i < count; ++i)
            set->images[i] = p[i].name, set->cameras[i] = p[i].cam;
        free(p);
    }
    return s;
}

pen_status pen_camera_set_load_colmap(pen_context *ctx, const char *model_dir,
                                      const char *images_dir, pen_camera_set *out) {
    memset(out, 0, sizeof *out);
    if (!model_dir) return pen__error(ctx, PEN_ERROR_ARGUMENT, "COLMAP import: no model folder");
    char *cameras_txt = join(ctx, model_dir, "cameras.txt");
    char *images_txt = join(ctx, model_dir, "images.txt");
    colmap_camera *cams = NULL;
    int cam_count = 0;
    pen_status s = cameras_txt && images_txt ? PEN_OK : PEN_ERROR_MEMORY;
    if (!s) s = read_colmap_cameras(ctx, cameras_txt, &cams, &cam_count);
    if (!s)
        s = read_colmap_images(ctx, images_txt, images_dir ? images_dir : model_dir, cams,
                               cam_count, out);
    free(cams);
    free(cameras_txt);
    free(images_txt);
    if (s) pen_camera_set_free(out);
    return s;
}

/* ---- transforms.json ------------------------------------------------------------------------- */

/* Number `name` of the frame, else of the top level; *found 0 when neither has it. */
static pen_status frame_number(pen_context *ctx, const where *wf, const where *wt,
                               const cJSON *frame, const cJSON *top, const char *name, double lo,
                               double hi, const char *what, double *out, int *found) {
    where w;
    const cJSON *item = pen__json_member(frame, name);
    if (item) {
        pen__json_child(wf, name, &w);
    } else {
        item = pen__json_member(top, name);
        pen__json_child(wt, name, &w);
    }
    *found = item != NULL;
    return item ? pen__json_number(ctx, &w, item, lo, hi, what, out) : PEN_OK;
}

/* Lens distortion in a transforms.json object (the top level or a frame): nerfstudio's and
 * instant-ngp's coefficients, a "camera_model" other than a pinhole, "is_fisheye". penumbra
 * renders a pinhole, so these are refused as COLMAP's distorted models are, naming the key;
 * coefficients of 0 are a pinhole's and pass. */
static pen_status pinhole_only(pen_context *ctx, const where *w, const cJSON *o) {
    static const char *const undistort =
        "undistort the images first and give their pinhole intrinsics (COLMAP's "
        "image_undistorter writes PINHOLE cameras)";
    static const char *const coeffs[] = {"k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2", NULL};
    where wk, wd = {w->file, ""};
    const char *distorted = NULL; /* the first non-zero coefficient */
    double d = 0.0;
    for (int k = 0; coeffs[k]; ++k) {
        const cJSON *item = pen__json_member(o, coeffs[k]);
        if (!item) continue;
        pen__json_child(w, coeffs[k], &wk);
        double v = 0.0;
        pen_status s = pen__json_number(ctx, &wk, item, -HUGE_VAL, HUGE_VAL,
                                        "a distortion coefficient", &v);
        if (s) return s;
        if (v != 0.0 && !distorted) distorted = coeffs[k], d = v, wd = wk;
    }
    const cJSON *model = pen__json_member(o, "camera_model");
    if (model) {
        pen__json_child(w, "camera_model", &wk);
        const char *name = NULL;
        pen_status s = pen__json_string(ctx, &wk, model, &name);
        if (s) return s;
        char with[64] = "";
        if (distorted) snprintf(with, sizeof with, " (%s %g)", distorted, d);
        if (strcmp(name, "PINHOLE") != 0 && strcmp(name, "SIMPLE_PINHOLE") != 0)
            return pen__json_error(ctx, PEN_ERROR_UNSUPPORTED, &wk,
                                   "camera model %s%s has lens distortion or is not a pinhole "
                                   "(expected \"PINHOLE\" or \"SIMPLE_PINHOLE\"): %s",
                                   name, with, undistort);
    }
    if (distorted)
        return pen__json_error(ctx, PEN_ERROR_UNSUPPORTED, &wd, "%g: lens distortion: %s", d,
                               undistort);
    const cJSON *fisheye = pen__json_member(o, "is_fisheye");
    if (fisheye && !cJSON_IsFalse(fisheye)) {
        pen__json_child(w, "is_fisheye", &wk);
        return pen__json_error(ctx, PEN_ERROR_UNSUPPORTED, &wk,
                               "a fisheye camera is not a pinhole: %s", undistort);
    }
    return PEN_OK;
}

static pen_status transforms_frame(pen_context *ctx, const char *path, const where *top_w,
                                   const cJSON *top, int i, const cJSON *frame, pen_camera *cam,
                                   char **image) {
    where wfs, wf, wp, wm;
    pen__json_child(top_w, "frames", &wfs);
    pen__json_index(&wfs, i, &wf);
    pen__json_child(&wf, "file_path", &wp);
    pen__json_child(&wf, "transform_matrix", &wm);
    pen_status s = pen__json_need_object(ctx, &wf, frame);
    if (!s) s = pinhole_only(ctx, &wf, frame);
    const char *rel = NULL;
    if (!s) s = pen__json_string(ctx, &wp, pen__json_member(frame, "file_path"), &rel);
    if (s) return s;
    *image = pen__io_path_resolve(ctx, path, rel);
    if (!*image) return PEN_ERROR_MEMORY;
    if (!file_exists(*image) && !strchr(strrchr(*image, '/') ? strrchr(*image, '/') : *image, '.')) {
        size_t n = strlen(*image);
        char *png = realloc(*image, n + 5);
        if (!png) return pen__error(ctx, PEN_ERROR_MEMORY, "%s: out of memory", path);
        memcpy(png + n, ".png", 5);
        *image = png;
    }
    if (!file_exists(*image))
        return pen__json_error(ctx, PEN_ERROR_IO, &wp, "image %s not found", *image);
    /* The camera-to-world matrix, OpenGL axes. */
    const cJSON *m = pen__json_member(frame, "transform_matrix");
    double M[16];
    if (!cJSON_IsArray(m) || cJSON_GetArraySize(m) != 4)
        return pen__json_error(ctx, PEN_ERROR_PARSE, &wm, "expected a 4x4 matrix (4 rows)");
    for (int r = 0; r < 4; ++r) {
        where wr;
        pen__json_index(&wm, r, &wr);
        float row[4];
        s = pen__json_floats(ctx, &wr, cJSON_GetArrayItem(m, r), 4, -PEN_SCENE_MAX_COORD,
                             PEN_SCENE_MAX_COORD, row);
        if (s) return s;
        for (int c = 0; c < 4; ++c)
            M[4 * r + c] = row[c];
    }
    /* (a projective last row would be read as an affine pose: refused as in a scene camera) */
    if (M[12] != 0.0 || M[13] != 0.0 || M[14] != 0.0 || M[15] != 1.0) {
        where wr;
        pen__json_index(&wm, 3, &wr);
        return pen__json_error(ctx, PEN_ERROR_PARSE, &wr,
                               "the last row of a 4x4 pose must be [0, 0, 0, 1], got [%g, %g, %g, "
                               "%g]",
                               M[12], M[13], M[14], M[15]);
    }
    /* World-to-camera in OpenCV axes: the rotation's columns are the camera's right, up and
     * backward axes, so R_cv has rows right, -up, -backward, and t = -R_cv centre. */
    double R[9], t[3], C[3] = {M[3], M[7], M[11]};
    for (int k = 0; k < 3; ++k) {
        R[k] = M[4 * k];
        R[3 + k] = -M[4 * k + 1];
        R[6 + k] = -M[4 * k + 2];
    }
    for (int r = 0; r < 3; ++r)
        t[r] = -(R[3 * r] * C[0] + R[3 * r + 1] * C[1] + R[3 * r + 2] * C[2]);
    char why[160];
    if (!pen__io_camera_pose(R, t, cam, why, sizeof why))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &wm, "%s", why);
    /* Intrinsics. */
    double w = 0, h = 0, fx = 0, fy = 0, cx = 0, cy = 0, ax = 0, ay = 0;
    int has_w, has_h, has_fx, has_fy, has_cx, has_cy, has_ax, has_ay;
    const char *dim = "an image size in pixels (1 .. 16384)";
    const char *focal = "a focal length in pixels, in (0, 1e7]";
    const char *angle = "a full field of view in radians, in (0, pi)";
    const char *centre = "a principal point coordinate in pixels";
    const double P = PEN_CAMERA_MAX_PRINCIPAL;
    where wt = *top_w;
    s = frame_number(ctx, &wf, &wt, frame, top, "w", 1, PEN_IMAGE_MAX_DIM, dim, &w, &has_w);
    if (!s) s = frame_number(ctx, &wf, &wt, frame, top, "h", 1, PEN_IMAGE_MAX_DIM, dim, &h, &has_h);
    if (!s) s = frame_number(ctx, &wf, &wt, frame, top, "fl_x", 1e-6, PEN_CAMERA_MAX_FOCAL, focal, &fx, &has_fx);
    if (!s) s = frame_number(ctx, &wf, &wt, frame, top, "fl_y", 1e-6, PEN_CAMERA_MAX_FOCAL, focal, &fy, &has_fy);
    if (!s) s = frame_number(ctx, &wf, &wt, frame, top, "camera_angle_x", 1e-6, 3.14159, angle, &ax, &has_ax);
    if (!s) s = frame_number(ctx, &wf, &wt, frame, top, "camera_angle_y", 1e-6, 3.14159, angle, &ay, &has_ay);
    if (!s) s = frame_number(ctx, &wf, &wt, frame, top, "cx", -P, P + PEN_IMAGE_MAX_DIM, centre, &cx, &has_cx);
    if (!s) s = frame_number(ctx, &wf, &wt, frame, top, "cy", -P, P + PEN_IMAGE_MAX_DIM, centre, &cy, &has_cy);
    if (s) return s;
    if (!has_w || !has_h) { /* the image knows its size */
        pen_image img;
        s = pen_image_load(ctx, *image, &img);
        if (s)
            return pen__json_error(ctx, PEN_ERROR_PARSE, &wf,
                                   "no \"w\" and \"h\", and the image could not be read: %s",
                                   pen_context_error(ctx));
        w = img.width, h = img.height;
        pen_image_free(&img);
    }
    if (w != floor(w) || h != floor(h))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &wf, "w and h must be whole pixels");
    if (!has_fx && !has_ax)
        return pen__json_error(ctx, PEN_ERROR_PARSE, &wf, "needs \"fl_x\" or \"camera_angle_x\"");
    if (!has_fx) fx = 0.5 * w / tan(0.5 * ax);
    if (!has_fy) fy = has_ay ? 0.5 * h / tan(0.5 * ay) : fx;
    cam->width = (int)w, cam->height = (int)h;
    cam->fx = (float)fx, cam->fy = (float)fy;
    cam->cx = (float)(has_cx ? cx : 0.5 * w), cam->cy = (float)(has_cy ? cy : 0.5 * h);
    cam->fov_y_deg = (float)fmin(2.0 * atan(0.5 * h / fy) * (180.0 / PEN_PI), 179.999);
    if (pen_camera_validate(ctx, cam)) return pen__json_wrap(ctx, PEN_ERROR_PARSE, &wf);
    return PEN_OK;
}

pen_status pen_camera_set_load_transforms(pen_context *ctx, const char *path,
                                          pen_camera_set *out) {
    memset(out, 0, sizeof *out);
    cJSON *root = NULL;
    pen_status s = pen__json_load(ctx, path, &root);
    if (s) return s;
    where top = {path, ""};
    const cJSON *frames = pen__json_member(root, "frames");
    where wf;
    pen__json_child(&top, "frames", &wf);
    if (!cJSON_IsObject(root)) {
        s = pen__json_error(ctx, PEN_ERROR_PARSE, &top, "expected an object");
    } else if (!cJSON_IsArray(frames) || cJSON_GetArraySize(frames) < 1 ||
               cJSON_GetArraySize(frames) > PEN_CAMERA_SET_MAX) {
        s = pen__json_error(ctx, PEN_ERROR_PARSE, &wf, "expected an array of 1 .. %d frames",
                            PEN_CAMERA_SET_MAX);
    } else if (!(s = pinhole_only(ctx, &top, root))) {
        int n = cJSON_GetArraySize(frames);
        s = set_alloc(ctx, n, out);
        int i = 0;
        const cJSON *frame;
        cJSON_ArrayForEach(frame, frames) {
            if (s) break;
            s = transforms_frame(ctx, path, &top, root, i, frame, &out->cameras[i],
                                 &out->images[i]);
            out->count = ++i;
        }
    }
    cJSON_Delete(root);
    if (s) pen_camera_set_free(out);
    return s;
}

/* ---- The views JSON ---------------------------------------------------------------------------- */

pen_status pen_camera_set_load_views(pen_context *ctx, const char *path, pen_camera_set *out) {
    memset(out, 0, sizeof *out);
    cJSON *root = NULL;
    pen_status s = pen__json_load(ctx, path, &root);
    if (s) return s;
    where top = {path, ""}, wv;
    pen__json_child(&top, "views", &wv);
    static const char *const known_top[] = {"views", NULL};
    /* "mask", "weight" and "exposure" are for tasks (src/optim/views.c); a camera set has no
     * use for them */
    static const char *const known[] = {"camera", "target", "mask", "weight", "exposure", NULL};
    const cJSON *views = pen__json_member(root, "views");
    s = pen__json_need_object(ctx, &top, root);
    if (!s) s = pen__json_known_keys(ctx, &top, root, known_top);
    if (!s && (!cJSON_IsArray(views) || cJSON_GetArraySize(views) < 1 ||
               cJSON_GetArraySize(views) > PEN_CAMERA_SET_MAX))
        s = pen__json_error(ctx, PEN_ERROR_PARSE, &wv, "expected an array of 1 .. %d views",
                            PEN_CAMERA_SET_MAX);
    if (!s) s = set_alloc(ctx, cJSON_GetArraySize(views), out);
    int i = 0;
    const cJSON *v;
    cJSON_ArrayForEach(v, views) {
        if (s) break;
        where w, wc, wt;
        pen__json_index(&wv, i, &w);
        pen__json_child(&w, "camera", &wc);
        pen__json_child(&w, "target", &wt);
        const char *rel = NULL;
        s = pen__json_need_object(ctx, &w, v);
        if (!s) s = pen__json_known_keys(ctx, &w, v, known);
        if (!s) s = pen__io_camera_parse(ctx, &wc, pen__json_member(v, "camera"), &out->cameras[i]);
        if (!s) s = pen__json_string(ctx, &wt, pen__json_member(v, "target"), &rel);
        if (!s && !(out->images[i] = pen__io_path_resolve(ctx, path, rel))) s = PEN_ERROR_MEMORY;
        out->count = ++i;
    }
    cJSON_Delete(root);
    if (s) pen_camera_set_free(out);
    return s;
}

pen_status pen_camera_set_save_views(pen_context *ctx, const char *path,
                                     const pen_camera_set *set) {
    if (!set || set->count < 1 || !set->cameras || !set->images)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: no views to write", path);
    for (int i = 0; i < set->count; ++i) {
        if (pen_camera_validate(ctx, &set->cameras[i]))
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: view %d: %s", path, i,
                              pen_context_error(ctx));
        where top = {path, ""}, wv, wc;
        pen__json_child(&top, "views", &wv);
        pen__json_index(&wv, i, &wc);
        pen__json_child(&wc, "camera", &wv);
        pen_status s = pen__io_camera_check(ctx, &wv, &set->cameras[i]);
        if (s) return s;
    }
    cJSON *root = cJSON_CreateObject();
    cJSON *views = root ? cJSON_AddArrayToObject(root, "views") : NULL;
    int ok = views != NULL;
    for (int i = 0; ok && i < set->count; ++i) {
        cJSON *v = cJSON_CreateObject();
        char *rel = v ? pen__io_path_relative(ctx, path, set->images[i]) : NULL;
        ok = v && rel && pen__json_add(v, "camera", pen__io_camera_json(&set->cameras[i])) &&
             pen__json_add(v, "target", cJSON_CreateString(rel));
        free(rel);
        if (ok) ok = cJSON_AddItemToArray(views, v);
        else cJSON_Delete(v);
    }
    char *text = ok ? cJSON_Print(root) : NULL;
    cJSON_Delete(root);
    if (!ok || !text) return pen__error(ctx, PEN_ERROR_MEMORY, "%s: out of memory", path);
    pen_status s = pen__io_write_file(ctx, path, text, strlen(text));
    free(text);
    return s;
}
