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

#endif
