/* Placing objects and framing the camera from the objects' posed vertices (src/scene/place.h).
 *
 * Everything is measured on the vertices the renderer draws, under the pose as pen_pose_apply
 * applies it (R (scale p) + t with R in double), so that an object stood on the ground touches it
 * to float rounding and a framed camera sees every vertex.
 *
 * Framing: with b the unit vector from the target towards the eye and r, u the camera's right and
 * up, a vertex q (relative to the target) lies at depth D - q.b from an eye at distance D, and
 * projects inside the image shrunk by 1/margin when |q.r| margin <= (D - q.b) tan_x and likewise
 * for u. So the nearest distance that shows every vertex is the largest over the vertices of
 * q.b + margin |q.r| / tan_x and q.b + margin |q.u| / tan_y: one pass, no search. tan_x and tan_y
 * are the half-extents of the image at unit depth, from the principal point to the nearer image
 * edge (a calibrated principal point off the centre frames with the nearer side). */
#include "scene/place.h"
#include "core/internal.h"
#include "core/vec.h"
#include "scene/camera.h"
#include "scene/pose_internal.h"

#include <math.h>

/* R and scale of a pose, as pen_pose_points_fwd applies them. */
static double pose_linear(const pen_pose *pose, double R[9]) {
    double w[3];
    for (int k = 0; k < 3; ++k)
        w[k] = (double)pose->rotation_axis_angle_deg[k] * (PEN_PI / 180.0);
    pen__pose_rotation_d(w, R, NULL);
    return (double)pose->scale;
}

/* Vertex i of an object, rotated and scaled (without the translation). */
static void posed_linear(const pen_object *ob, const double R[9], double s, int i, double q[3]) {
    const float *p = ob->mesh.positions + 3 * (size_t)i;
    for (int a = 0; a < 3; ++a)
        q[a] = s * (R[3 * a] * (double)p[0] + R[3 * a + 1] * (double)p[1] +
                    R[3 * a + 2] * (double)p[2]);
}

/* Bounds of the rotated, scaled vertices (no translation); 0 without vertices. */
static int linear_bounds(const pen_object *ob, double lo[3], double hi[3]) {
    for (int a = 0; a < 3; ++a)
        lo[a] = hi[a] = 0.0;
    if (ob->mesh.vertex_count <= 0 || !ob->mesh.positions) return 0;
    double R[9];
    const double s = pose_linear(&ob->pose, R);
    for (int i = 0; i < ob->mesh.vertex_count; ++i) {
        double q[3];
        posed_linear(ob, R, s, i, q);
        for (int a = 0; a < 3; ++a) {
            if (i == 0 || q[a] < lo[a]) lo[a] = q[a];
            if (i == 0 || q[a] > hi[a]) hi[a] = q[a];
        }
    }
    return 1;
}

void pen__object_bounds_d(const pen_object *ob, double lo[3], double hi[3]) {
    if (!linear_bounds(ob, lo, hi)) return;
    for (int a = 0; a < 3; ++a)
        lo[a] += (double)ob->pose.translation[a], hi[a] += (double)ob->pose.translation[a];
}

int pen__object_place(pen_object *ob, int on_ground, double ground_y, int centre) {
    double lo[3], hi[3];
    if (!linear_bounds(ob, lo, hi)) return 1;
    double t[3];
    pen__load3_d(ob->pose.translation, t);
    if (on_ground) t[1] = ground_y + t[1] - lo[1];
    if (centre) {
        t[0] -= 0.5 * (lo[0] + hi[0]);
        t[2] -= 0.5 * (lo[2] + hi[2]);
    }
    for (int a = 0; a < 3; ++a)
        if (!(fabs(t[a]) <= PEN_SCENE_MAX_COORD)) return 0;
    for (int a = 0; a < 3; ++a)
        ob->pose.translation[a] = (float)t[a];
    return 1;
}

int pen__camera_frame_objects(pen_camera *cam, const pen_object *objects, int count,
                              double azimuth_deg, double elevation_deg, double margin) {
    /* The target: the centre of the union of the objects' bounds. */
    double lo[3] = {0}, hi[3] = {0};
    int any = 0;
    for (int o = 0; o < count; ++o) {
        if (objects[o].mesh.vertex_count <= 0 || !objects[o].mesh.positions) continue;
        double l[3], h[3];
        pen__object_bounds_d(&objects[o], l, h);
        for (int a = 0; a < 3; ++a) {
            if (!any || l[a] < lo[a]) lo[a] = l[a];
            if (!any || h[a] > hi[a]) hi[a] = h[a];
        }
        any = 1;
    }
    if (!any) return 0;
    double c[3], b[3];
    for (int a = 0; a < 3; ++a)
        c[a] = 0.5 * (lo[a] + hi[a]);
    const double az = azimuth_deg * (PEN_PI / 180.0), el = elevation_deg * (PEN_PI / 180.0);
    b[0] = cos(el) * sin(az), b[1] = sin(el), b[2] = cos(el) * cos(az);

    /* The camera's frame and its half-extents at unit depth. */
    pen_camera probe = *cam;
    for (int a = 0; a < 3; ++a)
        probe.target[a] = (float)c[a], probe.eye[a] = (float)(c[a] + b[a]);
    probe.up[0] = 0.0f, probe.up[1] = 1.0f, probe.up[2] = 0.0f;
    double r[3], u[3], f[3], focal[2], cx, cy;
    pen__camera_frame_d(&probe, r, u, f);
    pen__camera_intrinsics_d(&probe, focal, &cx, &cy);
    const double tan_x = fmin(cx, (double)cam->width - cx) / focal[0];
    const double tan_y = fmin(cy, (double)cam->height - cy) / focal[1];
    if (!(tan_x > 0.0 && tan_y > 0.0)) return 0;

    double dist = 0.0, nearest = -INFINITY, radius = 0.0;
    for (int o = 0; o < count; ++o) {
        const pen_object *ob = &objects[o];
        if (ob->mesh.vertex_count <= 0 || !ob->mesh.positions) continue;
        double R[9];
        const double s = pose_linear(&ob->pose, R);
        for (int i = 0; i < ob->mesh.vertex_count; ++i) {
            double q[3];
            posed_linear(ob, R, s, i, q);
            for (int a = 0; a < 3; ++a)
                q[a] += (double)ob->pose.translation[a] - c[a];
            const double z = pen__dot_d(q, b);
            dist = fmax(dist, z + margin * fabs(pen__dot_d(q, r)) / tan_x);
            dist = fmax(dist, z + margin * fabs(pen__dot_d(q, u)) / tan_y);
            nearest = fmax(nearest, z);
            radius = fmax(radius, sqrt(pen__dot_d(q, q)));
        }
    }
    if (radius > 0.0)
        dist = fmax(dist, nearest + 0.1 * radius);
    else
        dist = 1.0; /* a single point: any distance frames it */
    double eye[3];
    for (int a = 0; a < 3; ++a) {
        eye[a] = c[a] + dist * b[a];
        if (!(fabs(eye[a]) <= PEN_SCENE_MAX_COORD && fabs(c[a]) <= PEN_SCENE_MAX_COORD)) return 0;
    }
    int apart = 0; /* in float: objects tiny against their distance from the origin */
    for (int a = 0; a < 3; ++a)
        apart |= (float)eye[a] != (float)c[a];
    if (!apart) return 0;
    for (int a = 0; a < 3; ++a)
        cam->eye[a] = (float)eye[a], cam->target[a] = (float)c[a];
    cam->up[0] = 0.0f, cam->up[1] = 1.0f, cam->up[2] = 0.0f;
    return 1;
}
