/* Protocol v2 delta records in C: what a tick's deltas cost the event loop.
 *
 * A line-for-line port of posecast.online.protocol.records.encode_deltas (the
 * reference, numpy), one pose at a time in double precision, the same operations in
 * the same order; tests/online/protocol/test_records.py parity-tests it against that
 * function. The numpy version costs about 2 ms for a tick of 48 players (call
 * overhead of a few hundred small array operations, on the event loop's thread);
 * this one a few microseconds a pose. Plain C, no SIMD and no fused multiply-adds:
 * it runs on every machine the module builds on, so it needs no instruction-set
 * dispatch.
 *
 * Quaternions are xyzw, Hamilton product (posecast.geometry.rotations). */
#pragma GCC optimize("fp-contract=off")

#include <math.h>
#include <string.h>

#include "pc_records.h"

#define ROT_STEP_RAD (1.0 / 512.0) /* records.ROT_STEP_RAD = 2**-9 */

static const int ROOT_WIDTHS[4] = {0, 5, 8, 14}; /* records.ROOT_WIDTHS */
static const int ROT_WIDTHS[4] = {0, 4, 7, 12};  /* records.ROT_WIDTHS */

static void qmul(const double *a, const double *b, double *o) {
    double ax = a[0], ay = a[1], az = a[2], aw = a[3];
    double bx = b[0], by = b[1], bz = b[2], bw = b[3];
    o[0] = aw * bx + ax * bw + ay * bz - az * by;
    o[1] = aw * by - ax * bz + ay * bw + az * bx;
    o[2] = aw * bz + ax * by - ay * bx + az * bw;
    o[3] = aw * bw - ax * bx - ay * by - az * bz;
}

static void conj4(const double *q, double *o) {
    o[0] = -q[0];
    o[1] = -q[1];
    o[2] = -q[2];
    o[3] = q[3];
}

/* records.quat2rotvec: the shorter way. */
static void quat2rotvec(const double *q_in, double *out) {
    double q[4];
    double s4 = q_in[3] < 0.0 ? -1.0 : 1.0;
    for (int c = 0; c < 4; c++) q[c] = s4 * q_in[c];
    double s = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
    double theta = 2.0 * atan2(s, q[3]);
    for (int c = 0; c < 3; c++) out[c] = s > 0.0 ? q[c] * (theta / s) : 0.0;
}

/* records.rotvec2quat: (v sin(t/2)/t, cos(t/2)). */
static void rotvec2quat(const double *v, double *o) {
    double theta = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    double k = theta > 0.0 ? sin(theta / 2.0) / theta : 0.0;
    for (int c = 0; c < 3; c++) o[c] = v[c] * k;
    o[3] = theta > 0.0 ? cos(theta / 2.0) : 1.0;
}

static void normalise(double *q) {
    double n = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (int c = 0; c < 4; c++) q[c] = q[c] / n;
}

/* The steps of a 3-int residual: the smallest class whose width holds all three
 * (class 0: all zero), or -1 when none does. */
static int width_class(const int64_t *r, const int *widths) {
    int64_t lo = r[0], hi = r[0];
    for (int c = 1; c < 3; c++) {
        if (r[c] < lo) lo = r[c];
        if (r[c] > hi) hi = r[c];
    }
    if (lo == 0 && hi == 0) return 0;
    for (int k = 1; k < 4; k++) {
        int64_t half = (int64_t)1 << (widths[k] - 1);
        if (lo >= -half && hi < half) return k;
    }
    return -1;
}

/* An LSB-first bit writer (numpy's packbits with bitorder="little"). */
typedef struct {
    uint8_t *out;
    int64_t bit;
} Bits;

static void put(Bits *b, int64_t value, int width) {
    for (int i = 0; i < width; i++, b->bit++)
        if ((value >> i) & 1) b->out[b->bit >> 3] |= (uint8_t)(1u << (b->bit & 7));
}

static void encode_one(const PcDeltaArgs *a, int64_t i) {
    const double *ref = a->ref_items + i * PC_REC_ITEMS * 4;
    const int64_t *step = a->step_rot + i * PC_REC_ITEMS * 3;
    const double *world = a->world + i * PC_REC_ITEMS * 4;
    double *items = a->new_items + i * PC_REC_ITEMS * 4;
    int64_t *d_rot = a->d_rot + i * PC_REC_ITEMS * 3;
    double new_world[PC_REC_ITEMS][4];
    int finite = 1;
    int64_t res[PC_REC_ITEMS + 1][3]; /* the root's residual, then the rotations' */
    for (int j = 0; j < PC_REC_ITEMS; j++) {
        /* The prediction: the reference times its last step. */
        double v[3], e[4], pred[4], target[4], u[4], w[3];
        for (int c = 0; c < 3; c++) v[c] = (double)step[3 * j + c] * ROT_STEP_RAD;
        rotvec2quat(v, e);
        qmul(ref + 4 * j, e, pred);
        int64_t p = a->parents[j];
        if (p < 0) {
            memcpy(target, world + 4 * j, sizeof(target));
        } else {
            double inv[4];
            conj4(new_world[p], inv);
            qmul(inv, world + 4 * j, target);
        }
        double ip[4];
        conj4(pred, ip);
        qmul(ip, target, u);
        quat2rotvec(u, w);
        int64_t *r = res[j + 1];
        double rv[3], er[4], q[4];
        for (int c = 0; c < 3; c++) {
            double steps = rint(w[c] / ROT_STEP_RAD);
            /* A NaN (a degenerate pose) has no integer: converting it is undefined in C
             * (numpy gives INT64_MIN). Such a pose does not fit a delta. */
            if (!(fabs(steps) <= 1e9)) {
                steps = 0.0;
                finite = 0;
            }
            r[c] = (int64_t)steps;
            rv[c] = (double)r[c] * ROT_STEP_RAD;
        }
        rotvec2quat(rv, er);
        qmul(pred, er, q);
        normalise(q);
        memcpy(items + 4 * j, q, sizeof(q));
        if (p < 0)
            memcpy(new_world[j], q, sizeof(q));
        else
            qmul(new_world[p], q, new_world[j]);
        for (int c = 0; c < 3; c++) d_rot[3 * j + c] = step[3 * j + c] + r[c];
    }
    for (int c = 0; c < 3; c++)
        res[0][c] = (a->root[3 * i + c] - a->ref_root[3 * i + c]) - a->step_root[3 * i + c];
    uint8_t *body = a->body + i * PC_REC_MAX_BYTES;
    memset(body, 0, PC_REC_MAX_BYTES);
    a->len[i] = 0;
    int64_t dseq = (a->seq[i] - a->ref_seq[i]) & 0xFFFFFFFFLL;
    if (dseq < 1 || dseq > 255 || !finite) return;
    Bits b = {body + 2, 0};
    for (int k = 0; k <= PC_REC_ITEMS; k++) {
        const int *widths = k == 0 ? ROOT_WIDTHS : ROT_WIDTHS;
        int cls = width_class(res[k], widths);
        if (cls < 0) return; /* does not fit: a keyframe instead */
        put(&b, cls, 2);
        for (int c = 0; c < 3; c++) put(&b, res[k][c], widths[cls]);
    }
    body[0] = (uint8_t)a->flags[i];
    body[1] = (uint8_t)dseq;
    a->len[i] = 2 + (b.bit + 7) / 8;
}

void pc_encode_deltas(const PcDeltaArgs *a) {
    for (int64_t i = 0; i < a->m; i++) encode_one(a, i);
}
