/* The camera of the scene JSON (docs/file-formats.md, "Camera"): reading and writing.
 *
 * Two ways to give each half of a camera:
 * - intrinsics: "fov_y_deg" (square pixels, principal point at the image centre), or
 *   "intrinsics": {"fx", "fy", "cx", "cy"} in pixels as calibration tools write them, measured
 *   from the image's top-left corner with pixel centres at +0.5 (COLMAP's convention);
 * - extrinsics: "eye", "target" and optional "up", or "world_to_camera" in the axes of
 *   calibration tools (x right, y down, z forward: OpenCV, COLMAP), as {"R": 3 rows, "t": [3]}
 *   or as a 4x4 matrix whose last row is 0 0 0 1.
 * A world-to-camera pose is stored as the look-at camera it equals, so that everything
 * downstream (rasterizer, reference, flat API) keeps one representation: eye = -R^T t,
 * forward = R's third row, up = minus its second row, target = eye + d forward with d the
 * distance from the eye to the world origin (reconstructions centre their scene there; the
 * rasterizer's near plane is 1e-3 of this distance), or 1 when the eye is at the origin.
 * That target must itself be a coordinate a file may hold (|x| <= PEN_SCENE_MAX_COORD): a camera
 * far out looking away would put it beyond, and the scene or views file written from it would be
 * refused. So d is shortened to where the ray leaves the bound; only the direction matters, and
 * the near plane only moves closer. A centre so near the bound, looking out, that d would fall
 * below 1e-2 of its distance to the origin is refused: the float target would no longer give the
 * direction to about 1e-5 rad.
 * The writer always writes eye, target and up (a target beyond the bound, from a camera built in
 * code, pulled in along its ray the same way), and "intrinsics" for a calibrated camera; the
 * savers read what they would write back first (pen__io_camera_check), so every file penumbra
 * writes is one it reads.
 */
#include "core/internal.h"
#include "io/io_internal.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

typedef pen__json_where where;

#define COORD PEN_SCENE_MAX_COORD

/* |R R^T - I| entrywise, and det R, for the check that R is a rotation. */
static double orthonormality_error(const double R[9], double *det) {
    double err = 0.0;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            double d = 0.0;
            for (int k = 0; k < 3; ++k)
                d += R[3 * i + k] * R[3 * j + k];
            err = fmax(err, fabs(d - (i == j ? 1.0 : 0.0)));
        }
    *det = R[0] * (R[4] * R[8] - R[5] * R[7]) - R[1] * (R[3] * R[8] - R[5] * R[6]) +
           R[2] * (R[3] * R[7] - R[4] * R[6]);
    return err;
}

/* The distance along unit f, at most d, at which eye + d f still lies within the coordinate
 * bound (eye inside it). */
static double within_bound(const double eye[3], const double f[3], double d) {
    for (int k = 0; k < 3; ++k) {
        if (f[k] > 0.0) d = fmin(d, (COORD - eye[k]) / f[k]);
        if (f[k] < 0.0) d = fmin(d, (-COORD - eye[k]) / f[k]);
    }
    return d;
}

int pen__io_camera_pose(const double R[9], const double t[3], pen_camera *cam, char *why,
                        size_t why_size) {
    double det, err = orthonormality_error(R, &det);
    if (!(err <= 1e-3)) {
        snprintf(why, why_size, "R is not a rotation (|R R^T - I| = %.3g, tolerance 1e-3)", err);
        return 0;
    }
    if (!(det > 0.0)) {
        snprintf(why, why_size, "R has determinant %.3g: a reflection, not a rotation", det);
        return 0;
    }
    double eye[3], dist = 0.0;
    for (int k = 0; k < 3; ++k) {
        eye[k] = -(R[k] * t[0] + R[3 + k] * t[1] + R[6 + k] * t[2]);
        dist += eye[k] * eye[k];
    }
    dist = dist > 0.0 ? sqrt(dist) : 1.0;
    for (int k = 0; k < 3; ++k)
        if (!(fabs(eye[k]) <= COORD)) {
            snprintf(why, why_size, "the camera centre -R^T t lies beyond %g", COORD);
            return 0;
        }
    const double d = within_bound(eye, R + 6, dist);
    if (!(d >= 1e-2 * dist)) {
        snprintf(why, why_size,
                 "the camera centre lies %.3g from the coordinate bound %g and looks out of it: "
                 "no look-at target within the bound gives its direction",
                 d, COORD);
        return 0;
    }
    for (int k = 0; k < 3; ++k) { /* (+ 0.0: no -0 in the files written from them) */
        cam->eye[k] = (float)(eye[k] + 0.0);
        cam->target[k] = (float)(eye[k] + d * R[6 + k] + 0.0);
        cam->up[k] = (float)(0.0 - R[3 + k]);
    }
    return 1;
}

/* n rows of n_cols finite numbers each (a matrix given as an array of rows). */
static pen_status rows(pen_context *ctx, const where *w, const cJSON *item, int n, int n_cols,
                       double lo, double hi, double *out) {
    if (!cJSON_IsArray(item) || cJSON_GetArraySize(item) != n)
        return pen__json_error(ctx, PEN_ERROR_PARSE, w, "expected an array of %d rows, got %s", n,
                               item ? pen__json_type_name(item) : "nothing");
    for (int i = 0; i < n; ++i) {
        where wr;
        pen__json_index(w, i, &wr);
        float row[4];
        pen_status s =
            pen__json_floats(ctx, &wr, cJSON_GetArrayItem(item, i), n_cols, lo, hi, row);
        if (s) return s;
        for (int j = 0; j < n_cols; ++j)
            out[n_cols * i + j] = row[j];
    }
    return PEN_OK;
}

/* "world_to_camera" -> eye, target, up (see the top of the file). */
static pen_status parse_world_to_camera(pen_context *ctx, const where *w, const cJSON *item,
                                        pen_camera *cam) {
    double R[9], t[3];
    if (cJSON_IsObject(item)) {
        static const char *const known[] = {"R", "t", NULL};
        where wr, wt;
        pen__json_child(w, "R", &wr);
        pen__json_child(w, "t", &wt);
        pen_status s = pen__json_known_keys(ctx, w, item, known);
        if (!s) s = rows(ctx, &wr, pen__json_member(item, "R"), 3, 3, -2.0, 2.0, R);
        float tf[3];
        if (!s) s = pen__json_floats(ctx, &wt, pen__json_member(item, "t"), 3, -COORD, COORD, tf);
        if (s) return s;
        for (int k = 0; k < 3; ++k)
            t[k] = tf[k];
    } else {
        double M[16];
        pen_status s = rows(ctx, w, item, 4, 4, -COORD, COORD, M);
        if (s) return s;
        if (M[12] != 0.0 || M[13] != 0.0 || M[14] != 0.0 || M[15] != 1.0)
            return pen__json_error(ctx, PEN_ERROR_PARSE, w,
                                   "the last row of a 4x4 pose must be [0, 0, 0, 1]");
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j)
                R[3 * i + j] = M[4 * i + j];
            t[i] = M[4 * i + 3];
        }
    }
    char why[160];
    if (!pen__io_camera_pose(R, t, cam, why, sizeof why))
        return pen__json_error(ctx, PEN_ERROR_PARSE, w, "%s", why);
    return PEN_OK;
}

static pen_status parse_intrinsics(pen_context *ctx, const where *w, const cJSON *item,
                                   pen_camera *cam) {
    static const char *const known[] = {"fx", "fy", "cx", "cy", NULL};
    static const char *const focal = "a focal length in pixels, in (0, 1e7]";
    static const char *const centre = "a principal point coordinate in pixels";
    pen_status s = pen__json_need_object(ctx, w, item);
    if (!s) s = pen__json_known_keys(ctx, w, item, known);
    double v[4];
    for (int k = 0; k < 4 && !s; ++k) {
        where wk;
        pen__json_child(w, known[k], &wk);
        /* The principal point may lie off the image (a cropped sensor), within the bound. */
        const double size = k == 2 ? cam->width : cam->height;
        s = pen__json_number(ctx, &wk, pen__json_member(item, known[k]),
                             k < 2 ? 1e-6 : -PEN_CAMERA_MAX_PRINCIPAL,
                             k < 2 ? PEN_CAMERA_MAX_FOCAL : size + PEN_CAMERA_MAX_PRINCIPAL,
                             k < 2 ? focal : centre, &v[k]);
    }
    if (s) return s;
    cam->fx = (float)v[0], cam->fy = (float)v[1], cam->cx = (float)v[2], cam->cy = (float)v[3];
    /* Informational (pen_camera): the vertical field of view these intrinsics give. */
    cam->fov_y_deg = (float)fmin(2.0 * atan(0.5 * cam->height / v[1]) * (180.0 / PEN_PI), 179.999);
    return PEN_OK;
}

/* One of two keys (or key groups) must be given, not both. */
static pen_status one_of(pen_context *ctx, const where *w, int a, const char *a_name, int b,
                         const char *b_name) {
    if (a && b)
        return pen__json_error(ctx, PEN_ERROR_PARSE, w, "give %s or %s, not both", a_name,
                               b_name);
    if (!a && !b)
        return pen__json_error(ctx, PEN_ERROR_PARSE, w, "needs %s or %s", a_name, b_name);
    return PEN_OK;
}

pen_status pen__io_camera_parse(pen_context *ctx, const where *w, const cJSON *o,
                                pen_camera *cam) {
    static const char *const known[] = {"width",  "height", "fov_y_deg",  "intrinsics",
                                        "eye",    "target", "up",         "world_to_camera",
                                        NULL};
    memset(cam, 0, sizeof *cam);
    pen_status s = pen__json_need_object(ctx, w, o);
    if (!s) s = pen__json_known_keys(ctx, w, o, known);
    where ww, wh;
    pen__json_child(w, "width", &ww);
    pen__json_child(w, "height", &wh);
    const char *dim = "a positive integer (at most 16384)";
    if (!s) s = pen__json_int(ctx, &ww, pen__json_member(o, "width"), 1, PEN_IMAGE_MAX_DIM, dim,
                              &cam->width);
    if (!s) s = pen__json_int(ctx, &wh, pen__json_member(o, "height"), 1, PEN_IMAGE_MAX_DIM, dim,
                              &cam->height);
    const cJSON *intr = pen__json_member(o, "intrinsics"), *pose = pen__json_member(o, "world_to_camera");
    const int look_at = pen__json_member(o, "eye") || pen__json_member(o, "target") ||
                        pen__json_member(o, "up");
    if (!s) s = one_of(ctx, w, pen__json_member(o, "fov_y_deg") != NULL, "\"fov_y_deg\"",
                       intr != NULL, "\"intrinsics\"");
    if (!s) s = one_of(ctx, w, look_at, "\"eye\"/\"target\"/\"up\"", pose != NULL,
                       "\"world_to_camera\"");
    if (s) return s;
    if (intr) {
        where wi;
        pen__json_child(w, "intrinsics", &wi);
        s = parse_intrinsics(ctx, &wi, intr, cam);
    } else {
        where wf;
        pen__json_child(w, "fov_y_deg", &wf);
        double fov = 0;
        s = pen__json_number(ctx, &wf, pen__json_member(o, "fov_y_deg"), 1e-3, 179.999,
                             "a number of degrees in (0, 180)", &fov);
        cam->fov_y_deg = (float)fov;
    }
    if (s) return s;
    if (pose) {
        where wp;
        pen__json_child(w, "world_to_camera", &wp);
        return parse_world_to_camera(ctx, &wp, pose, cam);
    }
    where we, wt, wu;
    pen__json_child(w, "eye", &we);
    pen__json_child(w, "target", &wt);
    pen__json_child(w, "up", &wu);
    s = pen__json_floats(ctx, &we, pen__json_member(o, "eye"), 3, -COORD, COORD, cam->eye);
    if (!s) s = pen__json_floats(ctx, &wt, pen__json_member(o, "target"), 3, -COORD, COORD,
                                 cam->target);
    cam->up[0] = 0.0f, cam->up[1] = 1.0f, cam->up[2] = 0.0f;
    if (!s && pen__json_member(o, "up"))
        s = pen__json_floats(ctx, &wu, pen__json_member(o, "up"), 3, -COORD, COORD, cam->up);
    if (s) return s;
    /* A frame must exist: a viewing direction, and an up vector not along it. */
    double f[3], u[3], x[3];
    for (int k = 0; k < 3; ++k)
        f[k] = (double)cam->target[k] - (double)cam->eye[k], u[k] = cam->up[k];
    x[0] = f[1] * u[2] - f[2] * u[1];
    x[1] = f[2] * u[0] - f[0] * u[2];
    x[2] = f[0] * u[1] - f[1] * u[0];
    double nf = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
    double nu = sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
    double nx = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
    if (!(nf > 0.0)) return pen__json_error(ctx, PEN_ERROR_PARSE, &wt, "equals camera.eye");
    if (!(nx > 1e-6 * nf * nu))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &wu,
                               "zero or parallel to the viewing direction");
    return PEN_OK;
}

cJSON *pen__io_camera_json(const pen_camera *c) {
    /* A target beyond the bound (a camera built in code) moves along its ray to within it. */
    float target[3] = {c->target[0], c->target[1], c->target[2]};
    double eye[3], f[3], n = 0.0;
    for (int k = 0; k < 3; ++k) {
        eye[k] = c->eye[k], f[k] = (double)c->target[k] - eye[k];
        n += f[k] * f[k];
    }
    n = sqrt(n);
    const int out = !(fabs(target[0]) <= COORD && fabs(target[1]) <= COORD &&
                      fabs(target[2]) <= COORD);
    if (out && n > 0.0 && isfinite(n) && fabs(eye[0]) <= COORD && fabs(eye[1]) <= COORD &&
        fabs(eye[2]) <= COORD) {
        for (int k = 0; k < 3; ++k)
            f[k] /= n;
        const double d = within_bound(eye, f, n);
        for (int k = 0; k < 3; ++k)
            target[k] = (float)(eye[k] + d * f[k]);
    }
    cJSON *o = cJSON_CreateObject();
    int ok = o && pen__json_add(o, "width", cJSON_CreateNumber(c->width)) &&
             pen__json_add(o, "height", cJSON_CreateNumber(c->height));
    if (ok && c->fx > 0.0f) {
        cJSON *in = cJSON_CreateObject();
        ok = in && pen__json_add(in, "fx", pen__json_float(c->fx)) &&
             pen__json_add(in, "fy", pen__json_float(c->fy)) &&
             pen__json_add(in, "cx", pen__json_float(c->cx)) &&
             pen__json_add(in, "cy", pen__json_float(c->cy));
        if (!ok) cJSON_Delete(in);
        ok = ok && pen__json_add(o, "intrinsics", in);
    } else if (ok) {
        ok = pen__json_add(o, "fov_y_deg", pen__json_float(c->fov_y_deg));
    }
    ok = ok && pen__json_add(o, "eye", pen__json_float_array(c->eye, 3)) &&
         pen__json_add(o, "target", pen__json_float_array(target, 3)) &&
         pen__json_add(o, "up", pen__json_float_array(c->up, 3));
    if (!ok) cJSON_Delete(o);
    return ok ? o : NULL;
}

pen_status pen__io_camera_check(pen_context *ctx, const where *w, const pen_camera *cam) {
    cJSON *o = pen__io_camera_json(cam);
    if (!o) return pen__error(ctx, PEN_ERROR_MEMORY, "%s: out of memory", w->file);
    pen_camera back;
    pen_status s = pen__io_camera_parse(ctx, w, o, &back);
    cJSON_Delete(o);
    if (!s) return PEN_OK;
    char why[1024];
    snprintf(why, sizeof why, "%s", pen_context_error(ctx));
    return pen__error(ctx, s, "%s (not written: it would not read back)", why);
}
