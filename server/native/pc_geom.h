/* Double-precision 3x3 helpers shared by the emit kernel (pc_impl.h, compiled once per
 * ISA level) and the shown pose's passes (pc_upper.c). Matrices are row-major
 * (m[3 * r + c]), quaternions xyzw. */
#ifndef PC_GEOM_H
#define PC_GEOM_H

#include <math.h>
#include <string.h>

/* o = a b; o may be a or b. */
static inline void pc_mm(const double *a, const double *b, double *o) {
    double t[9];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) t[3 * r + c] = a[3 * r] * b[c] + a[3 * r + 1] * b[3 + c] + a[3 * r + 2] * b[6 + c];
    memcpy(o, t, sizeof(t));
}

/* rotations.mat2quat: Shepperd's method, w >= 0. */
static inline void pc_mat2quat(const double *R, double *q) {
    double m00 = R[0], m11 = R[4], m22 = R[8], tr = m00 + m11 + m22;
    double c[4][4] = {
        {R[7] - R[5], R[2] - R[6], R[3] - R[1], 1 + tr},
        {1 + m00 - m11 - m22, R[1] + R[3], R[2] + R[6], R[7] - R[5]},
        {R[1] + R[3], 1 - m00 + m11 - m22, R[5] + R[7], R[2] - R[6]},
        {R[2] + R[6], R[5] + R[7], 1 - m00 - m11 + m22, R[3] - R[1]},
    };
    double key[4] = {tr, m00, m11, m22};
    int k = 0; /* argmax, the first of equals */
    for (int i = 1; i < 4; i++)
        if (key[i] > key[k]) k = i;
    double n = sqrt(c[k][0] * c[k][0] + c[k][1] * c[k][1] + c[k][2] * c[k][2] + c[k][3] * c[k][3]);
    double d = n > 1e-12 ? n : 1e-12, s = c[k][3] / d < 0 ? -1.0 : 1.0;
    for (int i = 0; i < 4; i++) q[i] = s * (c[k][i] / d);
}

/* geom.swing_mat: the smallest rotation taking direction a onto b (Rodrigues' formula,
 * R = c I + [v]x + v v^T / (1 + c) with v = a x b, c = a . b, on the directions
 * v / max(|v|, 1e-9), geom.unit3); opposite directions turn half a turn about a
 * perpendicular (a x x, or a x y where a is near x). */
static inline void pc_swing(const double *a, const double *b, double *R) {
    double na = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    double nb = sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
    na = na > 1e-9 ? na : 1e-9, nb = nb > 1e-9 ? nb : 1e-9;
    const double ua[3] = {a[0] / na, a[1] / na, a[2] / na}, ub[3] = {b[0] / nb, b[1] / nb, b[2] / nb};
    const double x = ua[1] * ub[2] - ua[2] * ub[1], y = ua[2] * ub[0] - ua[0] * ub[2],
                 z = ua[0] * ub[1] - ua[1] * ub[0], c = ua[0] * ub[0] + ua[1] * ub[1] + ua[2] * ub[2];
    if (c < -1.0 + 1e-9) {
        const double h[3] = {fabs(ua[0]) < 0.9 ? 1.0 : 0.0, fabs(ua[0]) < 0.9 ? 0.0 : 1.0, 0.0};
        double p[3] = {ua[1] * h[2] - ua[2] * h[1], ua[2] * h[0] - ua[0] * h[2], ua[0] * h[1] - ua[1] * h[0]};
        double n = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
        n = n > 1e-9 ? n : 1e-9;
        for (int k = 0; k < 3; k++) p[k] /= n;
        for (int r = 0; r < 3; r++)
            for (int k = 0; k < 3; k++) R[3 * r + k] = 2.0 * p[r] * p[k] - (r == k ? 1.0 : 0.0);
        return;
    }
    const double h = 1.0 / (1.0 + c), xh = x * h, yh = y * h, zh = z * h;
    R[0] = c + x * xh, R[1] = y * xh - z, R[2] = z * xh + y;
    R[3] = y * xh + z, R[4] = c + y * yh, R[5] = z * yh - x;
    R[6] = z * xh - y, R[7] = z * yh + x, R[8] = c + z * zh;
}

#endif
